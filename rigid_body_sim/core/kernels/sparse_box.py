"""
The box QP of a block-sparse operator by MPRGP: the inner solve for islands too large to factor.

``min ½ fᵀ S f + qᵀ f`` over ``lo ≤ f ≤ hi`` with ``S = A + ρ I``, ``A`` given by its 3 × 3
blocks (:func:`.contact_step.delassus`'s ``(ptr, col, blk)``) and ``ρ > 0``: the problem the
contact rows' proximal fixed point solves at each iteration (:func:`.contact_step.solve_island`,
there by an active-set method on a dense Cholesky factor). A pile of a thousand spheres is one
island of some 7,500 rows: its dense matrix alone is 450 MB and each factor seconds, where its
operator has some 200,000 non-zeros. This solves by products with the blocks alone.

The method is Dostál's modified proportioning with reduced gradient projections (MPRGP;
Dostál and Schöberl, *Comput. Optim. Appl.* 30, 2005; Dostál, *Optimal Quadratic Programming
Algorithms*, 2009, ch. 8): conjugate gradients on the rows inside their boxes, steps that
expand the set of rows on a bound by a projected gradient step of fixed length ``ᾱ ≤ 2/‖S‖``,
and proportioning steps that free rows whose bound no longer holds, when their part of the
gradient outweighs the free rows'. For a definite ``S`` it converges R-linearly at a rate
set by ``S``'s condition number alone, independent of which rows end on their bounds. The
rows are first scaled to a unit diagonal (Jacobi), which the contact rows need (their
diagonals span the masses' and the levers' range).

It stops when the projected gradient, in the rows' own units (``w = S f + q``: velocities),
is within ``tol`` in every row, measured on a gradient computed afresh (the iterations update
it by recurrence, which drifts by rounding); what it reached is returned.
"""

from numba import njit
import numpy as np

#: Γ of the proportioning test (the chopped gradient against the reduced free gradient).
PROPORTION = 1.0
#: The gradient is computed afresh every this many iterations (the recurrence drifts).
REFRESH = 50


@njit(cache=True)
def block_product(ptr: np.ndarray, col: np.ndarray, blk: np.ndarray, rho: float,
                  x: np.ndarray, out: np.ndarray) -> None:
    """Set ``out = (A + ρ I) x``, ``A`` by its blocks (each row's sum in column order)."""
    c = ptr.shape[0] - 1
    for k in range(c):
        for a in range(3):
            acc = 0.0
            for e in range(ptr[k], ptr[k + 1]):
                m = col[e]
                for b in range(3):
                    acc += blk[e, a, b] * x[3 * m + b]
            out[3 * k + a] = acc + rho * x[3 * k + a]


@njit(cache=True)
def _scaled_product(ptr: np.ndarray, col: np.ndarray, blk: np.ndarray, rho: float,
                    s: np.ndarray, y: np.ndarray, tmp: np.ndarray, out: np.ndarray) -> None:
    """Set ``out = D S D y`` with ``D = diag(s)`` (``tmp`` a work array)."""
    for i in range(y.shape[0]):
        tmp[i] = s[i] * y[i]
    block_product(ptr, col, blk, rho, tmp, out)
    for i in range(y.shape[0]):
        out[i] *= s[i]


@njit(cache=True)
def _gradient(ptr: np.ndarray, col: np.ndarray, blk: np.ndarray, rho: float, s: np.ndarray,
              y: np.ndarray, qs: np.ndarray, tmp: np.ndarray, g: np.ndarray) -> None:
    """Set ``g`` the scaled gradient ``D S D y + D q`` afresh (``qs = D q``)."""
    _scaled_product(ptr, col, blk, rho, s, y, tmp, g)
    for i in range(y.shape[0]):
        g[i] += qs[i]


@njit(cache=True)
def _split(y: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray, alpha: float,
           phi: np.ndarray) -> tuple:
    """
    Set ``phi`` the free gradient ``φ``; return ``(β·β, φ̃·φ)``.

    ``β`` the chopped gradient (of the rows on a bound that it would move into their box),
    ``φ̃`` the reduced free gradient (``φ`` cut where a step ``alpha`` along it would leave
    the box).
    """
    bb, pr = 0.0, 0.0
    for i in range(y.shape[0]):
        gi = g[i]
        if y[i] <= lo[i] and y[i] >= hi[i]:   # (a point box: no freedom)
            phi[i] = 0.0
        elif y[i] <= lo[i]:
            phi[i] = 0.0
            if gi < 0.0:
                bb += gi * gi
        elif y[i] >= hi[i]:
            phi[i] = 0.0
            if gi > 0.0:
                bb += gi * gi
        else:
            phi[i] = gi
            if gi > 0.0:
                pr += min((y[i] - lo[i]) / alpha, gi) * gi
            else:
                pr += max((y[i] - hi[i]) / alpha, gi) * gi
    return bb, pr


@njit(cache=True)
def _projected(y: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               s: np.ndarray) -> float:
    """Return ``max |g^P| / s``: the projected gradient in the rows' own units."""
    worst = 0.0
    for i in range(y.shape[0]):
        gi = g[i]
        if y[i] <= lo[i] and y[i] >= hi[i]:
            v = 0.0
        elif y[i] <= lo[i]:
            v = min(gi, 0.0)
        elif y[i] >= hi[i]:
            v = max(gi, 0.0)
        else:
            v = gi
        worst = max(worst, abs(v) / s[i])
    return worst


@njit(cache=True)
def mprgp(ptr: np.ndarray, col: np.ndarray, blk: np.ndarray, rho: float, q: np.ndarray,
          lo: np.ndarray, hi: np.ndarray, start: np.ndarray, tol: float,
          cap: int) -> tuple:
    """
    Return ``(f, converged, iterations, reached)``: the box QP of ``S = A + ρ I``.

    ``A`` by its blocks (``ptr``, ``col``, ``blk``; symmetric, semi-definite: ``S`` is then
    definite), ``q``, ``lo ≤ hi`` (either may be infinite; ``lo = hi``: held there),
    ``start`` the warm start (projected into the boxes). ``converged``: every row's
    projected gradient ``w = S f + q`` within ``tol`` (on its box's bound ``w`` may point
    out of it, else it is zero), by a gradient computed afresh; ``reached`` that measure;
    ``iterations`` the steps taken (each one product with the blocks, an expansion two),
    at most ``cap``.
    """
    n = q.shape[0]
    # Jacobi scaling: y = f / s with s = diag(S)^(-1/2); the scaled S has a unit diagonal.
    s = np.empty(n)
    c = ptr.shape[0] - 1
    for k in range(c):
        for e in range(ptr[k], ptr[k + 1]):
            if col[e] == k:
                for a in range(3):
                    s[3 * k + a] = blk[e, a, a]
    for i in range(n):
        s[i] = 1.0 / np.sqrt(s[i] + rho)
    # ‖D S D‖ ≤ its largest absolute row sum (Gershgorin): ᾱ = 1.9 / that bound.
    norm = 0.0
    for k in range(c):
        for a in range(3):
            row = rho * s[3 * k + a] ** 2
            for e in range(ptr[k], ptr[k + 1]):
                m = col[e]
                for b in range(3):
                    row += abs(blk[e, a, b]) * s[3 * k + a] * s[3 * m + b]
            norm = max(norm, row)
    alpha = 1.9 / norm
    ys, ls, hs, qs = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        ls[i], hs[i], qs[i] = lo[i] / s[i], hi[i] / s[i], q[i] * s[i]
        ys[i] = min(max(start[i] / s[i], ls[i]), hs[i])
    g, p, Ap, phi, tmp = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    _gradient(ptr, col, blk, rho, s, ys, qs, tmp, g)
    _split(ys, g, ls, hs, alpha, phi)
    for i in range(n):
        p[i] = phi[i]
    it, since = 0, 0
    reached = _projected(ys, g, ls, hs, s)
    while reached > tol and it < cap:
        it += 1
        since += 1
        bb, pr = _split(ys, g, ls, hs, alpha, phi)
        if bb <= PROPORTION * PROPORTION * pr:
            # Conjugate gradients on the free rows, as far as the boxes allow.
            _scaled_product(ptr, col, blk, rho, s, p, tmp, Ap)
            pAp, gp = 0.0, 0.0
            for i in range(n):
                pAp += p[i] * Ap[i]
                gp += g[i] * p[i]
            if not pAp > 0.0:   # (no direction left: the free gradient vanished)
                break
            a_cg = gp / pAp
            a_f = np.inf
            for i in range(n):
                if p[i] > 0.0:
                    a_f = min(a_f, (ys[i] - ls[i]) / p[i])
                elif p[i] < 0.0:
                    a_f = min(a_f, (ys[i] - hs[i]) / p[i])
            if a_cg <= a_f:
                for i in range(n):
                    ys[i] -= a_cg * p[i]
                    g[i] -= a_cg * Ap[i]
                _split(ys, g, ls, hs, alpha, phi)
                gamma = 0.0
                for i in range(n):
                    gamma += phi[i] * Ap[i]
                gamma /= pAp
                for i in range(n):
                    p[i] = phi[i] - gamma * p[i]
            else:
                # To the first bound met, then a projected step of length ᾱ (expansion).
                for i in range(n):
                    ys[i] = min(max(ys[i] - a_f * p[i], ls[i]), hs[i])
                    g[i] -= a_f * Ap[i]
                _split(ys, g, ls, hs, alpha, phi)
                for i in range(n):
                    ys[i] = min(max(ys[i] - alpha * phi[i], ls[i]), hs[i])
                _gradient(ptr, col, blk, rho, s, ys, qs, tmp, g)
                since = 0
                _split(ys, g, ls, hs, alpha, phi)
                for i in range(n):
                    p[i] = phi[i]
        else:
            # Proportioning: free the rows whose bound no longer holds (the chopped
            # gradient β), an exact line search along it, projected into the boxes.
            for i in range(n):
                d = 0.0
                if ys[i] <= ls[i] and not ys[i] >= hs[i] and g[i] < 0.0:
                    d = g[i]
                elif ys[i] >= hs[i] and not ys[i] <= ls[i] and g[i] > 0.0:
                    d = g[i]
                tmp[i] = d
            beta = tmp.copy()
            _scaled_product(ptr, col, blk, rho, s, beta, tmp, Ap)
            dAd, gd = 0.0, 0.0
            for i in range(n):
                dAd += beta[i] * Ap[i]
                gd += g[i] * beta[i]
            a_cg = gd / dAd
            inside = True
            for i in range(n):
                v = ys[i] - a_cg * beta[i]
                if v < ls[i] or v > hs[i]:
                    inside = False
                ys[i] = min(max(v, ls[i]), hs[i])
            if inside:
                for i in range(n):
                    g[i] -= a_cg * Ap[i]
            else:
                _gradient(ptr, col, blk, rho, s, ys, qs, tmp, g)
                since = 0
            _split(ys, g, ls, hs, alpha, phi)
            for i in range(n):
                p[i] = phi[i]
        reached = _projected(ys, g, ls, hs, s)
        if reached <= tol or since >= REFRESH:
            # (measured on a fresh gradient: the recurrence's drift is not convergence;
            # the search direction is kept)
            _gradient(ptr, col, blk, rho, s, ys, qs, tmp, g)
            since = 0
            reached = _projected(ys, g, ls, hs, s)
    f = np.empty(n)
    for i in range(n):   # (a row on its bound is there exactly: s (lo / s) may be an ulp off)
        f[i] = lo[i] if ys[i] <= ls[i] else (hi[i] if ys[i] >= hs[i] else
                                             min(max(s[i] * ys[i], lo[i]), hi[i]))
    return f, reached <= tol, it, reached
