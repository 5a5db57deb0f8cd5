"""Nominal NMPC (SPEC §7.3) in CasADi, and the base of the adaptive and robust variants.

Each step it predicts Φ, fills the parameter vector of ``cape.controllers.ocp.TrackingOCP`` and
solves warm-started with the settings' ``solver``: ``sqp`` (the default, ``cape.controllers.sqp``),
``ipopt`` or ``sqpmethod``. A model without a throttle path (DPM) has only its steering
optimised, the throttle from the PID speed loop. A failed SQP is rescued (Fatrop by default, or
IPOPT); when that fails too, the controller applies its previous plan's next input and counts a
fallback. The settings' schema: ``nmpc_settings.json``. Details: docs/modules.md.
"""

from __future__ import annotations

import json
import time
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from cape.controllers import shooting, stagewise
from cape.controllers.base import GAINS, Controller, PIDLoop, require
from cape.controllers.internal import N_STATE
from cape.controllers.ocp import TrackingOCP
from cape.controllers.registry import register_controller
from cape.controllers.shooting import (
    MultipleShootingNLP,
    check_ipopt_options,
    ipopt_options,
    sqpmethod_options,
)
from cape.controllers.solvers import OCPSolver, RescuableSolver, RescueSolver
from cape.controllers.sqp import CondensedSQP
from cape.errors import CapeError
from cape.numerics.compiled import source_digest
from cape.tracks.geometry import Projection
from cape.tracks.reference import ReferencePoints

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


def _settings_schema() -> dict[str, Any]:
    text = resources.files(__package__).joinpath("nmpc_settings.json").read_text("utf-8")
    schema = json.loads(text)
    schema["properties"]["speed"] = GAINS  # the PID speed loop's gains, shared with PID, RISE
    return schema


NMPC_SCHEMA: dict[str, Any] = _settings_schema()
"""The nominal NMPC's settings (the adaptive and robust variants add one section each)."""


@register_controller("nmpc")
class NominalNMPC(Controller):
    needs_internal_model = True
    settings_schema: ClassVar[dict[str, Any] | None] = NMPC_SCHEMA
    #: the problem it solves; a variant with other stage terms names its own subclass
    ocp_class: ClassVar[type[TrackingOCP]] = TrackingOCP

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
        self.ocp = self.ocp_class(
            self.horizon, self.settings, self.internal, self.limits, self.ts, self.line, self.track
        )
        self._build()

    # --- the solvers, built once ---------------------------------------------------------------
    def _build(self) -> None:
        """The solver of the settings' ``solver``: ``sqp`` (the condensed SQP, the default),
        ``ipopt`` (the reference) or ``sqpmethod`` (CasADi's SQP), the last two on the
        multiple-shooting NLP."""
        s, name = self.settings, str(self.settings["solver"])
        self._rescue: RescueSolver | None = None
        self.rescue_with: str | None = None
        self._fingerprint: str | None = None  # the compiled SQP's: names the same problem
        if name == "sqp":
            ocp = self.ocp
            sqp = CondensedSQP(
                "ocp",
                self.horizon,
                N_STATE,
                ocp.n_param,
                ocp.layout,
                ocp.model_step,
                ocp.stage_terms,
                self.limits,
                self.ts,
                {**s["sqp"], "compile": s.get("compile")},
                terms_key=ocp.terms_key(),
            )
            self._fingerprint = sqp.fingerprint
            self.solver: OCPSolver = sqp
            self.rescue_with = s["sqp"].get("rescue")
        elif name in ("ipopt", "sqpmethod"):
            self.solver = self._multiple_shooting(name)
        else:
            raise CapeError(
                f"controllers.{self.name}.solver: {name!r} is not one of sqp, ipopt, sqpmethod"
            )
        self.library = self.solver.library

    @property
    def rescue(self) -> RescueSolver | None:
        """The rescue solver, built the first time it is needed (most runs never need it)."""
        if self._rescue is None and self.rescue_with is not None:
            self._rescue = self._multiple_shooting(self.rescue_with)
        return self._rescue

    def libraries(self) -> list[Path]:
        """The compiled libraries of its solver and rescue (building the rescue's)."""
        solvers: list[Any] = [self.solver, self.rescue]
        return [s.library for s in solvers if s is not None and s.library is not None]

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
        ocp = self.ocp
        index = {"x": ocp.ix, "u": ocp.iu, "e": ocp.ie}
        return MultipleShootingNLP(
            "nmpc",
            name,
            ocp.nlp,
            ocp.nlp_bounds(),
            index,
            self.limits,
            ocp.layout["u_prev"],
            opts,
            s.get("compile"),
            self._rescue_key(name, shooting),
        )

    def _rescue_key(self, name: str, *modules: Any) -> str | None:
        """The cache key of rescue ``name``'s library, built by ``modules``: the condensed SQP's
        fingerprint names the same problem (model, terms, sizes, limits), so a cached library of
        the NLP loads without building its expressions. None without a compiled SQP."""
        sqp = self._fingerprint
        return None if sqp is None else f"{sqp}|{name}|{source_digest(*modules)}"

    def _stagewise(self) -> MultipleShootingNLP:
        """Fatrop on the stage-wise form of the same NLP (``cape.controllers.stagewise``)."""
        fatrop = self.settings.get("fatrop")
        if fatrop is None:
            raise CapeError(
                f"controllers.{self.name}.fatrop: missing; `sqp.rescue: fatrop` needs "
                "`fatrop: {max_iter: 100, cpu_s: 0.5}` (and optionally Fatrop's own `options`)"
            )
        ocp = self.ocp
        n_state = ocp.ix.shape[1]
        index = stagewise.stagewise_index(self.horizon, n_state)
        lbg, ubg = stagewise.stagewise_bounds(
            self.horizon, n_state, self.limits.max_steering_step(self.ts)
        )
        opts = stagewise.fatrop_options(int(fatrop["max_iter"]), lbg, ubg, fatrop.get("options"))
        return stagewise.StagewiseNLP(
            "nmpc",
            "fatrop",
            lambda: stagewise.stagewise_nlp(ocp),
            (lbg, ubg),
            index,
            self.limits,
            ocp.layout["u_prev"],
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
        self.solver.reset()
        self._plan: np.ndarray | None = None
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self.fallbacks = 0
        self.rescues = 0
        self.rescues_succeeded = 0  # rescues that converged where the SQP had not
        self.dhat = np.zeros(3)
        self._theta_one = np.ones(3)
        self.phi_now: np.ndarray | None = None

    def parameters(self, ref: ReferencePoints, phi: np.ndarray) -> np.ndarray:
        """The problem's parameter vector for this step."""
        bound = self.track.width / 2 - self.margin()
        return self.ocp.parameters(ref, phi, self.u_prev, bound, self.dhat, self.theta())

    def solve(
        self, x0: np.ndarray, params: np.ndarray, throttle: tuple[float, float]
    ) -> tuple[np.ndarray | None, bool]:
        """One solve, warm-started from the previous solution: the plan (N × 2) and success.
        When the condensed SQP does not converge and a rescue solver is configured, it solves
        the same problem from the SQP's last iterate (its states rolled out), and its solution
        becomes the SQP's next warm start."""
        start = time.perf_counter()
        plan, ok = self.solver.solve(x0, params, throttle)
        start = self.clock("solve", start)
        if ok or self.rescue_with is None:
            return plan, ok
        self.rescues += 1
        solver = self.solver
        assert isinstance(solver, RescuableSolver)  # only the SQP has a rescue
        inputs, slacks = solver.iterate()
        rescue = self.rescue
        assert rescue is not None
        guess = rescue.decision_vector(self.solver.states(), inputs, slacks)
        if not np.all(np.isfinite(guess)):  # the SQP's iterate left the floats: a cold start
            guess = None
        plan, ok = rescue.solve(x0, params, throttle, guess=guess)
        if ok:
            plan = solver.adopt(plan)
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
            "iterations": self.solver.stats.iterations,
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
