"""Numbers the paper reports, to print beside ours (one place; output order of the registry)."""
from __future__ import annotations

#: Appendix C, structural study: emulator absolute error on the 4,000 validation sets.
EMULATOR_VALIDATION_STRUCTURAL = {
    "mean": [9.81e-3, 4.72e-2, 4.52e-2, 1.20e-2, 3.44e-3, 1.10e-2, 9.77e-3, 2.74e-3,
             7.59e-3, 3.68e-3, 2.33e-2, 4.45e-2, 1.08e-4, 1.91e-3, 1.81e-1, 1.95e-2],
    "max": [7.57e-2, 6.68e-1, 3.92e-1, 2.35e-1, 2.33e-2, 2.87e-1, 1.86e-1, 7.82e-2,
            7.38e-2, 4.24e-2, 2.88e-1, 4.51e-1, 2.04e-3, 2.00e-2, 1.62e0, 2.12e-1],
    "std": [8.59e-3, 4.65e-2, 4.02e-2, 1.26e-2, 2.81e-3, 1.18e-2, 9.94e-3, 3.34e-3,
            7.30e-3, 3.49e-3, 2.38e-2, 4.33e-2, 1.01e-4, 1.82e-3, 1.60e-1, 1.84e-2],
}
#: Section 3.3, table 3: decoder on the validation outputs, pushed through the simulator.
INVERSION_STRUCTURAL = {
    "mean": [4.62e-2, 3.37e-1, 2.50e-1, 8.16e-2, 1.12e-2, 8.06e-2, 5.12e-2, 1.82e-2,
             4.89e-2, 2.72e-2, 1.49e-1, 3.29e-1, 5.04e-4, 1.41e-2, 1.02e0, 8.79e-2],
    "max": [4.06e-1, 3.34e0, 2.42e0, 1.60e0, 1.41e-1, 1.58e0, 1.08e0, 2.78e-1,
            1.12e0, 3.26e-1, 1.79e0, 4.67e0, 6.95e-3, 2.22e-1, 1.20e1, 6.54e-1],
    "std": [4.36e-2, 3.32e-1, 2.36e-1, 8.27e-2, 1.20e-2, 8.16e-2, 5.48e-2, 1.93e-2,
            5.20e-2, 2.71e-2, 1.57e-1, 3.41e-1, 5.09e-4, 1.44e-2, 9.32e-1, 8.07e-2],
}
#: Paper appendix B tables: total parameters of each network.
PARAMETER_COUNTS = {
    "structural": {"NN_e": 24376, "NN_v": 6246, "NN_d": 20439, "NN_f": 51712},
    "ehr": {"NN_e": 42096, "NN_v": 6246, "NN_d": 20439, "NN_f": 20280},
}
#: Section 3.4: maximum relative l2 error of the EHR emulator on the validation sets.
EHR_EMULATOR_MAX_REL_L2 = 0.00984
#: Section 3.3, table 4: the observation y* (sampled from NN_f in the paper), registry units.
Y_STAR = (72.91, 142.78, 111.55, 22.78, -1.51, 22.37, 13.13, 1.61, 12.56, 7.27, 76.81,
          153.61, 0.50, 5.60, 1725.48, 74.53)
#: Section 3.3.3: outputs of y* taken as missing.
MISSING_OUTPUTS = ("P_a_dia", "P_r_dia", "P_pa_dia", "P_w", "V_l_sys", "SVR", "PVR")
#: Section 3.3 headlines: largest relative l2 reconstruction error on the manifold of y*
#: (fraction), SVD modes for 99% of the energy and the energy they hold, largest relative
#: l2 error on the observed entries with missing data (fraction).
STRUCTURAL_HEADLINES = {"max_rel_error_manifold": 0.00139, "modes_99": 12, "energy_at_modes": 0.9928,
                        "max_rel_error_missing": 0.00408}
#: Section 3.1, figures 4-5: eigenvalues of A(t) (1/s) at the SR extremes, their times (s)
#: and the time constants tau_1, tau_2 (s) the paper quotes.
STIFFNESS_EXTREMES = {
    "SR max": dict(t=9.444, lambdas=(-520.95, -355.93, -3.75, -0.51, 6.25e-4, 2.91e-5), tau=(0.0019, 0.0028)),
    "SR min": dict(t=8.618, lambdas=(-4.40, -1.81, -1.77, -0.64, 2.22e-16, 3.47e-18), tau=(None, None)),
}
#: Section 3.4, table 5: e_k per output at delta = 0.25, 0.5, 1.0, 2.0 (registry units;
#: None where never observed).
EHR_DELTAS = (0.25, 0.5, 1.0, 2.0)
EHR_EK = {
    "Hr": (0.602, 0.440, 0.843, 2.636), "P_a_sys": (5.204, 2.284, 3.379, 2.738),
    "P_a_dia": (3.614, 1.605, 2.045, 2.627), "P_r_sys": (1.669, 1.323, 1.469, 1.476),
    "P_r_dia": (1.170, 1.684, 2.022, 3.383), "P_pa_sys": (1.907, 1.227, 1.606, 1.386),
    "P_pa_dia": (1.285, 1.062, 1.065, 1.290), "P_r_edp": (0.540, 0.599, 0.786, 2.787),
    "P_w": (0.887, 0.740, 1.258, 1.200), "P_cvp": (1.194, 0.371, 0.733, 0.821),
    "V_l_sys": (None, None, None, None), "V_l_dia": (50.960, 47.391, 103.402, 119.440),
    "LVEF": (0.012, 0.008, 0.015, 0.024), "CO": (0.200, 0.121, 0.281, 0.274),
    "SVR": (28.755, 24.728, 25.896, 41.233), "PVR": (1.924, 1.812, 2.010, 3.795),
}
