"""The NMPC's default solver: a condensed SQP with a trust region, every iterate feasible
(SPEC §7.3).

It solves the NMPC's own problem (``stage_terms``, ``step``) over the N inputs and the N track
slacks, the states eliminated by single shooting from the measured x_0. ``stats.status`` is
``converged`` or one of ``max_iter``, ``no_decrease``, ``not_finite``, ``qp_failed``; before any
solve it is ``not solved``. After a failure the next solve starts cold; the rescue and fallback
are the controller's (``cape.controllers.nmpc``). How a solve works: docs/modules.md.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from cape.numerics.compiled import cached_functions, compiled_functions

N_INPUT = 2
PREFIX = "ocp"
FUNCTIONS = {f: f"{PREFIX}_{f}" for f in ("lin", "lin_gn", "prepare", "trial", "rollout")}
ACTIVE_TOL = 1e-9  # a constraint within this of its bound is active
ACTIVE_WEIGHT = 100.0  # κ relative to the inputs' mean Gauss–Newton curvature
# the trust region on the inputs' step, as a fraction of each input's range
RADIUS_MAX, RADIUS_MIN, RADIUS_START_MIN = 2.0, 1e-7, 1e-2
MAX_SHRINK = 30  # QPs per linearisation at most
RATIO_ACCEPT, RATIO_POOR, RATIO_GOOD = 1e-4, 0.25, 0.75  # actual over predicted decrease
ROUNDOFF = 1e-12  # a predicted decrease below this fraction of F is rounding, not progress


@dataclass
class SolveStats:
    """What one solve did (read only when asked for: statistics are not on the hot path)."""

    success: bool
    iterations: int
    status: str


class CondensedSQP:
    """Solve the NMPC's problem for one step: ``solve(x0, params, throttle)``, warm-started from
    the previous solution when there is one.

    ``terms(x_next, u, u_before, e, p, k)`` returns the stage's cost, steering change, track
    offset and least-squares residual (``TrackingOCP.stage_terms``); ``step(x, u, p)`` is the
    internal model's step with the NLP's parameters; ``layout`` names the slices of the NLP's
    parameter vector (of length ``n_param``) holding the previous input and the track bound."""

    def __init__(
        self,
        name: str,
        horizon: int,
        n_state: int,
        n_param: int,
        layout: dict[str, slice],
        step: Any,
        terms: Any,
        limits: Any,
        ts: float,
        settings: dict[str, Any],
        terms_key: str | None = None,
    ) -> None:
        """``terms_key``: a digest of everything ``terms`` depends on (the controller's settings,
        the layout, the horizon, the code that defines it), so that finding the cached compiled
        library does not need the stage terms' expressions, the bulk of building the
        fingerprint; without it they are built and serialised."""
        self.n = horizon
        self.layout = layout
        self.n_state = n_state
        self.n_w = horizon * (N_INPUT + 1)
        self.tol = float(settings["tol"])
        self.newton_tol = float(settings.get("newton_tol", self.tol))
        self.max_iter = int(settings["max_iter"])
        self.radius_start = float(settings.get("radius", 0.5))
        # each input's range, the trust region's scale
        self._range = np.tile([limits.T_max - limits.T_min, 2 * limits.delta_max], horizon)
        self.n_q = n_state + 2 + n_param
        compile_settings = settings.get("compile") or {}
        functions, self.library = None, None
        self.fingerprint: str | None = None  # of the problem's generated code (when compiled)
        if compile_settings.get("enabled", False):
            fingerprint = self._fingerprint(n_param, step, terms, limits, ts, terms_key)
            self.fingerprint = fingerprint
            cached = cached_functions(FUNCTIONS, fingerprint, compile_settings)
            if cached is not None:  # no need to build the expressions
                functions, self.library = cached
            else:
                functions, self.library = compiled_functions(
                    name, self._functions(step, terms, limits, ts), compile_settings, fingerprint
                )
        if functions is None:
            functions = self._functions(step, terms, limits, ts)
        self._functions_of = functions
        self._qp = ca.conic(
            "qp",
            "daqp",
            {"h": ca.Sparsity.dense(self.n_w, self.n_w),
             "a": ca.Sparsity.dense(3 * horizon, self.n_w)},
            {"error_on_fail": False},
        )  # fmt: skip
        self._bind()
        self.reset()

    # --- the problem's functions -----------------------------------------------------------------
    def _fingerprint(
        self, n_param: int, step: Any, terms: Any, limits: Any, ts: float, terms_key: str | None
    ) -> str:
        """A digest of everything the generated code depends on: the problem's stage functions
        (serialised: the internal model's step, with the constants it holds, and every stage's
        terms, or ``terms_key`` naming what they depend on), this module's source (how the
        functions are built from them), the sizes, limits and sampling time. Cheap to form,
        unlike the functions themselves."""
        x, u, before = ca.SX.sym("x", self.n_state), ca.SX.sym("u", N_INPUT), ca.SX.sym("b", 2)
        e, p = ca.SX.sym("e"), ca.SX.sym("p", n_param)
        outputs = [step(x, u, p)]
        if terms_key is None:
            for k in range(self.n):
                outputs += [ca.vertcat(*[ca.vec(t) for t in terms(x, u, before, e, p, k)])]
        stage = ca.Function("stage", [x, u, before, e, p], outputs)
        digest = hashlib.sha256(stage.serialize().encode())
        digest.update(f"terms: {terms_key}".encode())
        digest.update(Path(__file__).read_bytes())
        digest.update(
            repr(
                (
                    self.n,
                    self.n_state,
                    n_param,
                    sorted((k, v.start, v.stop) for k, v in self.layout.items()),
                    limits,
                    ts,
                )
            ).encode()
        )
        return digest.hexdigest()

    def _functions(self, step: Any, terms: Any, limits: Any, ts: float) -> dict:
        name = PREFIX
        n, nx = self.n, self.n_state
        w = ca.SX.sym("w", self.n_w)
        q = ca.SX.sym("q", self.n_q)  # [x0, throttle bounds (2), NLP parameters]
        x0, throttle, p = q[:nx], q[nx : nx + 2], q[nx + 2 :]
        u = ca.reshape(w[: N_INPUT * n], N_INPUT, n)
        eps = w[N_INPUT * n :]
        bound = p[self.layout["bound"]]
        u_prev = p[self.layout["u_prev"]]

        def least_slack(offset: ca.SX) -> ca.SX:
            """The least feasible slack of a track offset: max(0, |offset| − bound)."""
            return ca.fmax(ca.fabs(offset) - bound, 0)

        def rollout(u_mat: ca.SX) -> list[ca.SX]:
            xs = [x0]
            for k in range(n):
                xs.append(step(xs[-1], u_mat[:, k], p))
            return xs

        def pieces(u_mat: ca.SX, e: ca.SX | None) -> tuple[ca.SX, ca.SX, ca.SX, list[ca.SX]]:
            """Cost, steering changes, offsets and residuals of inputs ``u_mat`` with slacks
            ``e`` (None: the least feasible slacks, i.e. the merit F)."""
            xs = rollout(u_mat)
            cost, rates, offsets, residuals = 0, [], [], []
            for k in range(n):
                before = u_prev if k == 0 else u_mat[:, k - 1]
                if e is None:
                    _, _, offset, _ = terms(xs[k + 1], u_mat[:, k], before, 0, p, k)
                    e_k = least_slack(offset)
                else:
                    e_k = e[k]
                stage_cost, rate, offset, res = terms(xs[k + 1], u_mat[:, k], before, e_k, p, k)
                cost += stage_cost
                rates.append(rate)
                offsets.append(offset)
                residuals.append(res)
            return cost, ca.vertcat(*rates), ca.vertcat(*offsets), residuals

        cost, rates, offsets, residuals = pieces(u, eps)
        n_u = N_INPUT * n
        uv, ev = w[:n_u], w[n_u:]
        track = ca.vertcat(offsets - eps, -offsets - eps)
        cons = ca.vertcat(rates, track)
        jac = ca.horzcat(ca.jacobian(cons, uv), ca.jacobian(cons, ev))
        # The QP's Hessian: the Lagrangian's exact Hessian (Newton: quadratic convergence). The
        # slacks enter the cost separably and the constraints linearly, so their block is the
        # constant diagonal 2·w2 and only the inputs' block needs computing and testing. At a
        # constraint active at the iterate (an input at its bound, a steering change at the rate
        # limit, a track offset beyond its bound) the Lagrangian may be indefinite harmlessly, in
        # a direction that constraint forbids; κ·aaᵀ for each such row a makes it positive
        # definite there without moving the QP's solution while the active set holds, as a
        # barrier's curvature does in an interior-point method. If the result is still not
        # positive definite (its Cholesky factorisation fails: the problem is truly non-convex
        # there, e.g. the measured car far outside the track), ``lin_gn`` replaces it with the
        # Gauss–Newton matrix, positive definite through the input-change and slack weights.
        nu = ca.SX.sym("nu", n)  # multipliers of the offsets (upper minus lower side)
        h_uu, _ = ca.hessian(cost + ca.dot(nu, offsets), uv)  # the Lagrangian's curvature
        g_u = ca.gradient(cost, uv)
        h_ee, g_e = ca.hessian(cost, ev)
        kappa = ACTIVE_WEIGHT * ca.sum1(ca.fabs(ca.diag(h_uu))) / n_u
        active = self._active_at(w, cons, throttle, bound, limits, ts)
        active = ca.vertcat(active[:n_u], active[self.n_w :])  # the inputs' bounds, the rows
        rows = ca.vertcat(ca.SX.eye(n_u), jac[:, :n_u])
        h_uu = h_uu + kappa * ca.mtimes(rows.T, ca.mtimes(ca.diag(active), rows))
        positive = ca.logic_all(ca.diag(ca.chol(h_uu)) > 0)  # NaN (a negative pivot) is false
        hess = ca.diagcat(h_uu, h_ee)
        step_max = limits.max_steering_step(ts)
        lbc = ca.vertcat(ca.DM.ones(n) * -step_max, -ca.DM.inf(2 * n))
        ubc = ca.vertcat(ca.DM.ones(n) * step_max, ca.repmat(bound, 2 * n, 1))
        lbw, ubw = self._bounds(throttle, limits)
        lin = ca.Function(
            f"{name}_lin",
            [w, q, nu],
            [ca.densify(hess), ca.vertcat(g_u, g_e), ca.densify(jac), lbc - cons, ubc - cons,
             lbw - w, ubw - w, cost, positive],
            ["w", "q", "nu"],
            ["h", "g", "a", "lba", "uba", "lbx", "ubx", "f", "positive"],
        )  # fmt: skip
        jr = ca.jacobian(ca.vertcat(*residuals), w)
        lin_gn = ca.Function(f"{name}_lin_gn", [w, q], [ca.densify(2 * ca.mtimes(jr.T, jr))])

        # prepare: shift the previous plan, project on the bounds, reset the slacks
        prev = ca.SX.sym("prev", N_INPUT * n)
        pu = ca.reshape(prev, N_INPUT, n)
        shifted = ca.horzcat(pu[:, 1:], pu[:, n - 1])
        cols, last = [], u_prev[1]
        for k in range(n):
            t_k = ca.fmin(ca.fmax(shifted[0, k], throttle[0]), throttle[1])
            d_k = ca.fmin(ca.fmax(shifted[1, k], last - step_max), last + step_max)
            d_k = ca.fmin(ca.fmax(d_k, -limits.delta_max), limits.delta_max)
            cols.append(ca.vertcat(t_k, d_k))
            last = d_k
        u0 = ca.horzcat(*cols)
        _, _, offs0, _ = pieces(u0, None)
        prepare = ca.Function(
            f"{name}_prepare", [prev, q], [ca.vertcat(ca.vec(u0), least_slack(offs0))]
        )

        # the trial point: the merit F at u + α·d_u, and that point with its slacks reset
        d = ca.SX.sym("d", self.n_w)
        alpha = ca.SX.sym("alpha")
        u_trial = w[: N_INPUT * n] + alpha * d[: N_INPUT * n]
        merit, _, trial_offsets, _ = pieces(ca.reshape(u_trial, N_INPUT, n), None)
        trial = ca.Function(
            f"{name}_trial",
            [w, d, q, alpha],
            [merit, ca.vertcat(u_trial, least_slack(trial_offsets)), trial_offsets],
            ["w", "d", "q", "alpha"],
            ["f", "w_trial", "offsets"],
        )
        roll = ca.Function(f"{name}_rollout", [w, q], [ca.horzcat(*rollout(u))])
        return {"lin": lin, "lin_gn": lin_gn, "prepare": prepare, "trial": trial,
                "rollout": roll}  # fmt: skip

    def _active_at(
        self, w: ca.SX, cons: ca.SX, throttle: ca.SX, bound: ca.SX, limits: Any, ts: float
    ) -> ca.SX:
        """A 0/1 mask of the constraints active at the (feasible) iterate ``w``, over the
        variables' bounds then the rows ``cons`` (steering changes, upper then lower track
        sides): a property of the iterate, so it settles as the iterates do."""
        lbw, ubw = self._bounds(throttle, limits)
        at_bound = ca.logic_or(w <= lbw + ACTIVE_TOL, w >= ubw - ACTIVE_TOL)
        n = self.n
        step_max = limits.max_steering_step(ts)
        rate = ca.fabs(cons[:n]) >= step_max - ACTIVE_TOL
        track = cons[n:] >= bound - ACTIVE_TOL
        return ca.vertcat(at_bound, rate, track)

    def _bounds(self, throttle: ca.SX, limits: Any) -> tuple[ca.SX, ca.SX]:
        n = self.n
        low_u = ca.repmat(ca.vertcat(throttle[0], -limits.delta_max), n, 1)
        high_u = ca.repmat(ca.vertcat(throttle[1], limits.delta_max), n, 1)
        return ca.vertcat(low_u, ca.DM.zeros(n)), ca.vertcat(high_u, ca.DM.inf(n))

    def _bind(self) -> None:
        """Preallocated arrays bound to the functions' buffers, the linearisation's outputs being
        the QP's inputs: a call copies no numbers, and one iteration is three calls."""
        n, nw = self.n, self.n_w
        f = self._functions_of
        self._q = np.zeros(self.n_q)
        self._prev = np.zeros(N_INPUT * n)
        self._w = np.zeros(nw)
        self._nu = np.zeros(n)
        self._lam_x = np.zeros(nw)
        self._d = np.zeros(nw)
        self._lam = np.zeros(3 * n)
        self._alpha = np.ones(1)  # the trial is the full step
        self._trial_f = np.zeros(1)
        self._w_trial = np.zeros(nw)
        self._trial_offsets = np.zeros(n)
        qp_in = {"h": np.zeros(nw * nw), "g": np.zeros(nw), "a": np.zeros(3 * n * nw),
                 "lba": np.zeros(3 * n), "uba": np.zeros(3 * n), "lbx": np.zeros(nw),
                 "ubx": np.zeros(nw)}  # fmt: skip
        self._value, self._positive = np.zeros(1), np.zeros(1)
        self._lbx, self._ubx = np.zeros(nw), np.zeros(nw)  # the step's bounds, before the region
        self._qp_lbx, self._qp_ubx = qp_in["lbx"], qp_in["ubx"]
        self._model = np.zeros(1)  # the QP's optimal value: the model's change
        self._g = qp_in["g"]
        self._uba, self._lba = qp_in["uba"], qp_in["lba"]
        self._a = qp_in["a"].reshape(3 * n, nw, order="F")  # a view: the QP's constraint matrix
        self._calls = {}
        for key, function, args, results in (
            ("prepare", f["prepare"], [self._prev, self._q], [self._w]),
            ("lin", f["lin"], [self._w, self._q, self._nu],
             [*list(qp_in.values())[:5], self._lbx, self._ubx, self._value, self._positive]),
            ("lin_gn", f["lin_gn"], [self._w, self._q], [qp_in["h"]]),
            ("qp", self._qp, [*qp_in.values(), np.zeros(nw), np.zeros(nw), np.zeros(3 * n)],
             [self._d, self._model, self._lam, self._lam_x]),
            ("trial", f["trial"], [self._w, self._d, self._q, self._alpha],
             [self._trial_f, self._w_trial, self._trial_offsets]),
        ):  # fmt: skip
            buffer, call = function.buffer()
            for i, array in enumerate(args):
                buffer.set_arg(i, memoryview(array))
            for i, array in enumerate(results):
                buffer.set_res(i, memoryview(array))
            # the buffer and every bound array must live as long as the call
            self._calls[key] = (buffer, call, args, results)

    # --- solving ------------------------------------------------------------------------------
    def reset(self) -> None:
        self._warm = False
        self._radius = self.radius_start
        self.stats = SolveStats(False, 0, "not solved")

    def solve(
        self, x0: np.ndarray, params: np.ndarray, throttle: tuple[float, float]
    ) -> tuple[np.ndarray | None, bool]:
        """The plan (N × 2 inputs) of this step and whether the solve converged."""
        nx = self.n_state
        q = self._q
        q[:nx] = x0
        q[nx] = throttle[0]
        q[nx + 1] = throttle[1]
        q[nx + 2 :] = params
        if not self._warm:  # cold: the previous input held over the horizon
            self._prev[:] = np.tile(params[self.layout["u_prev"]], self.n)
            self._nu[:] = 0.0
            self._radius = self.radius_start
        self._calls["prepare"][1]()
        status, iterations = "max_iter", self.max_iter
        self._last_newton = np.inf  # the size of the last full Newton step (∞: none yet)
        for iteration in range(1, self.max_iter + 1):
            status = self._iteration()
            if status != "continue":
                iterations = iteration
                break
        else:
            status = "max_iter"
        self._radius = max(self._radius, RADIUS_START_MIN)
        ok = status == "converged"
        self.stats = SolveStats(ok, iterations, status)
        if not ok:
            self._warm = False
            return None, False
        return self.adopt(self._w[: N_INPUT * self.n]), True

    def _iteration(self) -> str:
        """Linearise at the iterate, then solve QPs on a shrinking trust region until a step
        decreases F by a fair share of what the model predicts; "continue", "converged", or why
        the solve failed."""
        qp, trial = self._calls["qp"][1], self._calls["trial"][1]
        self._calls["lin"][1]()
        newton = bool(self._positive[0])
        if not newton:
            self._calls["lin_gn"][1]()
        value = float(self._value[0])
        if not np.isfinite(value):
            # the internal model's prediction along this iterate left the floats (a learned
            # model far outside its data): no QP can be posed here, the solve has failed
            return "not_finite"
        n_u, radius = N_INPUT * self.n, self._radius
        for _ in range(MAX_SHRINK):
            self._region(radius)
            try:
                qp()
            except RuntimeError:  # CasADi refuses a QP whose bounds are NaN: the same failure
                return "not_finite"
            predicted = -float(self._model[0])
            size = float(np.max(np.abs(self._d[:n_u])))
            step = float(np.max(np.abs(self._d[:n_u]) / self._range))  # in the region's unit
            if not (np.isfinite(predicted) and np.isfinite(step)):
                return "qp_failed"  # daqp returned no solution (it should not: H ≻ 0)
            if predicted <= ROUNDOFF * abs(value):
                return "converged"  # no decrease left above rounding: stationary
            inside = step < 0.99 * radius
            # converged: the QP's minimiser (not the region's edge) is within tol, or, in Newton's
            # quadratic regime (a full Newton step after one at least ten times larger), within
            # newton_tol, the error left after it being of the order of its square
            quadratic = newton and size <= min(0.1 * self._last_newton, self.newton_tol)
            done = inside and (size <= self.tol or quadratic)
            trial()
            actual = value - float(self._trial_f[0])
            rejected = not actual >= RATIO_ACCEPT * predicted  # a NaN trial value is rejected
            if rejected and not done and self._second_order_correction(value, predicted):
                actual = value - float(self._trial_f[0])
                rejected = False
            if not rejected or (done and actual >= 0):
                ratio = actual / predicted
                if ratio > RATIO_GOOD and not inside:
                    radius = min(2.0 * radius, RADIUS_MAX)
                elif ratio < RATIO_POOR:
                    radius = max(0.25 * step, RADIUS_MIN)
                self._radius = radius
                self._w[:] = self._w_trial
                self._nu[:] = self._lam[self.n : 2 * self.n] - self._lam[2 * self.n :]
                self._last_newton = size if newton and inside else np.inf
                return "converged" if done else "continue"
            if done:
                return "converged"  # within tol of the minimiser: F cannot tell better apart
            radius = 0.25 * step
            if not radius >= RADIUS_MIN:
                return "no_decrease"
        return "no_decrease"

    def merit(
        self, x0: np.ndarray, params: np.ndarray, throttle: tuple[float, float], plan: np.ndarray
    ) -> float:
        """F of a plan (N × 2 inputs) for this problem: its cost with the least feasible slacks,
        the value any solver's solution can be compared by (not on the hot path)."""
        q = np.concatenate([x0, throttle, params])
        w = np.concatenate([np.ravel(plan), np.zeros(self.n)])
        value, _, _ = self._functions_of["trial"](w, np.zeros(self.n_w), q, 0.0)
        return float(value)

    def adopt(self, inputs: np.ndarray) -> np.ndarray:
        """Take ``inputs`` (N × 2, or flat) as this step's solution, the next step's warm start;
        returns the plan (N × 2)."""
        self._prev[:] = np.ravel(inputs)
        self._warm = True
        return self._prev.reshape(self.n, N_INPUT).copy()

    def iterate(self) -> tuple[np.ndarray, np.ndarray]:
        """The current iterate's inputs (N × 2) and slacks (N) (after a failed solve: the best
        point found, every iterate being feasible and better than the last)."""
        n = self.n
        return self._w[: N_INPUT * n].reshape(n, N_INPUT).copy(), self._w[N_INPUT * n :].copy()

    def _region(self, radius: float) -> None:
        """The QP's bounds: the step's own, intersected with the trust region |d_i| ≤ radius ×
        (the range of input i) on the inputs (the slacks are not limited)."""
        n_u = N_INPUT * self.n
        np.maximum(self._lbx[:n_u], -radius * self._range, out=self._qp_lbx[:n_u])
        np.minimum(self._ubx[:n_u], radius * self._range, out=self._qp_ubx[:n_u])
        self._qp_lbx[n_u:] = self._lbx[n_u:]
        self._qp_ubx[n_u:] = self._ubx[n_u:]
        # d = 0 stays feasible even for an iterate outside a bound by the QP's tolerance, so
        # every QP of a shrinking region has a solution
        np.minimum(self._qp_lbx, 0.0, out=self._qp_lbx)
        np.maximum(self._qp_ubx, 0.0, out=self._qp_ubx)
        np.minimum(self._lba, 0.0, out=self._lba)
        np.maximum(self._uba, 0.0, out=self._uba)

    def _second_order_correction(self, value: float, predicted: float) -> bool:
        """The step was rejected: solve the QP again with the track offsets' linearisation
        corrected by their value at the trial point (the step's second-order error), and take
        the corrected step if it decreases F as predicted. Near a solution with active track
        constraints this is what keeps full steps, and Newton's convergence, from being cut by
        the constraints' curvature (the Maratos effect). True if the corrected step was taken;
        otherwise the original step and QP are restored."""
        n = self.n
        eps, d_eps = self._w[N_INPUT * n :], self._d[N_INPUT * n :]
        plus = self._a[n : 2 * n, :]
        # o(u + d) − J·d − o(u), with J·d = A_plus·d + dε and o(u) = bound − uba_plus + ε
        bound = self._q[self.n_state + 2 + self.layout["bound"].start]
        offsets = bound - self._uba[n : 2 * n] + eps
        shift = self._trial_offsets - (plus @ self._d + d_eps) - offsets
        if not np.all(np.isfinite(shift)):  # the trial point's prediction left the floats
            return False
        saved_d, saved_uba = self._d.copy(), self._uba.copy()
        self._uba[n : 2 * n] -= shift
        self._uba[2 * n :] += shift
        self._calls["qp"][1]()
        self._calls["trial"][1]()
        self._uba[:] = saved_uba
        if value - self._trial_f[0] >= RATIO_ACCEPT * predicted:
            return True
        self._d[:] = saved_d
        self._calls["trial"][1]()  # the original step's trial again
        return False

    def states(self) -> np.ndarray:
        """The predicted states of the last solution, (N+1) × n_state (not on the hot path)."""
        return np.asarray(self._functions_of["rollout"](self._w, self._q)).T
