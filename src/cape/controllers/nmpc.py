"""Nominal NMPC (SPEC §7.3) in CasADi.

Multiple shooting over N steps with the internal model's own discrete step (Euler velocities,
mid-step pose, the applied input as a state). Φ, the initial state, the previous input, the
reference points, the track constraint's centre points and normals, the constraint's bound and
an additive disturbance estimate are NLP *parameters*: the NLP is built once per run and each
solve is warm-started from the shifted previous solution.

Cost Σ_{k=1..N} ‖p_k − p_ref,k‖²_Q + Σ_{k=0..N−1} ‖Δu_k‖²_R + Σ (w1·ε_k + w2·ε_k²), with soft
track constraints |n_k·(p_k − c_k)| ≤ half width − margin + ε_k, input bounds and |Δδ| ≤ 0.1.
When the internal model has no throttle path (DPM predicts Frx), only the steering is
optimised and the throttle comes from the PID speed loop. When a solve fails, the controller
applies the next input of its previous plan and counts a fallback.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from cape.closedloop.internal import N_STATE
from cape.closedloop.reference import ReferencePoints
from cape.controllers.base import Controller, PIDLoop
from cape.controllers.registry import register_controller
from cape.errors import CapeError
from cape.tracks.geometry import Projection


@register_controller("nmpc")
class NominalNMPC(Controller):
    needs_internal_model = True

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.internal is None or self.track is None:
            raise CapeError(f"controller {self.name} needs an internal model and the track")
        self.horizon = int(self.settings["horizon"])
        self._prepare_track_lookup()
        self._build()

    # --- the track constraint's geometry, precomputed along the reference line ----------------
    def _prepare_track_lookup(self) -> None:
        path, centre = self.line.path, self.track.center
        s_hint = None
        points, normals = [], []
        for x, y in zip(path.x, path.y, strict=True):
            proj = centre.project(x, y, s_hint, 0.5 if s_hint is not None else None)
            s_hint = proj.s
            heading = float(centre.heading(proj.s))
            points.append((proj.x, proj.y))
            normals.append((-np.sin(heading), np.cos(heading)))
        self._centre = np.array(points)
        self._normal = np.array(normals)

    def _track_geometry(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        idx = (
            np.searchsorted(self.line.path.s_points, np.mod(s, self.line.length), side="right") - 1
        )
        return self._centre[idx], self._normal[idx]

    # --- the NLP, built once -------------------------------------------------------------------
    def _build(self) -> None:
        n, nx, internal = self.horizon, N_STATE, self.internal
        s = self.settings
        X = ca.SX.sym("X", nx, n + 1)
        U = ca.SX.sym("U", 2, n)
        E = ca.SX.sym("E", n)
        x0 = ca.SX.sym("x0", nx)
        phi = ca.SX.sym("phi", internal.n_phi)
        u_prev = ca.SX.sym("u_prev", 2)
        ref = ca.SX.sym("ref", 2, n)
        centre = ca.SX.sym("centre", 2, n)
        normal = ca.SX.sym("normal", 2, n)
        bound = ca.SX.sym("bound")
        dhat = ca.SX.sym("dhat", 3)
        q, r_t, r_d = float(s["Q"]), float(s["R"][0]), float(s["R"][1])
        w1, w2 = float(s["slack_penalty"][0]), float(s["slack_penalty"][1])
        cost = 0
        g = [X[:, 0] - x0]
        lbg, ubg = [np.zeros(nx)], [np.zeros(nx)]
        step_max = self.limits.max_steering_step(self.ts)
        for k in range(n):
            g.append(X[:, k + 1] - internal.step(X[:, k], U[:, k], phi, dhat))
            lbg.append(np.zeros(nx))
            ubg.append(np.zeros(nx))
            du = U[:, k] - (u_prev if k == 0 else U[:, k - 1])
            cost += r_t * du[0] ** 2 + r_d * du[1] ** 2
            g.append(du[1])
            lbg.append([-step_max])
            ubg.append([step_max])
            p = X[0:2, k + 1]
            cost += q * ca.sumsqr(p - ref[:, k]) + w1 * E[k] + w2 * E[k] ** 2
            offset = ca.dot(normal[:, k], p - centre[:, k])
            g += [offset - E[k] - bound, -offset - E[k] - bound]
            lbg += [[-np.inf], [-np.inf]]
            ubg += [[0.0], [0.0]]
        w = ca.vertcat(ca.vec(X), ca.vec(U), E)
        params = ca.vertcat(
            x0, phi, u_prev, ca.vec(ref), ca.vec(centre), ca.vec(normal), bound, dhat
        )
        nlp = {"x": w, "f": cost, "g": ca.vertcat(*g), "p": params}
        self.solver = self._solver(nlp, str(s["solver"]))
        self._lbg = np.concatenate([np.ravel(np.asarray(v, dtype=float)) for v in lbg])
        self._ubg = np.concatenate([np.ravel(np.asarray(v, dtype=float)) for v in ubg])
        self.n_w = w.shape[0]
        self.n_x = nx * (n + 1)
        self.n_u = 2 * n

    def _solver(self, nlp: dict[str, Any], name: str) -> ca.Function:
        s = self.settings
        if name == "ipopt":
            opts = {
                "ipopt.print_level": 0,
                "ipopt.sb": "yes",
                "ipopt.max_iter": int(s["ipopt_max_iter"]),
                "ipopt.warm_start_init_point": "yes",
                "print_time": False,
            }
            return ca.nlpsol("nmpc", "ipopt", nlp, opts)
        if name == "sqp":
            opts = {
                "qpsol": "qrqp",
                "qpsol_options": {
                    "print_iter": False,
                    "print_header": False,
                    "error_on_fail": False,
                },
                "hessian_approximation": "exact",
                "convexify_strategy": "none",
                "max_iter": int(s["sqp_max_iter"]),
                "print_header": False,
                "print_iteration": False,
                "print_status": False,
                "print_time": False,
                "error_on_fail": False,
            }
            return ca.nlpsol("nmpc", "sqpmethod", nlp, opts)
        raise CapeError(f"controllers.{self.name}.solver: {name!r} is not one of ipopt, sqp")

    # --- each step -------------------------------------------------------------------------------
    def reset(self, z0: np.ndarray) -> None:
        super().reset(z0)
        self.internal.reset(z0)
        self.speed = PIDLoop.from_config(self.settings["speed"], self.ts)
        self._w = None
        self._lam_x = None
        self._lam_g = None
        self._plan: np.ndarray | None = None
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self.fallbacks = 0
        self.dhat = np.zeros(3)

    def margin(self) -> float:
        return float(self.settings["margin"])

    def step(
        self, z: np.ndarray, proj: Projection, ref: ReferencePoints
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if self._last is not None:
            self.internal.observe(*self._last)
        n = self.horizon
        phi = self.internal.phi()
        x0 = np.concatenate([z, self.u_prev])
        refs = np.vstack([ref.x[1 : n + 1], ref.y[1 : n + 1]])
        centre, normal = self._track_geometry(ref.s[1 : n + 1])
        bound = self.track.width / 2 - self.margin()
        geometry = [refs.ravel(order="F"), centre.T.ravel(order="F"), normal.T.ravel(order="F")]
        params = np.concatenate([x0, phi, self.u_prev, *geometry, [bound], self.dhat])
        lbx, ubx = self._bounds(z, ref)
        w0 = self._initial_guess(x0)
        args = {"x0": w0, "p": params, "lbx": lbx, "ubx": ubx, "lbg": self._lbg, "ubg": self._ubg}
        if self._lam_x is not None:
            args["lam_x0"], args["lam_g0"] = self._lam_x, self._lam_g
        sol = self.solver(**args)
        ok = bool(self.solver.stats()["success"])
        if ok:
            w = np.array(sol["x"]).ravel()
            self._w, self._lam_x, self._lam_g = (
                w,
                np.array(sol["lam_x"]).ravel(),
                np.array(sol["lam_g"]).ravel(),
            )
            plan = w[self.n_x : self.n_x + self.n_u].reshape(n, 2)
            self._plan = plan
            u = plan[0]
        else:
            self.fallbacks += 1
            if self._plan is not None and len(self._plan) > 1:
                self._plan = self._plan[1:]
                u = self._plan[0]
            else:
                u = self.u_prev.copy()
            self._w = self._lam_x = self._lam_g = None
        u = self.limits.clip(u, delta_prev=float(self.u_prev[1]), ts=self.ts)
        self._last = (z.copy(), u.copy())
        self.u_prev = u
        return u, {"fallback": not ok}

    def _bounds(self, z: np.ndarray, ref: ReferencePoints) -> tuple[np.ndarray, np.ndarray]:
        n = self.horizon
        lbx = np.full(self.n_w, -np.inf)
        ubx = np.full(self.n_w, np.inf)
        lim = self.limits
        t_low, t_high = lim.T_min, lim.T_max
        if not self.internal.throttle_path:  # steering only; throttle from the speed loop
            t_low = t_high = float(
                np.clip(self.speed.step(float(ref.speed[0]) - z[3]), lim.T_min, lim.T_max)
            )
        u_lb = np.tile([t_low, -lim.delta_max], n)
        u_ub = np.tile([t_high, lim.delta_max], n)
        lbx[self.n_x : self.n_x + self.n_u] = u_lb
        ubx[self.n_x : self.n_x + self.n_u] = u_ub
        lbx[self.n_x + self.n_u :] = 0.0
        return lbx, ubx

    def _initial_guess(self, x0: np.ndarray) -> np.ndarray:
        n, nx = self.horizon, N_STATE
        if self._w is None:
            xs = np.tile(x0, n + 1)
            us = np.tile(self.u_prev, n)
            return np.concatenate([xs, us, np.zeros(n)])
        w = self._w
        xs = w[: self.n_x].reshape(n + 1, nx)
        us = w[self.n_x : self.n_x + self.n_u].reshape(n, 2)
        xs = np.vstack([x0, xs[2:], xs[-1:]])
        us = np.vstack([us[1:], us[-1:]])
        return np.concatenate([xs.ravel(), us.ravel(), np.zeros(n)])
