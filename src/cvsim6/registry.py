"""The single source of truth for CVSim-6 names, units, defaults and noise levels.

Every other module, rule, table and figure takes parameter and output names, units
and measurement-noise standard deviations from here.

Parameters are stored and sampled in clinical units (mL/mmHg, mmHg·s/mL, mmHg, mL,
bpm). The paper's input table lists the same defaults in CGS units; ``cgs_factor``
converts (``value_cgs = value_clinical * cgs_factor``), with 1 mmHg = 1333.22 Barye.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: 1 mmHg in Barye (dyn/cm^2).
MMHG_TO_BARYE = 1333.22
#: Total blood volume (mL), constant in CVSim-6.
V_TOTAL_ML = 5000.0
#: Conversion of mmHg·min/L (Wood units) to dyn·s/cm^5.
WOOD_TO_DYN = 80.0


@dataclass(frozen=True)
class Parameter:
    """One of the 23 model inputs, in clinical units."""

    name: str
    description: str
    default: float
    unit: str
    kind: str  # "rate", "pressure", "ratio", "compliance", "resistance", "volume"
    cgs_factor: float
    cgs_unit: str
    latex: str


@dataclass(frozen=True)
class Output:
    """One of the 16 clinical outputs, with its measurement-noise std (same unit)."""

    name: str
    description: str
    calculation: str
    unit: str
    noise_std: float
    latex: str


_C = MMHG_TO_BARYE
_COMP = dict(unit="mL/mmHg", kind="compliance", cgs_factor=1.0 / _C, cgs_unit="mL/Barye")
_RES = dict(unit="mmHg·s/mL", kind="resistance", cgs_factor=_C, cgs_unit="Barye·s/mL")
_VOL = dict(unit="mL", kind="volume", cgs_factor=1.0, cgs_unit="mL")

PARAMETERS: tuple[Parameter, ...] = (
    Parameter("Hr", "Heart rate", 72.0, "bpm", "rate", 1.0, "bpm", r"$Hr$"),
    Parameter("P_th", "Transthoracic pressure", -4.0, "mmHg", "pressure", _C, "Barye", r"$P_{th}$"),
    Parameter("r_sys", "Systolic ratio per heart cycle", 1.0 / 3.0, "-", "ratio", 1.0, "-", r"$r_{sys}$"),
    Parameter("C_l_dia", "Left ventricular diastolic compliance", 10.0, latex=r"$C_{l,dia}$", **_COMP),
    Parameter("C_l_sys", "Left ventricular systolic compliance", 0.4, latex=r"$C_{l,sys}$", **_COMP),
    Parameter("C_a", "Arterial compliance", 1.6, latex=r"$C_a$", **_COMP),
    Parameter("C_v", "Venous compliance", 100.0, latex=r"$C_v$", **_COMP),
    Parameter("C_r_dia", "Right ventricular diastolic compliance", 20.0, latex=r"$C_{r,dia}$", **_COMP),
    Parameter("C_r_sys", "Right ventricular systolic compliance", 1.2, latex=r"$C_{r,sys}$", **_COMP),
    Parameter("C_pa", "Pulmonary arterial compliance", 4.3, latex=r"$C_{pa}$", **_COMP),
    Parameter("C_pv", "Pulmonary venous compliance", 8.4, latex=r"$C_{pv}$", **_COMP),
    Parameter("R_l_in", "Left ventricular inflow resistance", 0.01, latex=r"$R_{l,in}$", **_RES),
    Parameter("R_l_out", "Left ventricular outflow resistance", 0.006, latex=r"$R_{l,out}$", **_RES),
    Parameter("R_a", "Arterial resistance", 1.0, latex=r"$R_a$", **_RES),
    Parameter("R_r_in", "Right ventricular inflow resistance", 0.05, latex=r"$R_{r,in}$", **_RES),
    Parameter("R_r_out", "Right ventricular outflow resistance", 0.003, latex=r"$R_{r,out}$", **_RES),
    Parameter("R_pv", "Pulmonary venous resistance", 0.08, latex=r"$R_{pv}$", **_RES),
    Parameter("V0_l", "Unstressed left ventricular volume", 15.0, latex=r"$V^0_l$", **_VOL),
    Parameter("V0_a", "Unstressed arterial volume", 715.0, latex=r"$V^0_a$", **_VOL),
    Parameter("V0_v", "Unstressed venous volume", 2500.0, latex=r"$V^0_v$", **_VOL),
    Parameter("V0_r", "Unstressed right ventricular volume", 15.0, latex=r"$V^0_r$", **_VOL),
    Parameter("V0_pa", "Unstressed pulmonary arterial volume", 90.0, latex=r"$V^0_{pa}$", **_VOL),
    Parameter("V0_pv", "Unstressed pulmonary venous volume", 490.0, latex=r"$V^0_{pv}$", **_VOL),
)

OUTPUTS: tuple[Output, ...] = (
    Output("Hr", "Heart rate", "copied from input", "bpm", 3.0, r"$Hr$"),
    Output("P_a_sys", "Systolic blood pressure", "max P_a over last 3 cycles", "mmHg", 1.5, r"$P_{a,sys}$"),
    Output("P_a_dia", "Diastolic blood pressure", "min P_a over last 3 cycles", "mmHg", 1.5, r"$P_{a,dia}$"),
    Output("P_r_sys", "Right ventricular systolic pressure", "max P_r over last 3 cycles", "mmHg", 1.0, r"$P_{r,sys}$"),
    Output("P_r_dia", "Right ventricular diastolic pressure", "min P_r over last 3 cycles", "mmHg", 1.0, r"$P_{r,dia}$"),
    Output("P_pa_sys", "Pulmonary arterial systolic pressure", "max P_pa over last 3 cycles", "mmHg", 1.0, r"$P_{pa,sys}$"),
    Output("P_pa_dia", "Pulmonary arterial diastolic pressure", "min P_pa over last 3 cycles", "mmHg", 1.0, r"$P_{pa,dia}$"),
    Output("P_r_edp", "Right ventricular end-diastolic pressure", "P_r at the end of cycle 12", "mmHg", 1.0, r"$P_{r,edp}$"),
    Output("P_w", "Pulmonary wedge pressure", "mean P_pv over last 3 cycles", "mmHg", 1.0, r"$P_w$"),
    Output("P_cvp", "Central venous pressure", "mean P_v over last 3 cycles", "mmHg", 0.5, r"$P_{cvp}$"),
    Output("V_l_sys", "Systolic left ventricular volume", "min V_l over last 3 cycles", "mL", 10.0, r"$V_{l,sys}$"),
    Output("V_l_dia", "Diastolic left ventricular volume", "max V_l over last 3 cycles", "mL", 20.0, r"$V_{l,dia}$"),
    Output("LVEF", "Left ventricular ejection fraction", "(V_l_dia - V_l_sys) / V_l_dia", "-", 0.02, r"LVEF"),
    Output("CO", "Cardiac output", "mean Q_a over last 3 cycles", "L/min", 0.2, r"CO"),
    Output("SVR", "Systemic vascular resistance", "(mean P_a - P_cvp) / CO", "dyn·s/cm^5", 50.0, r"SVR"),
    Output("PVR", "Pulmonary vascular resistance", "(mean P_pa - P_w) / CO", "dyn·s/cm^5", 5.0, r"PVR"),
)

PARAMETER_NAMES: tuple[str, ...] = tuple(p.name for p in PARAMETERS)
OUTPUT_NAMES: tuple[str, ...] = tuple(o.name for o in OUTPUTS)
N_PARAMETERS = len(PARAMETERS)
N_OUTPUTS = len(OUTPUTS)

PARAMETER_INDEX: dict[str, int] = {n: i for i, n in enumerate(PARAMETER_NAMES)}
OUTPUT_INDEX: dict[str, int] = {n: i for i, n in enumerate(OUTPUT_NAMES)}
PARAMETER_BY_NAME: dict[str, Parameter] = {p.name: p for p in PARAMETERS}
OUTPUT_BY_NAME: dict[str, Output] = {o.name: o for o in OUTPUTS}

#: Wide adult ranges of the outputs (their units): a simulated value outside is possible in
#: the model but seen in no patient, e.g. a compliance given in CGS instead of clinical units.
#: ``cvsim6 simulate`` warns about such values; nothing else depends on them.
PHYSIOLOGICAL_RANGE: dict[str, tuple[float, float]] = {
    "Hr": (30.0, 220.0), "P_a_sys": (50.0, 260.0), "P_a_dia": (25.0, 150.0), "P_r_sys": (8.0, 120.0),
    "P_r_dia": (-10.0, 35.0), "P_pa_sys": (8.0, 120.0), "P_pa_dia": (2.0, 70.0), "P_r_edp": (-10.0, 35.0),
    "P_w": (0.0, 45.0), "P_cvp": (-5.0, 35.0), "V_l_sys": (5.0, 500.0), "V_l_dia": (30.0, 800.0),
    "LVEF": (0.05, 0.9), "CO": (0.8, 20.0), "SVR": (200.0, 5000.0), "PVR": (0.0, 1500.0),
}

#: Compartment order used for states, pressures and volumes.
COMPARTMENTS: tuple[str, ...] = ("l", "a", "v", "r", "pa", "pv")
#: Flow order: edge k carries blood from compartment k to compartment k+1 (mod 6).
FLOWS: tuple[str, ...] = ("Q_l_out", "Q_a", "Q_r_in", "Q_r_out", "Q_pv", "Q_l_in")
#: The four ideal valves and the flow index each one gates.
VALVES: dict[str, int] = {"aortic": 0, "tricuspid": 2, "pulmonary": 3, "mitral": 5}

#: Noise levels delta of the EHR study (multipliers of ``noise_std``).
EHR_NOISE_LEVELS: tuple[float, ...] = (0.25, 0.5, 1.0, 2.0)


def default_parameters() -> np.ndarray:
    """The 23 default parameters, clinical units, in registry order."""
    return np.array([p.default for p in PARAMETERS], dtype=float)


def noise_std() -> np.ndarray:
    """Measurement-noise standard deviations of the 16 outputs (their own units)."""
    return np.array([o.noise_std for o in OUTPUTS], dtype=float)
