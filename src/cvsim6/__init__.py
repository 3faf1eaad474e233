"""CVSim-6 hemodynamics, inVAErt networks and the reproducible study around them."""
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("cvsim6")
except PackageNotFoundError:  # running from a source tree without install
    __version__ = "0.0.0+unknown"
