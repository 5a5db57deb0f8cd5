"""The NMPC's optimal-control problem (SPEC §7.3), defined once, stage by stage.

Cost Σ_{k=1..N} ‖p_k − p_ref,k‖²_Q + Σ_{k=0..N−1} ‖Δu_k‖²_R + Σ (w1·ε_k + w2·ε_k²), soft track
constraints |n_k·(p_k − c_k)| ≤ half width − margin + ε_k, input bounds, the steering rate limit
and the internal model's own discrete step. Φ, d̂ (SPEC §7.5), Θ (SPEC §7.4) and the other data
of a step are *parameters* (``layout``): built once per run, only the parameter vector changes.
``stage_terms`` and ``model_step`` build every formulation: ``cape.controllers.sqp``, ``nlp``
and ``cape.controllers.stagewise``. The parameters in full: docs/modules.md.
"""

from __future__ import annotations

import json
import sys
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from cape.controllers.internal import N_STATE, InternalModel
from cape.numerics.compiled import source_digest
from cape.tracks.reference import ReferenceLine, ReferencePoints
from cape.tracks.track import Track

N_INPUT = 2
STAGE = N_STATE + N_INPUT + 1  # x_k, u_k, ε_{k+1}


class TrackingOCP:
    """The problem of one NMPC: ``horizon`` stages of its ``internal`` model along ``line`` on
    ``track``, weighted by ``settings`` (``Q``, ``R``, ``slack_penalty``), within ``limits``."""

    #: the settings ``stage_terms`` reads; a subclass whose own ``stage_terms`` reads more
    #: extends this, so that its compiled library is keyed on them
    terms_settings: ClassVar[tuple[str, ...]] = ("Q", "R", "slack_penalty")

    def __init__(
        self,
        horizon: int,
        settings: dict[str, Any],
        internal: InternalModel,
        limits: Any,
        ts: float,
        line: ReferenceLine,
        track: Track,
    ) -> None:
        self.horizon = int(horizon)
        self.settings = settings
        self.internal = internal
        self.limits = limits
        self.ts = ts
        self.line = line
        self.track = track
        self._prepare_track_lookup()
        self._index()
        self._layout()

    # --- the track constraint's geometry, precomputed along the reference line ----------------
    def _prepare_track_lookup(self) -> None:
        """Each reference point's nearest centre-line point and the centre line's normal there.
        All points are projected on the whole centre line at once; should the nearest point
        jump along the centre line between consecutive reference points (a stretch of track
        passing near another), they are projected one by one instead, each within 0.5 m of the
        last."""
        path, centre = self.line.path, self.track.center
        s, points = centre.project_many(path.x, path.y)
        half = centre.length / 2
        if np.max(np.abs((np.diff(np.append(s, s[0])) + half) % centre.length - half)) > 0.5:
            s_hint, rows = None, []
            for x, y in zip(path.x, path.y, strict=True):
                proj = centre.project(x, y, s_hint, 0.5 if s_hint is not None else None)
                s_hint = proj.s
                rows.append((proj.s, proj.x, proj.y))
            s, points = np.array(rows)[:, 0], np.array(rows)[:, 1:]
        heading = centre.heading(s)
        self._centre = points
        self._normal = np.column_stack([-np.sin(heading), np.cos(heading)])

    def track_geometry(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The centre points and normals of the track constraint at arc lengths ``s``."""
        idx = (
            np.searchsorted(self.line.path.s_points, np.mod(s, self.line.length), side="right") - 1
        )
        return self._centre[idx], self._normal[idx]

    # --- where each variable lives in the multiple-shooting decision vector -------------------
    def _index(self) -> None:
        n = self.horizon
        base = np.arange(n) * STAGE
        self.ix = np.vstack([base[:, None] + np.arange(N_STATE), n * STAGE + np.arange(N_STATE)])
        self.iu = base[:, None] + N_STATE + np.arange(N_INPUT)
        self.ie = base + N_STATE + N_INPUT
        self.n_w = n * STAGE + N_STATE

    def states(self, w: np.ndarray) -> np.ndarray:
        """The predicted states, (N+1) × 8, of a decision vector."""
        return w[self.ix]

    def inputs(self, w: np.ndarray) -> np.ndarray:
        """The planned commands, N × 2, of a decision vector."""
        return w[self.iu]

    # --- the parameters ------------------------------------------------------------------------
    def _layout(self) -> None:
        """Where each parameter of the problem lives in its parameter vector."""
        n = self.horizon
        sizes = {
            "phi": self.internal.n_phi,
            "u_prev": N_INPUT,
            "ref": 2 * n,
            "centre": 2 * n,
            "normal": 2 * n,
            "bound": 1,
            "dhat": 3,
            "theta": 3,
        }
        self.layout, start = {}, 0
        for name, size in sizes.items():
            self.layout[name] = slice(start, start + size)
            start += size
        self.n_param = start

    def parameters(
        self,
        ref: ReferencePoints,
        phi: np.ndarray,
        u_prev: np.ndarray,
        bound: float,
        dhat: np.ndarray,
        theta: np.ndarray,
    ) -> np.ndarray:
        """The parameter vector of one step."""
        n = self.horizon
        centre, normal = self.track_geometry(ref.s[1 : n + 1])
        return np.concatenate(
            [
                phi,
                u_prev,
                np.column_stack([ref.x[1 : n + 1], ref.y[1 : n + 1]]).ravel(),
                centre.ravel(),
                normal.ravel(),
                [bound],
                dhat,
                theta,
            ]
        )

    # --- the problem, stage by stage -------------------------------------------------------------
    def stage_terms(
        self, x_next: Any, u: Any, u_before: Any, e: Any, p: Any, k: int
    ) -> tuple[Any, Any, Any, Any]:
        """Stage k of the problem, the one definition every formulation uses: its cost
        ``q‖p_{k+1} − p_ref‖² + r_T·ΔT² + r_δ·Δδ² + w1·ε + w2·ε²``, its steering change Δδ
        (bounded by the rate limit), the track offset of p_{k+1} along the centre line's normal
        (bounded by the soft constraint |offset| ≤ bound + ε), and the residual vector whose
        squared norm is the cost's quadratic part (Gauss–Newton)."""
        s = self.settings
        q, r_t, r_d = float(s["Q"]), float(s["R"][0]), float(s["R"][1])
        w1, w2 = float(s["slack_penalty"][0]), float(s["slack_penalty"][1])
        layout = self.layout
        ref = ca.reshape(p[layout["ref"]], 2, self.horizon)[:, k]
        centre = ca.reshape(p[layout["centre"]], 2, self.horizon)[:, k]
        normal = ca.reshape(p[layout["normal"]], 2, self.horizon)[:, k]
        du = u - u_before
        pos = x_next[0:2]
        cost = q * ca.sumsqr(pos - ref) + r_t * du[0] ** 2 + r_d * du[1] ** 2 + w1 * e + w2 * e**2
        residual = ca.vertcat(
            np.sqrt(q) * (pos - ref), np.sqrt(r_t) * du[0], np.sqrt(r_d) * du[1], np.sqrt(w2) * e
        )
        offset = ca.dot(normal, pos - centre)
        return cost, du[1], offset, residual

    def model_step(self, x: Any, u: Any, p: Any) -> Any:
        """The internal model's step with the problem's parameters (Φ, d̂, Θ)."""
        layout = self.layout
        return self.internal.step(x, u, p[layout["phi"]], p[layout["dhat"]], p[layout["theta"]])

    def nlp(self) -> dict[str, Any]:
        """The multiple-shooting NLP as CasADi expressions (IPOPT's and CasADi's sqpmethod's
        formulation); its constraints per stage: the dynamics, the steering rate, the soft
        track bound on either side (``nlp_bounds``)."""
        w = ca.SX.sym("w", self.n_w)
        p = ca.SX.sym("p", self.n_param)
        cost = 0
        g = []
        for k in range(self.horizon):
            x, u, e = w[self.ix[k]], w[self.iu[k]], w[self.ie[k]]
            x_next = w[self.ix[k + 1]]
            g.append(x_next - self.model_step(x, u, p))
            before = p[self.layout["u_prev"]] if k == 0 else w[self.iu[k - 1]]
            stage_cost, rate, offset, _ = self.stage_terms(x_next, u, before, e, p, k)
            cost += stage_cost
            bound = p[self.layout["bound"]]
            g += [rate, offset - e - bound, -offset - e - bound]
        return {"x": w, "f": cost, "g": ca.vertcat(*g), "p": p}

    def nlp_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The bounds (lbg, ubg) of ``nlp``'s constraints, without building it."""
        step_max = self.limits.max_steering_step(self.ts)
        stage_lb = [0.0] * N_STATE + [-step_max, -np.inf, -np.inf]
        stage_ub = [0.0] * N_STATE + [step_max, 0.0, 0.0]
        return np.array(stage_lb * self.horizon), np.array(stage_ub * self.horizon)

    def terms_key(self) -> str:
        """What ``stage_terms`` depends on, for a compiled library's key: the settings it reads,
        the parameter layout, the horizon, and the source of the class that defines it and of
        the classes it is made of (every NMPC of this problem shares one library)."""
        owner = next(c for c in type(self).__mro__ if "stage_terms" in vars(c))
        modules = {sys.modules[c.__module__] for c in owner.__mro__ if c is not object}
        sources = source_digest(*sorted(modules, key=lambda m: m.__name__))
        layout = sorted((k, v.start, v.stop) for k, v in self.layout.items())
        kept = {k: self.settings[k] for k in self.terms_settings}
        settings = json.dumps(kept, sort_keys=True, default=str)
        return f"{settings}|{layout}|{self.horizon}|{sources}"
