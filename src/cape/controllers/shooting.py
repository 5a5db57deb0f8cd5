"""The NMPC's problem as a multiple-shooting NLP, solved by IPOPT (the reference) or by CasADi's
``sqpmethod`` (the default until the condensed SQP of ``cape.controllers.sqp`` replaced it).

The decision variables are ordered stage by stage, ``[x_0, u_0, ε_1, x_1, u_1, ε_2, …, x_N]``,
and so are the constraints, so the KKT matrices are banded. The initial state is fixed through
the bounds of x_0. Each solve is warm-started from the shifted previous solution and its
multipliers; after a failed solve the next one starts cold (x_0 and the previous input held).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import casadi as ca
import numpy as np

from cape.controllers.sqp import SolveStats
from cape.numerics.compiled import make_nlpsol

N_INPUT = 2


class MultipleShootingNLP:
    """``solve(x0, params, throttle) → (plan | None, ok)`` on an NLP built once."""

    def __init__(
        self,
        name: str,
        plugin: str,
        nlp: Callable[[], dict[str, Any]],
        bounds: tuple[np.ndarray, np.ndarray],
        index: dict[str, np.ndarray],
        limits: Any,
        u_prev: slice,
        opts: dict[str, Any],
        compile_settings: dict[str, Any] | None,
        fingerprint: str | None = None,
    ) -> None:
        """``nlp()``: the problem's expressions ({x, f, g, p}), built only when no cached
        library has them; ``bounds``: (lbg, ubg); ``fingerprint``: a digest of everything the
        problem's code depends on, the key of its cached library (None: the generated code's
        own hash, which needs the expressions)."""
        self.ix, self.iu, self.ie = index["x"], index["u"], index["e"]
        self.n_w = int(max(self.ix.max(), self.iu.max(), self.ie.max())) + 1
        self.n = len(self.iu)
        self.u_prev_slice = u_prev
        self.solver, self.library = make_nlpsol(
            name, plugin, nlp, opts, compile_settings, fingerprint
        )
        self._lbg, self._ubg = ca.DM(bounds[0]), ca.DM(bounds[1])
        self._prepare = self._preparation(limits)
        self.reset()

    def _preparation(self, limits: Any) -> ca.Function:
        """(previous solution, x0, throttle bounds, shift) → (initial guess, lbx, ubx), as one
        CasADi function: the solution and multipliers stay CasADi matrices between steps, since
        converting arrays at the Python boundary costs more than the compiled NLP functions.
        ``shift`` 1: the previous step's solution, shifted by one stage; 0: a guess for this
        step, taken as it is (x_0 set to x0)."""
        n, nw, ix, iu = self.n, self.n_w, self.ix, self.iu
        n_state = ix.shape[1]
        w_prev, x0 = ca.SX.sym("w_prev", nw), ca.SX.sym("x0", n_state)
        throttle = ca.SX.sym("throttle", 2)  # lower and upper bound of every T_k
        shift = ca.SX.sym("shift")
        shifted = ca.SX.zeros(nw)
        for k in range(n + 1):  # x_0 ← x0, x_k ← x_{k+1} (the last one repeated)
            shifted[ix[k]] = x0 if k == 0 else w_prev[ix[min(k + 1, n)]]
        for k in range(n):
            shifted[iu[k]] = w_prev[iu[min(k + 1, n - 1)]]
        as_is = ca.SX(w_prev)
        as_is[ix[0]] = x0
        guess = ca.if_else(shift, shifted, as_is)
        lbx, ubx = ca.SX(np.full(nw, -np.inf)), ca.SX(np.full(nw, np.inf))
        lbx[iu[:, 1]], ubx[iu[:, 1]] = -limits.delta_max, limits.delta_max
        lbx[iu[:, 0]], ubx[iu[:, 0]] = throttle[0], throttle[1]
        lbx[ix[0]], ubx[ix[0]] = x0, x0
        lbx[self.ie] = 0.0
        return ca.Function("nmpc_prepare", [w_prev, x0, throttle, shift], [guess, lbx, ubx])

    def reset(self) -> None:
        self._sol: list[ca.DM] | None = None  # solution and multipliers (CasADi matrices)
        self.stats = SolveStats(False, 0, "not solved")

    def cold_start(self, x0: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        """x0 and the previous input held over the horizon (its shift is itself)."""
        w = np.zeros(self.n_w)
        w[self.ix] = x0
        w[self.iu] = u_prev
        return w

    def solve(
        self,
        x0: np.ndarray,
        params: np.ndarray,
        throttle: tuple[float, float],
        guess: np.ndarray | None = None,
    ) -> tuple[np.ndarray | None, bool]:
        """The plan (N × 2) and success; warm-started from the previous solution, or from
        ``guess`` (a full decision vector) when given."""
        if guess is not None:
            guess, lbx, ubx = self._prepare(guess, x0, throttle, False)
            multipliers = {}
        elif self._sol is None:
            start = self.cold_start(x0, params[self.u_prev_slice])
            guess, lbx, ubx = self._prepare(start, x0, throttle, True)
            multipliers = {}
        else:
            guess, lbx, ubx = self._prepare(self._sol[0], x0, throttle, True)
            multipliers = {"lam_x0": self._sol[1], "lam_g0": self._sol[2]}
        sol = self.solver(x0=guess, p=params, lbx=lbx, ubx=ubx, lbg=self._lbg, ubg=self._ubg,
                          **multipliers)  # fmt: skip
        stats = self.solver.stats()
        ok = bool(stats["success"])
        self.stats = SolveStats(ok, int(stats.get("iter_count", 0)), str(stats["return_status"]))
        if not ok:
            self._sol = None
            return None, False
        self._sol = [sol["x"], sol["lam_x"], sol["lam_g"]]
        return self.inputs(), True

    @property
    def w(self) -> np.ndarray:
        assert self._sol is not None
        return self._sol[0].full().ravel()

    def decision_vector(
        self, states: np.ndarray, inputs: np.ndarray, slacks: np.ndarray
    ) -> np.ndarray:
        """The NLP's decision vector of a trajectory (states (N+1) × n, inputs N × 2, slacks N)."""
        w = np.zeros(self.n_w)
        w[self.ix], w[self.iu], w[self.ie] = states, inputs, slacks
        return w

    def inputs(self) -> np.ndarray:
        """The planned inputs of the last solution, N × 2."""
        return self.w[self.iu]

    def states(self) -> np.ndarray:
        """The predicted states of the last solution, (N+1) × n_state."""
        return self.w[self.ix]


def ipopt_options(
    max_iter: int, tol: float | None = None, extra: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """CasADi's options for IPOPT; ``extra``: more of IPOPT's own options by name (e.g.
    ``mu_init``), from the controller's ``ipopt.options``."""
    opts: dict[str, Any] = {
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.max_iter": max_iter,
        "ipopt.warm_start_init_point": "yes",
        "print_time": False,
    }
    if tol is not None:
        opts["ipopt.tol"] = tol
    for name, value in (extra or {}).items():
        opts[f"ipopt.{name}"] = value
    return opts


def check_ipopt_options(options: Mapping[str, Any], where: str) -> None:
    """A ``CapeError`` naming ``where`` when IPOPT refuses an option's name or value."""
    from cape.errors import CapeError

    x = ca.SX.sym("x")
    try:
        ca.nlpsol("check", "ipopt", {"x": x, "f": x**2}, ipopt_options(1, extra=options))
    except RuntimeError as exc:
        reason = str(exc).strip().splitlines()[-1].split(": ", 1)[-1]
        raise CapeError(
            f"{where}: IPOPT refuses it ({reason}); the names and values are IPOPT's own "
            "(https://coin-or.github.io/Ipopt/OPTIONS.html)"
        ) from None


def sqpmethod_options(max_iter: int, tol: float, qp_max_iter: int) -> dict[str, Any]:
    """CasADi's SQP: exact Hessian, no convexification, qrqp."""
    quiet = {"print_iter": False, "print_header": False, "print_info": False}
    return {
        "qpsol": "qrqp",
        "qpsol_options": {**quiet, "error_on_fail": False, "max_iter": qp_max_iter},
        "hessian_approximation": "exact",
        "convexify_strategy": "none",
        "max_iter": max_iter,
        "tol_pr": tol,
        "tol_du": tol,
        "print_header": False,
        "print_iteration": False,
        "print_status": False,
        "print_time": False,
        "error_on_fail": False,
    }
