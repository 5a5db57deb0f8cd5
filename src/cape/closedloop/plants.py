"""Plants: what the car is in a closed-loop run (SPEC §5.1).

A plant advances the full state ``[X, Y, ψ, vx, vy, ω]`` by one sample given the input that
reaches it. Parametric mismatch (SPEC §6) is applied here, inside the plant, never inside a
controller.

- ``LearnedPlant``: a trained model is the world; it keeps its own history of the last H rows
  (at reset H copies of ``[vx0, 0, 0, 0, 0, 0, 0]``), predicts Φ, takes the Euler step of the
  velocities, then moves the pose with the new velocities and the mid-step heading.
- ``FixedParameterPlant``: the same physics with Φ frozen (SPEC §4.5); no network runs.
- ``TruthPlant``: the SPEC §1 model with the true parameters, RK4.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

from cape.models.physics import ModelPhysics
from cape.models.trained import TrainedModel
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


def advance_pose(x: np.ndarray, v_next: tuple[float, float, float], ts: float) -> np.ndarray:
    """New state from the new velocities and the mid-step heading (SPEC §5.1)."""
    vx, vy, omega = v_next
    psi_mid = x[2] + 0.5 * ts * omega
    c, s = np.cos(psi_mid), np.sin(psi_mid)
    return np.array(
        [
            x[0] + ts * (vx * c - vy * s),
            x[1] + ts * (vx * s + vy * c),
            x[2] + ts * omega,
            vx,
            vy,
            omega,
        ]
    )


class _ModelPhysicsPlant:
    """Shared bookkeeping: the state, the last applied input, the model's physics step."""

    def __init__(self, physics: ModelPhysics, transform: ParamTransform | None) -> None:
        self.physics = physics
        self.ts = physics.ts
        self.transform = transform or _identity
        self.x = np.zeros(6)
        self.u_prev = np.zeros(2)

    def reset(self, x0: np.ndarray) -> None:
        self.x = np.asarray(x0, dtype=float).copy()
        self.u_prev = np.zeros(2)

    def _advance(self, u: np.ndarray, p: dict[str, Any]) -> np.ndarray:
        x = self.x
        v = self.physics.step_with_params(
            x[3], x[4], x[5], (self.u_prev[0], self.u_prev[1]), (u[0], u[1]), p
        )
        self.x = advance_pose(x, v, self.ts)
        self.u_prev = np.asarray(u, dtype=float).copy()
        return self.x.copy()


class LearnedPlant(_ModelPhysicsPlant):
    """A trained learned model as the world, with its own window of the last H rows."""

    def __init__(self, model: TrainedModel, transform: ParamTransform | None = None) -> None:
        super().__init__(model.physics, transform)
        self.predictor = model.network
        self.window = np.zeros((model.physics.history, 7))

    def reset(self, x0: np.ndarray) -> None:
        super().reset(x0)
        self.window = np.zeros((self.physics.history, 7))
        self.window[:, 0] = self.x[3]

    def step(self, u: np.ndarray) -> np.ndarray:
        x, fb = self.x, self.u_prev
        row = np.array([x[3], x[4], x[5], fb[0], fb[1], u[0] - fb[0], u[1] - fb[1]])
        self.window = np.vstack([self.window[1:], row])
        phi = self.predictor.phi(self.window)
        return self._advance(u, self.transform(self.physics.physical_params(phi)))


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

    def step(self, u: np.ndarray) -> np.ndarray:
        return self._advance(u, self.params)


class TruthPlant:
    """The data-generating car: SPEC §1 with the true parameters, RK4 at Ts."""

    def __init__(
        self, params: Mapping[str, Any], ts: float, transform: ParamTransform | None = None
    ) -> None:
        self.ts = ts
        self.params = (transform or _identity)(params)
        self.x = np.zeros(6)

    def reset(self, x0: np.ndarray) -> None:
        self.x = np.asarray(x0, dtype=float).copy()

    def step(self, u: np.ndarray) -> np.ndarray:
        self.x = rk4_step(
            lambda x, v: state_derivative(x, v, self.params),
            self.x,
            np.asarray(u, dtype=float),
            self.ts,
        )
        return self.x.copy()
