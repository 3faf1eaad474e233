"""Downloads: a failed fetch names the URL and the config key of a local copy; nothing is left behind."""
import hashlib

import pytest

from cvsim6.data import downloads
from cvsim6.errors import DownloadError, UserFacingError


def test_failed_download_names_url_and_local_key(tmp_path):
    url = "http://127.0.0.1:9/EHR_dataset.csv"  # discard port: refused at once, no traffic leaves the machine
    out = tmp_path / "resources" / "EHR_dataset.csv"
    with pytest.raises(DownloadError) as info:
        downloads.download_checked(url, "0" * 64, out, local_key="ehr_data.path")
    message = str(info.value)
    assert url in message and "ehr_data.path" in message
    assert isinstance(info.value, UserFacingError)
    assert not out.exists() and not out.with_name(out.name + ".part").exists()


def test_file_url_download_is_checked(tmp_path):
    src = tmp_path / "origin.csv"
    src.write_bytes(b"a,b\n1,2\n")
    digest = hashlib.sha256(src.read_bytes()).hexdigest()
    out = tmp_path / "copy.csv"
    downloads.download_checked(src.as_uri(), digest, out)
    assert out.read_bytes() == src.read_bytes()
    with pytest.raises(downloads.ChecksumError, match="differs from the expected"):
        downloads.download_checked(src.as_uri(), "f" * 64, tmp_path / "bad.csv")
    assert not (tmp_path / "bad.csv").exists()
