"""Compiled constraint-row kernels against finite differences of Φ along motions."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from rigid_body_sim.core import Constraint, RigidBody
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core.bodies import BodySet
from rigid_body_sim.core.constraints import ConstraintSet
from rigid_body_sim.core.kernels.layout import PAR_E, PAR_E2, PAR_RA, PAR_RB, PAR_S, PAR_SCALAR
from rigid_body_sim.core.kernels.rows import (KIND_ANGLE, KIND_DISTANCE, KIND_DOT, KIND_LINE,
                                              KIND_POINT, pack_rows, rows_geometry, rows_rates)

JOINTS = ('ball', 'hinge', 'slider', 'fixed', 'distance')
N_BODIES = 4
EPS = np.finfo(float).eps


def random_constraint_set(seed):
    """
    Return a ConstraintSet of every joint type on random bodies, its state, a random motion.

    Each type appears twice to the world and twice between two bodies, once with an
    ``anchor_world`` (satisfied when added) and once with body-frame anchors (violated).
    Bodies have random principal axes and centre-of-mass offsets.
    """
    rng = np.random.default_rng(seed)
    bodies = []
    for i in range(N_BODIES):
        axes = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        inertia = axes @ np.diag(1.0 + rng.random(3)) @ axes.T
        bodies.append(RigidBody(f'b{i}', 1.0 + rng.random(), inertia,
                                com_body=0.3 * rng.normal(size=3),
                                position_world=rng.normal(size=3),
                                orientation_xyzw=so3.exp_quat(2.0 * rng.normal(size=3))))
    body_set = BodySet.from_bodies(bodies)
    state = body_set.initial_state(bodies)
    cs = ConstraintSet(body_set)
    k = 0
    for joint in JOINTS:
        for to_world in (True, False):
            for world_anchor in (True, False):
                a, b = rng.choice(N_BODIES, size=2, replace=False)
                kw = {'body_b': None if to_world else f'b{b}'}
                if world_anchor and joint != 'distance':
                    kw['anchor_world'] = rng.normal(size=3)
                else:
                    kw['anchor_a_body'] = 0.5 * rng.normal(size=3)
                    kw['anchor_b_body'] = 0.5 * rng.normal(size=3)
                if joint in ('hinge', 'slider', 'fixed'):
                    kw['axis_world'] = rng.normal(size=3)
                if joint == 'distance' and world_anchor:
                    kw['length'] = 0.7
                cs.add(Constraint(f'c{k}', joint, f'b{a}', **kw), state)
                k += 1
    return cs, state, random_motion(rng)


def random_motion(rng):
    """Return a random configuration and velocity (pos, quat, vel, omega) of the bodies."""
    quat = so3.exp_quat(2.0 * rng.normal(size=(N_BODIES, 3)))
    return (rng.normal(size=(N_BODIES, 3)), quat, rng.normal(size=(N_BODIES, 3)),
            rng.normal(size=(N_BODIES, 3)))


def random_rows(seed, m=40):
    """Return flat rows of every kind with random (not unit) vectors and scalars."""
    rng = np.random.default_rng(seed)
    table = []
    for k in range(m):
        kind = (KIND_POINT, KIND_DOT, KIND_LINE, KIND_DISTANCE, KIND_ANGLE)[k % 5]
        a = int(rng.integers(N_BODIES))
        b = N_BODIES if k % 3 == 0 else int((a + 1 + rng.integers(N_BODIES - 1)) % N_BODIES)
        vec = [rng.normal(size=3) for _ in range(5)]
        table.append((kind, int(rng.integers(3)), a, b, *vec, float(rng.normal())))
    return pack_rows(table)


def row_arrays(cs):
    """Return the flat row arrays of a ConstraintSet."""
    return cs.row_kind, cs.row_comp, cs.row_a, cs.row_b, cs.row_par


def geometry(rows, pos, quat):
    """Return Φ (m,), Ga (m, 6) and Gb (m, 6) from the kernel."""
    m = len(rows[0])
    phi, ga, gb = np.full(m, np.nan), np.full((m, 6), np.nan), np.full((m, 6), np.nan)
    rows_geometry(pos, quat, *rows, phi, ga, gb)
    return phi, ga, gb


def rates(rows, pos, quat, vel, omega, need_gamma=True):
    """Return Φ̇ (m,) and γ (m,) from the kernels."""
    _, ga, gb = geometry(rows, pos, quat)
    m = len(rows[0])
    phi_dot, gamma = np.full(m, np.nan), np.full(m, np.nan)
    rows_rates(pos, quat, vel, omega, *rows, ga, gb, need_gamma, phi_dot, gamma)
    return phi_dot, gamma


def along(pos, quat, vel, omega, t):
    """Return (pos, quat) at t on the zero-acceleration curve x + t v, R exp(t hat(Ω))."""
    return pos + t * vel, so3.quat_multiply(quat, so3.exp_quat(t * omega))


def assert_close(actual, expected, rtol):
    """Assert agreement to ``rtol`` relative to the largest entry of ``expected``."""
    scale = max(1.0, float(np.max(np.abs(expected))))
    err = float(np.max(np.abs(actual - expected)))
    assert np.all(np.isfinite(actual))
    assert err <= rtol * scale, f'error {err:.3g}, scale {scale:.3g}'


def cases():
    """Return (label, rows, pos, quat, vel, omega) of joints and of random rows."""
    out = []
    for seed in range(3):
        cs, _, motion = random_constraint_set(seed)
        out.append((f'joints{seed}', row_arrays(cs), *motion))
        out.append((f'rows{seed}', random_rows(seed),
                    *random_motion(np.random.default_rng(100 + seed))))
    return out


CASES = cases()
IDS = [c[0] for c in CASES]


def reference_phi(rows, pos, quat):
    """Return Φ (m,) of the rows by their definitions, one row at a time."""
    kind, comp, a, b, par = rows
    x = np.vstack([pos, np.zeros((1, 3))])
    R = np.concatenate([so3.quat_to_matrix(quat), np.eye(3)[None]])
    phi = np.zeros(len(kind))
    for k in range(len(kind)):
        i, j = a[k], b[k]
        ra, rb, s, e, e2 = (par[k, c:c + 3] for c in (PAR_RA, PAR_RB, PAR_S, PAR_E, PAR_E2))
        c = par[k, PAR_SCALAR]
        d = x[i] + R[i] @ ra - x[j] - R[j] @ rb
        if kind[k] == KIND_POINT:
            phi[k] = d[comp[k]]
        elif kind[k] == KIND_DOT:
            phi[k] = (R[j] @ e) @ (R[i] @ s) - c
        elif kind[k] == KIND_LINE:
            phi[k] = (R[j] @ e) @ d - c
        elif kind[k] == KIND_ANGLE:
            u = R[i] @ s
            theta = np.arctan2((R[j] @ e2) @ u, (R[j] @ e) @ u)
            phi[k] = (theta - c + np.pi) % (2.0 * np.pi) - np.pi   # in [−π, π)
        else:
            phi[k] = np.linalg.norm(d) - c
    return phi


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_phi_matches_the_row_definitions(case):
    _, rows, pos, quat, _, _ = case
    # bound: ~7 eps of terms (x + R p, R 4 eps off) summing to <= 3.3 max|Φ|, twice: 46 eps; x10
    assert_close(geometry(rows, pos, quat)[0], reference_phi(rows, pos, quat), 1e-13)


def test_joints_hold_where_they_were_added():
    cs, state, _ = random_constraint_set(11)
    phi = cs.geometry(state.pos_com_world, state.quat_principal_world).phi
    for name in cs.names:
        spec = cs.spec(name)
        rows = phi[cs.rows_of(name)]
        if spec.anchor_world is not None or spec.type.value in ('hinge', 'slider', 'fixed'):
            # Anchors given in the world frame, and the axis rows, start satisfied.
            held = rows if spec.anchor_world is not None else rows[cs.row_kind[
                cs.rows_of(name)] == KIND_DOT]
            # bound: rounding only (anchors to body frames and back): ~8 eps of 3 m = 5e-15
            assert np.max(np.abs(held)) < 1e-12, name
        if spec.type.value == 'distance' and spec.length is None:
            assert abs(rows[0]) < 1e-12   # bound: as above
        if spec.type.value == 'distance' and spec.length is not None:
            assert abs(rows[0]) > 1e-3   # violated: the length 0.7 is not the distance


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_jacobian_is_the_derivative_of_phi(case):
    _, rows, pos, quat, _, _ = case
    n = len(pos)
    _, ga, gb = geometry(rows, pos, quat)
    a, b = rows[2], rows[3]
    h = 1e-6
    for i in range(n):
        fd = np.zeros((len(a), 6))
        for j in range(6):
            dp, dq = pos.copy(), quat.copy()
            if j < 3:
                dp[i, j] += h
                plus = geometry(rows, dp, quat)[0]
                dp[i, j] -= 2 * h
                minus = geometry(rows, dp, quat)[0]
            else:
                # δR = R hat(δΘ): δΘ in the principal (body) frame.
                step = np.eye(3)[j - 3] * h
                dq[i] = so3.quat_multiply(quat[i], so3.exp_quat(step))
                plus = geometry(rows, pos, dq)[0]
                dq[i] = so3.quat_multiply(quat[i], so3.exp_quat(-step))
                minus = geometry(rows, pos, dq)[0]
            fd[:, j] = (plus - minus) / (2 * h)
        # Rows where i is body a, then body b; a row never has a == b.
        expected = np.zeros_like(fd)
        expected[a == i] = ga[a == i]
        expected[b == i] = gb[b == i]
        # bound: h² |d³Φ| / 6 ~ 1e-12 + rounding of Φ± (~5 eps of 12 m) / h = 1.3e-8; x8
        assert_close(expected, fd, 1e-7)


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_phi_dot_is_the_rate_of_phi(case):
    _, rows, pos, quat, vel, omega = case
    h = 1e-6
    fd = (geometry(rows, *along(pos, quat, vel, omega, h))[0]
          - geometry(rows, *along(pos, quat, vel, omega, -h))[0]) / (2 * h)
    phi_dot, gamma = rates(rows, pos, quat, vel, omega, need_gamma=False)
    assert_close(phi_dot, fd, 1e-7)   # bound: as the Jacobian's (h = 1e-6): 1.3e-8; x8
    # Exact: γ is not computed, and Φ̇ is the same kernel's arithmetic either way (same run).
    assert np.array_equal(gamma, np.zeros_like(gamma))
    assert np.array_equal(rates(rows, pos, quat, vel, omega)[0], phi_dot)


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_gamma_is_the_second_derivative_along_zero_acceleration(case):
    _, rows, pos, quat, vel, omega = case
    h = 1e-4
    phi0 = geometry(rows, pos, quat)[0]
    fd = (geometry(rows, *along(pos, quat, vel, omega, h))[0] - 2.0 * phi0
          + geometry(rows, *along(pos, quat, vel, omega, -h))[0]) / h**2
    gamma = rates(rows, pos, quat, vel, omega)[1]
    # bound: h² |d⁴Φ| / 12 ~ 1e-7 + rounding 4 (5 eps of 12 m) / h² = 5e-6 (worst case); x2
    assert_close(gamma, fd, 1e-5)
    # Not trivially satisfied: γ is of order one here.
    assert np.max(np.abs(gamma)) > 0.1


def test_constraint_set_assembles_kernel_rows_and_generic_rows():
    cs, state, (pos, quat, vel, omega) = random_constraint_set(7)
    mb = cs.n_builtin_rows
    assert mb == cs.n_rows == len(cs.row_kind) == len(cs.row_par)
    # Generic rows come after the built-in ones and keep their Python evaluation.
    cs.add(Constraint('gen', 'generic', 'b1', 'b2',
                      function=lambda xa, Ra, xb, Rb: np.array([xa @ xb, Ra[0] @ Rb[1]])),
           state)
    cs.add(Constraint('gen_world', 'generic', 'b3', None,
                      function=lambda xa, Ra, xb, Rb: np.array([xa[2] + Ra[2, 0]])), state)
    assert cs.n_builtin_rows == mb and cs.n_rows == mb + 3
    assert list(cs.rows_of('gen')) == [mb, mb + 1] and list(cs.rows_of('gen_world')) == [mb + 2]
    geo = cs.geometry(pos, quat)
    phi, ga, gb = geometry(row_arrays(cs), pos, quat)
    # Exact here and below: the same compiled kernel on the same rows (same run), copied.
    np.testing.assert_array_equal(geo.phi[:mb], phi)
    G = geo.jacobian.toarray()
    n = len(pos)
    expected = np.zeros((mb, 6 * n))
    for k in range(mb):
        a, b = cs.row_a[k], cs.row_b[k]
        expected[k, 6 * a:6 * a + 6] = ga[k]
        if b < n:
            expected[k, 6 * b:6 * b + 6] = gb[k]
    np.testing.assert_array_equal(G[:mb], expected)
    # The generic rows: Φ and a finite-difference G, γ along the motion.
    h = 1e-4
    fd = (cs.geometry(*along(pos, quat, vel, omega, h)).phi - 2.0 * geo.phi
          + cs.geometry(*along(pos, quat, vel, omega, -h)).phi) / h**2
    phi_dot, gamma = geo.rates(vel, omega)
    nu = np.hstack([vel, omega]).ravel()
    # bound: each of the kernel's Φ̇ and G ν within γ_12 |G||ν| (12 terms): 24 eps; x10
    assert np.max(np.abs(phi_dot - G @ nu)) <= 240 * EPS * np.max(np.abs(G) @ np.abs(nu))
    assert_close(gamma[:mb], fd[:mb], 1e-5)   # bound: as in the γ test: 5e-6; x2
    # bound: + the generic γ's own second difference (h = 1e-4 / |ν|): ~3e-5 (worst case); x3
    assert_close(gamma[mb:], fd[mb:], 1e-4)
    assert np.array_equal(geo.rates(vel, omega, need_gamma=False)[1], np.zeros(cs.n_rows))


def test_removing_constraints_rebuilds_the_rows():
    cs, _, (pos, quat, _, _) = random_constraint_set(3)
    names = cs.names
    for name in names[::2]:
        cs.remove(name)
    assert len(cs.row_kind) == cs.n_builtin_rows == cs.n_rows
    assert np.all(np.diff(cs.row_kind) >= 0)
    geo = cs.geometry(pos, quat)
    phi = geometry(row_arrays(cs), pos, quat)[0]
    for name in cs.names:
        np.testing.assert_array_equal(geo.phi[cs.rows_of(name)], phi[cs.rows_of(name)])
    for name in cs.names:
        cs.remove(name)
    empty = cs.geometry(pos, quat)
    assert empty.phi.shape == (0,) and empty.jacobian.toarray().shape == (0, 6 * N_BODIES)
    assert [r.shape for r in empty.rates(pos, pos)] == [(0,), (0,)]


_NO_JIT_SCRIPT = """
import json, sys
import numpy as np
sys.path.insert(0, {test_dir!r})
from test_row_kernels import CASES, geometry, rates
out = {{}}
for label, rows, pos, quat, vel, omega in CASES:
    phi, ga, gb = geometry(rows, pos, quat)
    phi_dot, gamma = rates(rows, pos, quat, vel, omega)
    out[label] = [a.tolist() for a in (phi, ga, gb, phi_dot, gamma)]
print(json.dumps(out))
"""


def test_kernels_run_unchanged_without_jit():
    env = dict(os.environ, NUMBA_DISABLE_JIT='1')
    script = _NO_JIT_SCRIPT.format(test_dir=os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.run([sys.executable, '-c', script], env=env, capture_output=True,
                          text=True, timeout=300, check=True)
    plain = json.loads(proc.stdout)
    for label, rows, pos, quat, vel, omega in CASES:
        compiled = (*geometry(rows, pos, quat), *rates(rows, pos, quat, vel, omega))
        for got, want in zip(plain[label], compiled):
            # bound: same operations and order (no fastmath); libm/FMA: 8 eps of terms <= 40; x10
            np.testing.assert_allclose(np.array(got), want, rtol=0, atol=7e-13)
