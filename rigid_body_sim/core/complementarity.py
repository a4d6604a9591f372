"""
Box-constrained linear complementarity problems: the inequality rows' forces.

Rows with bounds on their forces (a joint limit pushes only, ``s f ≥ 0``; a sticking
joint's friction ``|f| ≤ F``; an effort-limited drive ``|f| ≤ E``) are coupled
through the mechanism: a force on one row accelerates the others. With the equality
rows eliminated, the rows' accelerations (each relative to what its row, held, would
impose) are affine in their forces,

    w = S f + q,

``S`` the rows' Schur complement in the mechanism's constraint matrix (the rows'
Delassus operator with every equality row held: symmetric, positive definite when
the rows are independent) and ``q = −S f*`` for ``f*`` the forces with every row
held. The forces sought solve the box-constrained linear complementarity problem
(BLCP): ``lo ≤ f ≤ hi`` and, per row,

    f_i = lo_i ⇒ w_i ≥ 0,   f_i = hi_i ⇒ w_i ≤ 0,   lo_i < f_i < hi_i ⇒ w_i = 0

(a bound that pushes nothing lets its joint accelerate away from it; friction at
``+F`` lets the joint slide towards ``−``; a row inside its bounds holds). For ``S``
symmetric positive definite these are the optimality conditions of the strictly
convex quadratic programme ``min ½ fᵀSf + qᵀf`` on the box, whose solution is unique
(Cottle, Pang & Stone, *The Linear Complementarity Problem*, 1992, §3.1): each
method below finds that one solution, and :func:`residual` measures how well.

- :func:`solve_direct`: a primal active-set method (each iteration solves the free
  rows' equations exactly, the steps keep ``f`` in the box, and a row leaves its
  bound when its ``w`` has the wrong sign). Finite, exact to rounding: for small
  sets (the rows of a robot's joints), warm-started from the rows' present states.
- :func:`solve_pgs`: projected Gauss–Seidel (each row's force in turn set to the
  value that zeroes its ``w``, clipped to its box): coordinate descent on the same
  convex programme, linearly convergent for ``S`` positive definite; each sweep
  costs ``O(n²)`` dense. It stops when a sweep moves no force by more than a
  tolerance (force units) or at its iteration cap; converged means the first and
  the natural-map residual (:func:`residual`) within the tolerance too.
- :func:`solve`: the direct method from a warm start (the last solution, the rows'
  present forces: one iteration when the active set did not change); started cold,
  the direct method up to :data:`DIRECT_LIMIT` rows and beyond it PGS, which finds
  the active set approximately, then the direct method from PGS's forces, which
  finishes exactly (PGS alone would leave its tolerance's error in the forces).
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np

from .kernels.complementarity import pgs_sweeps

#: Rows up to which :func:`solve` uses the direct method alone.
DIRECT_LIMIT = 32
#: ``w``'s sign is trusted beyond this many ulps of its terms' magnitude.
ROUNDING_ULPS = 64.0
EPS = float(np.finfo(float).eps)
#: Per row: at its lower bound, free, at its upper bound.
AT_LOWER, FREE, AT_UPPER = -1, 0, 1


class BoxLCPSolution(NamedTuple):
    """The forces of a BLCP and how they were found."""

    f: np.ndarray            #: (n,) the rows' forces
    w: np.ndarray            #: (n,) their accelerations ``S f + q``
    state: np.ndarray        #: (n,) int: AT_LOWER, FREE or AT_UPPER per row
    residual: float          #: :func:`residual` at ``f`` (force units)
    iterations: int          #: the direct method's iterations, or PGS sweeps plus those
    converged: bool          #: False: stopped at the iteration cap (``f`` is the last)
    method: str              #: 'direct', 'pgs' or 'pgs+direct'


def check_problem(S: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> int:
    """
    Check a BLCP's data; return its size.

    Raises ValueError naming the field: ``S`` not square, not symmetric or with a
    non-positive diagonal, sizes that disagree, a NaN anywhere, ``lo > hi``.
    """
    S, q, lo, hi = (np.asarray(a, dtype=float) for a in (S, q, lo, hi))
    n = len(q)
    if S.shape != (n, n):
        raise ValueError(f'S: shape {S.shape}, expected ({n}, {n}) for {n} rows')
    if lo.shape != (n,) or hi.shape != (n,):
        raise ValueError(f'lo, hi: shapes {lo.shape}, {hi.shape}, expected ({n},)')
    if not (np.all(np.isfinite(S)) and np.all(np.isfinite(q))):
        raise ValueError('S, q: must be finite')
    if np.any(np.isnan(lo)) or np.any(np.isnan(hi)):
        raise ValueError('lo, hi: NaN bound')
    if np.any(lo > hi):
        i = int(np.flatnonzero(lo > hi)[0])
        raise ValueError(f'lo, hi: row {i} has lo {lo[i]} above hi {hi[i]}')
    if n and not np.all(np.diag(S) > 0.0):
        raise ValueError('S: diagonal must be positive (a row no force moves)')
    if n and not np.allclose(S, S.T, rtol=1e-9, atol=1e-12 * float(np.max(np.abs(S)))):
        raise ValueError('S: must be symmetric')
    return n


def residual(S: np.ndarray, q: np.ndarray, f: np.ndarray, lo: np.ndarray,
             hi: np.ndarray) -> float:
    """
    Return the natural-map residual ``max_i |f_i − clip(f_i − w_i / S_ii, lo_i, hi_i)|``.

    Zero exactly at the solution; in force units (each row's ``w`` over its own
    diagonal): how far a row's force is from what its own condition asks, with
    the others held. Infeasible forces (outside the box) count their distance too.
    """
    if not len(q):
        return 0.0
    w = S @ f + q
    d = np.diag(S)
    return float(np.max(np.abs(f - np.clip(f - w / d, lo, hi))))


def _rounding(S: np.ndarray, q: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Per row, the rounding ``w = S f + q`` may carry: ULPS times its terms' magnitude."""
    return ROUNDING_ULPS * EPS * (np.abs(S) @ np.abs(f) + np.abs(q))


def solve_direct(S: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 start: Optional[np.ndarray] = None,
                 max_iterations: Optional[int] = None) -> BoxLCPSolution:
    """
    Solve the BLCP by a primal active-set method, from ``start`` (clipped to the box).

    Each iteration solves the free rows' ``w_F = 0`` with the bound rows fixed; if
    the solution leaves the box, ``f`` moves towards it up to the first bound met,
    which that row joins; else ``f`` is that solution, and the bound row whose
    ``w`` has the wrong sign by the most (beyond its rounding) is freed. It ends
    when none has: every condition holds to rounding. The objective falls at
    every move of positive length, so no set recurs but through zero-length
    steps at degenerate ties (Nocedal & Wright, *Numerical Optimization*, 2006,
    §16.5); the cap (default ``10 (n + 1)``, far above what the rows of a
    mechanism take) guards those and is reported (``converged`` False).
    """
    S, q = np.asarray(S, dtype=float), np.asarray(q, dtype=float)
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    n = len(q)
    f = np.zeros(n) if start is None else np.array(start, dtype=float)
    f = np.clip(np.where(np.isfinite(f), f, 0.0), lo, hi)
    state = np.where(f <= lo, AT_LOWER, np.where(f >= hi, AT_UPPER, FREE))
    cap = 10 * (n + 1) if max_iterations is None else max_iterations
    for it in range(1, cap + 1):
        free = state == FREE
        fixed = ~free
        target = f.copy()
        if free.any():
            rhs = -(q[free] + S[np.ix_(free, fixed)] @ f[fixed])
            target[free] = np.linalg.solve(S[np.ix_(free, free)], rhs)
        step = target - f
        below, above = free & (target < lo), free & (target > hi)
        if below.any() or above.any():
            # Move towards the target up to the first bound met; that row joins it.
            # (The smallest ratio over the blocking rows, whatever its rounding: a
            # target past its bound by less than an ulp of the distance gives 1.)
            ratios = np.full(n, np.inf)
            ratios[below] = (lo[below] - f[below]) / step[below]
            ratios[above] = (hi[above] - f[above]) / step[above]
            hit = int(np.argmin(ratios))
            side = AT_LOWER if below[hit] else AT_UPPER
            alpha = min(max(float(ratios[hit]), 0.0), 1.0)
            f[free] += alpha * step[free]
            f[hit] = lo[hit] if side == AT_LOWER else hi[hit]
            state[hit] = side
            f = np.clip(f, lo, hi)
            continue
        f = target
        w = S @ f + q
        wrong = np.where(state == AT_LOWER, -w, np.where(state == AT_UPPER, w, -np.inf))
        wrong = wrong - _rounding(S, q, f)
        k = int(np.argmax(wrong)) if n else 0
        if not n or wrong[k] <= 0.0:
            return BoxLCPSolution(f, w, state, residual(S, q, f, lo, hi), it, True,
                                  'direct')
        state[k] = FREE
    w = S @ f + q
    return BoxLCPSolution(f, w, state, residual(S, q, f, lo, hi), cap, False, 'direct')


def solve_pgs(S: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray,
              start: Optional[np.ndarray] = None, tolerance: float = 1e-9,
              max_sweeps: int = 1000) -> BoxLCPSolution:
    """
    Solve the BLCP by projected Gauss–Seidel from ``start`` (clipped to the box).

    Stops when a sweep changes no force by more than ``tolerance`` (force units), or
    after ``max_sweeps``; ``converged`` says whether it stopped on the first and the
    natural-map residual is within ``tolerance`` too (else the forces are the last
    sweep's, never passed off as solved). Linear convergence, at a rate set by
    ``S``'s conditioning.
    """
    S, q = np.ascontiguousarray(S, dtype=float), np.ascontiguousarray(q, dtype=float)
    lo, hi = np.ascontiguousarray(lo, dtype=float), np.ascontiguousarray(hi, dtype=float)
    n = len(q)
    f = np.zeros(n) if start is None else np.array(start, dtype=float)
    f = np.ascontiguousarray(np.clip(np.where(np.isfinite(f), f, 0.0), lo, hi))
    sweeps = pgs_sweeps(S, q, lo, hi, f, tolerance, max_sweeps) if n else 0
    res = residual(S, q, f, lo, hi)
    converged = sweeps <= max_sweeps and res <= tolerance
    w = S @ f + q
    state = np.where(f <= lo, AT_LOWER, np.where(f >= hi, AT_UPPER, FREE))
    return BoxLCPSolution(f, w, state, res, min(sweeps, max_sweeps), converged, 'pgs')


def solve(S: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray,
          start: Optional[np.ndarray] = None, tolerance: float = 1e-9) -> BoxLCPSolution:
    """
    Solve the BLCP: the direct method, after PGS when large and started cold.

    ``start``: a warm start (the last solution, the rows' present forces): the
    direct method from it, whose first iteration keeps its active set (one
    iteration when the set is unchanged). Without one, up to :data:`DIRECT_LIMIT`
    rows the direct method from zero; beyond, PGS to ``tolerance`` finds the active
    set and the direct method from its forces finishes it to rounding (counting
    both). ``bench/complementarity.py`` measures these choices against the others.
    """
    check_problem(S, q, lo, hi)
    if start is not None or len(q) <= DIRECT_LIMIT:
        return solve_direct(S, q, lo, hi, start)
    rough = solve_pgs(S, q, lo, hi, None, tolerance)
    exact = solve_direct(S, q, lo, hi, rough.f)
    return exact._replace(iterations=rough.iterations + exact.iterations,
                          method='pgs+direct')


def lemke(M: np.ndarray, q: np.ndarray, max_pivots: Optional[int] = None) -> tuple:
    """
    Solve the LCP ``w = M z + q ≥ 0, z ≥ 0, zᵀw = 0`` by Lemke's complementary pivoting.

    Returns ``(z, ok)``. The covering vector is all ones; ties in the ratio test are
    broken lexicographically (by the rows of the basis' inverse over the pivot
    column), so degenerate problems (redundant contacts) do not cycle. Lemke's method
    ends at a solution for the copositive-plus matrices of frictional contact in the
    pyramid form (Stewart & Trinkle, Int. J. Numer. Methods Eng. 39, 1996), or on a
    secondary ray (``ok`` False) when it finds none; the cap (default ``50 n``) guards
    rounding. The pivots' rounding is then taken out: the basic ``z`` solve their rows'
    ``w = 0`` again in one least-squares solve, kept if no worse.
    """
    M, q = np.asarray(M, dtype=float), np.asarray(q, dtype=float)
    n = len(q)
    if n == 0 or np.all(q >= 0.0):
        return np.zeros(n), True
    # Tableau [I | −M | −e | q] over the variables w (0..n−1), z (n..2n−1), z0 (2n).
    T = np.hstack([np.eye(n), -M, -np.ones((n, 1)), q[:, None]])
    basis = np.arange(n)
    tol = 1e-12 * max(1.0, float(np.max(np.abs(M), initial=0.0)))
    entering = 2 * n
    row = int(np.argmin(q))
    cap = 50 * n if max_pivots is None else max_pivots
    for _ in range(cap):
        _pivot(T, row, entering)
        leaving = basis[row]
        basis[row] = entering
        if leaving == 2 * n:   # z0 left: a complementary solution
            break
        entering = leaving + n if leaving < n else leaving - n
        col = T[:, entering]
        rows = np.flatnonzero(col > tol)
        if not len(rows):
            return np.zeros(n), False   # a secondary ray
        ratios = np.maximum(T[rows, -1], 0.0) / col[rows]   # (a rounding-negative b: 0)
        best = rows[ratios <= ratios.min() + tol * max(1.0, abs(ratios.min()))]
        # Lexicographic tie-break on the basis' inverse (the w columns), row over pivot.
        for j in range(n):
            if len(best) == 1:
                break
            key = T[best, j] / col[best]
            best = best[key <= key.min() + tol]
        row = int(best[0])
    else:
        return np.zeros(n), False
    z = np.zeros(2 * n + 1)
    z[basis] = T[:, -1]
    z = np.maximum(z[n:2 * n], 0.0)
    support = np.sort(basis[(basis >= n) & (basis < 2 * n)] - n)
    if len(support):
        again = np.zeros(n)
        again[support] = np.linalg.lstsq(M[np.ix_(support, support)], -q[support],
                                         rcond=None)[0]
        again = np.maximum(again, 0.0)
        if _lcp_error(M, q, again) <= _lcp_error(M, q, z):
            z = again
    return z, True


def _lcp_error(M: np.ndarray, q: np.ndarray, z: np.ndarray) -> float:
    """Return the natural-map residual ``max |min(z, M z + q)|`` of an LCP."""
    return float(np.max(np.abs(np.minimum(z, M @ z + q)), initial=0.0))


def _pivot(T: np.ndarray, row: int, col: int) -> None:
    """Gauss–Jordan pivot of the tableau ``T`` on ``(row, col)``, in place."""
    T[row] /= T[row, col]
    others = np.arange(T.shape[0]) != row
    T[others] -= np.outer(T[others, col], T[row])
