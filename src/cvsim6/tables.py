"""The paper's model tables (Table 1: inputs, Table 2: outputs), built from the registry.

Every name, unit, default and noise level comes from :mod:`cvsim6.registry`;
nothing is retyped here. Tables are written twice: as CSV (full precision,
for machines) and as Markdown (rounded like the paper, for people).
"""
from __future__ import annotations

import math
from numbers import Integral, Real
from pathlib import Path

import pandas as pd

from cvsim6 import registry

__all__ = [
    "format_number",
    "to_markdown",
    "write_table",
    "input_parameter_table",
    "output_parameter_table",
    "write_input_table",
    "write_output_table",
]


def format_number(x: object) -> str:
    """Format one table cell the way the paper does.

    Integers print as such; floats with 0.1 <= |x| < 1e5 get two decimals
    (``72.00``, ``0.33``, ``1333.22``); smaller or larger ones use scientific
    notation with three significant digits (``7.50e-02``, ``3.00e-04``), so no
    value loses more than its third digit. Anything else prints as ``str``.
    """
    if isinstance(x, bool) or not isinstance(x, Real):
        return str(x)
    if isinstance(x, Integral):
        return str(int(x))
    x = float(x)
    if math.isnan(x):
        return ""
    if x == 0.0:
        return "0.00"
    if 0.1 <= abs(x) < 1e5:
        return f"{x:.2f}"
    return f"{x:.2e}"


def to_markdown(df: pd.DataFrame, caption: str | None = None) -> str:
    """A GitHub-flavoured Markdown table of ``df`` (index dropped), caption above it."""

    def cell(value: object) -> str:
        return format_number(value).replace("|", r"\|").replace("\n", " ")

    header = [str(c) for c in df.columns]
    rows = [[cell(v) for v in row] for row in df.itertuples(index=False, name=None)]
    lines = []
    if caption:
        lines += [f"**{caption}**", ""]
    lines.append("| " + " | ".join(header) + " |")
    lines.append("|" + "|".join("---" for _ in header) + "|")
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def write_table(df: pd.DataFrame, csv: str | Path, md: str | Path, caption: str | None = None) -> None:
    """Write ``df`` as CSV (full precision, no index) and as a Markdown table."""
    for path in (csv, md):
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(csv, index=False)
    Path(md).write_text(to_markdown(df, caption), encoding="utf-8")


def input_parameter_table() -> pd.DataFrame:
    """Table 1 of the paper: the 23 inputs with defaults in clinical and CGS units."""
    return pd.DataFrame(
        {
            "Num.": range(1, registry.N_PARAMETERS + 1),
            "Name": [p.name for p in registry.PARAMETERS],
            "Description": [p.description for p in registry.PARAMETERS],
            "Default (clinical)": [p.default for p in registry.PARAMETERS],
            "Unit (clinical)": [p.unit for p in registry.PARAMETERS],
            "Default (CGS)": [p.default * p.cgs_factor for p in registry.PARAMETERS],
            "Unit (CGS)": [p.cgs_unit for p in registry.PARAMETERS],
        }
    )


def output_parameter_table() -> pd.DataFrame:
    """Table 2 of the paper: the 16 outputs, how they are computed, and their noise std."""
    return pd.DataFrame(
        {
            "Num.": range(1, registry.N_OUTPUTS + 1),
            "Name": [o.name for o in registry.OUTPUTS],
            "Description": [o.description for o in registry.OUTPUTS],
            "Calculation": [o.calculation for o in registry.OUTPUTS],
            "Unit": [o.unit for o in registry.OUTPUTS],
            "Noise std": [o.noise_std for o in registry.OUTPUTS],
        }
    )


def write_input_table(csv: str | Path, md: str | Path) -> None:
    """Write Table 1 (model inputs) to ``csv`` and ``md``."""
    write_table(
        input_parameter_table(),
        csv,
        md,
        caption=f"CVSim-6 input parameters and defaults (1 mmHg = {registry.MMHG_TO_BARYE} Barye).",
    )


def write_output_table(csv: str | Path, md: str | Path) -> None:
    """Write Table 2 (model outputs and measurement-noise std) to ``csv`` and ``md``."""
    write_table(
        output_parameter_table(),
        csv,
        md,
        caption="CVSim-6 outputs and the standard deviation of their measurement noise.",
    )


def network_tables(training: dict, study: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The paper's appendix-B tables (architectures, schedules) for the config in use.

    Parameter counts are those of the networks built from the config, with the
    paper's counts beside them.
    """
    from . import networks as nw
    from .paper_values import PARAMETER_COUNTS

    cfg = training["studies"][study]
    e, f, d = cfg["emulator"], cfg["flow"], cfg["encoder_decoder"]
    ed = nw.EncoderDecoder(latent_dim=d["latent_dim"], encoder_hidden=d["encoder_hidden"],
                           encoder_layers=d["encoder_layers"], decoder_hidden=d["decoder_hidden"],
                           decoder_layers=d["decoder_layers"])
    counts = {
        "NN_e": nw.count_parameters(nw.Emulator(e["hidden"], e["layers"])),
        "NN_v": nw.count_parameters(ed.encoder),
        "NN_d": nw.count_parameters(ed.decoder),
        "NN_f": nw.count_parameters(nw.RealNVP(hidden=f["hidden"], blocks=f["blocks"],
                                               layers_per_block=f["layers_per_block"],
                                               batchnorm=bool(f["batchnorm"]))),
    }
    arch = pd.DataFrame([
        {"Module": "NN_e", "Hidden units": e["hidden"], "Layers": e["layers"], "Blocks": "",
         "Activation": "SiLU", "BatchNorm": "", "Parameters": counts["NN_e"]},
        {"Module": "NN_v", "Hidden units": d["encoder_hidden"], "Layers": d["encoder_layers"], "Blocks": "",
         "Activation": "SiLU", "BatchNorm": "", "Parameters": counts["NN_v"]},
        {"Module": "NN_d", "Hidden units": d["decoder_hidden"], "Layers": d["decoder_layers"], "Blocks": "",
         "Activation": "SiLU", "BatchNorm": "", "Parameters": counts["NN_d"]},
        {"Module": "NN_f", "Hidden units": f["hidden"], "Layers": f["layers_per_block"], "Blocks": f["blocks"],
         "Activation": "Tanh (scale), ReLU (translation)", "BatchNorm": bool(f["batchnorm"]),
         "Parameters": counts["NN_f"]},
    ])
    arch["Parameters (paper)"] = [PARAMETER_COUNTS[study][m] for m in arch["Module"]]
    rows = []
    for name, h in (("NN_e", e), ("NN_f", f), ("NN_v + NN_d", d)):
        rows.append({"Module": name, "Minibatch": h["batch_size"], "Initial lr": h["lr"],
                     "Epochs": h["epochs"], "Epochs per decay": h["lr_step"], "Decay rate": h["lr_gamma"],
                     "Weight decay": h.get("weight_decay", 0.0)})
    sched = pd.DataFrame(rows)
    return arch, sched


_REDUCTION_WORDS = {"sum": "per-sample sums", "mse": "means over components"}


def write_network_tables(training: dict, study: str, architecture_csv: str, architecture_md: str,
                         schedule_csv: str, schedule_md: str) -> None:
    """Write the architecture and schedule tables of ``study`` (CSV + Markdown)."""
    arch, sched = network_tables(training, study)
    d = training["studies"][study]["encoder_decoder"]
    write_table(arch, architecture_csv, architecture_md,
                caption=f"inVAErt modules, {study} study (config in use; paper counts beside)")
    write_table(sched, schedule_csv, schedule_md,
                caption=f"Training schedules, {study} study (config in use). [beta_d, beta_v, beta_r] = "
                        f"[{d['beta_d']}, {d['beta_v']}, {d['beta_r']}] on the decoder, KL and re-evaluation terms "
                        f"(squared errors as {_REDUCTION_WORDS[d.get('reduction', 'sum')]}), dim(w) = {d['latent_dim']}, "
                        f"noise levels {training['studies'][study]['noise_levels']}")
