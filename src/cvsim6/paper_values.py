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
