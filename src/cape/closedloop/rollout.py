"""One closed-loop run: a lap of the reference with a plant, a controller and disturbances
(SPEC §5): the loop, the lap and failure rules, the metrics and the time series.

reference ─► controller ─► actuator delay ─► plant ─► process disturbance
     ▲                                                        │
     └──── measured state ◄── noise + IMU bias ◄──────────────┘
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cape.closedloop.disturbances import DisturbancePipeline
from cape.closedloop.envelope import Envelope, divergence_record
from cape.closedloop.plants import Plant
from cape.controllers.base import Controller
from cape.numerics import interrupt
from cape.specs.run import Penalty, RolloutSettings
from cape.tracks.geometry import cross_track_error, wrap_angle
from cape.tracks.reference import ProgressTracker, ReferenceLine
from cape.tracks.track import Track

FAILURES = ("off_track", "timeout", "diverged", "plant_diverged")
"""A failed run's reasons: the car left the track, the lap took too long, the loop became
non-finite, or a learned plant left the envelope of its training data (its own failure, not
the controller's: cape.closedloop.envelope)."""


@dataclass
class LapResult:
    """What a run produced: the summary metrics and the full time series (one row per step)."""

    metrics: dict[str, Any]
    series: dict[str, np.ndarray]
    solve_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    plant_s: float = 0.0
    """Wall seconds spent in the plant's steps (the lap's other parts: the controller's solve
    times, and the loop around both)."""
    controller_s: dict[str, float] = field(default_factory=dict)
    """Wall seconds of the named parts of the controller's steps (``Controller.phase_s``: an
    NMPC's estimate, internal Φ, parameters, solve, rescue, adaptation)."""
    rescues_succeeded: int = 0
    """Steps whose rescue converged where the SQP had not (``metrics["rescues"]`` tried)."""


def initial_state(line: ReferenceLine, vx0: float) -> np.ndarray:
    """First point of the reference, heading along it, vx0, vy0 = ω0 = 0 (SPEC §2)."""
    x, y = line.path.position(0.0)
    return np.array([float(x), float(y), float(line.path.heading(0.0)), vx0, 0.0, 0.0])


def run_lap(
    plant: Plant,
    controller: Controller,
    line: ReferenceLine,
    track: Track,
    disturbances: DisturbancePipeline,
    settings: RolloutSettings,
    *,
    envelope: Envelope | None = None,
) -> LapResult:
    """Drive one lap under ``settings`` (``rollout``: its horizon, time limit, start speed,
    penalty and failure window); never raises for a failed run (the failure, its reason and
    where it happened are recorded: see ``failure_location``). ``envelope``: a learned
    plant's, whose state beyond it (or non-finite) ends the run as ``plant_diverged`` before
    the disturbances act on it."""
    ts = line.ts
    horizon, time_limit = int(settings.horizon), float(settings.time_limit)
    penalty = settings.penalty
    max_steps = round(time_limit / ts)
    x = initial_state(line, float(settings.vx0))
    plant.reset(x)
    disturbances.reset(delta0=0.0)
    car = ProgressTracker(line)  # the true progress: laps and tracking errors
    seen = ProgressTracker(line)  # the controller's view, from the measured state
    car.reset(x[0], x[1])
    z = disturbances.measure(x)
    proj_seen = seen.reset(z[0], z[1])
    controller.reset(z)
    rows: list[tuple[float, ...]] = []  # one per step, the columns of SERIES_KEYS
    solve_ms: list[float] = []
    plant_s = 0.0
    failure: str | None = None
    lap_time: float | None = None
    steps = 0
    fallback_steps: list[bool] = []
    rescued, iterations = 0, []
    last_pose = x[:2].copy()
    diverged: tuple[int, np.ndarray] | None = None
    centre_s = track.center.project(x[0], x[1]).s
    # signals are raised by the loop's own check, never inside a solver (cape.numerics.interrupt)
    with interrupt.deferred():
        for k in range(max_steps):
            ref = line.points(proj_seen.s, horizon)
            start = time.perf_counter()
            try:
                u_cmd, info = controller.step(z, proj_seen, ref)
            except FloatingPointError:
                failure = "diverged"
                break
            solve_ms.append((time.perf_counter() - start) * 1e3)
            interrupt.check()  # a Ctrl-C or SIGTERM during the step stops the run here
            fallback_steps.append(bool(info.get("fallback", False)))
            rescued += bool(info.get("rescued", False))
            if "iterations" in info:
                iterations.append(int(info["iterations"]))
            if not np.isfinite(u_cmd).all():
                failure = "diverged"
                break
            u_app = disturbances.actuate(u_cmd)
            start = time.perf_counter()
            x_plant = plant.step(u_app)
            plant_s += time.perf_counter() - start
            if envelope is not None and envelope.left(x_plant):
                failure, diverged = "plant_diverged", (k + 1, np.array(x_plant, dtype=float))
                steps = k + 1  # as for "diverged": the step that failed, not in the series
                break
            x = disturbances.after_plant(x_plant)
            steps = k + 1
            if not np.isfinite(x).all():
                failure = "diverged"
                break
            last_pose = x[:2].copy()
            proj_car = car.update(x[0], x[1])
            # tracking errors against the reference point issued for this step (k = 1)
            x_ref, y_ref, psi_ref = ref.at(1)
            dx, dy = x_ref - x[0], y_ref - x[1]
            e_x = dx * math.cos(psi_ref) + dy * math.sin(psi_ref)
            e_y = -dx * math.sin(psi_ref) + dy * math.cos(psi_ref)
            psi_path = line.path.heading_at(proj_car.s)
            e_cte = cross_track_error(x[0], x[1], proj_car.x, proj_car.y, psi_path)
            z = disturbances.measure(x)
            reference = (x_ref, y_ref, psi_ref, float(ref.speed[1]))
            errors = (e_x, e_y, e_cte, wrap_angle(psi_path - x[2]))
            rows.append(((k + 1) * ts, *x, *z, *reference, *u_cmd, *u_app, *errors, solve_ms[-1]))
            on_centre = track.center.project(x[0], x[1], s_hint=centre_s, window=line.window)
            centre_s = on_centre.s
            if abs(on_centre.offset) > track.width / 2:
                failure = "off_track"
                break
            if car.total >= line.length:
                lap_time = round((k + 1) * ts, 9)  # 7.56, not 7.5600000000000005
                break
            proj_seen = seen.update(z[0], z[1])
        else:
            failure = "timeout"
    table = np.array(rows, dtype=float).reshape(-1, len(SERIES_KEYS))
    series = {key: np.ascontiguousarray(table[:, j]) for j, key in enumerate(SERIES_KEYS)}
    metrics = summarise(series, failure, lap_time, steps, time_limit, penalty)
    metrics.update(divergence_record(*(diverged or (None, None))))
    metrics["fallbacks"] = sum(fallback_steps)  # steps whose solve failed (model-based)
    metrics["rescues"] = rescued  # steps the SQP left to its rescue
    metrics["solver_iterations_median"] = float(np.median(iterations)) if iterations else None
    metrics["solver_iterations_max"] = max(iterations) if iterations else None
    window = max(round(float(settings.failure_window) / ts), 0)
    metrics.update(
        failure_location(failure, car.total, line.length, last_pose, fallback_steps, window)
    )
    return LapResult(
        metrics,
        series,
        np.asarray(solve_ms),
        plant_s,
        dict(getattr(controller, "phase_s", {})),
        int(getattr(controller, "rescues_succeeded", 0)),
    )


def failure_location(
    failure: str | None,
    progress: float,
    length: float,
    pose: np.ndarray,
    fallback_steps: list[bool],
    window: int,
) -> dict[str, Any]:
    """Where a failed run was lost: its progress along the reference (m and fraction of the
    lap), the car's last finite position, and the solver fallbacks in the ``window`` steps
    before (a failing solver, not the car, may be the cause). All None for a lap."""
    if failure is None:
        return {"failure_s": None, "failure_fraction": None, "failure_X": None,
                "failure_Y": None, "fallbacks_before_failure": None}  # fmt: skip
    recent = fallback_steps[-window:] if window else []
    return {
        "failure_s": float(progress),
        "failure_fraction": float(progress / length),
        "failure_X": float(pose[0]),
        "failure_Y": float(pose[1]),
        "fallbacks_before_failure": int(sum(recent)),
    }


SERIES_KEYS = (
    "t", "X", "Y", "psi", "vx", "vy", "omega",
    "z_X", "z_Y", "z_psi", "z_vx", "z_vy", "z_omega",
    "ref_X", "ref_Y", "ref_psi", "ref_v",
    "T_cmd", "delta_cmd", "T_applied", "delta_applied",
    "e_x", "e_y", "e_cte", "e_psi", "solve_ms",
)  # fmt: skip


def summarise(
    series: dict[str, np.ndarray],
    failure: str | None,
    lap_time: float | None,
    steps: int,
    time_limit: float,
    penalty: Penalty,
) -> dict[str, Any]:
    """The per-run metrics of SPEC §5.3 (deterministic: no wall-clock numbers)."""
    success = failure is None and lap_time is not None

    def mean_abs(key: str) -> float | None:
        return float(np.mean(np.abs(series[key]))) if series[key].size else None

    speed = np.hypot(series["vx"], series["vy"])
    du = np.abs(np.diff(np.column_stack([series["T_cmd"], series["delta_cmd"]]), axis=0))
    return {
        "success": bool(success),
        "failure": failure,
        "lap_time": lap_time,
        "lap_time_penalised": lap_time if success else float(penalty.lap_time),
        "mean_abs_ex": mean_abs("e_x"),
        "mean_abs_ey": mean_abs("e_y"),
        "mean_abs_ex_penalised": mean_abs("e_x") if success else float(penalty.tracking_error),
        "mean_abs_ey_penalised": mean_abs("e_y") if success else float(penalty.tracking_error),
        "mean_abs_cte": mean_abs("e_cte"),
        "mean_speed": float(speed.mean()) if speed.size else None,
        "mean_abs_dT": float(du[:, 0].mean()) if du.size else None,
        "mean_abs_ddelta": float(du[:, 1].mean()) if du.size else None,
        "steps": int(steps),
        "time_limit": float(time_limit),
    }
