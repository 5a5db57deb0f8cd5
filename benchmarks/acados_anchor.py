"""An anchor from the field: the nominal NMPC's problem in acados (SQP and SQP-RTI with HPIPM)
beside the project's default solver, on the same recorded problems.

acados is the race-car community's standard NMPC solver; timing it on the very problems the
study solves tells whether the default condensed SQP (``cape.controllers.sqp``) is in the
field's range, and if not, where it loses the time. acados is an optional extra of this
benchmark only, never a dependency of the study or of CI: it is installed apart, because its
wheel bundles its own CasADi in the same ``casadi/`` folder, which a plain install would write
over the venv's CasADi (IPOPT then breaks while ``pip list`` still names the venv's version):

    pip install --no-deps --target .acados -r benchmarks/requirements-acados.txt
    rm -rf .acados/casadi
    python benchmarks/acados_anchor.py [--acados .acados] [--internal truth epm] [--eta 0 4]
                                       [--repeats 3] [--json PATH]

The script sets ``ACADOS_SOURCE_DIR``, ``ACADOS_PYTHON_INTERFACE_PATH`` and ``LD_LIBRARY_PATH``
from ``--acados`` and restarts itself once (the dynamic loader reads ``LD_LIBRARY_PATH`` only
when a process starts; without ``ACADOS_SOURCE_DIR`` acados stops at a prompt to download its
template renderer).

The same optimal control problem (SPEC §7.3) is posed from the project's own definitions: the
internal model's step (``TrackingOCP.model_step``) is acados's discrete dynamics, the stage's
residual and track offset (``TrackingOCP.stage_terms``) are its least-squares cost and its
nonlinear constraint, with Φ, d̂, Θ and each stage's reference, centre point and normal as the
stage's parameters. The controls are the input *changes* Δu (the commanded input is a state):
the rate bound is then a bound on a control, the input bounds are state bounds, and the cost's
Hessian is exact under Gauss–Newton (only the dynamics' curvature is dropped). The project's SQP
itself optimises the inputs (the states eliminated); with inputs as controls, acados's
Gauss–Newton SQP diverged from a cold start when this was tried first (issue 22).

The laps are recorded as ``benchmarks/nmpc_step.py`` records them (ground-truth plant, seed 0,
nominal NMPC with the default solver). Then, in one process, the problems are replayed in
order, *interleaved* (each problem through every solver before the next, the order rotating),
each solver warm-started from its own previous solution, ``--repeats`` times:

  default       the config's solver (the condensed SQP, its IPOPT rescue included)
  acados SQP    full SQP to tolerance, HPIPM, full (fc) and partial (pc) condensing
  acados RTI    SQP-RTI: one Gauss–Newton iteration per step (real-time practice)
  reference     IPOPT at tolerance 1e-8 (once), for the first-input agreement

acados's settings are its race-car defaults where the problem allows: Gauss–Newton, full steps,
HPIPM. Measured on the true model's η = 0 lap: HPIPM's ``SPEED`` mode gives the same answers
as ``BALANCE`` (acados's default) 25–30 % faster (``SPEED_ABS`` computes no residuals, so the
SQP never detects convergence); ``--tol`` 1e-7 is the loosest KKT tolerance at which every first
input agrees with the default's within 1e-3 (1e-6, acados's default, left 3 % outside, up to
1.5e-3, and 9 % with BALANCE: the cost is small, ~1e-3, so an absolute KKT tolerance is loose in
the inputs' units). At η = 4,
an exact Hessian (regularised by PROJECT, MIRROR or CONVEXIFY), merit backtracking, a kept
warm start after a failure and 100 iterations were tried: none removes the full SQP's failures.

acados is timed two ways: the wall time of a step as this script drives it (setting the
stage parameters and x0, the shifted warm start, reading the plan; thin ctypes calls bound
once, as the default binds its functions through ``Function.buffer``) and acados's own
``time_tot`` (inside its C solve only). Per lap and solver it prints the median, p90, p99 and
max (ms), iterations, failures and the first input's agreement with the reference and with the
default, and the cost of acados's plans against the default's (the project's merit F: the cost
with the least feasible slacks, what any plan is compared by). When acados's full SQP is more
than twice as fast, the default's time is split into its parts (``--parts``, on by default).
"""

from __future__ import annotations

import argparse
import ctypes
import os
import re
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _common import add_config, json_output, run, study_config  # a sibling module
from nmpc_step import Problem, controller_with, record_lap, replay, row

from cape.errors import CapeError
from cape.layout import paths

ENV = ("ACADOS_SOURCE_DIR", "ACADOS_PYTHON_INTERFACE_PATH", "LD_LIBRARY_PATH")
TIMES = {"c_ms": b"time_tot", "lin_ms": b"time_lin", "condense_ms": b"time_qp_xcond",
         "hpipm_ms": b"time_qp_solver_call"}  # fmt: skip
INSTALL = (
    "install acados apart, never into the venv (its wheel's casadi/ would overwrite the venv's): "
    "`pip install --no-deps --target .acados -r benchmarks/requirements-acados.txt && rm -rf "
    ".acados/casadi`, then run `python benchmarks/acados_anchor.py --acados .acados`"
)


# --- the environment: acados beside the venv, never in it ----------------------------------------
def acados_environment(folder: Path) -> dict[str, str]:
    """The variables acados needs for an install made with ``pip install --target folder``."""
    root = folder.resolve() / "acados"
    lib = root / "install" / "lib"
    paths = [str(lib), *filter(None, os.environ.get("LD_LIBRARY_PATH", "").split(":"))]
    return {
        "ACADOS_SOURCE_DIR": str(root / "install"),
        "ACADOS_PYTHON_INTERFACE_PATH": str(root / "acados_template"),
        "LD_LIBRARY_PATH": ":".join(dict.fromkeys(paths)),
    }


def ensure_environment(folder: Path) -> None:
    """Check the install, then restart this script once with acados's variables set, unless
    they already are. Exits with what to do when something is missing."""
    root = folder.resolve() / "acados"
    if not (root / "acados_template" / "__init__.py").is_file():
        raise CapeError(f"acados is not installed (not found under {folder}/acados); {INSTALL}")
    if (folder / "casadi").exists():
        raise CapeError(
            f"{folder}/casadi is acados's bundled CasADi 3.6.7: delete it (rm -rf "
            f"{folder}/casadi) so that only the venv's CasADi is ever imported"
        )
    renderer = root / "install" / "bin" / "t_renderer"
    if not os.access(renderer, os.X_OK):
        raise CapeError(f"{renderer}: missing or not executable; reinstall: {INSTALL}")
    wanted = acados_environment(folder)
    lib = wanted["LD_LIBRARY_PATH"].split(":")[0]
    current = os.environ.get("LD_LIBRARY_PATH", "").split(":")
    ready = all(os.environ.get(k) == wanted[k] for k in ENV[:2]) and lib in current
    if not ready:
        if os.environ.get("CAPE_ACADOS_RESTARTED"):
            raise CapeError(f"acados's environment could not be set; set {', '.join(ENV)}")
        env = {**os.environ, **wanted, "CAPE_ACADOS_RESTARTED": "1"}
        os.execve(sys.executable, [sys.executable, *sys.argv], env)
    sys.path.append(str(root))  # after the venv's site-packages: its CasADi comes first


def check_casadi() -> None:
    """The venv's CasADi, not acados's bundled one, must be the one imported."""
    import casadi

    expected = os.environ.get("CAPE_CASADI_VERSION", "3.8.2")
    if casadi.__version__ != expected or ".acados" in casadi.__file__:
        raise CapeError(
            f"CasADi {casadi.__version__} from {casadi.__file__}, not the venv's {expected}: "
            f"acados's bundled CasADi is on the path or installed over the venv's. {INSTALL}"
        )


# --- the problem, posed in acados ----------------------------------------------------------------
class AcadosNMPC:
    """The nominal NMPC's problem as an acados OCP built from the controller's own definitions;
    ``solve(x0, params, throttle)`` as the controller's solver, warm-started from its own shifted
    previous solution (cold after a failure: x0 held, Δu = 0).

    State x̃ = [x (the internal model's 8), the previous command (2)], control Δu (2), stage
    parameters [Φ, d̂, Θ, reference point, centre point, normal]. Stage 0 has no track constraint
    and no position cost in the NMPC (x_0 is measured): its normal is zero, so its offset is 0,
    and its cost is the input change's alone."""

    def __init__(
        self,
        controller: Any,
        kind: str,
        qp: str,
        folder: Path,
        tol: float,
        max_iter: int,
        options: dict[str, Any] | None = None,
    ) -> None:
        import casadi as ca
        from acados_template import AcadosModel, AcadosOcp, AcadosOcpSolver

        self.controller = controller
        self.kind = kind
        s, layout = controller.settings, controller.ocp.layout
        n, n_phi = controller.horizon, controller.internal.n_phi
        self.n, self.nx, self.nu = n, 8 + 2, 2
        self.layout = layout
        self.n_p = n_phi + 3 + 3 + 6
        x = ca.SX.sym("x", self.nx)
        du = ca.SX.sym("du", self.nu)
        p = ca.SX.sym("p", self.n_p)
        # the stage's parameters in the controller's layout (stage_terms reads column 0)
        full = ca.SX.zeros(controller.ocp.n_param)
        full[layout["phi"]] = p[:n_phi]
        full[layout["dhat"]] = p[n_phi : n_phi + 3]
        full[layout["theta"]] = p[n_phi + 3 : n_phi + 6]
        geometry = n_phi + 6
        for j, name in enumerate(("ref", "centre", "normal")):
            start = layout[name].start
            full[start : start + 2] = p[geometry + 2 * j : geometry + 2 * j + 2]
        command_before, command = x[8:10], x[8:10] + du
        step = controller.ocp.model_step(x[:8], command, full)
        _, _, offset, residual = controller.ocp.stage_terms(
            x[:8], command, command_before, 0, full, 0
        )
        _, _, _, terminal = controller.ocp.stage_terms(
            x[:8], command_before, command_before, 0, full, 0
        )
        model = AcadosModel()
        model.name = re.sub(r"\W", "_", f"cape_{folder.name}")
        model.x, model.u, model.p = x, du, p
        model.disc_dyn_expr = ca.vertcat(step, command)
        model.cost_y_expr_0 = residual[2:4]  # [√r_T ΔT, √r_δ Δδ]
        model.cost_y_expr = residual[:4]  # [√q (p − p_ref), √r_T ΔT, √r_δ Δδ]
        model.cost_y_expr_e = terminal[:2]
        model.con_h_expr = offset
        model.con_h_expr_e = offset

        ocp = AcadosOcp()
        ocp.model = model
        ocp.dims.N = n
        ocp.parameter_values = np.zeros(self.n_p)
        # acados's stage cost is ½‖y‖²_W: W = 2I gives the residuals' squared norm
        for suffix, size in (("_0", 2), ("", 4), ("_e", 2)):
            setattr(ocp.cost, f"cost_type{suffix}", "NONLINEAR_LS")
            setattr(ocp.cost, f"W{suffix}", 2.0 * np.eye(size))
            setattr(ocp.cost, f"yref{suffix}", np.zeros(size))
        w1, w2 = (float(v) for v in s["slack_penalty"])
        limits = controller.limits
        step_max = limits.max_steering_step(controller.ts)
        c = ocp.constraints
        c.x0 = np.zeros(self.nx)
        c.idxbu, c.lbu, c.ubu = np.array([1]), np.array([-step_max]), np.array([step_max])
        self.input_low = np.array([limits.T_min, -limits.delta_max])
        self.input_high = np.array([limits.T_max, limits.delta_max])
        for suffix in ("", "_e"):
            setattr(c, f"idxbx{suffix}", np.array([8, 9]))
            setattr(c, f"lbx{suffix}", self.input_low.copy())
            setattr(c, f"ubx{suffix}", self.input_high.copy())
            # the track's bound is set per problem (it is an NLP parameter of the controller)
            setattr(c, f"lh{suffix}", np.array([-1.0]))
            setattr(c, f"uh{suffix}", np.array([1.0]))
            setattr(c, f"idxsh{suffix}", np.array([0]))
            # soft: w1·ε + w2·ε² is acados's z·s + ½·Z·s², on each side
            for side in ("l", "u"):
                setattr(ocp.cost, f"z{side}{suffix}", np.array([w1]))
                setattr(ocp.cost, f"Z{side}{suffix}", np.array([2.0 * w2]))
        o = ocp.solver_options
        # acados weighs each stage's cost by its time step (a cost integrated over time): steps
        # of 1 leave the NMPC's sum as it is (the dynamics are discrete, tf is not their time)
        o.tf = float(n)
        o.integrator_type = "DISCRETE"
        o.hessian_approx = "GAUSS_NEWTON"
        o.qp_solver = qp
        o.nlp_solver_type = "SQP_RTI" if kind == "rti" else "SQP"
        o.nlp_solver_max_iter = max_iter
        o.tol = tol
        o.print_level = 0
        for key, value in (options or {}).items():
            setattr(o, key, value)
        folder.mkdir(parents=True, exist_ok=True)
        ocp.code_export_directory = str(folder / "c_generated_code")
        start = time.perf_counter()
        self.solver = AcadosOcpSolver(ocp, json_file=str(folder / "ocp.json"), verbose=False)
        self.build_seconds = time.perf_counter() - start
        self._bind()
        self.reset()

    def _bind(self) -> None:
        """The C calls of one step, their argument types set once (the stock Python interface
        sets them again on every call) and the arrays they read and write preallocated."""
        lib, solver = self.solver.shared_lib, self.solver
        name = solver.model_name
        vp, i, dp = ctypes.c_void_p, ctypes.c_int, ctypes.POINTER(ctypes.c_double)
        self._update_params = getattr(lib, f"{name}_acados_update_params")
        self._update_params.argtypes = [vp, i, dp, i]
        self._solve = getattr(lib, f"{name}_acados_solve")
        self._solve.argtypes, self._solve.restype = [vp], i
        for attr, fn in (("_out_set", lib.ocp_nlp_out_set), ("_out_get", lib.ocp_nlp_out_get),
                         ("_con_set", lib.ocp_nlp_constraints_model_set)):  # fmt: skip
            fn.argtypes = [vp, vp, vp, i, ctypes.c_char_p, vp]
            setattr(self, attr, fn)
        self._get = lib.ocp_nlp_get
        self._get.argtypes = [vp, vp, ctypes.c_char_p, vp]
        self._capsule = solver.capsule
        self._config, self._dims = solver.nlp_config, solver.nlp_dims
        self._in, self._out, self._nlp = solver.nlp_in, solver.nlp_out, solver.nlp_solver
        n = self.n
        self.X = np.zeros((n + 1, self.nx))
        self.U = np.zeros((n, self.nu))
        self.P = np.zeros((n + 1, self.n_p))
        self._x0 = np.zeros(self.nx)
        self._box = np.zeros((2, 2))  # the command's bounds at stages 1..N: low, high
        self._bound = np.zeros(2)  # the track offset's bounds
        self._iter = np.zeros(1, dtype=np.int64)
        self._time = np.zeros(1)
        self._p_ptr = [self.P[k].ctypes.data_as(dp) for k in range(n + 1)]
        self._x_ptr = [self.X[k].ctypes.data for k in range(n + 1)]
        # (reading ``.ctypes.data`` builds an object each time: the addresses are taken once)
        self._x0_ptr = self._x0.ctypes.data
        self._box_ptr = [self._box[0].ctypes.data, self._box[1].ctypes.data]
        self._bound_ptr = [self._bound[:1].ctypes.data, self._bound[1:].ctypes.data]
        self._u_ptr = [self.U[k].ctypes.data for k in range(n)]

    def reset(self) -> None:
        self._warm = False
        self._box_set = (self.input_low.copy(), self.input_high.copy())
        self._bound_set = None
        self.iterations = 0
        self.time_tot = 0.0
        self.status = -1

    def _set_box(self, throttle: tuple[float, float]) -> None:
        low = np.array([throttle[0], self.input_low[1]])
        high = np.array([throttle[1], self.input_high[1]])
        if np.array_equal(low, self._box_set[0]) and np.array_equal(high, self._box_set[1]):
            return
        self._box[0], self._box[1] = low, high
        for k in range(1, self.n + 1):
            for field, side in ((b"lbx", 0), (b"ubx", 1)):
                self._con_set(self._config, self._dims, self._in, k, field,
                              self._box_ptr[side])  # fmt: skip
        self._box_set = (low, high)

    def _set_bound(self, bound: float) -> None:
        if bound == self._bound_set:
            return
        self._bound[:] = (-bound, bound)
        for k in range(self.n + 1):
            self._con_set(self._config, self._dims, self._in, k, b"lh", self._bound_ptr[0])
            self._con_set(self._config, self._dims, self._in, k, b"uh", self._bound_ptr[1])
        self._bound_set = bound

    def solve(
        self, x0: np.ndarray, params: np.ndarray, throttle: tuple[float, float]
    ) -> tuple[np.ndarray | None, bool]:
        """The plan (N × 2 commands) and whether acados reported success."""
        layout, n, n_phi = self.layout, self.n, self.controller.internal.n_phi
        u_prev = params[layout["u_prev"]]
        P = self.P
        P[:, :n_phi] = params[layout["phi"]]
        P[:, n_phi : n_phi + 3] = params[layout["dhat"]]
        P[:, n_phi + 3 : n_phi + 6] = params[layout["theta"]]
        g = n_phi + 6
        P[1:, g : g + 2] = params[layout["ref"]].reshape(n, 2)
        P[1:, g + 2 : g + 4] = params[layout["centre"]].reshape(n, 2)
        P[1:, g + 4 : g + 6] = params[layout["normal"]].reshape(n, 2)
        for k in range(n + 1):
            self._update_params(self._capsule, k, self._p_ptr[k], self.n_p)
        self._set_bound(float(params[layout["bound"]][0]))
        self._set_box(throttle)
        x0_full = self._x0
        x0_full[:8] = x0
        x0_full[8:] = u_prev
        ptr = self._x0_ptr
        self._con_set(self._config, self._dims, self._in, 0, b"lbx", ptr)
        self._con_set(self._config, self._dims, self._in, 0, b"ubx", ptr)
        X, U = self.X, self.U
        if self._warm:  # shift the previous solution by one stage, x_0 the measured state
            X[:-1] = X[1:]
            U[:-1] = U[1:]
            U[-1] = 0.0
        else:
            X[:] = x0_full
            U[:] = 0.0
        X[0] = x0_full
        for k in range(n + 1):
            self._out_set(self._config, self._dims, self._out, k, b"x", self._x_ptr[k])
        for k in range(n):
            self._out_set(self._config, self._dims, self._out, k, b"u", self._u_ptr[k])
        self.status = self._solve(self._capsule)
        for k in range(n + 1):
            self._out_get(self._config, self._dims, self._out, k, b"x", self._x_ptr[k])
        for k in range(n):
            self._out_get(self._config, self._dims, self._out, k, b"u", self._u_ptr[k])
        # SQP: converged (0); RTI: its one iteration done (0, or 2 "max_iter" in some versions)
        ok = self.status == 0 or (self.kind == "rti" and self.status == 2)
        self._warm = ok
        if not ok:
            return None, False
        return X[1:, 8:10].copy(), True

    def statistics(self) -> dict[str, float]:
        """Iterations and acados's own times (ms) of the last solve (read off the timed path):
        in total, linearising (the model's and the constraints' functions and Jacobians),
        condensing, and inside HPIPM."""
        out = {"iterations": 0.0}
        self._get(self._config, self._nlp, b"sqp_iter", self._iter.ctypes.data)
        out["iterations"] = float(self._iter[0])
        for key, field in TIMES.items():
            self._get(self._config, self._nlp, field, self._time.ctypes.data)
            out[key] = float(self._time[0]) * 1e3
        return out

    def cost(self) -> float:
        """acados's own cost of its last solution (the slacks' penalty included)."""
        return float(self.solver.get_cost())


# --- the replay: every solver on every problem, interleaved --------------------------------------
class Contender:
    """One solver in the replay: its reset, its solve, and what it reports after a solve."""

    def __init__(self, label: str, solver: Any, controller: Any | None = None) -> None:
        self.label = label
        self.solver = solver  # an AcadosNMPC, or the controller itself (the default)
        self.controller = controller

    def reset(self, z0: np.ndarray) -> None:
        if self.controller is not None:
            self.controller.reset(z0)
        else:
            self.solver.reset()

    def solve(self, problem: Problem) -> tuple[np.ndarray | None, bool]:
        return self.solver.solve(*problem)

    def statistics(self) -> dict[str, float]:
        if self.controller is not None:
            return {"iterations": float(self.controller.solver.stats.iterations)}
        return {**self.solver.statistics(), "cost": self.solver.cost()}


def interleaved(contenders: list[Contender], problems: list[Problem]) -> list[dict[str, Any]]:
    """One replay of the lap: problem by problem, each through every solver (the order rotating
    so that none always runs first after another's caches), each warm-started from its own
    previous solution. Per solver: wall times (ms), success, first inputs, plans, statistics."""
    n = len(problems)
    for c in contenders:
        c.reset(problems[0][0][:6])
    out = [{"ms": np.empty(n), "ok": np.zeros(n, bool), "first": np.full((n, 2), np.nan),
            "plans": [None] * n, "stats": []} for _ in contenders]  # fmt: skip
    order = list(range(len(contenders)))
    for i, problem in enumerate(problems):
        for j in order[i % len(order) :] + order[: i % len(order)]:
            start = time.perf_counter()
            plan, ok = contenders[j].solve(problem)
            elapsed = time.perf_counter() - start
            r = out[j]
            r["ms"][i] = elapsed * 1e3
            r["ok"][i] = ok
            r["stats"].append(contenders[j].statistics())
            if ok:
                r["first"][i] = plan[0]
                r["plans"][i] = plan
    for r in out:
        r["iterations"] = np.array([s["iterations"] for s in r["stats"]])
    return out


def merged(replays: list[dict[str, Any]]) -> dict[str, Any]:
    """The replays of one solver as one sample of times; the solutions of the first (the
    replays are deterministic: only the times differ)."""
    first = replays[0]
    out = dict(first)
    for key in ("ms", "ok", "iterations"):
        out[key] = np.concatenate([r[key] for r in replays])
    for key in TIMES:
        if key in first["stats"][0]:
            out[key] = np.concatenate([[s[key] for s in r["stats"]] for r in replays])
    return out


# --- where the default's time goes ---------------------------------------------------------------
def default_parts(controller: Any, problems: list[Problem]) -> dict[str, float]:
    """One replay of the default with each of its compiled calls timed (prepare, the
    linearisation, the Gauss–Newton fallback, the QP through CasADi's daqp, the line search's
    trial points): the median per solve of each, the rest being the Python of the SQP's loop
    (and the IPOPT rescue when one runs). The timers add ~0.1 µs per call."""
    backend = controller.solver
    spent: dict[str, float] = {}
    counts: dict[str, int] = {}
    saved = dict(backend._calls)

    def timed(key: str, call: Any) -> Any:
        def wrapper() -> Any:
            start = time.perf_counter()
            result = call()
            spent[key] += time.perf_counter() - start
            counts[key] += 1
            return result

        return wrapper

    for key, (buffer, call, args, results) in saved.items():
        backend._calls[key] = (buffer, timed(key, call), args, results)
    rows = []
    try:
        controller.reset(problems[0][0][:6])
        for problem in problems:
            for key in saved:
                spent[key], counts[key] = 0.0, 0
            start = time.perf_counter()
            controller.solve(*problem)
            total = time.perf_counter() - start
            rows.append([total, *spent.values(), *counts.values()])
    finally:
        backend._calls.update(saved)
    table = np.array(rows)
    keys = list(saved)
    total = table[:, 0] * 1e3
    parts = table[:, 1 : 1 + len(keys)] * 1e3
    calls = table[:, 1 + len(keys) :]
    out = {"total_ms": float(np.median(total))}
    for i, key in enumerate(keys):
        out[f"{key}_ms"] = float(np.median(parts[:, i]))
        out[f"{key}_calls"] = float(np.median(calls[:, i]))
        out[f"{key}_share"] = float(parts[:, i].sum() / total.sum())
    rest = total - parts.sum(axis=1)
    out["python_ms"] = float(np.median(rest))
    out["python_share"] = float(rest.sum() / total.sum())
    out["python_per_call_us"] = float(np.median(rest / calls.sum(axis=1)) * 1e3)
    return out


# --- the lap ------------------------------------------------------------------------------------
def compare(
    r: dict[str, Any], default: dict[str, Any], merit: Any, problems: list[Problem]
) -> dict[str, Any]:
    """A solver's first inputs and costs against the default's, on the problems both solved:
    the share within 1e-3, and F(plan) relative to the default's F (positive: higher)."""
    diff = np.max(np.abs(r["first"] - default["first"]), axis=1)
    both = np.isfinite(diff)
    rel = np.array([
        (merit(problems[i], r["plans"][i]) - merit(problems[i], default["plans"][i]))
        / max(merit(problems[i], default["plans"][i]), 1e-12)
        for i in np.flatnonzero(both)
    ])  # fmt: skip
    return {
        "vs_default_within_1e-3": float(np.mean(diff[both] <= 1e-3)),
        "vs_default_max_diff": float(np.max(diff[both])),
        "cost_rel_median": float(np.median(rel)),
        "cost_rel_max": float(np.max(rel)),
        "cost_rel_min": float(np.min(rel)),
        "cost_higher_1e-6": int(np.sum(rel > 1e-6)),
        "cost_lower_1e-6": int(np.sum(rel < -1e-6)),
        "cost_higher_1pc": int(np.sum(rel > 1e-2)),
        "cost_lower_1pc": int(np.sum(rel < -1e-2)),
        "compared": int(both.sum()),
    }


def build_contenders(
    config: dict[str, Any], internal: str, args: argparse.Namespace
) -> tuple[Any, list[Contender]]:
    """The default controller and the acados solvers of its problem (generated and compiled
    under ``--build``, ~6 s each)."""
    default = controller_with(config, internal, args.models)
    contenders = [Contender(f"default ({config['controllers']['nmpc']['solver']})", default,
                            default)]  # fmt: skip
    options = {"hpipm_mode": args.hpipm_mode}
    for kind in ("sqp", "rti"):
        for qp in args.condensing:
            name = f"{internal}_{kind}_{qp}"
            solver = AcadosNMPC(default, kind, CONDENSING[qp], args.build / name, args.tol,
                                args.max_iter if kind == "sqp" else 1, options)  # fmt: skip
            print(f"acados {kind} ({qp}) for {internal}: generated and compiled in "
                  f"{solver.build_seconds:.1f} s")  # fmt: skip
            contenders.append(Contender(f"acados {kind.upper()} {qp}", solver))
    return default, contenders


def benchmark_lap(
    config: dict[str, Any], internal: str, eta: float, args: argparse.Namespace,
    default: Any, contenders: list[Contender],
) -> dict[str, Any]:  # fmt: skip
    problems = record_lap(config, internal, eta, args.models)
    tight = {"max_iter": 1000, "tol": 1e-8}
    reference = replay(controller_with(config, internal, args.models, solver="ipopt", ipopt=tight),
                       problems)  # fmt: skip
    interleaved(contenders, problems[:20])  # warm up caches and the compiled code
    replays = [interleaved(contenders, problems) for _ in range(max(1, args.repeats))]
    results = [merged([r[j] for r in replays]) for j in range(len(contenders))]

    def merit(problem: Problem, plan: np.ndarray) -> float:
        return default.solver.merit(*problem, plan)

    def merit_at(i: int, plan: np.ndarray) -> float:
        return merit(problems[i], plan)

    print(f"{'solver':34} {'median':>8} {'p90':>8} {'p99':>8} {'max':>8} {'it.med':>5} "
          f"{'it.max':>5} {'fail':>5}   first-input diff vs IPOPT 1e-8, share ≤ 1e-3")  # fmt: skip
    rows: dict[str, Any] = {}
    base = results[0]
    for c, r in zip(contenders, results, strict=True):
        rows[c.label] = row(c.label, r, reference, merit_at)
        if "c_ms" in r:
            inner = {**r, "ms": r["c_ms"]}
            rows[c.label]["acados_time_tot"] = row("  its time_tot (C, inside solve)", inner,
                                                   None)  # fmt: skip
            rows[c.label]["acados_parts_median_ms"] = {
                k: float(np.median(r[k])) for k in TIMES if k in r
            }
    row("reference IPOPT, tol 1e-8", reference, None)
    print(f"\n{'against the default':34} {'ratio':>6} {'C ratio':>7} {'≤1e-3':>7} {'max diff':>9} "
          f"{'F rel. median':>13} {'max':>9} {'min':>9} {'higher':>6} {'lower':>6}")  # fmt: skip
    med = float(np.median(base["ms"]))
    for c, r in zip(contenders[1:], results[1:], strict=True):
        cmp = compare(r, base, merit, problems)
        ratio = med / float(np.median(r["ms"]))
        c_ratio = med / float(np.median(r["c_ms"]))
        rows[c.label].update(cmp, speedup_wall=ratio, speedup_c=c_ratio)
        within = 100 * cmp["vs_default_within_1e-3"]
        print(f"{c.label:34} {ratio:6.2f} {c_ratio:7.2f} {within:6.1f}%"
              f" {cmp['vs_default_max_diff']:9.1e} {cmp['cost_rel_median']:13.1e} "
              f"{cmp['cost_rel_max']:9.1e} {cmp['cost_rel_min']:9.1e} "
              f"{cmp['cost_higher_1e-6']:6d} {cmp['cost_lower_1e-6']:6d}")  # fmt: skip
    print(
        "(ratio: the default's median wall time over the solver's; C ratio: over acados's own "
        "time_tot; F rel.: the project's merit of the plan relative to the default's)"
    )
    # each solver alone over the lap, as nmpc_step.py times it: interleaving evicts each solver's
    # code and data from the caches between its solves (as the plant, the network and the other
    # controller code do in a closed-loop run), which costs some solvers more than others
    alone = {c.label: float(np.median(interleaved([c], problems)[0]["ms"])) for c in contenders}
    for c in contenders:
        rows[c.label]["alone_median_ms"] = alone[c.label]
    first = contenders[0].label
    print(
        "alone (one replay per solver, not interleaved), median ms and the default's over it: "
        + ", ".join(f"{k} {v:.3f} ({alone[first] / v:.2f})" for k, v in alone.items())
    )
    for c, r in zip(contenders[1:], results[1:], strict=True):
        # the posing's check: acados's own cost of its solution against the project's merit F of
        # its plan (equal when the problems are the same and the solution dynamically feasible,
        # which an RTI iterate is not quite)
        ok = np.flatnonzero(r["ok"][: len(problems)])
        own = np.array([r["stats"][i]["cost"] for i in ok])
        f = np.array([merit(problems[i], r["plans"][i]) for i in ok])
        gap = float(np.max(np.abs(own - f) / np.maximum(np.abs(f), 1e-12)))
        rows[c.label]["own_cost_vs_merit_max_rel"] = gap
        print(
            f"{c.label}: its own cost against F of its plan, largest relative difference {gap:.1e}"
        )
    for c in contenders[1:]:
        cmp = rows[c.label]
        print(
            f"{c.label}: F more than 1 % above the default's in {cmp['cost_higher_1pc']}, "
            f"below in {cmp['cost_lower_1pc']} of {cmp['compared']} problems"
        )
    for c, r in zip(contenders[1:], results[1:], strict=True):
        parts = rows[c.label]["acados_parts_median_ms"]
        glue = float(np.median(r["ms"] - r["c_ms"]))
        print(f"{c.label}: medians per solve, linearise {parts['lin_ms']:.3f} ms, condense "
              f"{parts['condense_ms']:.3f}, HPIPM {parts['hpipm_ms']:.3f}, time_tot "
              f"{parts['c_ms']:.3f}; Python and the C calls around solve {glue:.3f}")  # fmt: skip
    parts = default_parts(default, problems)
    keys = [k[:-3] for k in parts if k.endswith("_ms") and k not in ("total_ms", "python_ms")]
    text = ", ".join(f"{k} {parts[k + '_ms']:.3f} ms ×{parts[k + '_calls']:.0f} "
                     f"({100 * parts[k + '_share']:.0f} %)" for k in keys)  # fmt: skip
    print(f"default, medians per solve (instrumented replay, total {parts['total_ms']:.3f} ms): "
          f"{text}; Python around them {parts['python_ms']:.3f} ms "
          f"({100 * parts['python_share']:.0f} %, {parts['python_per_call_us']:.1f} µs per "
          f"call)")  # fmt: skip
    return {"internal": internal, "eta": eta, "problems": len(problems), "solvers": rows,
            "default_parts": parts,
            "default_rescues_last_replay": int(default.rescues)}  # fmt: skip


CONDENSING = {"fc": "FULL_CONDENSING_HPIPM", "pc": "PARTIAL_CONDENSING_HPIPM"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--acados", type=Path, default=Path(".acados"),
                        help="the folder acados was installed into with pip --target")  # fmt: skip
    parser.add_argument("--internal", nargs="+", default=["truth", "epm"])
    parser.add_argument("--eta", nargs="+", type=float, default=[0.0, 4.0])
    parser.add_argument("--models", type=Path, default=Path(paths.models_of(0)),
                        help="the draw's models folder (default: draw 0's)")  # fmt: skip
    parser.add_argument("--build", type=Path, default=Path(paths.RESULTS, "acados"),
                        help="where acados's generated code and libraries go")  # fmt: skip
    parser.add_argument("--condensing", nargs="+", choices=list(CONDENSING),
                        default=["fc", "pc"])  # fmt: skip
    parser.add_argument("--tol", type=float, default=1e-7,
                        help="acados's KKT tolerance (stationarity, equalities, inequalities, "
                        "complementarity) for the full SQP")  # fmt: skip
    parser.add_argument("--max-iter", type=int, default=30, help="the default's max_iter")
    parser.add_argument("--hpipm-mode", default="SPEED",
                        choices=["BALANCE", "SPEED", "ROBUST"])  # fmt: skip
    parser.add_argument("--repeats", type=int, default=3, help="interleaved replays of each lap")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    add_config(parser)
    args = parser.parse_args()
    ensure_environment(args.acados)
    check_casadi()
    with json_output(args.json, "acados_anchor.py") as write:
        config = study_config(args)
        results = []
        for internal in args.internal:
            default, contenders = build_contenders(config, internal, args)
            for eta in args.eta:
                results.append(benchmark_lap(config, internal, eta, args, default, contenders))
        write(results)


if __name__ == "__main__":
    sys.exit(run(main))
