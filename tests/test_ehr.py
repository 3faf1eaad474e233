"""The EHR loader: layout checks, units, patient selection."""
from pathlib import Path

import pandas as pd
import pytest

from conftest import LOCAL_EHR_CSV, needs_local_ehr
from cvsim6.data import downloads
from cvsim6.data import ehr
from cvsim6 import registry


def synthetic(path, edit=None, n_patients=84):
    """A file in the EHR layout with known values: feature i, patient j -> i + j/100."""
    rows = []
    for i, name in enumerate(ehr.EHR_FEATURES):
        cells = [f"{i + j / 100:.2f}" for j in range(1, n_patients + 1)]
        cells[4] = "none"  # patient 5 misses everything
        rows.append([name] + cells)
    if edit:
        edit(rows)
    Path(path).write_text("\n".join(",".join(r) for r in rows) + "\n")
    return path


def test_synthetic_file_units_and_mapping(tmp_path):
    out = ehr.ehr_outputs(synthetic(tmp_path / "e.csv"))
    assert list(out.columns) == list(registry.OUTPUT_NAMES)
    assert list(out.index[:3]) == [1, 2, 3]
    assert out.loc[3, "P_r_dia"] == pytest.approx(7.03)  # row 7
    assert out.loc[3, "P_pa_sys"] == pytest.approx(24.03)  # row 24
    assert out.loc[3, "LVEF"] == pytest.approx(0.2103)  # row 21, percent -> fraction
    assert out.loc[5].isna().all()
    sel = ehr.select_patients(out)
    assert 5 not in sel.index and len(sel) == 83


@pytest.mark.parametrize("edit, message", [
    (lambda r: r[3].__setitem__(17, "abc"), r"row 3 \(cardiac_output\), patient 17: value 'abc' is neither a number nor 'none'"),
    (lambda r: r[9].__setitem__(2, "nan"), r"row 9 \(rvedp\), patient 2: value 'nan'"),
    (lambda r: r[6].__setitem__(0, "cvp_typo"), r"row 6 is feature 'cvp_typo', expected 'cvp'"),
    (lambda r: r.pop(), r"expected 26 rows x 85 columns .* found 25 x 85"),
])
def test_broken_files_name_row_and_patient(tmp_path, edit, message):
    with pytest.raises(ehr.EHRFormatError, match=message):
        ehr.read_ehr(synthetic(tmp_path / "e.csv", edit))


def test_selection_threshold_is_more_than_ten(tmp_path):
    def keep(n_present):
        def edit(rows):
            # patient 1 keeps only the first n_present outputs
            present = [ehr.OUTPUT_ROWS[o][0] for o in registry.OUTPUT_NAMES[:n_present]]
            for i, r in enumerate(rows):
                if i not in present:
                    r[1] = "none"
        return edit
    for n, selected in ((10, False), (11, True)):
        out = ehr.ehr_outputs(synthetic(tmp_path / f"e{n}.csv", keep(n)))
        assert (1 in ehr.select_patients(out).index) is selected


@needs_local_ehr
def test_real_file_selects_46_patients_with_the_paper_counts(tmp_path):
    real = LOCAL_EHR_CSV
    assert downloads.sha256_of(real) == "5beb040de24c2b6abad0963c002584957a7f422be084ccd7654c5c501b7e48ee"
    out = ehr.ehr_outputs(real)
    sel = ehr.select_patients(out)
    assert len(out) == 84 and len(sel) == 46
    paper_counts = [46, 46, 46, 44, 11, 46, 46, 44, 46, 3, 0, 3, 45, 46, 46, 46]
    assert [int(sel[c].notna().sum()) for c in registry.OUTPUT_NAMES] == paper_counts
    assert sel["LVEF"].dropna().between(0, 1).all()
    ehr.write_patient_selection(str(real), str(tmp_path / "p.csv"), str(tmp_path / "c.csv"), str(tmp_path / "c.md"))
    assert len(pd.read_csv(tmp_path / "p.csv")) == 46
