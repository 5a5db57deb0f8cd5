"""Nominal NMPC (SPEC §7.3) in CasADi, and the base of the adaptive and robust variants.

Multiple shooting over N steps with the internal model's own discrete step (Euler velocities,
mid-step pose, the applied input as a state). The decision variables are ordered stage by stage,
``[x_0, u_0, ε_1, x_1, u_1, ε_2, …, x_N]``, and so are the constraints, so the QP's KKT matrix is
banded and the sparse QP solver's factorisation stays cheap. The initial state is fixed through
the bounds of x_0. Φ, the previous input, the reference points, the track constraint's centre
points and normals, the constraint's bound, an additive disturbance estimate d̂ (SPEC §7.5) and
the drivetrain factors Θ (SPEC §7.4) are NLP *parameters*: the NLP is built once per run and each
solve is warm-started from the shifted previous solution.

Cost Σ_{k=1..N} ‖p_k − p_ref,k‖²_Q + Σ_{k=0..N−1} ‖Δu_k‖²_R + Σ (w1·ε_k + w2·ε_k²), with soft
track constraints |n_k·(p_k − c_k)| ≤ half width − margin + ε_k, input bounds and |Δδ| ≤ 0.1.
When the internal model has no throttle path (DPM predicts Frx), only the steering is
optimised and the throttle comes from the PID speed loop. When a solve fails, the controller
applies the next input of its previous plan and counts a fallback.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from cape.closedloop.internal import N_STATE
from cape.closedloop.reference import ReferencePoints
from cape.controllers.base import Controller, PIDLoop, require
from cape.controllers.compiled import make_nlpsol
from cape.controllers.registry import register_controller
from cape.errors import CapeError
from cape.tracks.geometry import Projection

N_INPUT = 2
SETTINGS = ("horizon", "Q", "R", "margin", "slack_penalty", "solver", "ipopt_max_iter",
            "sqp_max_iter", "sqp_tol", "qp_max_iter", "speed")  # fmt: skip
STAGE = N_STATE + N_INPUT + 1  # x_k, u_k, ε_{k+1}


@register_controller("nmpc")
class NominalNMPC(Controller):
    needs_internal_model = True

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.internal is None or self.track is None:
            raise CapeError(f"controller {self.name} needs an internal model and the track")
        require(self.settings, SETTINGS, f"controllers.{self.name}")
        self.horizon = int(self.settings["horizon"])
        self._prepare_track_lookup()
        self._index()
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

    # --- where each variable lives in the decision vector ---------------------------------------
    def _index(self) -> None:
        n = self.horizon
        base = np.arange(n) * STAGE
        self._ix = np.vstack([base[:, None] + np.arange(N_STATE), n * STAGE + np.arange(N_STATE)])
        self._iu = base[:, None] + N_STATE + np.arange(N_INPUT)
        self._ie = base + N_STATE + N_INPUT
        self.n_w = n * STAGE + N_STATE

    def states(self, w: np.ndarray) -> np.ndarray:
        """The predicted states, (N+1) × 8, of a decision vector."""
        return w[self._ix]

    def inputs(self, w: np.ndarray) -> np.ndarray:
        """The planned commands, N × 2, of a decision vector."""
        return w[self._iu]

    # --- the NLP, built once -------------------------------------------------------------------
    def _symbols(self) -> dict[str, ca.SX]:
        n = self.horizon
        return {
            "phi": ca.SX.sym("phi", self.internal.n_phi),
            "u_prev": ca.SX.sym("u_prev", N_INPUT),
            "ref": ca.SX.sym("ref", 2, n),
            "centre": ca.SX.sym("centre", 2, n),
            "normal": ca.SX.sym("normal", 2, n),
            "bound": ca.SX.sym("bound"),
            "dhat": ca.SX.sym("dhat", 3),
            "theta": ca.SX.sym("theta", 3),
        }

    def nlp(self) -> dict[str, Any]:
        """The NLP as CasADi expressions, with the bounds of its constraints."""
        n, internal, s = self.horizon, self.internal, self.settings
        w = ca.SX.sym("w", self.n_w)
        p = self._symbols()
        q, r_t, r_d = float(s["Q"]), float(s["R"][0]), float(s["R"][1])
        w1, w2 = float(s["slack_penalty"][0]), float(s["slack_penalty"][1])
        step_max = self.limits.max_steering_step(self.ts)
        cost = 0
        g, lbg, ubg = [], [], []
        for k in range(n):
            x, u, e = w[self._ix[k]], w[self._iu[k]], w[self._ie[k]]
            x_next = w[self._ix[k + 1]]
            g.append(x_next - internal.step(x, u, p["phi"], p["dhat"], p["theta"]))
            lbg += [0.0] * N_STATE
            ubg += [0.0] * N_STATE
            du = u - (p["u_prev"] if k == 0 else w[self._iu[k - 1]])
            cost += r_t * du[0] ** 2 + r_d * du[1] ** 2
            g.append(du[1])
            lbg.append(-step_max)
            ubg.append(step_max)
            pos = x_next[0:2]
            cost += q * ca.sumsqr(pos - p["ref"][:, k]) + w1 * e + w2 * e**2
            offset = ca.dot(p["normal"][:, k], pos - p["centre"][:, k])
            g += [offset - e - p["bound"], -offset - e - p["bound"]]
            lbg += [-np.inf, -np.inf]
            ubg += [0.0, 0.0]
        params = ca.vertcat(*[ca.vec(v) for v in p.values()])
        return {
            "problem": {"x": w, "f": cost, "g": ca.vertcat(*g), "p": params},
            "lbg": np.array(lbg, dtype=float),
            "ubg": np.array(ubg, dtype=float),
        }

    def _build(self) -> None:
        built = self.nlp()
        self.solver, self.library = self._solver(built["problem"], str(self.settings["solver"]))
        self._prepare = self._wrap(self.solver, built["lbg"], built["ubg"])

    def _wrap(self, solver: ca.Function, lbg: np.ndarray, ubg: np.ndarray) -> ca.Function:
        """The solver's call for one step, with the warm start and the bounds formed by one
        compiled-in-CasADi function: (previous solution, x0, throttle bounds) → (initial guess,
        lbx, ubx). The solution and multipliers stay CasADi matrices between steps and the
        constant constraint bounds are converted once: converting arrays at the Python boundary
        would cost more than the compiled NLP functions themselves."""
        n, nw = self.horizon, self.n_w
        w_prev, x0 = ca.SX.sym("w_prev", nw), ca.SX.sym("x0", N_STATE)
        throttle = ca.SX.sym("throttle", 2)  # lower and upper bound of every T_k
        ix, iu = self._ix, self._iu
        guess = ca.SX.zeros(nw)
        for k in range(n + 1):  # x_0 ← x0, x_k ← x_{k+1} (the last one repeated)
            source = x0 if k == 0 else w_prev[ix[min(k + 1, n)]]
            guess[ix[k]] = source
        for k in range(n):
            guess[iu[k]] = w_prev[iu[min(k + 1, n - 1)]]
        lim = self.limits
        lbx, ubx = ca.SX(np.full(nw, -np.inf)), ca.SX(np.full(nw, np.inf))
        lbx[iu[:, 1]], ubx[iu[:, 1]] = -lim.delta_max, lim.delta_max
        lbx[iu[:, 0]], ubx[iu[:, 0]] = throttle[0], throttle[1]
        lbx[ix[0]], ubx[ix[0]] = x0, x0
        lbx[self._ie] = 0.0
        self._lbg_dm, self._ubg_dm = ca.DM(lbg), ca.DM(ubg)
        return ca.Function("nmpc_prepare", [w_prev, x0, throttle], [guess, lbx, ubx])

    def _solver(self, nlp: dict[str, Any], name: str) -> tuple[ca.Function, Path | None]:
        s = self.settings
        if name == "ipopt":
            opts: dict[str, Any] = {
                "ipopt.print_level": 0,
                "ipopt.sb": "yes",
                "ipopt.max_iter": int(s["ipopt_max_iter"]),
                "ipopt.warm_start_init_point": "yes",
                "print_time": False,
            }
            plugin = "ipopt"
        elif name == "sqp":
            opts = {
                "qpsol": "qrqp",
                "qpsol_options": {
                    "print_iter": False,
                    "print_header": False,
                    "print_info": False,
                    "error_on_fail": False,
                    "max_iter": int(s["qp_max_iter"]),
                },
                "hessian_approximation": "exact",
                "convexify_strategy": "none",
                "max_iter": int(s["sqp_max_iter"]),
                "tol_pr": float(s["sqp_tol"]),
                "tol_du": float(s["sqp_tol"]),
                "print_header": False,
                "print_iteration": False,
                "print_status": False,
                "print_time": False,
                "error_on_fail": False,
            }
            plugin = "sqpmethod"
        else:
            raise CapeError(f"controllers.{self.name}.solver: {name!r} is not one of ipopt, sqp")
        return make_nlpsol(self.name, plugin, nlp, opts, s.get("compile"))

    # --- what the variants change ----------------------------------------------------------------
    def estimate(self, z: np.ndarray) -> np.ndarray:
        """The state the NLP starts from (the robust NMPC filters it)."""
        return z

    def margin(self) -> float:
        return float(self.settings["margin"])

    def theta(self) -> np.ndarray:
        """Drivetrain factors Θ relative to the internal model's own (the adaptive NMPC's)."""
        return self._theta_one

    # --- each step -------------------------------------------------------------------------------
    def reset(self, z0: np.ndarray) -> None:
        super().reset(z0)
        self.internal.reset(z0)
        self.speed = PIDLoop.from_config(self.settings["speed"], self.ts)
        self._sol: list[ca.DM] | None = None  # solution and multipliers, kept as CasADi matrices
        self._plan: np.ndarray | None = None
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self.fallbacks = 0
        self.dhat = np.zeros(3)
        self._theta_one = np.ones(3)
        self.phi_now: np.ndarray | None = None

    @property
    def _w(self) -> np.ndarray | None:
        """The last solution as an array (None after a failure)."""
        return None if self._sol is None else self._sol[0].full().ravel()

    def parameters(self, ref: ReferencePoints, phi: np.ndarray) -> np.ndarray:
        """The NLP's parameter vector for this step."""
        n = self.horizon
        centre, normal = self._track_geometry(ref.s[1 : n + 1])
        return np.concatenate(
            [
                phi,
                self.u_prev,
                np.column_stack([ref.x[1 : n + 1], ref.y[1 : n + 1]]).ravel(),
                centre.ravel(),
                normal.ravel(),
                [self.track.width / 2 - self.margin()],
                self.dhat,
                self.theta(),
            ]
        )

    def solve(
        self, x0: np.ndarray, params: np.ndarray, throttle: tuple[float, float]
    ) -> tuple[list[ca.DM], bool]:
        """One NLP solve, warm-started from the previous solution (or x0 and u_prev held)."""
        if self._sol is None:
            guess, lbx, ubx = self._prepare(self.cold_start(x0), x0, throttle)
            multipliers = {}
        else:
            guess, lbx, ubx = self._prepare(self._sol[0], x0, throttle)
            multipliers = {"lam_x0": self._sol[1], "lam_g0": self._sol[2]}
        sol = self.solver(
            x0=guess,
            p=params,
            lbx=lbx,
            ubx=ubx,
            lbg=self._lbg_dm,
            ubg=self._ubg_dm,
            **multipliers,
        )
        out = [sol["x"], sol["lam_x"], sol["lam_g"]]
        return out, bool(self.solver.stats()["success"])

    def cold_start(self, x0: np.ndarray) -> np.ndarray:
        """x0 and the previous input held over the horizon (its shift is itself)."""
        w = np.zeros(self.n_w)
        w[self._ix] = x0
        w[self._iu] = self.u_prev
        return w

    def throttle_bounds(self, z: np.ndarray, ref: ReferencePoints) -> tuple[float, float]:
        """(T_min, T_max), or the speed loop's throttle held when the model has no throttle path."""
        lim = self.limits
        if self.internal.throttle_path:
            return lim.T_min, lim.T_max
        t = float(np.clip(self.speed.step(float(ref.speed[0]) - z[3]), lim.T_min, lim.T_max))
        return t, t

    def step(
        self, z: np.ndarray, proj: Projection, ref: ReferencePoints
    ) -> tuple[np.ndarray, dict[str, Any]]:
        z = self.estimate(z)
        if self._last is not None:
            self.internal.observe(*self._last)
        phi = self.internal.phi()
        self.phi_now = phi
        x0 = np.concatenate([z, self.u_prev])
        out, ok = self.solve(x0, self.parameters(ref, phi), self.throttle_bounds(z, ref))
        if ok:
            self._sol = out
            self._plan = self.inputs(out[0].full().ravel())
            u = self._plan[0]
        else:
            self.fallbacks += 1
            if self._plan is not None and len(self._plan) > 1:
                self._plan = self._plan[1:]
                u = self._plan[0]
            else:
                u = self.u_prev.copy()
            self._sol = None
        u = self.limits.clip(u, delta_prev=float(self.u_prev[1]), ts=self.ts)
        self._last = (z.copy(), u.copy())
        self.u_prev = u
        return u, {"fallback": not ok}
