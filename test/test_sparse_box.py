"""
The box QP of a block-sparse operator by MPRGP (:mod:`.kernels.sparse_box`).

References: the dense active-set solve of the same problem (:func:`.contact_step.solve_box`,
exact to rounding: ``S`` definite, the solution unique) and the error bound of a strongly
monotone affine problem: ``‖f − f*‖ ≤ (1 + λ_max) / λ_min ‖f − P(f − (S f + q))‖``
(Facchinei and Pang, *Finite-Dimensional Variational Inequalities*, 2003, Prop. 6.3.1;
``λ`` of ``S``, ``P`` the projection on the boxes). The operators are those of random
contacts (a sphere's rows, the Delassus operator by its blocks) with more rows than the
bodies have freedoms: ``A`` singular, ``S = A + ρ I`` conditioned by ``ρ`` alone.
"""

import numpy as np
import pytest

from rigid_body_sim.core.kernels.contact_step import delassus, solve_box
from rigid_body_sim.core.kernels.sparse_box import block_product, mprgp


def _contacts(rng, nb, nc, r=0.05):
    """Return ``(D, A)``: ``nc`` contacts of ``nb`` spheres by blocks, and dense."""
    ba = rng.integers(0, nb, nc)
    bb = rng.integers(0, nb + 1, nc)   # (nb: the world)
    bb[bb == ba] = nb
    Ga, Gb = np.zeros((3 * nc, 6)), np.zeros((3 * nc, 6))
    G = np.zeros((3 * nc, 6 * nb))
    for k in range(nc):
        n = rng.standard_normal(3)
        n /= np.linalg.norm(n)
        t1 = np.cross(n, (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 1.0, 0.0))
        t1 /= np.linalg.norm(t1)
        F = np.stack([n, t1, np.cross(n, t1)])
        Ga[3 * k:3 * k + 3] = np.hstack([F, np.cross(-r * n, F)])
        Gb[3 * k:3 * k + 3] = -np.hstack([F, np.cross(r * n, F)])
        G[3 * k:3 * k + 3, 6 * ba[k]:6 * ba[k] + 6] = Ga[3 * k:3 * k + 3]
        if bb[k] < nb:
            G[3 * k:3 * k + 3, 6 * bb[k]:6 * bb[k] + 6] = Gb[3 * k:3 * k + 3]
    minv = np.tile(np.array([1.0] * 3 + [1.0 / (0.4 * r * r)] * 3), (nb, 1))
    return delassus(Ga, Gb, ba, bb, minv), (G * minv.ravel()) @ G.T


def _boxes(rng, c, mu=0.5):
    """Return ``(lo, hi)``: normal rows ``[0, ∞)``, friction rows ``±μ p̂`` (some points)."""
    pn = rng.random(c) * (rng.random(c) < 0.8)   # (a fifth unloaded: point boxes [0, 0])
    lo, hi = np.zeros(3 * c), np.full(3 * c, np.inf)
    for j in (1, 2):
        lo[j::3], hi[j::3] = -mu * pn, mu * pn
    return lo, hi


@pytest.mark.parametrize('seed, rho_rel', [(0, 1e-4), (1, 1e-4), (2, 1e-3), (3, 1e-2)])
def test_mprgp_solves_the_box_qp_of_a_redundant_contact_operator(seed, rho_rel):
    rng = np.random.default_rng(seed)
    nb, nc = 60, 150   # (450 rows on 360 freedoms)
    D, A = _contacts(rng, nb, nc)
    n = 3 * nc
    rho = rho_rel * float(np.max(np.diag(A)))
    S = A + rho * np.eye(n)
    lo, hi = _boxes(rng, nc)
    q = 0.01 * rng.standard_normal(n)
    q[0::3] -= 0.01   # (most normal rows approaching)
    # The product with the blocks: each row the dense one's terms in another order, within
    # n eps of the sum of their magnitudes (twice: both sums round).
    x = rng.standard_normal(n)
    out = np.empty(n)
    block_product(*D, rho, x, out)
    eps = np.finfo(float).eps
    assert np.all(np.abs(out - S @ x) <= 2 * n * eps * (np.abs(S) @ np.abs(x)))
    tol = 1e-10   # m/s, of w = S f + q up to ~0.03 m/s
    f, converged, iterations, reached = mprgp(*D, rho, q, lo, hi, np.zeros(n), tol, 20000)
    assert converged and reached <= tol and 0 < iterations < 20000
    assert np.all(f >= lo) and np.all(f <= hi)
    # Its own measure, recomputed: the projected gradient of w.
    w = S @ f + q
    gp = np.where(f <= lo, np.minimum(w, 0.0), np.where(f >= hi, np.maximum(w, 0.0), w))
    gp[lo == hi] = 0.0
    assert np.max(np.abs(gp)) <= tol + 2 * n * eps * float(np.max(np.abs(S) @ np.abs(f)
                                                                  + np.abs(q)))
    # Against the exact active-set solve, within the error bound of its natural residual.
    L, order, first = np.empty((n, n)), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    f_ref, ok, _ = solve_box(S, q, lo, hi, np.zeros(n), L, order, first,
                             np.zeros(3, dtype=np.int64))
    assert ok
    lam = np.linalg.eigvalsh(S)
    assert lam[0] < 10 * rho   # (A singular: S conditioned by ρ alone)
    natural = f - np.clip(f - w, lo, hi)
    bound = (1 + lam[-1]) / lam[0] * np.linalg.norm(natural)
    # (and the reference's own rounding: condition number times n eps of its largest)
    exact = lam[-1] / lam[0] * n * eps * np.max(np.abs(f_ref))
    assert np.linalg.norm(f - f_ref) <= bound + exact


def test_mprgp_keeps_point_boxes_and_starts_where_it_is_told():
    # Rows whose box is a point stay there; a start at the solution takes no step and
    # returns it.
    rng = np.random.default_rng(9)
    D, A = _contacts(rng, 20, 40)
    n = 120
    rho = 1e-4 * float(np.max(np.diag(A)))
    lo, hi = _boxes(rng, 40)
    q = 0.01 * rng.standard_normal(n)
    f, converged, _, _ = mprgp(*D, rho, q, lo, hi, np.zeros(n), 1e-12, 20000)
    assert converged
    point = lo == hi
    assert point.any() and np.all(f[point] == lo[point])
    # (f / s rounds each row by an ulp, which moves w by ~1e-15: within a tolerance ten
    # times the first's it takes no step)
    again, converged2, iterations, _ = mprgp(*D, rho, q, lo, hi, f, 1e-11, 20000)
    assert converged2 and iterations == 0
    # (f / s · s: within an ulp of each row)
    np.testing.assert_allclose(again, f, rtol=2 * np.finfo(float).eps, atol=0)
