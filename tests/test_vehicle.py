"""The single-track equations (SPEC §1): hand-computed values, backends, integrators, limits."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
import torch

from cape.vehicle import (
    ACTUATOR_LIMITS,
    GROUND_TRUTH,
    INTEGRATORS,
    VehicleParams,
    drivetrain_force,
    state_derivative,
    tire_forces,
)
from cape.vehicle.dynamics import slip_angles

P = GROUND_TRUTH.as_dict()
# A general state and input: every term of the equations is non-zero.
X0 = np.array([0.3, -0.2, 0.7, 1.8, 0.1, 0.9])
U0 = np.array([0.4, 0.12])


def test_straight_line_acceleration_by_hand() -> None:
    """No offsets, vy = ω = δ = 0: only the drivetrain acts.

    Frx = (0.287 − 0.0545·1)·0.5 − 0.0518 − 0.00035·1² = 0.0641 N; v̇x = 0.0641 / 0.041.
    """
    p = GROUND_TRUTH.replace(Shf=0.0, Svf=0.0, Shr=0.0, Svr=0.0).as_dict()
    dx = state_derivative(np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0]), np.array([0.5, 0.0]), p)
    np.testing.assert_allclose(dx, [1.0, 0.0, 0.0, 0.0641 / 0.041, 0.0, 0.0], rtol=0, atol=1e-15)
    assert drivetrain_force(1.0, 0.5, p) == pytest.approx(0.0641, abs=1e-15)


def test_kinematics_rotate_body_velocity_by_heading() -> None:
    """ψ = π/2: Ẋ = −vy, Ẏ = vx, ψ̇ = ω."""
    dx = state_derivative(np.array([0.0, 0.0, math.pi / 2, 2.0, 0.5, 0.3]), np.array([0.0, 0.0]), P)
    np.testing.assert_allclose(dx[:3], [-0.5, 2.0, 0.3], atol=1e-15)


def test_pure_slip_tyre_force_by_hand() -> None:
    """With C = 1, E = 0 and no offsets, F = D·sin(atan(Bα)) = D·Bα/√(1 + B²α²)."""
    p = dict(P, Cf=1.0, Ef=0.0, Cr=1.0, Er=0.0, Shf=0.0, Svf=0.0, Shr=0.0, Svr=0.0)
    # vx = 1, vy = ω = 0, δ = 0.1: αf = 0.1, αr = 0.
    f_fy, f_ry = tire_forces(1.0, 0.0, 0.0, 0.1, p)
    b_alpha = 5.579 * 0.1
    assert f_fy == pytest.approx(0.192 * b_alpha / math.sqrt(1 + b_alpha**2), abs=1e-15)
    assert f_ry == pytest.approx(0.0, abs=1e-15)


def test_general_state_against_independent_high_precision_values() -> None:
    """All terms at once, against values computed independently with 30-digit arithmetic
    (mpmath) from the SPEC §1 formulas and the ground-truth table."""
    alpha_f, alpha_r = slip_angles(1.8, 0.1, 0.9, 0.12, P)
    assert alpha_f == pytest.approx(0.048758713918642518566, abs=1e-15)
    assert alpha_r == pytest.approx(-0.042795716089081727016, abs=1e-15)
    f_fy, f_ry = tire_forces(1.8, 0.1, 0.9, 0.12, P)
    assert f_fy == pytest.approx(0.060701685286731700285, abs=1e-15)
    assert f_ry == pytest.approx(-0.048352382672021271645, abs=1e-15)
    assert drivetrain_force(1.8, 0.4, P) == pytest.approx(0.022626, abs=1e-15)
    expected = [
        1.3122941683883100619,
        1.2360760557562927392,
        0.9,
        0.46461627483336654342,
        -1.3294445197187919062,
        120.26324430646313905,
    ]
    np.testing.assert_allclose(state_derivative(X0, U0, P), expected, rtol=1e-13, atol=1e-14)


def test_numpy_torch_casadi_agree() -> None:
    """The one set of equations gives the same numbers on all three backends (to 1e-12)."""
    rng = np.random.default_rng(7)
    states = np.column_stack(
        [
            rng.uniform(-2, 2, 50),
            rng.uniform(-2, 2, 50),
            rng.uniform(-3, 3, 50),
            rng.uniform(0.1, 3.5, 50),
            rng.uniform(-0.5, 0.5, 50),
            rng.uniform(-4, 4, 50),
        ]
    ).T
    inputs = np.vstack([rng.uniform(-0.1, 1.0, 50), rng.uniform(-0.35, 0.35, 50)])
    ref = state_derivative(states, inputs, P)  # batched NumPy, shape (6, 50)

    t_out = state_derivative(torch.tensor(states), torch.tensor(inputs), P)
    assert isinstance(t_out, torch.Tensor)
    np.testing.assert_allclose(t_out.numpy(), ref, rtol=1e-12, atol=1e-12)

    x, u = ca.SX.sym("x", 6), ca.SX.sym("u", 2)
    f = ca.Function("f", [x, u], [state_derivative(x, u, P)])
    for k in range(states.shape[1]):
        np.testing.assert_allclose(
            np.array(f(states[:, k], inputs[:, k])).ravel(), ref[:, k], rtol=1e-12, atol=1e-12
        )
        np.testing.assert_allclose(
            state_derivative(states[:, k], inputs[:, k], P), ref[:, k], rtol=1e-12, atol=1e-12
        )


def test_torch_parameters_carry_gradients() -> None:
    """Learned models pass Φ as tensors; the equations must be differentiable in them."""
    p = {k: torch.tensor(v, dtype=torch.float64, requires_grad=True) for k, v in P.items()}
    out = state_derivative(torch.tensor(X0), torch.tensor(U0), p)
    out[3:].sum().backward()
    assert p["Bf"].grad is not None and torch.isfinite(p["Bf"].grad)
    assert p["Cm1"].grad.item() == pytest.approx(0.4 / P["m"])  # ∂v̇x/∂Cm1 = T/m


@pytest.mark.parametrize(("name", "order"), [("euler", 1), ("rk4", 4), ("rkf", 5)])
def test_integrator_order_on_linear_ode(name: str, order: int) -> None:
    """ẋ = −x from x = 1 over 1 s: the global error shrinks like h^order."""
    step = INTEGRATORS[name]
    errors = []
    for n in (10, 20):
        x, h = np.array([1.0]), 1.0 / n
        for _ in range(n):
            x = step(lambda x, u: -x, x, None, h)
        errors.append(abs(x[0] - math.exp(-1.0)))
    assert math.log2(errors[0] / errors[1]) == pytest.approx(order, abs=0.3)


def test_integrators_work_on_casadi_symbols() -> None:
    x, u = ca.SX.sym("x", 6), ca.SX.sym("u", 2)
    f = lambda x, u: state_derivative(x, u, P)  # noqa: E731
    for name, step in INTEGRATORS.items():
        F = ca.Function(name, [x, u], [step(f, x, u, 0.02)])
        np.testing.assert_allclose(
            np.array(F(X0, U0)).ravel(), step(f, X0, U0, 0.02), rtol=1e-12, atol=1e-12
        )


def test_actuator_limits() -> None:
    lim = ACTUATOR_LIMITS
    np.testing.assert_allclose(lim.clip([2.0, 1.0]), [1.0, 0.35])
    np.testing.assert_allclose(lim.clip([-1.0, -1.0]), [-0.1, -0.35])
    # steering rate 5 rad/s at 50 Hz: at most 0.1 rad per step
    assert lim.max_steering_step(0.02) == pytest.approx(0.1)
    np.testing.assert_allclose(lim.clip([0.5, 0.3], delta_prev=0.0, ts=0.02), [0.5, 0.1])
    np.testing.assert_allclose(lim.clip([0.5, 0.3], delta_prev=0.3, ts=0.02), [0.5, 0.3])
    with pytest.raises(ValueError, match="sampling time"):
        lim.clip([0.5, 0.3], delta_prev=0.0)


def test_parameter_sets_are_typed_and_named() -> None:
    assert isinstance(GROUND_TRUTH, VehicleParams)
    assert GROUND_TRUTH.m == 0.041 and GROUND_TRUTH.Iz == 27.8e-6
    heavier = GROUND_TRUTH.replace(m=GROUND_TRUTH.m * 1.05)
    assert heavier.m == pytest.approx(0.04305) and GROUND_TRUTH.m == 0.041
    with pytest.raises(KeyError, match="unknown vehicle parameter"):
        GROUND_TRUTH.replace(mass=1.0)
    with pytest.raises(AttributeError):
        GROUND_TRUTH.m = 1.0  # type: ignore[misc]
