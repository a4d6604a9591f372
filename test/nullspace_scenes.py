"""
Random jointed mechanisms for the null-space premise (issue 19): rows, blocks, masses.

Joints are made as :meth:`rigid_body_sim.core.constraints.ConstraintSet` makes
them when a constraint is added (anchor and axis in world axes at the current
state, the frame ``(k, e1, e2)`` of ``perpendicular_frame``, the same point,
dot and line rows), packed with :func:`~rigid_body_sim.core.kernels.rows.pack_rows`
and evaluated with :func:`~rigid_body_sim.core.kernels.rows.rows_geometry`; the
state is then moved a little off the joints (``Φ ≠ 0``) before the blocks are
taken. No :class:`~rigid_body_sim.core.Simulation` is built (its step kernels
take minutes to compile, and only the rows' blocks are needed).
"""

from __future__ import annotations

import numpy as np
from rigid_body_sim.core.kernels.rows import (frames, KIND_DISTANCE, KIND_DOT, KIND_LINE,
                                              KIND_POINT, pack_rows, rows_geometry)
import scipy.linalg

TYPES = ('fixed', 'hinge', 'ball', 'slider')
LINK = 0.1   # m


def unit(v):
    """Return v / |v|."""
    return v / np.linalg.norm(v)


def random_quat(rng):
    """Return a uniformly random unit quaternion (x, y, z, w)."""
    return unit(rng.normal(size=4))


def quat_matrix(q):
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    R = np.empty((2, 3, 3))
    frames(np.asarray(q, dtype=float)[None], R)
    return R[0]


def perpendicular_frame(k):
    """Right-handed orthonormal frame (k, e1, e2) as rows, as in constraints.py."""
    helper = np.eye(3)[np.argmin(np.abs(k))]
    e1 = unit(np.cross(k, helper))
    return np.array([k, e1, np.cross(k, e1)])


def joint_rows(kind, a, b, pos, R, anchor, axis):
    """Rows ``(kind, comp, a, b, r_a, r_b, s, e, e2, scalar)`` of one joint, at this state."""
    n = len(pos)

    def local(i, p):
        return p if i == n else R[i].T @ (p - pos[i])

    def rot(i):
        return np.eye(3) if i == n else R[i]

    r_a, r_b = local(a, anchor), local(b, anchor)
    frame = perpendicular_frame(unit(axis))
    fa = [rot(a).T @ v for v in frame]
    fb = [rot(b).T @ v for v in frame]
    rows = []
    if kind in ('ball', 'hinge', 'fixed'):
        rows += [(KIND_POINT, c, a, b, r_a, r_b, None, None, None, 0.0) for c in range(3)]
    if kind in ('hinge', 'slider', 'fixed'):
        rows += [(KIND_DOT, 0, a, b, None, None, fa[0], fb[1], None, 0.0),
                 (KIND_DOT, 0, a, b, None, None, fa[0], fb[2], None, 0.0)]
    if kind in ('slider', 'fixed'):
        rows.append((KIND_DOT, 0, a, b, None, None, fa[1], fb[2], None, 0.0))
    if kind == 'slider':
        rows += [(KIND_LINE, 0, a, b, r_a, r_b, None, fb[1], None, 0.0),
                 (KIND_LINE, 0, a, b, r_a, r_b, None, fb[2], None, 0.0)]
    if kind == 'distance':
        # The anchor on a; on b a point a link's length along the axis (as a rope).
        p_b = anchor + LINK * unit(axis)
        rows.append((KIND_DISTANCE, 0, a, b, r_a, local(b, p_b), None, None, None,
                     float(np.linalg.norm(p_b - anchor))))
    return rows


class Mechanism:
    """
    A random forest of bodies joined by built-in joints, each root joined to the world or free.

    Parameters
    ----------
    rng : numpy.random.Generator
    parents : sequence of int
        Parent body of each body (``-1``: the world, or none for a body in ``free``).
    kinds : sequence of str
        Joint type of each body's joint to its parent (``TYPES`` or ``'distance'``;
        ignored for a free root).
    straight : float
        0: random link directions (random joint angles); small: a nearly straight chain.
    mass_ratio : float or None
        Masses alternate 1 and ``mass_ratio`` (kg) instead of random 0.1..10.
    off : float
        Size of the displacement off the joints (m and rad) before the blocks are taken.
    massless_tip : bool
        The last body of 1e-6 kg.
    free : collection of int
        Roots (``parents[i] == -1``) without a joint: free-floating trees.

    Attributes
    ----------
    a, b, kind, comp : ndarray of int64
        The rows (``b == n``: the world).
    Ga, Gb : ndarray, shape (m, 6)
        Their blocks at the displaced state.
    minv6 : ndarray, shape (n, 6)
        Inverse masses.
    R : ndarray, shape (n + 1, 3, 3)
        Rotations of the displaced state (:func:`frames`).
    phi : ndarray, shape (m,)
        The rows' Φ there.
    pos, quat, par : ndarray
        The displaced state and the rows' parameters (``pack_rows``).

    """

    def __init__(self, rng, parents, kinds, straight=0.0, mass_ratio=None, off=1e-2,
                 massless_tip=False, free=()):
        n = len(parents)
        self.n = n
        pos = np.zeros((n, 3))
        quat = np.array([random_quat(rng) for _ in range(n)])
        R = np.array([quat_matrix(q) for q in quat])
        anchors = []
        base_dir = unit(rng.normal(size=3))
        for i, p in enumerate(parents):
            if p < 0:
                anchor = np.zeros(3)
            else:
                anchor = pos[p] + 0.5 * LINK * unit(rng.normal(size=3)) if not straight \
                    else pos[p] + 0.5 * LINK * unit(base_dir + straight * rng.normal(size=3))
            direction = unit(rng.normal(size=3)) if not straight \
                else unit(base_dir + straight * rng.normal(size=3))
            pos[i] = anchor + 0.5 * LINK * direction
            anchors.append(anchor)
        if mass_ratio is None:
            mass = 10.0 ** rng.uniform(-1.0, 1.0, size=n)
        else:
            mass = np.where(np.arange(n) % 2 == 0, 1.0, float(mass_ratio))
        if massless_tip:
            mass[-1] = 1e-6
        # Principal inertias of link-like bodies: m L² (1/12 .. 1/200), random per axis.
        inertia = mass[:, None] * LINK ** 2 * 10.0 ** rng.uniform(-2.3, -1.1, size=(n, 3))
        self.minv6 = np.hstack([np.repeat(1.0 / mass[:, None], 3, axis=1), 1.0 / inertia])
        rows = []
        for i, (p, kind) in enumerate(zip(parents, kinds)):
            if i in free:
                continue   # a free-floating root: no joint
            other = n if p < 0 else p
            a, b = (i, other) if (p < 0 or rng.random() < 0.5) else (other, i)
            axis = unit(rng.normal(size=3)) if not straight \
                else unit(np.cross(base_dir, [0.3, 0.5, 0.8]) + straight * rng.normal(size=3))
            rows += joint_rows(kind, a, b, pos, R, anchors[i], axis)
        # As ConstraintSet numbers them: all point rows, then dots, then lines.
        rows.sort(key=lambda row: row[0])
        self.kind, self.comp, self.a, self.b, par = pack_rows(rows)
        # Off the joints: Φ ≠ 0 where the blocks are taken.
        pos = pos + off * rng.normal(size=pos.shape)
        quat = np.array([unit(q + 0.5 * off * rng.normal(size=4)) for q in quat])
        m = len(rows)
        self.pos, self.quat, self.par = pos, quat, par
        self.phi = np.empty(m)
        self.Ga, self.Gb = np.empty((m, 6)), np.empty((m, 6))
        rows_geometry(pos, quat, self.kind, self.comp, self.a, self.b, par, self.phi,
                      self.Ga, self.Gb)
        self.R = np.empty((n + 1, 3, 3))
        frames(quat, self.R)
        self.kinds = tuple(kinds)

    @property
    def m(self) -> int:
        """Return the number of rows."""
        return int(self.a.size)

    def dense_A(self):
        """Return ``A = G M⁻¹ Gᵀ`` (float64) and ``G`` (m, 6n) from the blocks."""
        n, m = self.n, self.m
        G = np.zeros((m, 6 * n + 6))
        r = np.arange(m)
        for k in range(6):
            G[r, 6 * self.a + k] += self.Ga[:, k]   # a != b: one block per entry, exact
            G[r, 6 * self.b + k] += self.Gb[:, k]
        G = G[:, :6 * n]
        return G @ (self.minv6.ravel()[:, None] * G.T), G

    def reference(self, rhs_columns, iterations=5):
        """
        Return ``A⁻¹ rhs`` to about ``1e-30 cond(A)`` (refined with double-double residuals).

        The residual ``rhs − G (M⁻¹ (Gᵀ x))`` is evaluated from the blocks in double-double
        arithmetic (error about ``1e-32 |G| |M⁻¹| |Gᵀ| |x|``), ``x`` kept as a double-double
        sum, the corrections solved with the float64 ``A``. (Forming ``A`` in np.longdouble
        instead, 64-bit significands, leaves ``A`` wrong by about ``1e-19 |G| |M⁻¹| |Gᵀ|``:
        1.3e-13 in λ on a chain of fixed joints of cond(A) 3e8.)

        Returns ``(x, cond(A))``, x in float64.
        """
        A, G = self.dense_A()
        minv = self.minv6.ravel()
        rhs = np.asarray(rhs_columns, dtype=float)
        lu = scipy.linalg.lu_factor(A)
        xh = scipy.linalg.lu_solve(lu, rhs)
        xl = np.zeros_like(xh)
        for _ in range(iterations):
            yh, yl = _dd_matmul(G.T, xh, xl)
            yh, yl = _dd_scale(yh, yl, minv[:, None])
            wh, wl = _dd_matmul(G, yh, yl)
            resid = (rhs - wh) - wl
            xh, xl = _dd_add(xh, xl, scipy.linalg.lu_solve(lu, resid))
        return xh + xl, float(np.linalg.cond(A))


class ShakeSystem:
    """
    SHAKE's Newton matrix ``A = G_E diag(I, J_r) M⁻¹ G_Sᵀ`` on a mechanism (issue 19).

    The start configuration is the mechanism's (displaced) state; the end is the start
    moved by a small random step (``step`` m per ``LINK`` in position, about ``step`` rad
    in orientation), as a drift moves it.

    Parameters
    ----------
    mech : Mechanism
    rng : numpy.random.Generator
    step : float
        Size of the drift.
    jacobian : str
        ``'right'``: ``J_r`` of each body's rotation over the drift
        (``constrained_step._right_jacobians``, as for isotropic bodies; not symmetric);
        ``'random'``: ``I + 0.1 N(0, 1)`` per body (a general 3 x 3, as an anisotropic
        body's carried through its rotor flows).

    Attributes
    ----------
    GaS, GbS, GaE, GbE : ndarray, shape (m, 6)
        The blocks at the start and at the end.
    RS, RE : ndarray, shape (n + 1, 3, 3)
        The rotations there.
    Jr : ndarray, shape (n, 3, 3)
    Ga2, Gb2 : ndarray, shape (m, 6)
        ``G_E diag(I, J_r)`` as the step forms it (``_apply_jacobians``).

    """

    def __init__(self, mech, rng, step=0.05, jacobian='right'):
        from rigid_body_sim.core.kernels.constrained_step import (_apply_jacobians,
                                                                  _right_jacobians)
        self.mech = mech
        n, m = mech.n, mech.m
        self.GaS, self.GbS, self.RS = mech.Ga, mech.Gb, mech.R
        pos = mech.pos + step * LINK * rng.normal(size=mech.pos.shape)
        quat = np.array([unit(q + 0.5 * step * rng.normal(size=4)) for q in mech.quat])
        self.phiE = np.empty(m)
        self.GaE, self.GbE = np.empty((m, 6)), np.empty((m, 6))
        rows_geometry(pos, quat, mech.kind, mech.comp, mech.a, mech.b, mech.par, self.phiE,
                      self.GaE, self.GbE)
        self.RE = np.empty((n + 1, 3, 3))
        frames(quat, self.RE)
        self.Jr = np.empty((n, 3, 3))
        if jacobian == 'right':
            _right_jacobians(mech.quat, quat, self.Jr)
        else:
            self.Jr[:] = np.eye(3) + 0.1 * rng.normal(size=(n, 3, 3))
        self.Ga2, self.Gb2 = np.empty((m, 6)), np.empty((m, 6))
        _apply_jacobians(self.GaE, self.GbE, mech.a, mech.b, self.Jr, self.Ga2, self.Gb2)

    def dense(self):
        """Return ``G_E``, ``D = diag(I, J_r)`` per body and ``G_S`` (dense, float64)."""
        mech = self.mech
        n = mech.n
        D = np.zeros((6 * n, 6 * n))
        for i in range(n):
            D[6 * i:6 * i + 3, 6 * i:6 * i + 3] = np.eye(3)
            D[6 * i + 3:6 * i + 6, 6 * i + 3:6 * i + 6] = self.Jr[i]
        return dense_G(mech, self.GaE, self.GbE), D, dense_G(mech, self.GaS, self.GbS)

    def reference(self, rhs_columns, iterations=6):
        """
        Return ``A⁻¹ rhs`` refined with double-double residuals, and cond(A).

        As :meth:`Mechanism.reference`: the residual ``rhs − G_E (D (M⁻¹ (G_Sᵀ x)))`` from
        the blocks and ``J_r`` in double-double arithmetic (``A`` exactly as the data
        define it, ``D`` not rounded into ``G_E``), ``x`` kept as a double-double sum, the
        corrections solved with the float64 ``A``.
        """
        GE, D, GS = self.dense()
        minv = self.mech.minv6.ravel()
        A = GE @ D @ (minv[:, None] * GS.T)
        rhs = np.asarray(rhs_columns, dtype=float)
        lu = scipy.linalg.lu_factor(A)
        xh = scipy.linalg.lu_solve(lu, rhs)
        xl = np.zeros_like(xh)
        for _ in range(iterations):
            yh, yl = _dd_matmul(GS.T, xh, xl)
            yh, yl = _dd_scale(yh, yl, minv[:, None])
            yh, yl = _dd_matmul(D, yh, yl)
            wh, wl = _dd_matmul(GE, yh, yl)
            resid = (rhs - wh) - wl
            xh, xl = _dd_add(xh, xl, scipy.linalg.lu_solve(lu, resid))
        return xh + xl, float(np.linalg.cond(A))


def dense_G(mech, Ga, Gb):
    """Return the dense ``G`` (m, 6n) of blocks ``Ga``, ``Gb`` on the mechanism's rows."""
    n, m = mech.n, mech.m
    G = np.zeros((m, 6 * n + 6))
    r = np.arange(m)
    for k in range(6):
        G[r, 6 * mech.a + k] += Ga[:, k]   # a != b: one block per entry, exact
        G[r, 6 * mech.b + k] += Gb[:, k]
    return G[:, :6 * n]


_SPLIT = 134217729.0   # 2^27 + 1 (Dekker)


def _two_prod(a, b):
    """Return ``p, e`` with ``p = fl(a b)`` and ``p + e = a b`` exactly (Dekker)."""
    p = a * b
    c = _SPLIT * a
    ah = c - (c - a)
    al = a - ah
    c = _SPLIT * b
    bh = c - (c - b)
    bl = b - bh
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


def _dd_add(hi, lo, b, e=0.0):
    """Return the double-double ``(hi, lo) + (b, e)``."""
    s = hi + b
    bb = s - hi
    t = (hi - (s - bb)) + (b - bb) + lo + e
    h = s + t
    return h, t - (h - s)


def _dd_scale(hi, lo, v):
    """Return the double-double ``(hi, lo) v`` (v float64)."""
    p, e = _two_prod(hi, v)
    h = p + (e + lo * v)
    return h, (e + lo * v) - (h - p)


def _dd_matmul(M, xh, xl):
    """Return the double-double ``M (xh + xl)`` (M float64, mostly zeros), column by column."""
    hi = np.zeros((M.shape[0], xh.shape[1]))
    lo = np.zeros_like(hi)
    for k in range(M.shape[1]):
        rows = np.flatnonzero(M[:, k])
        col = M[rows, k][:, None]
        p, e = _two_prod(col, xh[k][None, :])
        hi[rows], lo[rows] = _dd_add(hi[rows], lo[rows], p, e + col * xl[k][None, :])
    return hi, lo


def chain_parents(n):
    """Parents of a chain: body 0 on the world, body i on body i − 1."""
    return [-1] + list(range(n - 1))


def tree_parents(rng, n):
    """Parents of a random tree: body 0 on the world, body i on one of the bodies before it."""
    return [-1] + [int(rng.integers(i)) for i in range(1, n)]


def mixed_kinds(rng, n, distance=False):
    """Joint types drawn from all four (and ``'distance'``, a rope's one row, if asked)."""
    kinds = TYPES + ('distance',) if distance else TYPES
    return [kinds[int(rng.integers(len(kinds)))] for _ in range(n)]
