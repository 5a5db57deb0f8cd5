"""The pure-pursuit controller that drove the car when the BayesRace data were recorded.

It follows SPEC §3 to the letter, including its tie rule and its lack of input clipping,
because the published data sets (and so every trained model) depend on those details.
"""

from __future__ import annotations

import math

import numpy as np

from cape.tracks.geometry import ClosedPath


class PurePursuit:
    """Lookahead ``lookahead`` (m) on a raceline with speed profile; throttle gain ``kp``."""

    def __init__(
        self,
        raceline_x: np.ndarray,
        raceline_y: np.ndarray,
        speed: np.ndarray,
        lookahead: float,
        kp: float,
        wheelbase: float,
    ) -> None:
        self.raceline_x = np.asarray(raceline_x, dtype=float)
        self.raceline_y = np.asarray(raceline_y, dtype=float)
        self.speed = np.asarray(speed, dtype=float)
        self.lookahead, self.kp, self.wheelbase = lookahead, kp, wheelbase
        self._path = ClosedPath(self.raceline_x, self.raceline_y)
        if len(self._path) != self.raceline_x.size:
            raise ValueError("the raceline must not repeat its first point at the end")

    def target_index(self, X: float, Y: float) -> int:
        """Index of the goal point: the projection's segment start, stepped past ``lookahead``.

        ``ClosedPath`` numbers the closing segment N−1 (last), which is the SPEC's index −1 in
        the tie order, and ``ind − 1`` then indexes the same speed either way.
        """
        ind = self._path.project(X, Y).segment
        n = self.raceline_x.size
        while math.hypot(self.raceline_x[ind] - X, self.raceline_y[ind] - Y) < self.lookahead:
            ind = (ind + 1) % n
        return ind

    def command(self, state: np.ndarray) -> tuple[float, float, float]:
        """``(T, δ, v_ref)`` for the state ``[X, Y, ψ, vx, …]``, unclipped."""
        X, Y, psi, vx = state[0], state[1], state[2], state[3]
        ind = self.target_index(X, Y)
        vref = float(self.speed[ind - 1])
        throttle = self.kp * (vref - vx)
        alpha = np.arctan2(self.raceline_y[ind] - Y, self.raceline_x[ind] - X) - psi
        delta = np.arctan2(2 * self.wheelbase * np.sin(alpha) / self.lookahead, 1)
        return float(throttle), float(delta), vref
