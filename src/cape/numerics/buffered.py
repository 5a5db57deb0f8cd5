"""CasADi functions called through ``Function.buffer()`` on preallocated arrays.

A call of a CasADi function with arguments converts every input and output at the Python
boundary; through its buffer, on arrays bound once, nothing is converted (the difference:
docs/design.md). The closed loop's per-step numerics (the plant's step, the EKF's prediction,
the NMPC's solver) run thousands of times per lap, so they call their functions this way.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class BufferedCall:
    """``f(*inputs) → outputs`` on arrays bound to ``f``'s buffer (every input and output dense).

    The returned arrays are the bound ones: copy what must outlive the next call."""

    def __init__(self, function: Any) -> None:
        self.function = function
        self.inputs = [np.zeros(function.nnz_in(i)) for i in range(function.n_in())]
        self.outputs = [np.zeros(function.nnz_out(i)) for i in range(function.n_out())]
        self._buffer, self._call = function.buffer()
        for i, array in enumerate(self.inputs):
            self._buffer.set_arg(i, memoryview(array))
        for i, array in enumerate(self.outputs):
            self._buffer.set_res(i, memoryview(array))

    def __call__(self, *args: Any) -> list[np.ndarray]:
        for array, value in zip(self.inputs, args, strict=True):
            array[:] = value
        self._call()
        return self.outputs
