"""Nominal NMPC (SPEC §7.3): laps, its NLP's prediction, solver agreement, fallback."""

from __future__ import annotations

import copy
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from cape.closedloop.internal import N_STATE
from cape.closedloop.rollout import initial_state
from cape.closedloop.setup import build_internal, build_run


@pytest.fixture()
def cfg(config, track_dir, tmp_path: Path):
    cfg = copy.deepcopy(config)
    cfg["tracks"]["dir"] = str(track_dir)
    from cape.tracks.raceline import build_raceline
    from cape.tracks.track import load_track
    from cape.vehicle import ACTUATOR_LIMITS, GROUND_TRUTH

    rl = build_raceline(
        load_track(track_dir, "ETHZMobil", "ethzMobil", 0.46),
        cfg["reference"],
        GROUND_TRUTH,
        ACTUATOR_LIMITS,
    )
    np.savez(tmp_path / "line.npz", x=rl.x, y=rl.y, speed=rl.speed)
    cfg["_raceline"] = str(tmp_path / "line.npz")
    return cfg


def _run(cfg, solver="sqp", **kw):
    c = copy.deepcopy(cfg)
    c["controllers"]["nmpc"]["solver"] = solver
    return build_run(c, "truth", "nmpc", 0.0, 0, "truth", Path("unused"), c["_raceline"], **kw)


def test_nmpc_with_the_true_internal_model_laps(cfg) -> None:
    run = _run(cfg)
    result = run()
    m = result.metrics
    assert m["success"], m
    assert 6.8 < m["lap_time"] < 7.4  # the prototype: 6.98 s
    assert m["mean_abs_ey"] < 0.02
    assert run.controller.fallbacks == 0


def test_internal_step_is_the_same_on_numpy_and_casadi(cfg) -> None:
    internal = build_internal(cfg, "truth", Path("unused"))
    x, u, phi = ca.SX.sym("x", N_STATE), ca.SX.sym("u", 2), ca.SX.sym("phi", internal.n_phi)
    f = ca.Function("f", [x, u, phi], [internal.step(x, u, phi)])
    rng = np.random.default_rng(0)
    for _ in range(20):
        xv = np.r_[
            rng.normal(size=3), rng.uniform(0.5, 3), rng.normal(0, 0.2, 2), rng.uniform(0, 0.5), 0.1
        ]
        uv = np.array([rng.uniform(-0.1, 1), rng.uniform(-0.3, 0.3)])
        np.testing.assert_allclose(
            np.array(f(xv, uv, internal.phi())).ravel(),
            internal.step(xv, uv, internal.phi()),
            rtol=1e-12,
            atol=1e-14,
        )


def _first_step(cfg):
    """A fresh NMPC that has solved its first problem from the start of the lap."""
    run = _run(cfg)
    controller, line = run.controller, run.line
    x0 = initial_state(line, 1.0)
    controller.reset(x0)
    proj = line.project(x0[0], x0[1], None)
    ref = line.points(proj.s, controller.horizon)
    controller.step(x0, proj, ref)
    return controller, x0, proj, ref


def test_the_nlp_prediction_is_the_internal_models_own_rollout(cfg) -> None:
    controller, x0, _, _ = _first_step(cfg)
    w = controller._w
    n = controller.horizon
    xs = w[: controller.n_x].reshape(n + 1, N_STATE)
    us = w[controller.n_x : controller.n_x + controller.n_u].reshape(n, 2)
    x = np.r_[x0, 0.0, 0.0]
    for k in range(n):
        x = controller.internal.step(x, us[k], controller.internal.phi())
        np.testing.assert_allclose(xs[k + 1], x, atol=1e-8)


def test_default_solver_agrees_with_ipopt_on_a_recorded_run(cfg) -> None:
    """Both solvers on the same 120 recorded steps: first inputs within 1e-3."""
    recorded = _run(cfg, "sqp")
    result = recorded()
    sqp, ipopt = _run(cfg, "sqp").controller, _run(cfg, "ipopt").controller
    line = recorded.line
    x0 = initial_state(line, 1.0)
    sqp.reset(x0)
    ipopt.reset(x0)
    states = np.column_stack([result.series[k] for k in ("X", "Y", "psi", "vx", "vy", "omega")])
    z = x0
    worst = 0.0
    s_hint = None
    for k in range(120):
        proj = line.project(z[0], z[1], s_hint)
        s_hint = proj.s
        ref = line.points(proj.s, sqp.horizon)
        u_sqp, _ = sqp.step(z, proj, ref)
        u_ipopt, _ = ipopt.step(z, proj, ref)
        worst = max(worst, float(np.max(np.abs(u_sqp - u_ipopt))))
        z = states[k]
    assert worst <= 1e-3


def test_a_failed_solve_falls_back_to_the_previous_plan(cfg) -> None:
    controller, x0, proj, ref = _first_step(cfg)
    plan = controller._plan.copy()

    class _Failing:
        def __call__(self, **_kw):
            return {"x": np.zeros(controller.n_w), "lam_x": 0, "lam_g": 0}

        def stats(self):
            return {"success": False}

    controller.solver = _Failing()
    u, info = controller.step(x0, proj, ref)
    assert info["fallback"] and controller.fallbacks == 1
    np.testing.assert_allclose(u, _rate_limited(plan[1], plan[0]))


def _rate_limited(u: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
    """What the controller applies: the input saturated and steering-rate limited."""
    from cape.vehicle import ACTUATOR_LIMITS

    return ACTUATOR_LIMITS.clip(u, delta_prev=float(u_prev[1]), ts=0.02)
