"""
The box-constrained LCP solvers against an exhaustive reference and against each other.

The reference enumerates every assignment of rows to their lower bound, free, or
upper bound (3^n of them), solves the free rows' equations for each, and keeps those
meeting every condition: for ``S`` symmetric positive definite exactly one does
(the convex programme's unique minimizer), which the test checks too.
"""

import itertools

import numpy as np
import pytest
from rigid_body_sim.core.complementarity import (AT_LOWER, AT_UPPER, check_problem, DIRECT_LIMIT,
                                                 FREE, lemke, residual, solve, solve_direct,
                                                 solve_pgs)

EPS = np.finfo(float).eps


def spd(rng, n, condition=100.0):
    """Return a random symmetric positive definite matrix of the given condition number."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    eig = np.geomspace(1.0, condition, n)
    S = (Q * eig) @ Q.T
    return 0.5 * (S + S.T)


def problem(rng, n, condition=100.0):
    """Return a random BLCP: bounds of every kind (one-sided, two-sided, infinite, fixed)."""
    S = spd(rng, n, condition)
    q = rng.standard_normal(n) * 3.0
    kind = rng.integers(0, 4, n)
    width = rng.uniform(0.1, 2.0, n)
    lo = np.select([kind == 0, kind == 1, kind == 2], [0.0 * width, -width, -np.inf], -np.inf)
    hi = np.select([kind == 0, kind == 1, kind == 2], [np.inf + 0 * width, width, 0.0 * width],
                   np.inf)
    return S, q, lo, hi


def enumerate_solutions(S, q, lo, hi, slack):
    """Every assignment meeting the conditions (to ``slack``): their forces."""
    n = len(q)
    found = []
    for states in itertools.product((AT_LOWER, FREE, AT_UPPER), repeat=n):
        states = np.array(states)
        if np.any((states == AT_LOWER) & ~np.isfinite(lo)) or \
                np.any((states == AT_UPPER) & ~np.isfinite(hi)):
            continue
        f = np.where(states == AT_LOWER, lo, np.where(states == AT_UPPER, hi, 0.0))
        free = states == FREE
        if free.any():
            f[free] = np.linalg.solve(S[np.ix_(free, free)],
                                      -(q[free] + S[np.ix_(free, ~free)] @ f[~free]))
        w = S @ f + q
        ok = np.all(f >= lo - slack) and np.all(f <= hi + slack)
        ok &= np.all(w[states == AT_LOWER] >= -slack) and np.all(w[states == AT_UPPER] <= slack)
        if ok:
            found.append(f)
    return found


@pytest.mark.parametrize('seed', range(40))
def test_the_direct_method_finds_the_one_solution_the_enumeration_finds(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 7))
    S, q, lo, hi = problem(rng, n)
    # bound: the free rows' solve is backward stable: errors of cond(S) eps |f| (cond
    # 100), far inside 1e-9 for forces of order 10.
    slack = 1e-9
    found = enumerate_solutions(S, q, lo, hi, slack)
    # (Assignments differing only by a row exactly at a bound with w = 0 give one f.)
    assert found and all(np.allclose(f, found[0], atol=slack, rtol=0) for f in found)
    start = rng.standard_normal(n) * 5.0            # any warm start, even outside the box
    sol = solve_direct(S, q, lo, hi, start)
    assert sol.converged and sol.method == 'direct'
    assert np.max(np.abs(sol.f - found[0])) <= slack
    # The residual is rounding: cond(S) (100) times 64 ulps of the forces, with room.
    assert sol.residual <= 1e-11 * max(1.0, float(np.max(np.abs(sol.f))))
    assert np.all(sol.f >= lo) and np.all(sol.f <= hi)


def test_unbounded_rows_are_the_equations_and_fixed_rows_stay_put():
    rng = np.random.default_rng(3)
    S = spd(rng, 5)
    q = rng.standard_normal(5)
    inf = np.full(5, np.inf)
    sol = solve_direct(S, q, -inf, inf)
    assert np.allclose(S @ sol.f + q, 0.0, atol=1e-13) and list(sol.state) == [FREE] * 5
    fixed = np.array([0.3, -0.2, 0.0, 1.0, 2.0])
    sol = solve_direct(S, q, fixed, fixed)
    assert np.array_equal(sol.f, fixed) and sol.residual == 0.0


def test_a_single_bound_pushes_or_lets_go():
    # One joint on its lower bound: S = 1/I. Pushed into it (q < 0: it would
    # accelerate into the bound) the force is -q/S; pulled away (q > 0), zero.
    S = np.array([[0.5]])
    push = solve_direct(S, np.array([-2.0]), np.array([0.0]), np.array([np.inf]))
    assert push.f[0] == pytest.approx(4.0, rel=1e-15) and push.state[0] == FREE
    pull = solve_direct(S, np.array([2.0]), np.array([0.0]), np.array([np.inf]))
    assert pull.f[0] == 0.0 and pull.w[0] == 2.0 and pull.state[0] == AT_LOWER


def test_friction_at_its_bound_lets_the_joint_slide_against_it():
    # A sticking joint needing 3 N m held by friction F = 1: the force saturates at
    # -1 and the joint accelerates (w = S (f - f*) < 0... sign: f = lo => w >= 0).
    S = np.array([[2.0]])
    q = -S @ np.array([-3.0])                      # f* = -3: the force holding it
    sol = solve_direct(S, q, np.array([-1.0]), np.array([1.0]))
    assert sol.f[0] == -1.0 and sol.state[0] == AT_LOWER
    assert sol.w[0] == pytest.approx(4.0, rel=1e-15)   # S (f - f*) = 2 (−1 + 3)


@pytest.mark.parametrize('seed', range(10))
def test_pgs_converges_to_the_direct_solution_within_its_tolerance(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(5, 40))
    # Diagonally dominant-ish (contact-like, condition 10): PGS's linear rate is fast.
    S, q, lo, hi = problem(rng, n, condition=10.0)
    exact = solve_direct(S, q, lo, hi)
    rough = solve_pgs(S, q, lo, hi, tolerance=1e-10, max_sweeps=20000)
    assert rough.converged and rough.residual <= 1e-10
    # The error bound of a strongly monotone variational inequality: with z = D^½ f
    # (D = diag S) the problem's operator has moduli μ, L (the extreme eigenvalues of
    # D^-½ S D^-½) and its natural residual is D^½ r, so ‖D^½ (f − f*)‖₂ ≤ (1 + L)/μ
    # ‖D^½ r‖₂; in the max norm that is at most √(d_max/d_min) (1 + L)/μ √n ‖r‖∞.
    d = np.diag(S)
    eig = np.linalg.eigvalsh(S / np.sqrt(np.outer(d, d)))
    bound = np.sqrt(d.max() / d.min()) * (1.0 + eig[-1]) / eig[0] * np.sqrt(n) * rough.residual
    assert np.max(np.abs(rough.f - exact.f)) <= bound + 1e-12


def test_pgs_warm_started_at_the_solution_takes_one_sweep():
    rng = np.random.default_rng(5)
    S, q, lo, hi = problem(rng, 30, condition=10.0)
    exact = solve_direct(S, q, lo, hi)
    warm = solve_pgs(S, q, lo, hi, start=exact.f, tolerance=1e-10)
    assert warm.converged and warm.iterations == 1


def test_pgs_says_when_it_stops_short():
    rng = np.random.default_rng(6)
    S, q, lo, hi = problem(rng, 30, condition=1e4)
    short = solve_pgs(S, q, lo, hi, tolerance=1e-14, max_sweeps=3)
    assert not short.converged and short.iterations == 3 and short.residual > 1e-14


def test_large_problems_are_polished_to_the_direct_solution():
    rng = np.random.default_rng(8)
    n = DIRECT_LIMIT * 3
    S, q, lo, hi = problem(rng, n, condition=50.0)
    sol = solve(S, q, lo, hi)
    assert sol.method == 'pgs+direct' and sol.converged
    exact = solve_direct(S, q, lo, hi)
    # Both exact to rounding: cond 50 times 64 ulps of forces of order 10, with room.
    assert np.max(np.abs(sol.f - exact.f)) <= 1e-10
    assert sol.residual <= 1e-11 * max(1.0, float(np.max(np.abs(sol.f))))


@pytest.mark.parametrize('field, args, message', [
    ('S', (np.ones((2, 3)), np.zeros(2), np.zeros(2), np.ones(2)), 'shape'),
    ('S', (np.array([[1.0, 2.0], [0.0, 1.0]]), np.zeros(2), np.zeros(2), np.ones(2)),
     'symmetric'),
    ('S', (np.array([[0.0]]), np.zeros(1), np.zeros(1), np.ones(1)), 'diagonal'),
    ('lo', (np.eye(2), np.zeros(2), np.array([1.0, 0.0]), np.array([0.0, 1.0])), 'above'),
    ('q', (np.eye(2), np.array([np.nan, 0.0]), np.zeros(2), np.ones(2)), 'finite'),
])
def test_bad_problems_are_refused_naming_the_field(field, args, message):
    with pytest.raises(ValueError, match=message) as err:
        check_problem(*args)
    assert field in str(err.value)


def test_the_residual_is_zero_only_at_the_solution():
    rng = np.random.default_rng(9)
    S, q, lo, hi = problem(rng, 6)
    sol = solve_direct(S, q, lo, hi)
    assert residual(S, q, sol.f, lo, hi) == sol.residual
    moved = sol.f.copy()
    k = int(np.argmax(sol.state == FREE)) if np.any(sol.state == FREE) else 0
    moved[k] = np.clip(moved[k] + 0.1, lo[k], hi[k]) if moved[k] + 0.1 <= hi[k] \
        else moved[k] - 0.1
    assert residual(S, q, moved, lo, hi) > 1e-3


def test_a_target_past_its_bound_by_less_than_an_ulp_still_blocks():
    # A warm start at f = (1, 0) whose free solve gives f0 = −1e-17: the ratio of the
    # move to the bound rounds to 1. The blocking row must still be the one that joins
    # its bound (a search that took only ratios below 1 took none and wrote the last
    # row's infinite bound: f = (0, inf), NaN residual; found in review).
    sol = solve_direct(np.eye(2), np.array([1e-17, 1.0]), np.zeros(2), np.full(2, np.inf),
                       start=np.array([1.0, 0.0]))
    assert sol.converged and np.array_equal(sol.f, [0.0, 0.0])
    assert list(sol.state) == [AT_LOWER, AT_LOWER] and sol.residual == 0.0


def _lcp_residual(M, q, z):
    """Return max |min(z, M z + q)|: zero at a solution of the LCP."""
    return float(np.max(np.abs(np.minimum(z, M @ z + q)), initial=0.0))


@pytest.mark.parametrize('seed', range(3))
def test_lemke_solves_lcps_of_positive_semidefinite_matrices_with_a_solution(seed):
    # Positive definite: always a unique solution. Semidefinite of half rank (redundant
    # rows): q made from a chosen solution z*, w* (complementary), so one exists.
    # Complementarity to rounding of the pivots over O(1) data: 1e-10.
    rng = np.random.default_rng(seed)
    for trial in range(40):
        n = int(rng.integers(1, 16))
        if trial % 2 == 0:
            B = rng.normal(size=(n, n))
            M = B @ B.T + 1e-2 * np.eye(n)
            q = rng.normal(size=n)
        else:
            B = rng.normal(size=(n, max(1, n // 2)))
            M = B @ B.T
            z_star = np.where(rng.random(n) < 0.5, rng.random(n), 0.0)
            w_star = np.where(z_star > 0.0, 0.0, rng.random(n))
            q = w_star - M @ z_star
        z, ok = lemke(M, q)
        assert ok
        assert np.all(z >= 0.0)
        assert _lcp_residual(M, q, z) <= 1e-10, (trial, n)


def test_lemke_ends_on_a_ray_when_the_lcp_has_no_solution():
    # w = 0 z − 1 < 0 for every z: no solution; and a semidefinite M with q outside its
    # feasible cone (M = [[1, −1], [−1, 1]], q = (−1, −1): w₁ + w₂ = −2 always).
    for M, q in ((np.zeros((1, 1)), np.array([-1.0])),
                 (np.array([[1.0, -1.0], [-1.0, 1.0]]), np.array([-1.0, -1.0]))):
        z, ok = lemke(M, q)
        assert not ok
    # q ≥ 0: z = 0 at once.
    z, ok = lemke(np.eye(3), np.ones(3))
    assert ok and np.all(z == 0.0)
