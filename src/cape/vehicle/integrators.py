"""One-step integrators over any backend: forward Euler, classic RK4 and the 6-stage
Runge–Kutta–Fehlberg step with its 5th-order weights (the BayesRace data generator, SPEC §3).

They use only arithmetic on the state, so NumPy arrays, PyTorch tensors and CasADi symbols
all work. ``f(x, u)`` is the continuous dynamics; ``u`` is held over the step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

Dynamics = Callable[[Any, Any], Any]


def euler_step(f: Dynamics, x: Any, u: Any, h: float) -> Any:
    """x + h·f(x, u)."""
    return x + h * f(x, u)


def rk4_step(f: Dynamics, x: Any, u: Any, h: float) -> Any:
    """Classic 4th-order Runge–Kutta step."""
    k1 = f(x, u)
    k2 = f(x + (h / 2) * k1, u)
    k3 = f(x + (h / 2) * k2, u)
    k4 = f(x + h * k3, u)
    return x + (h / 6) * (k1 + 2 * k2 + 2 * k3 + k4)


def rkf_step(f: Dynamics, x: Any, u: Any, h: float) -> Any:
    """Runge–Kutta–Fehlberg (RKF45) stages, advanced with the 5th-order solution."""
    k1 = f(x, u)
    k2 = f(x + h * (1 / 4 * k1), u)
    k3 = f(x + h * (3 / 32 * k1 + 9 / 32 * k2), u)
    k4 = f(x + h * (1932 / 2197 * k1 - 7200 / 2197 * k2 + 7296 / 2197 * k3), u)
    k5 = f(x + h * (439 / 216 * k1 - 8 * k2 + 3680 / 513 * k3 - 845 / 4104 * k4), u)
    k6 = f(
        x + h * (-8 / 27 * k1 + 2 * k2 - 3544 / 2565 * k3 + 1859 / 4104 * k4 - 11 / 40 * k5),
        u,
    )
    return x + h * (
        16 / 135 * k1 + 6656 / 12825 * k3 + 28561 / 56430 * k4 - 9 / 50 * k5 + 2 / 55 * k6
    )


INTEGRATORS: dict[str, Callable[[Dynamics, Any, Any, float], Any]] = {
    "euler": euler_step,
    "rk4": rk4_step,
    "rkf": rkf_step,
}
"""Integrators by the names the config uses."""
