"""Nominal NMPC (SPEC §7.3) in CasADi, and the base of the adaptive and robust variants.

The optimal control problem is defined once, stage by stage (``stage_terms``, ``model_step``):
cost Σ_{k=1..N} ‖p_k − p_ref,k‖²_Q + Σ_{k=0..N−1} ‖Δu_k‖²_R + Σ (w1·ε_k + w2·ε_k²), soft track
constraints |n_k·(p_k − c_k)| ≤ half width − margin + ε_k, input bounds and |Δδ| ≤ 0.1, and
the internal model's own discrete step (Euler velocities, mid-step pose, the applied input as a
state). Φ, the previous input, the reference points, the track constraint's centre points and
normals, the constraint's bound, an additive disturbance estimate d̂ (SPEC §7.5) and the
drivetrain factors Θ (SPEC §7.4) are *parameters*: the problem is built once per run and each
solve is warm-started from the shifted previous solution.

Two formulations of that problem, chosen by ``solver``: ``sqp`` (the default) eliminates the
states and solves the condensed problem with a feasible-iterate SQP (``cape.controllers.sqp``);
``ipopt`` (the reference) and ``sqpmethod`` (CasADi's SQP) solve the
multiple-shooting NLP (``nlp``, ``cape.controllers.shooting``). When the internal model has no
throttle path (DPM predicts Frx), only the steering is optimised and the throttle comes from the
PID speed loop. When the SQP does not converge, a rescue solves the same problem from its last
iterate: Fatrop on the stage-wise form of the NLP (``cape.controllers.stagewise``, the default)
or IPOPT on the multiple-shooting NLP. When that fails too, the controller applies the next
input of its previous plan and counts a fallback.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from cape.compiled import source_digest
from cape.controllers import shooting, stagewise
from cape.controllers.base import GAINS, Controller, PIDLoop, require
from cape.controllers.internal import N_STATE
from cape.controllers.registry import register_controller
from cape.controllers.shooting import (
    MultipleShootingNLP,
    check_ipopt_options,
    ipopt_options,
    sqpmethod_options,
)
from cape.controllers.sqp import CondensedSQP
from cape.errors import CapeError
from cape.tracks.geometry import Projection
from cape.tracks.reference import ReferencePoints

N_INPUT = 2
SETTINGS = (
    "horizon",
    "Q",
    "R",
    "margin",
    "slack_penalty",
    "solver",
    "sqp",
    "ipopt",
    "sqpmethod",
    "speed",
)
STAGE = N_STATE + N_INPUT + 1  # x_k, u_k, ε_{k+1}

_POSITIVE = {"type": "number", "exclusiveMinimum": 0}
_PAIR = {"type": "array", "items": {"type": "number", "minimum": 0}, "minItems": 2, "maxItems": 2}
NMPC_SCHEMA: dict[str, Any] = {
    "type": "object",
    "required": [*SETTINGS, "margin"],
    "additionalProperties": False,
    "properties": {
        "horizon": {"type": "integer", "minimum": 1},
        "Q": {"type": "number", "minimum": 0},
        "R": _PAIR,
        "margin": {"type": "number"},
        "slack_penalty": _PAIR,
        "solver": {"enum": ["sqp", "ipopt", "sqpmethod"]},
        "sqp": {
            "type": "object",
            "required": ["max_iter", "tol"],
            "additionalProperties": False,
            "properties": {
                "max_iter": {"type": "integer", "minimum": 1},
                "tol": _POSITIVE,
                "newton_tol": _POSITIVE,
                "radius": _POSITIVE,
                "rescue": {"enum": ["fatrop", "ipopt", None]},
            },
        },
        "ipopt": {
            "type": "object",
            "required": ["max_iter"],
            "additionalProperties": False,
            "properties": {
                "max_iter": {"type": "integer", "minimum": 1},
                "tol": _POSITIVE,
                "options": {  # IPOPT's own options by name, e.g. mu_init
                    "type": "object",
                    "additionalProperties": {"type": ["number", "string"]},
                },
            },
        },
        "fatrop": {
            "type": "object",
            "required": ["max_iter", "cpu_s"],
            "additionalProperties": False,
            "properties": {
                "max_iter": {"type": "integer", "minimum": 1},
                "cpu_s": _POSITIVE,
                "options": {  # Fatrop's own options by name, e.g. mu_init
                    "type": "object",
                    "additionalProperties": {"type": ["number", "string", "boolean"]},
                },
            },
        },
        "sqpmethod": {
            "type": "object",
            "required": ["max_iter", "tol", "qp_max_iter"],
            "additionalProperties": False,
            "properties": {
                "max_iter": {"type": "integer", "minimum": 1},
                "tol": _POSITIVE,
                "qp_max_iter": {"type": "integer", "minimum": 1},
            },
        },
        "compile": {
            "type": "object",
            "additionalProperties": False,
            "properties": {
                "enabled": {"type": "boolean"},
                "cache": {"type": "string"},
                "compiler": {"type": "string"},
                "flags": {"type": "array", "items": {"type": "string"}},
            },
        },
        "speed": GAINS,
    },
}
"""The nominal NMPC's settings (the adaptive and robust variants add one section each)."""


@register_controller("nmpc")
class NominalNMPC(Controller):
    needs_internal_model = True
    settings_schema: ClassVar[dict[str, Any] | None] = NMPC_SCHEMA

    @classmethod
    def check_settings(cls, name: str, settings: dict[str, Any], source: str = "config") -> None:
        """IPOPT and Fatrop know their own option names and values: ask them, on a tiny
        problem."""
        options = settings.get("ipopt", {}).get("options")
        if options:
            check_ipopt_options(options, f"{source}: `controllers.{name}.ipopt.options`")
        options = settings.get("fatrop", {}).get("options")
        if options:
            stagewise.check_fatrop_options(
                options, f"{source}: `controllers.{name}.fatrop.options`"
            )

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.internal is None or self.track is None:
            raise CapeError(f"controller {self.name} needs an internal model and the track")
        require(self.settings, SETTINGS, f"controllers.{self.name}")
        self.horizon = int(self.settings["horizon"])
        self._prepare_track_lookup()
        self._index()
        self._layout()
        self._build()

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
    def _layout(self) -> None:
        """Where each parameter of the NLP lives in its parameter vector."""
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

    def stage_terms(
        self, x_next: Any, u: Any, u_before: Any, e: Any, p: Any, k: int
    ) -> tuple[Any, Any, Any, Any]:
        """Stage k of the optimal control problem, the one definition both formulations use:
        its cost ``q‖p_{k+1} − p_ref‖² + r_T·ΔT² + r_δ·Δδ² + w1·ε + w2·ε²``, its steering change
        Δδ (bounded by the rate limit), the track offset of p_{k+1} along the centre line's
        normal (bounded by the soft constraint |offset| ≤ bound + ε), and the residual vector
        whose squared norm is the cost's quadratic part (Gauss–Newton)."""
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
        """The internal model's step with the NLP's parameters (Φ, d̂, Θ)."""
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
            x, u, e = w[self._ix[k]], w[self._iu[k]], w[self._ie[k]]
            x_next = w[self._ix[k + 1]]
            g.append(x_next - self.model_step(x, u, p))
            before = p[self.layout["u_prev"]] if k == 0 else w[self._iu[k - 1]]
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

    #: the settings ``stage_terms`` reads; a subclass whose own ``stage_terms`` reads more
    #: extends this, so that its compiled library is keyed on them
    terms_settings: ClassVar[tuple[str, ...]] = ("Q", "R", "slack_penalty")

    def _terms_key(self) -> str:
        """What ``stage_terms`` depends on, for the compiled library's key: the settings it
        reads, the parameter layout, the horizon, and the source of the class that defines it
        and of the classes it is made of. The adaptive and robust NMPCs inherit the nominal
        terms, so the three share one library."""
        owner = next(c for c in type(self).__mro__ if "stage_terms" in vars(c))
        modules = {sys.modules[c.__module__] for c in owner.__mro__ if c is not object}
        sources = source_digest(*sorted(modules, key=lambda m: m.__name__))
        layout = sorted((k, v.start, v.stop) for k, v in self.layout.items())
        kept = {k: self.settings[k] for k in self.terms_settings}
        settings = json.dumps(kept, sort_keys=True, default=str)
        return f"{settings}|{layout}|{self.horizon}|{sources}"

    def _build(self) -> None:
        """The solver of the settings' ``solver``: ``sqp`` (the condensed SQP, the default),
        ``ipopt`` (the reference) or ``sqpmethod`` (CasADi's SQP), the last
        two on the multiple-shooting NLP."""
        s, name = self.settings, str(self.settings["solver"])
        compile_settings = s.get("compile")
        self._rescue: MultipleShootingNLP | None = None
        self.rescue_with: str | None = None
        if name == "sqp":
            self.backend: Any = CondensedSQP(
                "ocp",
                self.horizon,
                N_STATE,
                self.n_param,
                self.layout,
                self.model_step,
                self.stage_terms,
                self.limits,
                self.ts,
                {**s["sqp"], "compile": compile_settings},
                terms_key=self._terms_key(),
            )
            self.rescue_with = s["sqp"].get("rescue")
        elif name in ("ipopt", "sqpmethod"):
            self.backend = self._multiple_shooting(name)
        else:
            raise CapeError(
                f"controllers.{self.name}.solver: {name!r} is not one of sqp, ipopt, sqpmethod"
            )
        self.library = self.backend.library

    @property
    def rescue(self) -> MultipleShootingNLP | None:
        """The rescue solver, built the first time it is needed (most runs never need it)."""
        if self._rescue is None and self.rescue_with is not None:
            self._rescue = self._multiple_shooting(self.rescue_with)
        return self._rescue

    def _multiple_shooting(self, name: str) -> MultipleShootingNLP:
        s = self.settings
        if name == "fatrop":
            return self._stagewise()
        if name == "ipopt":
            ipopt = s["ipopt"]
            opts = ipopt_options(int(ipopt["max_iter"]), ipopt.get("tol"), ipopt.get("options"))
        else:
            m = s["sqpmethod"]
            opts = sqpmethod_options(int(m["max_iter"]), float(m["tol"]), int(m["qp_max_iter"]))
        index = {"x": self._ix, "u": self._iu, "e": self._ie}
        return MultipleShootingNLP(
            "nmpc",
            name,
            self.nlp,
            self.nlp_bounds(),
            index,
            self.limits,
            self.layout["u_prev"],
            opts,
            s.get("compile"),
            self._rescue_key(name, shooting),
        )

    def _rescue_key(self, name: str, *modules: Any) -> str | None:
        """The cache key of rescue ``name``'s library, built by ``modules``: the condensed SQP's
        fingerprint names the same problem (model, terms, sizes, limits), so a cached library of
        the NLP loads without building its expressions. None without a compiled SQP."""
        sqp = getattr(getattr(self, "backend", None), "fingerprint", None)
        return None if sqp is None else f"{sqp}|{name}|{source_digest(*modules)}"

    def _stagewise(self) -> MultipleShootingNLP:
        """Fatrop on the stage-wise form of the same NLP (``cape.controllers.stagewise``)."""
        fatrop = self.settings.get("fatrop")
        if fatrop is None:
            raise CapeError(
                f"controllers.{self.name}.fatrop: missing; `sqp.rescue: fatrop` needs "
                "`fatrop: {max_iter: 100, cpu_s: 0.5}` (and optionally Fatrop's own `options`)"
            )
        n_state = self._ix.shape[1]
        index = stagewise.stagewise_index(self.horizon, n_state)
        lbg, ubg = stagewise.stagewise_bounds(
            self.horizon, n_state, self.limits.max_steering_step(self.ts)
        )
        opts = stagewise.fatrop_options(int(fatrop["max_iter"]), lbg, ubg, fatrop.get("options"))
        return stagewise.StagewiseNLP(
            "nmpc",
            "fatrop",
            lambda: stagewise.stagewise_nlp(self),
            (lbg, ubg),
            index,
            self.limits,
            self.layout["u_prev"],
            opts,
            self.settings.get("compile"),
            self._rescue_key("fatrop", shooting, stagewise),
            copies=index["c"],
            cpu_s=float(fatrop["cpu_s"]),
        )

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
        self.backend.reset()
        self._plan: np.ndarray | None = None
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self.fallbacks = 0
        self.rescues = 0
        self.rescues_succeeded = 0  # rescues that converged where the SQP had not
        self.dhat = np.zeros(3)
        self._theta_one = np.ones(3)
        self.phi_now: np.ndarray | None = None

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
    ) -> tuple[np.ndarray | None, bool]:
        """One solve, warm-started from the previous solution: the plan (N × 2) and success.
        When the condensed SQP does not converge and a rescue solver is configured, it solves
        the same problem from the SQP's last iterate (its states rolled out), and its solution
        becomes the SQP's next warm start."""
        start = time.perf_counter()
        plan, ok = self.backend.solve(x0, params, throttle)
        start = self.clock("solve", start)
        if ok or self.rescue_with is None:
            return plan, ok
        self.rescues += 1
        inputs, slacks = self.backend.iterate()
        rescue = self.rescue
        assert rescue is not None
        guess = rescue.decision_vector(self.backend.states(), inputs, slacks)
        if not np.all(np.isfinite(guess)):  # the SQP's iterate left the floats: a cold start
            guess = None
        plan, ok = rescue.solve(x0, params, throttle, guess=guess)
        if ok:
            plan = self.backend.adopt(plan)
            self.rescues_succeeded += 1
        self.clock("rescue", start)
        return plan, ok

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
        start = time.perf_counter()
        z = self.estimate(z)
        start = self.clock("estimate", start)
        if self._last is not None:
            self.internal.observe(*self._last)
        phi = self.internal.phi()
        self.phi_now = phi
        start = self.clock("internal_phi", start)
        x0 = np.concatenate([z, self.u_prev])
        rescues = self.rescues
        params, throttle = self.parameters(ref, phi), self.throttle_bounds(z, ref)
        self.clock("parameters", start)
        plan, ok = self.solve(x0, params, throttle)
        info = {
            "fallback": not ok,
            "rescued": self.rescues > rescues,
            "iterations": self.backend.stats.iterations,
        }
        if ok:
            self._plan = plan
            u = plan[0]
        else:
            self.fallbacks += 1
            if self._plan is not None and len(self._plan) > 1:
                self._plan = self._plan[1:]
                u = self._plan[0]
            else:
                u = self.u_prev.copy()
        u = self.limits.clip(u, delta_prev=float(self.u_prev[1]), ts=self.ts)
        self._last = (z.copy(), u.copy())
        self.u_prev = u
        return u, info
