"""Plants: what the car is in a closed-loop run (SPEC §5.1).

A plant advances the full state ``[X, Y, ψ, vx, vy, ω]`` by one sample given the input that
reaches it. Parametric mismatch (SPEC §6) is applied here, inside the plant, never inside a
controller. ``LearnedPlant`` (a trained model is the world), ``FixedParameterPlant`` (Φ frozen,
SPEC §4.5) and ``TruthPlant`` (the SPEC §1 model, RK4). How each steps: docs/modules.md.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import casadi as ca
import numpy as np

from cape.models.physics import ModelPhysics
from cape.models.trained import TrainedModel
from cape.numerics.buffered import BufferedCall
from cape.numerics.compiled import serialized_function, source_digest
from cape.vehicle.backend import ops_for
from cape.vehicle.dynamics import state_derivative
from cape.vehicle.integrators import rk4_step

ParamTransform = Callable[[Mapping[str, Any]], dict[str, Any]]


class Plant(Protocol):
    ts: float

    def reset(self, x0: np.ndarray) -> None: ...

    def step(self, u: np.ndarray) -> np.ndarray:
        """The state after one sample with input ``u = [T, δ]`` reaching the wheels' actuators."""
        ...


def _identity(p: Mapping[str, Any]) -> dict[str, Any]:
    return dict(p)


def advance_pose(x: Any, v_next: tuple[Any, Any, Any], ts: float) -> Any:
    """New state from the new velocities and the mid-step heading (SPEC §5.1), any backend."""
    vx, vy, omega = v_next
    ops = ops_for(x, vx, vy, omega)
    psi_mid = x[2] + 0.5 * ts * omega
    c, s = ops.cos(psi_mid), ops.sin(psi_mid)
    return ops.stack(
        [
            x[0] + ts * (vx * c - vy * s),
            x[1] + ts * (vx * s + vy * c),
            x[2] + ts * omega,
            vx,
            vy,
            omega,
        ]
    )


def _physics_step(physics: ModelPhysics, params: Any, phi: ca.SX | None) -> ca.Function:
    """The plant's step as one CasADi function, built from the same backend-neutral equations:
    (x, previous input, input[, Φ]) → next x. ``params`` maps Φ (a symbol, or None for frozen
    values) to the parameter mapping the equations read."""
    x, u_fb, u = ca.SX.sym("x", 6), ca.SX.sym("u_fb", 2), ca.SX.sym("u", 2)
    p = params(phi)
    v = physics.step_with_params(x[3], x[4], x[5], (u_fb[0], u_fb[1]), (u[0], u[1]), p)
    inputs = [x, u_fb, u] + ([phi] if phi is not None else [])
    return ca.Function("plant_step", inputs, [advance_pose(x, v, physics.ts)])


class _ModelPhysicsPlant:
    """Shared bookkeeping: the state, the last applied input, the model's physics step (one
    compiled-in-CasADi function, called through its buffer: a few microseconds a step)."""

    def __init__(self, physics: ModelPhysics, transform: ParamTransform | None) -> None:
        self.physics = physics
        self.ts = physics.ts
        self.transform = transform or _identity
        self.x = np.zeros(6)
        self.u_prev = np.zeros(2)

    def reset(self, x0: np.ndarray) -> None:
        self.x = np.asarray(x0, dtype=float).copy()
        self.u_prev = np.zeros(2)

    def _advance(self, u: np.ndarray, *phi: np.ndarray) -> np.ndarray:
        self.x = self._step(self.x, self.u_prev, u, *phi)[0].copy()
        self.u_prev = np.asarray(u, dtype=float).copy()
        return self.x.copy()


class LearnedPlant(_ModelPhysicsPlant):
    """A trained learned model as the world, with its own window of the last H rows."""

    def __init__(self, model: TrainedModel, transform: ParamTransform | None = None) -> None:
        super().__init__(model.physics, transform)
        self.predictor = model.network
        self.window = np.zeros((model.physics.history, 7))
        phi = ca.SX.sym("phi", len(self.physics.param_names))
        params = lambda phi: self.transform(self.physics.physical_params(phi))  # noqa: E731
        self._step = BufferedCall(_physics_step(self.physics, params, phi))

    def reset(self, x0: np.ndarray) -> None:
        super().reset(x0)
        self.window = np.zeros((self.physics.history, 7))
        self.window[:, 0] = self.x[3]

    def step(self, u: np.ndarray) -> np.ndarray:
        x, fb = self.x, self.u_prev
        row = np.array([x[3], x[4], x[5], fb[0], fb[1], u[0] - fb[0], u[1] - fb[1]])
        self.window = np.vstack([self.window[1:], row])
        return self._advance(u, self.predictor.phi(self.window))


class FixedParameterPlant(_ModelPhysicsPlant):
    """A model's physics with Φ frozen at its training median (SPEC §4.5)."""

    def __init__(
        self,
        physics: ModelPhysics,
        frozen: Mapping[str, float],
        transform: ParamTransform | None = None,
    ) -> None:
        super().__init__(physics, transform)
        self.params = self.transform(physics.frozen_params(dict(frozen)))
        # the frozen values enter as an input, as Φ does in the learned plant, so both plants
        # evaluate the same expressions in the same order
        names = list(frozen)
        self._frozen = np.array([float(frozen[n]) for n in names])
        values = ca.SX.sym("frozen", len(names))

        def params(vec: ca.SX) -> dict[str, Any]:
            return self.transform(physics.frozen_params({n: vec[i] for i, n in enumerate(names)}))

        self._step = BufferedCall(_physics_step(physics, params, values))

    def step(self, u: np.ndarray) -> np.ndarray:
        return self._advance(u, self._frozen)


class TruthPlant:
    """The data-generating car: SPEC §1 with the true parameters, RK4 at Ts (one CasADi
    function of the shared equations, called through its buffer)."""

    def __init__(
        self,
        params: Mapping[str, Any],
        ts: float,
        transform: ParamTransform | None = None,
        cache: dict[str, Any] | None = None,
    ) -> None:
        """``cache``: the ``rollout.compile`` settings, whose cache keeps the built function
        (``cape.numerics.compiled.serialized_function``: the same function, without building it)."""
        self.ts = ts
        self.params = (transform or _identity)(params)
        self.x = np.zeros(6)

        def build() -> ca.Function:
            x, u = ca.SX.sym("x", 6), ca.SX.sym("u", 2)
            rk4 = rk4_step(lambda x, v: state_derivative(x, v, self.params), x, u, ts)
            return ca.Function("truth_rk4", [x, u], [rk4])

        from cape.vehicle import backend, dynamics, integrators

        key = repr((sorted(self.params.items()), ts))
        key += source_digest(sys.modules[__name__], dynamics, integrators, backend)
        self._step = BufferedCall(serialized_function("truth_rk4", key, build, cache))

    def reset(self, x0: np.ndarray) -> None:
        self.x = np.asarray(x0, dtype=float).copy()

    def step(self, u: np.ndarray) -> np.ndarray:
        self.x = self._step(self.x, u)[0].copy()
        return self.x.copy()
