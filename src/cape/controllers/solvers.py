"""What the NMPC asks of the solvers behind it: two small interfaces, so that the controller, its
rescue and the ``cape`` command use a solver without reaching into it.

- ``OCPSolver``: the step's solver (the condensed SQP, or IPOPT or CasADi's sqpmethod on the
  multiple-shooting NLP): reset, solve, statistics, the predicted states, its compiled library.
- ``RescuableSolver``: a solver whose failed solve another can take over (the condensed SQP):
  its last iterate, and adopting the rescue's answer as its own next warm start.
- ``RescueSolver``: the solver that takes over (Fatrop or IPOPT on the same problem), started
  from a guess.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from cape.controllers.sqp import SolveStats


class OCPSolver(Protocol):
    library: Path | None
    stats: SolveStats

    def reset(self) -> None:
        """Forget the previous solution: the next solve starts cold."""

    def solve(
        self, x0: np.ndarray, params: np.ndarray, throttle: tuple[float, float]
    ) -> tuple[np.ndarray | None, bool]:
        """The plan (N × 2 inputs) of this step, warm-started, and whether it converged."""
        ...

    def states(self) -> np.ndarray:
        """The predicted states of the last solve, (N+1) × n_state."""
        ...


@runtime_checkable
class RescuableSolver(Protocol):
    def iterate(self) -> tuple[np.ndarray, np.ndarray]:
        """The current iterate's inputs (N × 2) and slacks (N): where a failed solve stopped."""
        ...

    def adopt(self, inputs: np.ndarray) -> np.ndarray:
        """Take ``inputs`` as this step's solution and the next warm start; the plan (N × 2)."""
        ...


class RescueSolver(Protocol):
    library: Path | None
    stats: SolveStats

    def decision_vector(
        self, states: np.ndarray, inputs: np.ndarray, slacks: np.ndarray
    ) -> np.ndarray:
        """The rescue's decision vector of a trajectory, its starting guess."""
        ...

    def solve(
        self,
        x0: np.ndarray,
        params: np.ndarray,
        throttle: tuple[float, float],
        guess: np.ndarray | None = None,
    ) -> tuple[np.ndarray | None, bool]:
        """The plan (N × 2) and success, started from ``guess`` when given."""
        ...
