"""An extended Kalman filter on the measured state, built on the controller's internal model
(SPEC §7.5).

The state is the car's [X, Y, ψ, vx, vy, ω]; the last applied input rides along as a known
quantity (the internal model's 8-state step). The prediction and its Jacobian are one CasADi
function built once. The covariances follow the disturbance levels of the run (SPEC §6): the
measurement covariance from the relative noise (and the IMU bias walk's growth on ψ and ω), the
process covariance from the process noise and crosswind plus a floor for the model's own error.
With no measurement noise (η = 0) the measurement covariance is zero and the estimate is the
measurement itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from cape.controllers.internal import InternalModel
from cape.tracks.geometry import wrap_angle

N_EKF = 6


@dataclass(frozen=True)
class NoiseLevels:
    """What a controller may know of the run's disturbances: their sizes, never their draws."""

    measurement_sigma: float = 0.0  # relative
    measurement_floor: tuple[float, ...] = (0.0,) * N_EKF
    process_sigma: float = 0.0  # relative, on vx, vy, ω
    process_floor: float = 0.0
    bias_sigma: tuple[float, float] = (0.0, 0.0)  # per step, on ψ and ω
    wind: tuple[float, float, float, float] | None = None  # vy gain, vx floor, ω gain, ω floor
    wrap_heading: bool = True  # the heading noise scales with the wrapped heading (SPEC §6)

    @classmethod
    def from_pipeline(cls, pipe: Any) -> NoiseLevels:
        """The levels of a ``DisturbancePipeline`` (inactive sources contribute nothing)."""
        kw: dict[str, Any] = {}
        if pipe.noise is not None:
            kw["measurement_sigma"] = float(pipe.noise.sigma)
            kw["measurement_floor"] = tuple(float(v) for v in np.broadcast_to(
                pipe.noise.floor, (N_EKF,)))  # fmt: skip
            kw["wrap_heading"] = bool(pipe.noise.wrap_heading)
        if pipe.process is not None:
            kw["process_sigma"] = float(pipe.process.sigma)
            kw["process_floor"] = float(pipe.process.floor)
        if pipe.bias is not None:
            kw["bias_sigma"] = (float(pipe.bias.sigma_psi), float(pipe.bias.sigma_omega))
        if pipe.wind is not None:
            w = pipe.wind
            kw["wind"] = (float(w.vy_gain), float(w.vx_floor), float(w.omega_gain),
                          float(w.omega_floor))  # fmt: skip
        return cls(**kw)


class ExtendedKalmanFilter:
    def __init__(
        self, internal: InternalModel, levels: NoiseLevels, model_std: tuple[float, ...]
    ) -> None:
        if len(model_std) != N_EKF:
            raise ValueError(f"ekf_model_std needs {N_EKF} values (X, Y, ψ, vx, vy, ω)")
        self.internal = internal
        self.levels = levels
        self.model_var = np.asarray(model_std, dtype=float) ** 2
        x = ca.SX.sym("x", N_EKF)
        applied = ca.SX.sym("applied", 2)
        u = ca.SX.sym("u", 2)
        phi = ca.SX.sym("phi", internal.n_phi)
        nxt = internal.step(ca.vertcat(x, applied), u, phi)
        self._predict = ca.Function(
            "ekf_predict",
            [x, applied, u, phi],
            [nxt[:N_EKF], ca.jacobian(nxt[:N_EKF], x)],
        )

    def reset(self, z: np.ndarray) -> None:
        self.x = np.asarray(z, dtype=float).copy()
        self.P = np.diag(self.measurement_var(self.x, 0)) + np.diag(self.model_var)
        self.steps = 0
        self.prior: np.ndarray | None = None

    def measurement_var(self, z: np.ndarray, steps: int) -> np.ndarray:
        lv = self.levels
        size = np.abs(z)
        if lv.wrap_heading:
            size[2] = abs(wrap_angle(float(z[2])))
        var = (lv.measurement_sigma * size + np.asarray(lv.measurement_floor)) ** 2
        var[2] += steps * lv.bias_sigma[0] ** 2  # the bias walk's spread so far
        var[5] += steps * lv.bias_sigma[1] ** 2
        return var

    def process_var(self, x: np.ndarray) -> np.ndarray:
        lv = self.levels
        var = self.model_var.copy()
        var[3:6] += (lv.process_sigma * np.abs(x[3:6]) + lv.process_floor) ** 2
        if lv.wind is not None:
            vy_gain, vx_floor, omega_gain, omega_floor = lv.wind
            var[4] += (vy_gain * max(abs(x[3]), vx_floor)) ** 2
            var[5] += (omega_gain * max(abs(x[5]), omega_floor)) ** 2
        return var

    def update(
        self,
        z: np.ndarray,
        applied: np.ndarray,
        u: np.ndarray,
        phi: np.ndarray,
    ) -> np.ndarray:
        """Predict from the last estimate with the input applied since, then correct with the
        measurement ``z``; returns the new estimate (the prior is kept in ``self.prior``)."""
        prior, jac = self._predict(self.x, applied, u, phi)
        prior = np.asarray(prior, dtype=float).ravel()
        jac = np.asarray(jac, dtype=float)
        self.steps += 1
        P = jac @ self.P @ jac.T + np.diag(self.process_var(prior))
        innovation = np.asarray(z, dtype=float) - prior
        innovation[2] = wrap_angle(innovation[2])
        S = P + np.diag(self.measurement_var(z, self.steps))
        gain = np.linalg.solve(S.T, P.T).T  # P S⁻¹ (H = I)
        self.x = prior + gain @ innovation
        self.P = (np.eye(N_EKF) - gain) @ P
        self.prior = prior
        return self.x.copy()
