"""The inVAErt networks for CVSim-6: emulator, Real-NVP density estimator, encoder/decoder.

Shapes and spaces: ``v`` are model parameters, (N, 23), registry order; ``y`` clinical outputs,
(N, 16). Every network works in standardized space and carries its own scalers; methods named
``*_physical``/``predict``/``invert`` take and return physical (clinical) units.

Modules: :mod:`~cvsim6.nets.layers` (MLP, standardizers), :mod:`~cvsim6.nets.emulator`,
:mod:`~cvsim6.nets.flow`, :mod:`~cvsim6.nets.encoder_decoder` (with its loss and the training
noise), :mod:`~cvsim6.nets.io` (one ``.pt`` file per network) and
:mod:`~cvsim6.nets.published` (the paper's own networks, converted). The names below are the
architecture's public API, re-exported so that ``from cvsim6 import nets`` reaches them.
"""
from cvsim6.nets.emulator import Emulator, emulator_loss
from cvsim6.nets.encoder_decoder import (DEFAULT_CORRECTOR_STEPS, EncoderDecoder, draw_noise,
                                         encoder_decoder_loss, kl_divergence, make_reevaluator,
                                         squared_error)
from cvsim6.nets.flow import AffineCoupling, FlowBatchNorm, RealNVP, flow_nll
from cvsim6.nets.io import FORMAT, MODEL_CLASSES, build_model, load_model, read_info, save_model
from cvsim6.nets.layers import MLP, LogStandardizer, Standardizer, count_parameters

__all__ = [
    "AffineCoupling", "DEFAULT_CORRECTOR_STEPS", "Emulator", "EncoderDecoder", "FORMAT", "FlowBatchNorm",
    "LogStandardizer", "MLP", "MODEL_CLASSES", "RealNVP", "Standardizer", "build_model", "count_parameters",
    "draw_noise", "emulator_loss", "encoder_decoder_loss", "flow_nll", "kl_divergence", "load_model",
    "make_reevaluator", "read_info", "save_model", "squared_error",
]
