"""The physics half of a learned model (SPEC §4), free of PyTorch.

Which parameters Φ holds and which are fixed, how Φ becomes the mapping the shared vehicle
equations read, how the commanded input becomes the applied one, and which optional terms of
the equations a model switches on. Written on the backend-neutral equations of ``cape.vehicle``.
A new model is one subclass registered with ``@register_model("name")``. Background:
docs/modules.md.
"""

from __future__ import annotations

from typing import Any, ClassVar

from cape.vehicle.backend import ops_for
from cape.vehicle.dynamics import velocity_derivatives
from cape.vehicle.params import GROUND_TRUTH

N_FEATURES = 7
"""Columns of a window row: ``[vx, vy, ω, T_fb, δ_fb, ΔT, Δδ]``."""


def component(phi: Any, i: int) -> Any:
    """Φ's i-th component: the last axis of an array/tensor, the i-th entry of a CasADi vector."""
    if type(phi).__module__.startswith("casadi"):
        return phi[i]
    return phi[..., i]


class ModelPhysics:
    """Φ → one Euler step of [vx, vy, ω], for any backend."""

    name: ClassVar[str] = "?"
    param_names: ClassVar[tuple[str, ...]] = ()
    """Names of Φ's components, in order."""
    fixed: ClassVar[tuple[str, ...]] = ("lf", "lr", "m")
    """Vehicle parameters not learned, taken from the known geometry and mass of the car."""
    throttle_path: ClassVar[bool] = True
    """False when the dynamics do not depend on the throttle (Frx predicted)."""
    bounded: ClassVar[bool] = True
    """True when every component of Φ has physical bounds (the network ends in a guard)."""

    def __init__(self, spec: dict[str, Any], ts: float) -> None:
        self.spec = spec
        self.ts = float(ts)
        self.history = int(spec["history"])
        self._constants = {k: getattr(GROUND_TRUTH, k) for k in self.fixed}
        if self.bounded:
            missing = [n for n in self.param_names if n not in spec.get("bounds", {})]
            if missing:
                raise ValueError(f"model {self.name}: config lacks bounds for {missing}")

    def bounds(self) -> tuple[list[float], list[float]]:
        """Lower and upper bounds of Φ's components, from the config."""
        b = self.spec["bounds"]
        return [b[n][0] for n in self.param_names], [b[n][1] for n in self.param_names]

    def physical_params(self, phi: Any) -> dict[str, Any]:
        """The mapping the vehicle equations read: Φ's components plus the fixed constants."""
        p = dict(self._constants)
        for i, name in enumerate(self.param_names):
            p[name] = component(phi, i)
        return p

    def applied_inputs(
        self, u_fb: tuple[Any, Any], u_cmd: tuple[Any, Any], p: dict[str, Any]
    ) -> tuple[Any, Any]:
        """The input that reaches the wheels this step (instantaneous actuators by default)."""
        return u_cmd

    def equation_terms(self, p: dict[str, Any]) -> dict[str, Any]:
        """Optional terms of the equations this model switches on (``frx``, ``cg_height``)."""
        return {}

    def step_velocities(
        self, vx: Any, vy: Any, omega: Any, u_fb: tuple[Any, Any], u_cmd: tuple[Any, Any], phi: Any
    ) -> tuple[Any, Any, Any]:
        """One forward-Euler step of [vx, vy, ω] with parameters Φ (any backend)."""
        return self.step_with_params(vx, vy, omega, u_fb, u_cmd, self.physical_params(phi))

    def step_with_params(
        self,
        vx: Any,
        vy: Any,
        omega: Any,
        u_fb: tuple[Any, Any],
        u_cmd: tuple[Any, Any],
        p: dict[str, Any],
    ) -> tuple[Any, Any, Any]:
        """The same step from the parameter mapping itself: what a plant uses when it changes the
        parameters (a mismatch) or freezes them (the fixed-parameter variants)."""
        throttle, delta = self.applied_inputs(u_fb, u_cmd, p)
        dvx, dvy, domega = velocity_derivatives(
            vx, vy, omega, throttle, delta, p, **self.equation_terms(p)
        )
        return vx + self.ts * dvx, vy + self.ts * dvy, omega + self.ts * domega

    def frozen_params(self, frozen: dict[str, float]) -> dict[str, Any]:
        """Parameters of the fixed-parameter variant (SPEC §4.5): constants + frozen Φ."""
        return {**self._constants, **frozen}

    @staticmethod
    def first_order_lag(u_fb: Any, u_cmd: Any, tau: Any, ts: float) -> Any:
        """``u_fb + min(1, Ts/τ)·(u_cmd − u_fb)``: τ ≤ Ts means no lag."""
        ops = ops_for(u_fb, u_cmd, tau)
        return u_fb + ops.minimum(1.0, ts / tau) * (u_cmd - u_fb)
