"""
Projected Gauss–Seidel sweeps of a box-constrained LCP, compiled.

``w = S f + q`` with ``lo ≤ f ≤ hi`` (:mod:`..complementarity` states the problem
and its conditions): each sweep sets each row's force in turn to the value that
zeroes its ``w`` with the others as they are, clipped to its box. Dense ``S``
(n, n), C-contiguous float64.
"""

from __future__ import annotations

from numba import njit
import numpy as np


@njit(cache=True)
def pgs_sweeps(S: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray, f: np.ndarray,
               tolerance: float, max_sweeps: int) -> int:
    """
    Run PGS sweeps on ``f`` in place until one moves no force by more than ``tolerance``.

    Returns the sweeps taken (``max_sweeps + 1`` when the cap stopped them).
    """
    n = q.shape[0]
    for sweep in range(1, max_sweeps + 1):
        largest = 0.0
        for i in range(n):
            w = q[i]
            for j in range(n):
                w += S[i, j] * f[j]
            value = f[i] - w / S[i, i]
            if value < lo[i]:
                value = lo[i]
            elif value > hi[i]:
                value = hi[i]
            change = abs(value - f[i])
            if change > largest:
                largest = change
            f[i] = value
        if largest <= tolerance:
            return sweep
    return max_sweeps + 1
