"""The NMPC's problem stage by stage, for Fatrop (SPEC §7.3: any solver of the same OCP).

The same optimal control problem as ``TrackingOCP.nlp`` (``cape.controllers.ocp``), in the form
Fatrop's structure detection reads: ``[x_0, u_0 | x_1, c_1, u_1, ε_1 | … | x_N, c_N, ε_N]``,
stage k carrying a copy c_k of u_{k−1}. The feasible sets and the costs are the same; only the
copies are added. The layout and why: docs/modules.md.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import Any

import casadi as ca
import numpy as np

from cape.controllers.guard import Guarded, WorkerError
from cape.controllers.shooting import MultipleShootingNLP
from cape.controllers.sqp import SolveStats

N_INPUT = 2


def stagewise_index(horizon: int, n_state: int) -> dict[str, np.ndarray]:
    """Where x_k (rows k = 0…N), u_k and ε_{k+1} (k = 0…N−1) live, and c_{k+1} (k = 0…N−1),
    the copy of u_k that stage k+1 carries in its state."""
    ix, ic, iu, ie, at = [], [], [], [], 0
    for k in range(horizon + 1):
        ix.append(np.arange(at, at + n_state))
        at += n_state
        if k >= 1:
            ic.append(np.arange(at, at + N_INPUT))
            at += N_INPUT
        if k < horizon:
            iu.append(np.arange(at, at + N_INPUT))
            at += N_INPUT
        if k >= 1:
            ie.append(at)
            at += 1
    return {"x": np.array(ix), "c": np.array(ic), "u": np.array(iu), "e": np.array(ie)}


def stagewise_bounds(horizon: int, n_state: int, step_max: float) -> tuple[np.ndarray, np.ndarray]:
    """(lbg, ubg) of ``stagewise_nlp``'s constraints: per stage the gap of the dynamics and of
    the input's copy (k < N), the track bound on either side (k ≥ 1), the steering rate
    (k < N)."""
    lower: list[float] = []
    upper: list[float] = []
    for k in range(horizon + 1):
        if k < horizon:
            lower += [0.0] * (n_state + N_INPUT)
            upper += [0.0] * (n_state + N_INPUT)
        if k >= 1:
            lower += [-np.inf, -np.inf]
            upper += [0.0, 0.0]
        if k < horizon:
            lower.append(-step_max)
            upper.append(step_max)
    return np.array(lower), np.array(upper)


def stagewise_nlp(ocp: Any) -> dict[str, Any]:
    """The NLP's expressions ({x, f, g, p}) from the problem's ``model_step`` and
    ``stage_terms`` (``cape.controllers.ocp.TrackingOCP``), in the order of
    ``stagewise_index`` and ``stagewise_bounds``."""
    n, n_state = ocp.horizon, ocp.ix.shape[1]
    index = stagewise_index(n, n_state)
    w = ca.SX.sym("w", int(index["e"][-1]) + 1)
    p = ca.SX.sym("p", ocp.n_param)
    bound = p[ocp.layout["bound"]]
    cost = 0
    track: list[Any] = [[] for _ in range(n + 1)]
    rates, gaps = [], []
    for k in range(n):
        x, u, e = w[index["x"][k]], w[index["u"][k]], w[int(index["e"][k])]
        x_next = w[index["x"][k + 1]]
        before = p[ocp.layout["u_prev"]] if k == 0 else w[index["c"][k - 1]]
        stage_cost, rate, offset, _ = ocp.stage_terms(x_next, u, before, e, p, k)
        cost += stage_cost
        gaps.append(ca.vertcat(x_next - ocp.model_step(x, u, p), w[index["c"][k]] - u))
        rates.append(rate)
        track[k + 1] = [offset - e - bound, -offset - e - bound]
    g: list[Any] = []
    for k in range(n + 1):
        if k < n:
            g.append(gaps[k])
        g += track[k]
        if k < n:
            g.append(rates[k])
    return {"x": w, "f": cost, "g": ca.vertcat(*g), "p": p}


class StagewiseNLP(MultipleShootingNLP):
    """``MultipleShootingNLP`` on ``stagewise_nlp``: every guess carries the input copies
    c_{k+1} = u_k, so that a guess that satisfies the dynamics satisfies the copies' gaps; each
    solve runs in a worker whose CPU time per solve is bounded by ``cpu_s`` (``Guarded``)."""

    def __init__(self, *args: Any, copies: np.ndarray, cpu_s: float, **kwargs: Any) -> None:
        self.ic = copies
        super().__init__(*args, **kwargs)
        self.guarded = Guarded(self._solve_here, cpu_s)

    def solve(
        self,
        x0: np.ndarray,
        params: np.ndarray,
        throttle: tuple[float, float],
        guess: np.ndarray | None = None,
    ) -> tuple[np.ndarray | None, bool]:
        kept = None if self._sol is None else [d.full() for d in self._sol]
        try:
            reply = self.guarded((x0, params, throttle, guess, kept))
        except WorkerError as exc:  # a failed solve, said as what it was: never a CPU limit
            print(f"warning: {exc}", file=sys.stderr)
            self._sol = None
            self.stats = SolveStats(False, 0, f"the solver's worker failed: {exc.cause}")
            return None, False
        if reply is None:
            self._sol = None
            self.stats = SolveStats(False, 0, f"more than {self.guarded.cpu_s} s of CPU")
            return None, False
        plan, ok, self.stats, sol = reply
        self._sol = None if sol is None else [ca.DM(a) for a in sol]
        return plan, ok

    def _solve_here(self, request: tuple) -> tuple:
        """One solve as ``MultipleShootingNLP`` does it, from the caller's last solution."""
        x0, params, throttle, guess, kept = request
        self._sol = None if kept is None else [ca.DM(a) for a in kept]
        plan, ok = MultipleShootingNLP.solve(self, x0, params, throttle, guess)
        sol = None if self._sol is None else [d.full() for d in self._sol]
        return plan, ok, self.stats, sol

    def _preparation(self, limits: Any) -> ca.Function:
        base = super()._preparation(limits)
        symbols = [ca.SX.sym(f"a{i}", base.sparsity_in(i)) for i in range(base.n_in())]
        guess, lbx, ubx = base(*symbols)
        for k in range(self.n):
            guess[self.ic[k]] = guess[self.iu[k]]
        return ca.Function("nmpc_prepare_stagewise", symbols, [guess, lbx, ubx])


def fatrop_options(
    max_iter: int, lbg: np.ndarray, ubg: np.ndarray, extra: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """CasADi's options for Fatrop on ``stagewise_nlp``; ``extra``: Fatrop's own options."""
    return {
        "structure_detection": "auto",
        "equality": [bool(lo == hi) for lo, hi in zip(lbg, ubg, strict=True)],
        "print_time": False,
        "fatrop": {"max_iter": max_iter, "print_level": 0, **dict(extra or {})},
    }


def check_fatrop_options(options: Mapping[str, Any], where: str) -> None:
    """A ``CapeError`` naming ``where`` when Fatrop refuses an option's name or value, found by
    solving a two-stage problem with them (Fatrop reads its options at the first solve)."""
    from cape.errors import CapeError

    x, u = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    w = ca.vertcat(x[0], u, x[1])
    nlp = {"x": w, "f": u**2 + x[1] ** 2, "g": x[1] - x[0] - u}
    solver = ca.nlpsol("check", "fatrop", nlp, fatrop_options(1, np.zeros(1), np.zeros(1), options))
    try:
        solver(x0=0.0, lbx=[1.0, -np.inf, -np.inf], ubx=[1.0, np.inf, np.inf], lbg=0.0, ubg=0.0)
    except RuntimeError as exc:
        reason = str(exc).strip().splitlines()[-1].split(": ", 1)[-1]
        raise CapeError(
            f"{where}: Fatrop refuses it ({reason}); the names are Fatrop's own "
            "(e.g. mu_init, tol, acceptable_tol, bound_push)"
        ) from None
