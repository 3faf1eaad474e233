"""Files fetched from their public origin and checked against a SHA-256 digest."""
from __future__ import annotations

import hashlib
import logging
import urllib.error
import urllib.request
from pathlib import Path

from cvsim6.errors import DownloadError

log = logging.getLogger(__name__)


class ChecksumError(ValueError):
    """A file is missing or its SHA-256 differs from the expected one; the message names both."""


def sha256_of(path: str | Path) -> str:
    """Hex SHA-256 digest of the file at ``path``."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def check_sha256(path: str | Path, sha256: str, what: str = "") -> None:
    """Raise :class:`ChecksumError` if ``path`` is missing or its digest is not ``sha256``.

    ``what`` names the setting or origin the expectation comes from, for the message.
    """
    path = Path(path)
    hint = f" ({what})" if what else ""
    if not path.is_file():
        raise ChecksumError(f"{path}: file not found; expected a file with SHA-256 {sha256}{hint}")
    got = sha256_of(path)
    if got != sha256:
        raise ChecksumError(f"{path}: SHA-256 {got} differs from the expected {sha256}{hint}")


def download_checked(url: str, sha256: str, output: str | Path, what: str = "", local_key: str = "") -> None:
    """Download ``url`` to ``output`` and check its SHA-256; on a mismatch nothing is left
    at ``output`` (the download goes to ``output.part`` first). A failed download raises
    :class:`~cvsim6.errors.DownloadError` naming the URL and ``local_key``, the config key
    that points the workflow at a local copy instead."""
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    tmp = output.with_name(output.name + ".part")
    log.info("downloading %s", url)
    try:
        with urllib.request.urlopen(url, timeout=60) as r, open(tmp, "wb") as fh:  # noqa: S310
            fh.write(r.read())
    except (urllib.error.URLError, OSError) as e:
        tmp.unlink(missing_ok=True)
        reason = getattr(e, "reason", None) or e
        avoid = f"; offline, set {local_key} to a local copy (a second --configfile)" if local_key else ""
        raise DownloadError(f"could not download {url} ({reason}){avoid}") from e
    try:
        check_sha256(tmp, sha256, what or url)
    except ChecksumError:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(output)
