"""The paper's published figures (SPEC §10), the anchors CAPE's results are held against.

Public numbers, kept in one place so that tables, the scorecard and the docs quote the same
values. Keys are model names of the config.
"""

from __future__ import annotations

COMPLEXITY = {
    # params_M (DPM as printed, truncated; 0.0288 M counted), size_MB, flops_M, inference_ms
    "dpm": {"params_M": 0.028, "size_MB": 0.11, "flops_M": 0.023, "inference_ms": 0.081},
    "ddm": {"params_M": 2.878, "size_MB": 10.98, "flops_M": 5.740, "inference_ms": 0.072},
    "epm": {"params_M": 0.917, "size_MB": 3.46, "flops_M": 1.802, "inference_ms": 0.063},
}
"""Model complexity and inference efficiency."""

PARAMETER_COUNT_CHECK = {"dpm": 0.0288e6, "ddm": 2.878e6, "epm": 0.917e6}
"""Parameter counts the architecture must match within 2 % (SPEC §4.1: DPM against 0.0288 M)."""

OPENLOOP_RMSE = {
    "epm": {"vx": 1.19e-4, "vy": 5.43e-5, "omega": 1.67e-4},
    "ddm": {"vx": 8.72e-5, "vy": 4.02e-4, "omega": 3.99e-3},
    "dpm": {"vx": 0.0343, "vy": 0.1252, "omega": 4.306},
}
"""Open-loop one-step RMSE (the paper's "Open Loop Results")."""

ADAPTIVE_LAP_TIME = {"epm": 5.82, "ddm": 8.80, "dpm": 12.99}
"""Adaptive NMPC, failure-penalised lap time (s) averaged over η (learned study)."""

ETA1_RELATIVE = {
    # EPM against (DPM, DDM), averaged over the five controllers at η = 1, in %
    "mean_abs_ex_penalised": {"dpm": -29.0, "ddm": -17.2},
    "mean_abs_ey_penalised": {"dpm": -24.6, "ddm": -12.3},
    "mean_speed": {"dpm": 39.9, "ddm": 3.1},
}
"""EPM's relative difference at η = 1."""

NMPC_FAILURES = {"epm": 0, "ddm": 12, "dpm": 19}
"""Failures of the three NMPCs over the 11 η levels (33 runs) per learned model."""

BEST_BICYCLE = {
    "dpm": {"controller": "nmpc", "max_eta": 3.0, "lap_time": 7.74},
    "ddm": {"controller": "rnmpc", "max_eta": 0.5, "lap_time": 7.32},
    "epm": {"controller": "nmpc", "max_eta": 2.5, "lap_time": 5.66},
}
"""Best controller per fixed-parameter bicycle model: the highest η completed and its lap time."""
