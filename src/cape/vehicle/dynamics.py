"""The single-track vehicle equations of SPEC §1, written once for every backend.

Every model in the study uses these functions: the ground-truth simulator with the true
parameters, the learned models with their predicted Φ, the NMPCs with Φ as an NLP
parameter. Parameters are read from a mapping (``VehicleParams.as_dict()``, a dict of tensor
columns, or a dict of CasADi symbols), so where they come from is the caller's business.

State ``x = [X, Y, ψ, vx, vy, ω]``, input ``u = [T, δ]``. Missing offsets ``Shf, Svf, Shr, Svr``
count as zero (the Deep Pacejka model has none).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from cape.vehicle.backend import ops_for
from cape.vehicle.params import GRAVITY

Params = Mapping[str, Any]


def slip_angles(vx: Any, vy: Any, omega: Any, delta: Any, p: Params) -> tuple[Any, Any]:
    """Front and rear slip angles αf, αr (rad)."""
    ops = ops_for(vx, vy, omega, delta, *p.values())
    speed = ops.abs(vx)
    alpha_f = delta - ops.atan2(p["lf"] * omega + vy, speed) + p.get("Shf", 0.0)
    alpha_r = ops.atan2(p["lr"] * omega - vy, speed) + p.get("Shr", 0.0)
    return alpha_f, alpha_r


def _pacejka(alpha: Any, B: Any, C: Any, D: Any, E: Any, Sv: Any, ops: Any) -> Any:
    """Simplified Pacejka magic formula: lateral force of one axle."""
    b_alpha = B * alpha
    return Sv + D * ops.sin(C * ops.atan(b_alpha - E * (b_alpha - ops.atan(b_alpha))))


def pacejka(alpha: Any, B: Any, C: Any, D: Any, E: Any, Sv: Any = 0.0) -> Any:
    """One axle's lateral force (N) at slip angle ``alpha`` on any backend (the formula of
    ``tire_forces``, for looking at a tyre curve by itself)."""
    return _pacejka(alpha, B, C, D, E, Sv, ops_for(alpha, B, C, D, E, Sv))


def tire_forces(vx: Any, vy: Any, omega: Any, delta: Any, p: Params) -> tuple[Any, Any]:
    """Lateral tyre forces Ffy, Fry (N) from the Pacejka formula."""
    ops = ops_for(vx, vy, omega, delta, *p.values())
    alpha_f, alpha_r = slip_angles(vx, vy, omega, delta, p)
    f_fy = _pacejka(alpha_f, p["Bf"], p["Cf"], p["Df"], p["Ef"], p.get("Svf", 0.0), ops)
    f_ry = _pacejka(alpha_r, p["Br"], p["Cr"], p["Dr"], p["Er"], p.get("Svr", 0.0), ops)
    return f_fy, f_ry


def drivetrain_force(vx: Any, throttle: Any, p: Params) -> Any:
    """Longitudinal rear force Frx = (Cm1 − Cm2·vx)·T − Cr0 − Cr2·vx² (N)."""
    return (p["Cm1"] - p["Cm2"] * vx) * throttle - p["Cr0"] - p["Cr2"] * vx**2


def axle_load_factors(frx: Any, height: Any, p: Params, ops: Any) -> tuple[Any, Any]:
    """Dynamic load transfer (SPEC §4.3): ``Fz/Fz0`` of the front and rear axle.

    ``a_x = Frx/m``; ``Fz_f = m·(g·lr − h·a_x)/(lf+lr)``, ``Fz_r = m·(g·lf + h·a_x)/(lf+lr)``,
    each floored at 1 % of its static value, divided by the static loads. With h = 0 both
    factors are exactly 1.
    """
    wheelbase = p["lf"] + p["lr"]
    a_x = frx / p["m"]
    # the same association as the dynamic loads, so that h = 0 gives factors of exactly 1
    static_f = p["m"] * (GRAVITY * p["lr"]) / wheelbase
    static_r = p["m"] * (GRAVITY * p["lf"]) / wheelbase
    fz_f = ops.maximum(p["m"] * (GRAVITY * p["lr"] - height * a_x) / wheelbase, 0.01 * static_f)
    fz_r = ops.maximum(p["m"] * (GRAVITY * p["lf"] + height * a_x) / wheelbase, 0.01 * static_r)
    return fz_f / static_f, fz_r / static_r


def velocity_derivatives(
    vx: Any,
    vy: Any,
    omega: Any,
    throttle: Any,
    delta: Any,
    p: Params,
    frx: Any = None,
    cg_height: Any = None,
) -> tuple[Any, Any, Any]:
    """Body accelerations (v̇x, v̇y, ω̇).

    ``frx`` replaces the drivetrain law when a model predicts the longitudinal force itself
    (the Deep Pacejka model); then ``throttle`` is not used. ``cg_height`` (m) switches on
    the Enhanced Physics Model's load-sensitive tyre forces (SPEC §4.3): both lateral forces,
    offsets included, are scaled by their axle's ``Fz/Fz0``.
    """
    ops = ops_for(vx, vy, omega, throttle, delta, frx, cg_height, *p.values())
    f_fy, f_ry = tire_forces(vx, vy, omega, delta, p)
    f_rx = drivetrain_force(vx, throttle, p) if frx is None else frx
    if cg_height is not None:
        load_f, load_r = axle_load_factors(f_rx, cg_height, p, ops)
        f_fy, f_ry = f_fy * load_f, f_ry * load_r
    sin_d, cos_d = ops.sin(delta), ops.cos(delta)
    dvx = (f_rx - f_fy * sin_d) / p["m"] + vy * omega
    dvy = (f_ry + f_fy * cos_d) / p["m"] - vx * omega
    domega = (f_fy * p["lf"] * cos_d - f_ry * p["lr"]) / p["Iz"]
    return dvx, dvy, domega


def state_derivative(x: Sequence[Any] | Any, u: Sequence[Any] | Any, p: Params) -> Any:
    """ẋ = f(x, u) for the full state, stacked along the first axis like ``x``.

    ``x`` has shape (6,) or (6, B) and ``u`` (2,) or (2, B) on NumPy/PyTorch; on CasADi they are
    column vectors. The result has the backend's type and ``x``'s layout.
    """
    psi, vx, vy, omega = x[2], x[3], x[4], x[5]
    throttle, delta = u[0], u[1]
    ops = ops_for(x, u, *p.values())
    dvx, dvy, domega = velocity_derivatives(vx, vy, omega, throttle, delta, p)
    cos_p, sin_p = ops.cos(psi), ops.sin(psi)
    return ops.stack(
        [
            vx * cos_p - vy * sin_p,
            vx * sin_p + vy * cos_p,
            omega,
            dvx,
            dvy,
            domega,
        ]
    )
