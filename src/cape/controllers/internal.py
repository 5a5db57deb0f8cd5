"""A controller's internal model (SPEC §7.3): its discrete step, and where its Φ comes from.

- ``learned``: Φ predicted once per step from the controller's own history, held over the horizon;
- ``fixed``: the frozen Φ of SPEC §4.5;
- ``truth``: the ground-truth parameters in the Deep Dynamics structure (the ceiling).

The step is the learned models', on the backend-neutral equations; its state carries the last
applied input, ``[X, Y, ψ, vx, vy, ω, T_app, δ_app]``. Why: docs/modules.md.
"""

from __future__ import annotations

from typing import Any, get_args

import numpy as np

from cape.layout.names import PlantKind
from cape.models.physics import ModelPhysics
from cape.models.trained import PhiPredictor
from cape.vehicle.backend import ops_for
from cape.vehicle.params import GROUND_TRUTH

N_STATE = 8
DRIVETRAIN = ("Cm1", "Cr0", "Cr2")


class InternalModel:
    def __init__(
        self,
        model: ModelPhysics,
        source: PlantKind,
        fixed: dict[str, float] | None = None,
        predictor: PhiPredictor | None = None,
    ) -> None:
        if source not in get_args(PlantKind):
            raise ValueError(f"unknown Φ source {source!r}")
        if (source == "learned") != (fixed is None) or (source == "learned") != (
            predictor is not None
        ):
            raise ValueError(
                "a learned internal model predicts Φ (it needs the network); "
                "the others need fixed values"
            )
        self.model = model
        self.source = source
        self.ts = model.ts
        self.throttle_path = model.throttle_path or source != "learned"
        self.predictor = predictor
        self._fixed_names = tuple(fixed or ())
        self.fixed_phi = None if fixed is None else np.array(list(fixed.values()), dtype=float)
        self.window = np.zeros((model.history, 7))
        self.u_prev = np.zeros(2)
        # the drivetrain law's nominal values, the scale of Θ for a model without one (DPM)
        self.nominal_drivetrain = {n: float(GROUND_TRUTH.as_dict()[n]) for n in DRIVETRAIN}

    @property
    def n_phi(self) -> int:
        return len(self.param_names)

    @property
    def param_names(self) -> tuple[str, ...]:
        if self.source == "learned":
            return self.model.param_names
        return tuple(self._fixed_names)

    def reset(self, z0: np.ndarray) -> None:
        self.window = np.zeros((self.model.history, 7))
        self.window[:, 0] = z0[3]
        self.u_prev = np.zeros(2)

    def observe(self, z: np.ndarray, u: np.ndarray) -> None:
        """Append the row of this step (measured state, the command about to be applied)."""
        fb = self.u_prev
        row = np.array([z[3], z[4], z[5], fb[0], fb[1], u[0] - fb[0], u[1] - fb[1]])
        self.window = np.vstack([self.window[1:], row])
        self.u_prev = np.asarray(u, dtype=float).copy()

    def phi(self) -> np.ndarray:
        """Φ for the coming horizon."""
        if self.predictor is not None:
            return self.predictor.phi(self.window)
        assert self.fixed_phi is not None
        return self.fixed_phi

    def params(self, phi: Any) -> dict[str, Any]:
        if self.source == "learned":
            return self.model.physical_params(phi)
        return self.model.frozen_params({n: phi[i] for i, n in enumerate(self._fixed_names)})

    def corrected(self, p: dict[str, Any], theta: Any, vx: Any, throttle: Any) -> dict[str, Any]:
        """The parameters with the drivetrain correction Θ (relative factors, SPEC §7.4)."""
        if theta is None:
            return p
        p = dict(p)
        if "Cm1" in p:
            for i, name in enumerate(DRIVETRAIN):
                p[name] = p[name] * theta[i]
            return p
        # DPM: the same relative factors act on the drivetrain law at its nominal values,
        # added to the predicted force
        cm1, cr0, cr2 = (self.nominal_drivetrain[n] for n in DRIVETRAIN)
        p["Frx"] = (
            p["Frx"]
            + (theta[0] - 1) * cm1 * throttle
            - (theta[1] - 1) * cr0
            - (theta[2] - 1) * cr2 * vx**2
        )
        return p

    def step(self, x: Any, u: Any, phi: Any, dhat: Any = None, theta: Any = None) -> Any:
        """One step of the 8-state internal model (NumPy or CasADi), optional additive velocity
        disturbance estimate ``dhat`` (continuous, 3 components) and drivetrain factors
        ``theta`` (SPEC §7.4)."""
        p = self.params(phi)
        fb, cmd = (x[6], x[7]), (u[0], u[1])
        applied = self.model.applied_inputs(fb, cmd, p)
        p = self.corrected(p, theta, x[3], applied[0])
        vx, vy, omega = self.model.step_with_params(x[3], x[4], x[5], applied, applied, p)
        if dhat is not None:
            vx, vy, omega = (
                vx + self.ts * dhat[0],
                vy + self.ts * dhat[1],
                omega + self.ts * dhat[2],
            )
        ops = ops_for(x, u, phi)
        psi_mid = x[2] + 0.5 * self.ts * omega
        c, s = ops.cos(psi_mid), ops.sin(psi_mid)
        return ops.stack(
            [
                x[0] + self.ts * (vx * c - vy * s),
                x[1] + self.ts * (vx * s + vy * c),
                x[2] + self.ts * omega,
                vx,
                vy,
                omega,
                applied[0],
                applied[1],
            ]
        )


def fixed_internal(
    model: ModelPhysics, frozen: dict[str, float], source: str = "fixed"
) -> InternalModel:
    """An internal model with constant Φ (frozen, or the truth)."""
    return InternalModel(model, source, dict(frozen))
