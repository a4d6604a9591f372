"""
Compiled kernels: contact steps of bodies no joint couples, whole.

:class:`..contact_step.ContactSteps` takes a step with contact in Python over
compiled detection and integration: some sixty numpy calls and up to four
integrator calls a step, about a millisecond. For scenes of free bodies the same
steps run here, as many as the caller asks in one call (:func:`contact_steps`),
with the Python path's arithmetic and structure (its docstring's names), function
for function:

* :func:`_step` (``ContactSteps.step``): a step that starts with no contact within the
  margin is the free step and the detection at its end alone, unless that end overlaps
  deeper than the tolerance (an event: the general path); otherwise the touching
  contacts' rows at the start
  (``G`` as two (3c, 6) blocks, on body ``a`` and body ``b``); :func:`_impact` for
  those approaching (inelastic below ``P_BOUNCE``); the rows the step holds
  (:func:`_step_rows`: those touching, and those apart closing slower than
  ``P_UNLOCATED``, asked to close at most their gaps); :func:`_held`, the trial step
  with the forces held; a new contact overlapping at its end is located
  (:func:`_locate`) and the step taken again from there, up to ``MAX_EVENTS`` events;
  :func:`_accept` at the end;
* :func:`_held` (``_held_step``): the LCP ``w = A p + q`` (``A = G M⁻¹ Gᵀ``, ``q =
  G ṽ``) by the friction boxes' fixed point over a proximal active-set solve
  (:func:`solve_rows`, :func:`solve_box`: its Cholesky factor updated as rows join
  and leave, and kept from one iteration to the next), warm-started
  from the last step's normal impulses (where that fixed point stalls, Newton's method
  on the rows' natural map, :func:`newton`, then Lemke's pivoting on the pyramid:
  :func:`pyramid`, or, for an island of more than ``P_PIVOT_CONTACTS`` contacts, its
  blocks' fixed point: :func:`_by_blocks`, then pivoting if that fails and the island
  has at most ``P_PIVOT_LAST_CONTACTS``); sticking contacts that begin to slip turned
  to their slip (:func:`slip_turn`); the step with the forces held, its model
  checked at the end's geometry (each contact found again: :func:`match`) and
  corrected up to ``MODEL_CORRECTIONS`` times;
* :func:`_locate` (``_locate``): regula falsi (Illinois) on the new contact's depth;
* :func:`_accept` (``_settle``): depth projected out, loaded contacts held.

What the kernel does not take it gives back untouched (``BAIL``) and the Python path
takes that step: a row no impulse moves (a point on an axle: joints, which this
kernel never sees), a non-finite step (the Python path raises its error). A step whose
impacts the log cannot take ends the call before it (``FULL``: the log read, the next
call takes it). The results agree with the Python path's to rounding (the tests run
both). The counters a step adds are written to ``cnt`` (:data:`COUNTERS`); a step
given back adds nothing there (the Python path that takes it counts its work).
"""

from __future__ import annotations

import math

from numba import njit, types
from numba.np.linalg import _LAPACK, F_INT_nptype
import numpy as np

from .contact import all_bounds, broad_phase, narrow_phase, plane_pairs, shape_frames
from .free_step import FINITE, free_step, HAS_POSITION_FORCES, outputs, state_parts
from .layout import O_WIDTH, W_BODY, W_FORCE, W_IN_BODY, W_KIND, W_POINT, W_TORQUE, WRENCH_APPLIED
from .so3 import quat_exp_multiply, quat_matrix
from .sparse_box import block_product, mprgp
from .views import address, pinned, pinned_int, raw_tree

#: Slots of the tolerances ``prm`` (the constants of :mod:`..contact_step`).
(P_LOCATION, P_RATE, P_FRICTION_TOLERANCE, P_FRICTION_ITERATIONS, P_PROXIMAL,
 P_MODEL_TOLERANCE, P_MODEL_CORRECTIONS, P_HOLD_RATE, P_RATE_FLOOR, P_MAX_EVENTS,
 P_MAX_BOUNCES, P_MAX_LOCATION_ITERATIONS, P_RESIDUAL_TOLERANCE, P_PROJECTION_PASSES,
 P_PIVOT_TOLERANCE, P_PIVOT_REGULARIZATION_1, P_PIVOT_REGULARIZATION_2,
 P_BOUNCE, P_UNLOCATED, P_STALL_ITERATIONS, P_NEWTON_ITERATIONS, P_NEWTON_REFINEMENTS,
 P_SPARSE_CONTACTS, P_SPARSE_PROXIMAL, P_SPARSE_RESIDUAL, P_SPARSE_ITERATIONS,
 P_SPARSE_INNER, P_PGS_SWEEPS, P_SPARSE_HISTORY, P_PIVOT_CONTACTS, P_PIVOT_LAST_CONTACTS,
 P_WIDTH) = range(32)
#: The counters of :class:`..contact_step.ContactSteps` this kernel adds to, in ``cnt``'s order.
COUNTERS = ('lcp_solves', 'lcp_iterations_max', 'lcp_failures', 'complementarity_max',
            'model_corrections', 'held_rates', 'impacts', 'located_steps', 'events_capped',
            'max_depth', 'projections', 'max_projected', 'projection_left', 'lcp_pivoted',
            'lcp_newton', 'lcp_sparse', 'lcp_pgs', 'end_depth')
(C_SOLVES, C_ITERATIONS_MAX, C_FAILURES, C_COMPLEMENTARITY, C_CORRECTIONS, C_HELD,
 C_IMPACTS, C_LOCATED, C_CAPPED, C_MAX_DEPTH, C_PROJECTIONS, C_MAX_PROJECTED,
 C_PROJECTION_LEFT, C_PIVOTED, C_NEWTON, C_SPARSE, C_PGS, C_END_DEPTH) = range(18)
#: The counters that are maxima (the others are sums).
MAXIMA = ('lcp_iterations_max', 'complementarity_max', 'max_depth', 'max_projected',
          'projection_left', 'end_depth')
#: Why :func:`contact_steps` stopped: every step taken; an event (the Python path's);
#: the detector's buffers too small (grow them and call again); the impact log full (read
#: it and call again, or, where the first step's impacts alone overflow it, grow it).
DONE, BAIL, GROW, FULL = 0, 1, 2, 3
#: Per row of a box LCP: at its lower bound, free, at its upper bound.
AT_LOWER, FREE, AT_UPPER = -1, 0, 1
ROUNDING_ULPS = 64.0
EPS = 2.220446049250313e-16
#: Beyond this many unknowns Newton's linear solves factor by LAPACK's ``dgetrf``
#: (:func:`lapack_lu`: blocked), up to it by the loops' LU (:func:`lu_factor`: no call's
#: overhead). A factor and four solves, random dense systems, one BLAS thread, this
#: machine's Xeon: 24 unknowns 11.7 µs by the loops, 11.0 by LAPACK; 48: 38.7 and 25.6;
#: 100: 269 and 112; 400: 14.6 ms and 2.5.
NEWTON_LAPACK_ROWS = 24
#: The squared distance (m²) within which a contact takes the last step's normal impulse.
WARM_RADIUS2 = 1e-6


# -- detection ------------------------------------------------------------------------------

@njit(cache=True)
def detect(pos: np.ndarray, quat: np.ndarray, vel: np.ndarray, om: np.ndarray, det: tuple,
           buf: tuple, frames: np.ndarray, out: np.ndarray) -> tuple:
    """
    Return the contacts at the state, as :meth:`..shapes.ContactDetector.detect`.

    ``(count, shape_a, shape_b, body_a, body_b, point, normal, depth)``; count −1: a
    buffer is too small.

    ``det``: the detector's arrays ``(kind, size, c_body, R_body, body, group, mask,
    solids, planes, solid_body, solid_group, solid_mask, excluded, live, margin, hulls,
    hull_at)``;
    ``buf``: its buffers ``(pairs, plane_pairs, points, normals, depths, owner, lo, hi,
    c, R)``; ``out`` (n, O_WIDTH) is overwritten with the bodies' outputs.
    """
    (kind, size, c_body, R_body, body, group, mask, solids, planes, solid_body, solid_group,
     solid_mask, excluded, live, margin, hulls, hull_at) = det
    pairs, ppairs, points, normals, depths, owner, lo, hi, c, R = buf
    n = pos.shape[0]
    outputs(pos, quat, vel, om, frames, out)
    shape_frames(out, body, c_body, R_body, c, R)
    all_bounds(kind, c, R, size, solids, margin, lo, hi)
    k = broad_phase(lo, hi, solid_body, solid_group, solid_mask, n, excluded, pairs)
    kp = plane_pairs(solids, planes, body, group, mask, n, excluded, ppairs)
    if k > pairs.shape[0] or kp > ppairs.shape[0]:
        return _no_contacts(-1)
    every = np.empty((k + kp, 2), dtype=np.int64)
    for i in range(k):
        every[i, 0], every[i, 1] = solids[pairs[i, 0]], solids[pairs[i, 1]]
    for i in range(kp):
        every[k + i, 0], every[k + i, 1] = ppairs[i, 0], ppairs[i, 1]
    count = narrow_phase(every, kind, c, R, size, hulls, hull_at, margin, points, normals,
                         depths, owner)
    if count > depths.shape[0]:
        return _no_contacts(-1)
    # (two allocations, the contacts' arrays views of them: each a C-contiguous run)
    ints = np.empty(4 * count, dtype=np.int64)
    sa, sb = ints[:count], ints[count:2 * count]
    ba, bb = ints[2 * count:3 * count], ints[3 * count:]
    for j in range(count):
        a, b = every[owner[j], 0], every[owner[j], 1]
        sa[j], sb[j], ba[j], bb[j] = live[a], live[b], body[a], body[b]
    floats = np.empty(7 * count)
    pt, nr = floats[:3 * count].reshape((count, 3)), floats[3 * count:6 * count].reshape(
        (count, 3))
    dp = floats[6 * count:]
    for j in range(count):
        for a in range(3):
            pt[j, a], nr[j, a] = points[j, a], normals[j, a]
        dp[j] = depths[j]
    return count, sa, sb, ba, bb, pt, nr, dp


#: The slots of the contact steps' table of their arrays (:func:`_arrays_table`; ``ctx[5]``):
#: slot ``k < MT_ARRAYS`` the address of array ``k``, ``MT_ARRAYS + 2 k`` its two
#: dimensions (1: a vector). ``ctx`` is ``(method, n_applied, flags, steps_slot, dt,
#: this table, the detector's table)``: a call with it moves a dozen words, not the
#: hundreds of its arrays' descriptions, and counts one reference (the table's), not
#: one for each array.
(MT_BODY, MT_GFORCE, MT_WBUF, MT_KICK, MT_COUNTS, MT_WS, MT_FRAMES, MT_OUT, MT_MU, MT_E,
 MT_RADIUS, MT_PRM, MT_MINV, MT_ARRAYS) = range(14)


@njit(cache=True, inline='always')
def _slot(mt: np.ndarray, k: int, a: np.ndarray) -> None:
    """Set the table's slot ``k``: array ``a``'s address and its dimensions."""
    mt[k] = address(a)
    mt[MT_ARRAYS + 2 * k] = a.shape[0]
    mt[MT_ARRAYS + 2 * k + 1] = 1 if a.ndim == 1 else a.shape[a.ndim - 1]


@njit(cache=True, inline='always')
def _arrays_table(model: tuple, kick: np.ndarray, counts: np.ndarray, ws: np.ndarray,
                  frames: np.ndarray, out: np.ndarray, shape_mu: np.ndarray,
                  shape_e: np.ndarray, radius: np.ndarray, prm: np.ndarray,
                  minv: np.ndarray) -> np.ndarray:
    """Return the table of the contact steps' arrays (:data:`MT_ARRAYS`)."""
    mt = np.empty(3 * MT_ARRAYS, dtype=np.int64)
    _slot(mt, MT_BODY, model[0])
    _slot(mt, MT_GFORCE, model[1])
    _slot(mt, MT_WBUF, model[2])
    _slot(mt, MT_KICK, kick)
    _slot(mt, MT_COUNTS, counts)
    _slot(mt, MT_WS, ws)
    _slot(mt, MT_FRAMES, frames)
    _slot(mt, MT_OUT, out)
    _slot(mt, MT_MU, shape_mu)
    _slot(mt, MT_E, shape_e)
    _slot(mt, MT_RADIUS, radius)
    _slot(mt, MT_PRM, prm)
    _slot(mt, MT_MINV, minv)
    return mt


@njit(cache=True, inline='always')
def _matrix(ctx: tuple, k: int) -> np.ndarray:
    """Return the table's array ``k`` (two dimensions; ``MT_*``) as a view."""
    mt = ctx[5]
    return pinned(mt, k, (mt[MT_ARRAYS + 2 * k], mt[MT_ARRAYS + 2 * k + 1]))


@njit(cache=True, inline='always')
def _vector(ctx: tuple, k: int) -> np.ndarray:
    """Return the table's array ``k`` (one dimension) as a view."""
    mt = ctx[5]
    return pinned(mt, k, (mt[MT_ARRAYS + 2 * k],))


@njit(cache=True, inline='always')
def _cx_model(ctx: tuple) -> tuple:
    """Return ``(body, gforce, wbuf)``: the model :func:`_advance` takes."""
    return _matrix(ctx, MT_BODY), _matrix(ctx, MT_GFORCE), _matrix(ctx, MT_WBUF)


@njit(cache=True, inline='always')
def _cx_counts(ctx: tuple) -> np.ndarray:
    """Return the work tally (int64; :data:`MT_COUNTS`) as a view."""
    mt = ctx[5]
    return pinned_int(mt, MT_COUNTS, (mt[MT_ARRAYS + 2 * MT_COUNTS],))


#: :func:`detect`'s ``det`` (its 16 arrays and its margin, as an array of one) and ``buf``
#: (10 arrays) in one :class:`.views.Pinned` table (``ContactSteps._detector_table``): slot
#: ``k < DT_ARRAYS`` the address of array ``k``, ``DT_DIMS + 3 k`` its dimensions (up to
#: three). The contact steps pass it in ``ctx`` where they passed the 26 arrays: every
#: call with ``ctx`` moved about 200 words more for them, and the step makes many.
DT_ARRAYS = 27
DT_DIMS = DT_ARRAYS


@njit(cache=True, inline='always')
def _dim(tab: np.ndarray, k: int, x: int) -> int:
    """Return dimension ``x`` of the table's array ``k``."""
    return tab[DT_DIMS + 3 * k + x]


@njit(cache=True, inline='always')
def _detector(tab: np.ndarray) -> tuple:
    """Return :func:`detect`'s ``(det, buf)``: views of the table's arrays (:data:`DT_ARRAYS`)."""
    det = (pinned_int(tab, 0, (_dim(tab, 0, 0),)),
           pinned(tab, 1, (_dim(tab, 1, 0), _dim(tab, 1, 1))),
           pinned(tab, 2, (_dim(tab, 2, 0), _dim(tab, 2, 1))),
           pinned(tab, 3, (_dim(tab, 3, 0), _dim(tab, 3, 1), _dim(tab, 3, 2))),
           pinned_int(tab, 4, (_dim(tab, 4, 0),)), pinned_int(tab, 5, (_dim(tab, 5, 0),)),
           pinned_int(tab, 6, (_dim(tab, 6, 0),)), pinned_int(tab, 7, (_dim(tab, 7, 0),)),
           pinned_int(tab, 8, (_dim(tab, 8, 0),)), pinned_int(tab, 9, (_dim(tab, 9, 0),)),
           pinned_int(tab, 10, (_dim(tab, 10, 0),)), pinned_int(tab, 11, (_dim(tab, 11, 0),)),
           pinned_int(tab, 12, (_dim(tab, 12, 0),)), pinned_int(tab, 13, (_dim(tab, 13, 0),)),
           pinned(tab, 14, (1,))[0], pinned(tab, 15, (_dim(tab, 15, 0),)),
           pinned_int(tab, 16, (_dim(tab, 16, 0),)))
    buf = (pinned_int(tab, 17, (_dim(tab, 17, 0), _dim(tab, 17, 1))),
           pinned_int(tab, 18, (_dim(tab, 18, 0), _dim(tab, 18, 1))),
           pinned(tab, 19, (_dim(tab, 19, 0), _dim(tab, 19, 1))),
           pinned(tab, 20, (_dim(tab, 20, 0), _dim(tab, 20, 1))),
           pinned(tab, 21, (_dim(tab, 21, 0),)), pinned_int(tab, 22, (_dim(tab, 22, 0),)),
           pinned(tab, 23, (_dim(tab, 23, 0), _dim(tab, 23, 1))),
           pinned(tab, 24, (_dim(tab, 24, 0), _dim(tab, 24, 1))),
           pinned(tab, 25, (_dim(tab, 25, 0), _dim(tab, 25, 1))),
           pinned(tab, 26, (_dim(tab, 26, 0), _dim(tab, 26, 1), _dim(tab, 26, 2))))
    return det, buf


@njit(cache=True)
def _no_contacts(count: int) -> tuple:
    z = np.zeros(0, dtype=np.int64)
    return count, z, z.copy(), z.copy(), z.copy(), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)


# -- the rows -------------------------------------------------------------------------------

@njit(cache=True)
def rotations(quat: np.ndarray) -> np.ndarray:
    """Return the principal-to-world matrices (n + 1, 3, 3), the world's (identity) last."""
    n = quat.shape[0]
    R = np.zeros((n + 1, 3, 3))
    for i in range(n):
        quat_matrix(quat[i], R[i])
    for a in range(3):
        R[n, a, a] = 1.0
    return R


@njit(cache=True)
def _cross(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> tuple:
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True)
def point_velocity(pos: np.ndarray, vel: np.ndarray, om: np.ndarray, R: np.ndarray, i: int,
                   p: np.ndarray) -> tuple:
    """Return the world velocity of point ``p`` on body ``i`` (the world: 0), and its lever."""
    n = pos.shape[0]
    if i >= n:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    r0, r1, r2 = p[0] - pos[i, 0], p[1] - pos[i, 1], p[2] - pos[i, 2]
    w0 = R[i, 0, 0] * om[i, 0] + R[i, 0, 1] * om[i, 1] + R[i, 0, 2] * om[i, 2]
    w1 = R[i, 1, 0] * om[i, 0] + R[i, 1, 1] * om[i, 1] + R[i, 1, 2] * om[i, 2]
    w2 = R[i, 2, 0] * om[i, 0] + R[i, 2, 1] * om[i, 1] + R[i, 2, 2] * om[i, 2]
    c0, c1, c2 = _cross(w0, w1, w2, r0, r1, r2)
    return vel[i, 0] + c0, vel[i, 1] + c1, vel[i, 2] + c2, r0, r1, r2


@njit(cache=True)
def rows(pos: np.ndarray, vel: np.ndarray, om: np.ndarray, R: np.ndarray, sel: np.ndarray,
         ba_all: np.ndarray, bb_all: np.ndarray, pt_all: np.ndarray, nr_all: np.ndarray,
         sa_all: np.ndarray, sb_all: np.ndarray, shape_mu: np.ndarray, shape_e: np.ndarray,
         rate: float, ba: np.ndarray, bb: np.ndarray) -> tuple:
    """
    Return the rows of contacts ``sel`` at the state, as ``ContactSteps.rows``.

    ``(frame, lever_a, lever_b, mu, e, sliding, vn, Ga, Gb)``; ``ba``, ``bb``: the
    contacts' bodies, ``ba_all[sel]`` and ``bb_all[sel]`` (the caller's, kept).

    ``frame`` (c, 3, 3) rows ``n, t₁, t₂``; ``Ga``, ``Gb`` (3c, 6): each row on body
    a's and body b's velocities (``v`` world, ``Ω`` principal; ``Gb`` zero for the world).
    """
    c = sel.shape[0]
    # (one allocation for the float arrays, each a C-contiguous run of it; every entry is
    # written below, G's by _jacobian_into)
    fl = np.empty(54 * c)
    frame = fl[:9 * c].reshape((c, 3, 3))
    la, lb = fl[9 * c:12 * c].reshape((c, 3)), fl[12 * c:15 * c].reshape((c, 3))
    mu, e, vn = fl[15 * c:16 * c], fl[16 * c:17 * c], fl[17 * c:18 * c]
    Ga, Gb = fl[18 * c:36 * c].reshape((3 * c, 6)), fl[36 * c:].reshape((3 * c, 6))
    sliding = np.zeros(c, dtype=np.bool_)
    for k in range(c):
        j = sel[k]
        p, nrm = pt_all[j], nr_all[j]
        va0, va1, va2, r0, r1, r2 = point_velocity(pos, vel, om, R, ba_all[j], p)
        la[k, 0], la[k, 1], la[k, 2] = r0, r1, r2
        vb0, vb1, vb2, r0, r1, r2 = point_velocity(pos, vel, om, R, bb_all[j], p)
        lb[k, 0], lb[k, 1], lb[k, 2] = r0, r1, r2
        v0, v1, v2 = va0 - vb0, va1 - vb1, va2 - vb2
        s = v0 * nrm[0] + v1 * nrm[1] + v2 * nrm[2]
        vn[k] = s
        t0, t1, t2 = v0 - s * nrm[0], v1 - s * nrm[1], v2 - s * nrm[2]
        speed = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        if speed > rate:
            sliding[k] = True
            t0, t1, t2 = t0 / speed, t1 / speed, t2 / speed
        else:
            t0, t1, t2 = any_tangent(nrm)
        frame[k, 0, 0], frame[k, 0, 1], frame[k, 0, 2] = nrm[0], nrm[1], nrm[2]
        frame[k, 1, 0], frame[k, 1, 1], frame[k, 1, 2] = t0, t1, t2
        x0, x1, x2 = _cross(nrm[0], nrm[1], nrm[2], t0, t1, t2)
        frame[k, 2, 0], frame[k, 2, 1], frame[k, 2, 2] = x0, x1, x2
        mu[k] = math.sqrt(shape_mu[sa_all[j]] * shape_mu[sb_all[j]])
        e[k] = max(shape_e[sa_all[j]], shape_e[sb_all[j]])
    _jacobian_into(frame, ba, bb, la, lb, R, pos.shape[0], Ga, Gb)
    return frame, la, lb, mu, e, sliding, vn, Ga, Gb


@njit(cache=True)
def any_tangent(nrm: np.ndarray) -> tuple:
    """Return a unit vector perpendicular to the unit ``nrm`` (as ``_any_tangent``)."""
    k = 0
    if abs(nrm[1]) < abs(nrm[k]):
        k = 1
    if abs(nrm[2]) < abs(nrm[k]):
        k = 2
    h0, h1, h2 = (1.0 if k == 0 else 0.0), (1.0 if k == 1 else 0.0), (1.0 if k == 2 else 0.0)
    t0, t1, t2 = _cross(nrm[0], nrm[1], nrm[2], h0, h1, h2)
    s = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    return t0 / s, t1 / s, t2 / s


@njit(cache=True)
def _jacobian_row(G: np.ndarray, row: int, sign: float, d0: float, d1: float, d2: float,
                  r0: float, r1: float, r2: float, R: np.ndarray, i: int) -> None:
    """Set ``G[row]``: the row of direction ``d`` at lever ``r`` on body ``i``, times ``sign``."""
    x0, x1, x2 = _cross(r0, r1, r2, d0, d1, d2)
    G[row, 0], G[row, 1], G[row, 2] = sign * d0, sign * d1, sign * d2
    for m in range(3):
        G[row, 3 + m] = sign * (R[i, 0, m] * x0 + R[i, 1, m] * x1 + R[i, 2, m] * x2)


@njit(cache=True)
def jacobian(frame: np.ndarray, ba: np.ndarray, bb: np.ndarray, la: np.ndarray,
             lb: np.ndarray, R: np.ndarray, n: int) -> tuple:
    """Return ``Ga``, ``Gb`` (3c, 6): row ``d``, lever ``r``: ``(d, Rᵀ (r × d))``, b's negated."""
    c = frame.shape[0]
    Ga, Gb = np.empty((3 * c, 6)), np.empty((3 * c, 6))
    _jacobian_into(frame, ba, bb, la, lb, R, n, Ga, Gb)
    return Ga, Gb


@njit(cache=True)
def _jacobian_into(frame: np.ndarray, ba: np.ndarray, bb: np.ndarray, la: np.ndarray,
                   lb: np.ndarray, R: np.ndarray, n: int, Ga: np.ndarray,
                   Gb: np.ndarray) -> None:
    """Write :func:`jacobian`'s ``Ga``, ``Gb`` into the given (3c, 6) arrays (the world's: 0)."""
    for k in range(frame.shape[0]):
        for side in range(2):
            i = ba[k] if side == 0 else bb[k]
            if i >= n:
                G = Ga if side == 0 else Gb
                for a in range(3):
                    for x in range(6):
                        G[3 * k + a, x] = 0.0
                continue
            r = la[k] if side == 0 else lb[k]
            G = Ga if side == 0 else Gb
            sign = 1.0 if side == 0 else -1.0
            for a in range(3):
                _jacobian_row(G, 3 * k + a, sign, frame[k, a, 0], frame[k, a, 1],
                              frame[k, a, 2], r[0], r[1], r[2], R, i)


@njit(cache=True)
def apply_rows(Ga: np.ndarray, Gb: np.ndarray, ba: np.ndarray, bb: np.ndarray,
               vel: np.ndarray, om: np.ndarray) -> np.ndarray:
    """Return ``G ν`` (3c,) for the bodies' velocities ``vel`` (world), ``om`` (principal)."""
    w = np.empty(Ga.shape[0])
    for row in range(Ga.shape[0]):
        w[row] = _row_rate(Ga, Gb, ba, bb, vel, om, row)
    return w


@njit(cache=True)
def _row_rate(Ga: np.ndarray, Gb: np.ndarray, ba: np.ndarray, bb: np.ndarray,
              vel: np.ndarray, om: np.ndarray, row: int) -> float:
    """Return :func:`apply_rows`' entry ``row``: its two bodies' sums (the world's: none)."""
    n = vel.shape[0]
    k = row // 3
    w = 0.0
    for side in range(2):
        i = ba[k] if side == 0 else bb[k]
        if i >= n:
            continue
        G = Ga if side == 0 else Gb
        s = 0.0
        for m in range(3):
            s += G[row, m] * vel[i, m] + G[row, 3 + m] * om[i, m]
        w += s
    return w


@njit(cache=True)
def delassus(Ga: np.ndarray, Gb: np.ndarray, ba: np.ndarray, bb: np.ndarray,
             minv: np.ndarray) -> tuple:
    """
    Return ``A = G M⁻¹ Gᵀ`` (3c, 3c) by its 3 × 3 blocks: ``(ptr, col, blk)``.

    ``minv`` (n, 6) per body ``1/m`` (3) and ``1/J`` (3). Only two contacts on a common
    body have a non-zero block (a pile's contact meets a dozen others, a stack's those of
    the interfaces next to it): contact ``k``'s are ``blk[ptr[k]:ptr[k + 1]]`` (3, 3),
    in the columns (contacts) ``col[ptr[k]:ptr[k + 1]]``, increasing. Storage and cost
    grow as the blocks, not as ``c²``: the contacts are first listed per body. Each
    entry is the dense product's to the bit (the same terms added in the same order).
    """
    n = minv.shape[0]
    c = ba.shape[0]
    # The contacts on each body, increasing: on_body[start[i]:start[i + 1]] (the work
    # arrays one allocation: start, fill, each contact's column count, on_body).
    work = np.empty(2 * n + 1 + 3 * c, dtype=np.int64)
    start, fill = work[:n + 1], work[n + 1:2 * n + 1]
    counts = work[2 * n + 1:2 * n + 1 + c]
    start[:] = 0
    for k in range(c):
        for side in range(2):
            i = ba[k] if side == 0 else bb[k]
            if i < n:
                start[i + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    on_body = work[2 * n + 1 + c:2 * n + 1 + c + start[n]]
    fill[:] = start[:n]
    for k in range(c):
        for side in range(2):
            i = ba[k] if side == 0 else bb[k]
            if i < n:
                on_body[fill[i]] = k
                fill[i] += 1
    # Each contact's columns: the merge of its two bodies' lists (counted, then filled;
    # ptr and col one allocation).
    total = 0
    for k in range(c):
        counts[k] = _merged(on_body, start, ba[k], bb[k], n, on_body[:0])
        total += counts[k]
    pc = np.empty(c + 1 + total, dtype=np.int64)
    ptr, col = pc[:c + 1], pc[c + 1:]
    ptr[0] = 0
    for k in range(c):
        ptr[k + 1] = ptr[k] + counts[k]
    blk = np.zeros((ptr[c], 3, 3))
    for k in range(c):
        _merged(on_body, start, ba[k], bb[k], n, col[ptr[k]:ptr[k + 1]])
        for e in range(ptr[k], ptr[k + 1]):
            m = col[e]
            for side_k in range(2):   # (the dense product's order: k's sides, then m's)
                i = ba[k] if side_k == 0 else bb[k]
                if i >= n:
                    continue
                Gk = Ga if side_k == 0 else Gb
                for side_m in range(2):
                    if (ba[m] if side_m == 0 else bb[m]) != i:
                        continue
                    Gm = Ga if side_m == 0 else Gb
                    for a in range(3):
                        r = 3 * k + a
                        for b in range(3):
                            s = 3 * m + b
                            acc = 0.0
                            for x in range(6):
                                acc += Gk[r, x] * minv[i, x] * Gm[s, x]
                            blk[e, a, b] += acc
    return ptr, col, blk


@njit(cache=True)
def _merged(on_body: np.ndarray, start: np.ndarray, i: int, j: int, n: int,
            out: np.ndarray) -> int:
    """
    Return how many contacts are on body ``i`` or ``j`` (``≥ n``: none); fill ``out``.

    ``out`` of its length takes them, increasing (the merge of the two bodies' lists of
    :func:`delassus`); an ``out`` of no length: counted only.
    """
    a0, a1 = (start[i], start[i + 1]) if i < n else (0, 0)
    b0, b1 = (start[j], start[j + 1]) if j < n else (0, 0)
    write = out.shape[0] > 0
    count = 0
    while a0 < a1 or b0 < b1:
        if b0 >= b1 or (a0 < a1 and on_body[a0] < on_body[b0]):
            v = on_body[a0]
            a0 += 1
        elif a0 >= a1 or on_body[b0] < on_body[a0]:
            v = on_body[b0]
            b0 += 1
        else:   # (on both bodies)
            v = on_body[a0]
            a0 += 1
            b0 += 1
        if write:
            out[count] = v
        count += 1
    return count


@njit(cache=True)
def blocks(A: np.ndarray) -> tuple:
    """Return a dense ``A`` (3c, 3c) as :func:`delassus`'s blocks: those with a non-zero."""
    c = A.shape[0] // 3
    nnz = 0
    for k in range(c):
        for m in range(c):
            if _block_nonzero(A, k, m):
                nnz += 1
    ptr = np.zeros(c + 1, dtype=np.int64)
    col = np.empty(nnz, dtype=np.int64)
    blk = np.zeros((nnz, 3, 3))
    e = 0
    for k in range(c):
        for m in range(c):
            if _block_nonzero(A, k, m):
                col[e] = m
                for a in range(3):
                    for b in range(3):
                        blk[e, a, b] = A[3 * k + a, 3 * m + b]
                e += 1
        ptr[k + 1] = e
    return ptr, col, blk


@njit(cache=True)
def _block_nonzero(A: np.ndarray, k: int, m: int) -> bool:
    for a in range(3):
        for b in range(3):
            if A[3 * k + a, 3 * m + b] != 0.0:
                return True
    return False


@njit(cache=True)
def block_affine(D: tuple, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Return ``A p + q`` of :func:`delassus`'s blocks ``D`` (each row's sum in column order)."""
    ptr, col, blk = D
    w = np.empty(3 * (ptr.shape[0] - 1))
    block_product(ptr, col, blk, 0.0, p, w)   # (+ 0 p: exact, p finite)
    for a in range(w.shape[0]):
        w[a] += q[a]
    return w


@njit(cache=True)
def response(Ga: np.ndarray, Gb: np.ndarray, ba: np.ndarray, bb: np.ndarray,
             minv: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Return the velocity change ``M⁻¹ Gᵀ p`` (n, 6) of impulses ``p`` (3c,)."""
    n = minv.shape[0]
    dv = np.zeros((n, 6))
    for row in range(Ga.shape[0]):
        if p[row] == 0.0:
            continue
        k = row // 3
        for side in range(2):
            i = ba[k] if side == 0 else bb[k]
            if i >= n:
                continue
            G = Ga if side == 0 else Gb
            for x in range(6):
                dv[i, x] += minv[i, x] * G[row, x] * p[row]
    return dv


# -- the box LCP ---------------------------------------------------------------------------

@njit(cache=True)
def solve_box(S: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray,
              start: np.ndarray, L: np.ndarray, order: np.ndarray, first: np.ndarray,
              meta: np.ndarray) -> tuple:
    """
    Return ``(f, converged, iterations)``: the BLCP by the primal active-set method.

    :func:`..complementarity.solve_direct`'s method, cap and rounding test, with three
    differences, in how an iteration's free rows' equations are solved and in how many
    rows it frees, not in the solution (unique: ``S`` definite):

    * the free rows' Cholesky factor is kept (``L`` (n, n), ``order`` its rows,
      ``first`` each row's first non-zero column, ``meta`` ``[rows, valid, updates]``)
      and updated as one row joins (:func:`_chol_append`, ``O(n²)``) or leaves
      (:func:`_chol_delete`, Givens rotations), where the method it follows factors
      every iteration (``O(n³)``); the caller may pass the factor of its last call
      (the friction boxes' fixed point calls this with the same ``S`` and nearly the
      same free rows), brought to this call's free rows the same way, or factored
      afresh where more than a quarter of them differ, or after ``n`` updates; a fresh
      factor takes its rows in reverse Cuthill–McKee order (:func:`envelope_order`), the
      factor's envelope (what its loops run over) a pile's few neighbours wide;
    * a solve that moves no row out of its box is refined once against ``S`` before it
      is taken (the factor's updates perturb it by rounding; one step of refinement
      brings the solution back to ``S``'s own);
    * at a solution of the free rows' equations, every bound row whose ``w`` has the
      wrong sign is freed at once, not the worst alone (warm-started from the last
      iteration of a fixed point, several rows' bounds moved). The objective still
      falls at every move of positive length; a freed row the coupled move would take
      out of its box at once is blocked at once (a move of length zero), and the last
      of them freed alone moves into its box (Nocedal & Wright, *Numerical
      Optimization*, 2006, §16.5): the method stays finite, with the same cap.

    A row whose box is a point (``lo = hi``) is held there, never freed. A pivot that
    rounding made non-positive drops the factor; that iteration solves by LAPACK's LU,
    the next factors afresh.
    """
    n = q.shape[0]
    work = np.empty((6, n))
    marks = np.empty((3, n), dtype=np.int64)
    pat = pattern(S)
    return _solve_box(S, q, lo, hi, start, L, order, first, meta, work, marks, pat,
                      envelope_order(pat))


@njit(cache=True)
def pattern(S: np.ndarray) -> np.ndarray:
    """
    Return the non-zero columns of each row of ``S`` (n, n), in one array ``pat``.

    Row ``i``'s columns, increasing, are ``pat[pat[i]:pat[i + 1]]`` (the first ``n + 1``
    entries point into the rest). A pile's contact meets a dozen others, so most of a
    large island's row is zero: the box LCP's sums over rows run over these alone.
    """
    n = S.shape[0]
    nnz = 0
    for i in range(n):
        for j in range(n):
            if S[i, j] != 0.0:
                nnz += 1
    pat = np.empty(n + 1 + nnz, dtype=np.int64)
    at = n + 1
    for i in range(n):
        pat[i] = at
        for j in range(n):
            if S[i, j] != 0.0:
                pat[at] = j
                at += 1
    pat[n] = at
    return pat


@njit(cache=True)
def envelope_order(pat: np.ndarray) -> np.ndarray:
    """
    Return the rows of :func:`pattern` ``pat``'s matrix in reverse Cuthill–McKee order.

    Breadth first from a row of least degree in each connected part, each row's rows not
    yet met taken by increasing degree (ties: the lower row), and the whole reversed
    (Cuthill & McKee 1969, reversed by George 1971). The box solves factor their free
    rows in this order (:func:`_refactor`): a Cholesky factor's envelope is then the
    width of the contact graph's levels, a few contacts in a pile, where in the rows'
    own order (the detector's) it spans most of an island.
    """
    n = pat[0] - 1
    if pat[n] - pat[0] == n * n:
        # Dense (a box's four contacts, any small island): every row of degree n, so the
        # order is 0, 1, …, n − 1 (the first row, then the others by row), reversed.
        dense = np.empty(n, dtype=np.int64)
        for i in range(n):
            dense[i] = n - 1 - i
        return dense
    deg = np.empty(n, dtype=np.int64)
    for i in range(n):
        deg[i] = pat[i + 1] - pat[i]
    seen = np.zeros(n, dtype=np.bool_)
    out = np.empty(n, dtype=np.int64)
    head, tail = 0, 0
    while tail < n:
        s = -1
        for i in range(n):
            if not seen[i] and (s < 0 or deg[i] < deg[s]):
                s = i
        seen[s] = True
        out[tail] = s
        tail += 1
        while head < tail:
            v = out[head]
            head += 1
            t0 = tail
            for t in range(pat[v], pat[v + 1]):
                u = pat[t]
                if not seen[u]:
                    seen[u] = True
                    out[tail] = u
                    tail += 1
            for a in range(t0 + 1, tail):   # (by degree, then row: an insertion sort)
                x = out[a]
                b = a - 1
                while b >= t0 and (deg[out[b]] > deg[x]
                                   or (deg[out[b]] == deg[x] and out[b] > x)):
                    out[b + 1] = out[b]
                    b -= 1
                out[b + 1] = x
    return out[::-1].copy()


@njit(cache=True)
def _solve_box(S: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               start: np.ndarray, L: np.ndarray, order: np.ndarray, first: np.ndarray,
               meta: np.ndarray, work: np.ndarray, marks: np.ndarray,
               pat: np.ndarray, perm: np.ndarray) -> tuple:
    """
    Return :func:`solve_box` with its work arrays passed: ``work`` (6, n), ``marks`` (3, n).

    The returned ``f`` is ``work[0]`` (a view: the caller copies what it keeps). The free
    rows' right sides ``q_i + Σ_bound S_ij f_j`` (``rb``, by row) are kept from one
    iteration to the next: a row meeting its bound adds its term to each free row's
    (``O(free)``, not ``O(free × bound)``), a row freed takes its term out and gets its
    own; they are computed afresh at each call and each fresh factor. ``pat``:
    :func:`pattern` of ``S`` (symmetric): every sum over a row of ``S`` (the right sides,
    the refinement's residual, the bound rows' ``w``) and every update of the right
    sides runs over its non-zeros alone, in increasing column (the sums the dense loops
    formed, but for the refinement's, whose order of terms is the columns', not the
    factor's). ``perm``: the order a fresh factor takes its free rows in
    (:func:`envelope_order` of ``pat``).
    """
    n = q.shape[0]
    f, rhs, x, r, target, rb = work[0], work[1], work[2], work[3], work[4], work[5]
    state, bound, inside = marks[0], marks[1], marks[2]
    for i in range(n):
        x0 = start[i] if math.isfinite(start[i]) else 0.0
        f[i] = min(max(x0, lo[i]), hi[i])
        state[i] = AT_LOWER if f[i] <= lo[i] else (AT_UPPER if f[i] >= hi[i] else FREE)
    nfree = 0
    for i in range(n):
        if state[i] == FREE:
            nfree += 1
    # The last call's factor, brought to this call's free rows (or factored afresh).
    fresh = meta[1] == 0
    if not fresh:
        keep = 0
        for a in range(meta[0]):
            if state[order[a]] == FREE:
                keep += 1
        changes = (meta[0] - keep) + (nfree - keep)
        fresh = 4 * changes > nfree + 4 or meta[2] + changes > n
    if not fresh:
        a = meta[0] - 1
        while a >= 0:
            if state[order[a]] != FREE:
                _chol_delete(L, first, order, meta[0], a)
                meta[0] -= 1
                meta[2] += 1
            a -= 1
        for i in range(n):
            inside[i] = 0
        for a in range(meta[0]):
            inside[order[a]] = 1
        for i in range(n):
            if state[i] == FREE and inside[i] == 0:
                if _chol_append(S, order, meta[0], i, L, first):
                    meta[0] += 1
                    meta[2] += 1
                else:
                    fresh = True
                    break
    if fresh:
        _refactor(S, state, L, order, first, meta, perm)
    cap = 10 * (n + 1)
    stale = True
    for it in range(1, cap + 1):
        if meta[1] == 0 and it > 1:
            _refactor(S, state, L, order, first, meta, perm)
            stale = True
        nf = meta[0]
        nb = 0
        for j in range(n):
            if state[j] != FREE:
                bound[nb] = j
                nb += 1
        for i in range(n):
            target[i] = f[i]
        hit, at, best, side = -1, -1, np.inf, FREE
        if nf:
            if stale:
                for a in range(nf):
                    i = order[a]
                    s = q[i]
                    for t in range(pat[i], pat[i + 1]):
                        j = pat[t]
                        if state[j] != FREE:
                            s += S[i, j] * f[j]
                    rb[i] = s
                stale = False
            for a in range(nf):
                rhs[a] = -rb[order[a]]
            if meta[1]:
                _chol_solve(L, first, nf, rhs, x)
            else:
                Sf = np.empty((nf, nf))
                for a in range(nf):
                    for b in range(nf):
                        Sf[a, b] = S[order[a], order[b]]
                x[:nf] = np.linalg.solve(Sf, rhs[:nf])
            for a in range(nf):
                target[order[a]] = x[a]
            hit, at, best, side = _blocking(order, nf, target, f, lo, hi)
            if hit < 0 and meta[1]:
                # The step ends here: refined once against S (the updates' rounding
                # taken out), and its blocking looked at again.
                for a in range(nf):
                    i = order[a]
                    s = rhs[a]
                    for t in range(pat[i], pat[i + 1]):
                        j = pat[t]
                        if state[j] == FREE:
                            s -= S[i, j] * target[j]
                    r[a] = s
                _chol_solve(L, first, nf, r, r)
                for a in range(nf):
                    target[order[a]] = x[a] + r[a]
                hit, at, best, side = _blocking(order, nf, target, f, lo, hi)
        if hit >= 0:
            alpha = min(max(best, 0.0), 1.0)
            for a in range(nf):
                i = order[a]
                f[i] += alpha * (target[i] - f[i])
            f[hit] = lo[hit] if side == AT_LOWER else hi[hit]
            state[hit] = side
            for i in range(n):
                f[i] = min(max(f[i], lo[i]), hi[i])
            if meta[1]:
                _chol_delete(L, first, order, nf, at)
            else:
                order[at:nf - 1] = order[at + 1:nf].copy()
            meta[0] -= 1
            meta[2] += 1
            # (its term joins the free rows' right sides)
            for t in range(pat[hit], pat[hit + 1]):
                j = pat[t]
                if state[j] == FREE:
                    rb[j] += S[j, hit] * f[hit]
            continue
        for i in range(n):
            f[i] = target[i]
        # Every bound row whose w has the wrong sign (beyond its rounding) is freed.
        freed = 0
        nf0 = meta[0]
        for b in range(nb):
            i = bound[b]
            if not hi[i] > lo[i]:
                continue
            w, mag = q[i], abs(q[i])
            for t in range(pat[i], pat[i + 1]):
                j = pat[t]
                w += S[i, j] * f[j]
                mag += abs(S[i, j]) * abs(f[j])
            wrong = -w if state[i] == AT_LOWER else w
            if wrong > ROUNDING_ULPS * EPS * mag:
                state[i] = FREE
                freed += 1
                # (its term leaves the free rows' right sides)
                for t in range(pat[i], pat[i + 1]):
                    j = pat[t]
                    if state[j] == FREE and j != i:
                        rb[j] -= S[j, i] * f[i]
                if meta[1] and _chol_append(S, order, meta[0], i, L, first):
                    meta[2] += 1
                else:
                    order[meta[0]] = i
                    meta[1] = 0
                meta[0] += 1
        if freed == 0:
            return f, True, it
        # The freed rows' own right sides.
        for a in range(nf0, meta[0]):
            j = order[a]
            s = q[j]
            for t in range(pat[j], pat[j + 1]):
                k = pat[t]
                if state[k] != FREE:
                    s += S[j, k] * f[k]
            rb[j] = s
    return f, False, cap


@njit(cache=True)
def _blocking(order: np.ndarray, nf: int, target: np.ndarray, f: np.ndarray, lo: np.ndarray,
              hi: np.ndarray) -> tuple:
    """
    Return ``(row, at, ratio, side)``: the free row a move from ``f`` to ``target`` meets first.

    The smallest ratio of the distance to a bound over the move (ties: the lowest row;
    ``row`` −1: none leaves its box); ``at`` its place in ``order``, ``side`` the bound.
    """
    hit, at, best, side = -1, -1, np.inf, FREE
    for a in range(nf):
        i = order[a]
        step = target[i] - f[i]
        if target[i] < lo[i]:
            ratio = (lo[i] - f[i]) / step
            if ratio < best or hit < 0 or (ratio == best and i < hit):
                hit, at, best, side = i, a, ratio, AT_LOWER
        elif target[i] > hi[i]:
            ratio = (hi[i] - f[i]) / step
            if ratio < best or hit < 0 or (ratio == best and i < hit):
                hit, at, best, side = i, a, ratio, AT_UPPER
    return hit, at, best, side


@njit(cache=True)
def _refactor(S: np.ndarray, state: np.ndarray, L: np.ndarray, order: np.ndarray,
              first: np.ndarray, meta: np.ndarray, perm: np.ndarray) -> None:
    """Factor the free rows (``state`` FREE, in ``perm``'s order) afresh into ``L``, ``meta``."""
    nf = 0
    for a in range(perm.shape[0]):
        i = perm[a]
        if state[i] == FREE:
            order[nf] = i
            nf += 1
    meta[0], meta[2] = nf, 0
    meta[1] = 1 if _chol_factor(S, order, nf, L, first) else 0


@njit(cache=True)
def _chol_factor(S: np.ndarray, order: np.ndarray, nf: int, L: np.ndarray,
                 first: np.ndarray) -> bool:
    """
    Factor ``S[order, order]`` (its first ``nf``) as ``L Lᵀ``: False at a non-positive pivot.

    ``L`` keeps each row's envelope (from ``first``, its first non-zero column: a stack's
    rows are banded); what lies before it is never read.
    """
    for a in range(nf):
        i = order[a]
        first[a] = a
        for b in range(a):
            if S[i, order[b]] != 0.0:
                first[a] = b
                break
        for b in range(first[a], a + 1):
            L[a, b] = S[i, order[b]]
    for j in range(nf):
        d = L[j, j]
        for k in range(first[j], j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, nf):
            if first[i] > j:
                continue
            s = L[i, j]
            for k in range(max(first[i], first[j]), j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    return True


@njit(cache=True)
def _chol_append(S: np.ndarray, order: np.ndarray, nf: int, i: int, L: np.ndarray,
                 first: np.ndarray) -> bool:
    """
    Append row ``i`` to the factor of ``S[order[:nf], order[:nf]]`` (row ``nf`` of ``L``).

    Its row of ``L`` solves ``L l = S[order, i]`` (forward, from its first non-zero), its
    pivot ``√(S_ii − lᵀl)``; False where that is not positive (the factor left as it was).
    """
    f0 = nf
    for b in range(nf):
        if S[i, order[b]] != 0.0:
            f0 = b
            break
    d = S[i, i]
    for b in range(f0, nf):
        s = S[i, order[b]]
        for k in range(max(f0, first[b]), b):
            s -= L[nf, k] * L[b, k]
        s /= L[b, b]
        L[nf, b] = s
        d -= s * s
    if not d > 0.0:
        return False
    L[nf, nf] = math.sqrt(d)
    first[nf], order[nf] = f0, i
    return True


@njit(cache=True)
def _chol_delete(L: np.ndarray, first: np.ndarray, order: np.ndarray, nf: int, at: int) -> None:
    """
    Take row ``at`` out of an ``nf``-row factor ``L Lᵀ``: the rest factor the rest.

    The rows below move up one; each then reaches one column past its diagonal, which
    Givens rotations of columns ``(j, j + 1)``, ``j = at …``, take out (``L Q`` keeps
    ``L Lᵀ``): ``O((nf − at)²)``. A row whose envelope began at ``j + 1`` gains column ``j``.
    """
    for r in range(at, nf - 1):
        order[r] = order[r + 1]
        fr = first[r + 1]
        for k in range(fr, r + 2):
            L[r, k] = L[r + 1, k]
        first[r] = fr
    for j in range(at, nf - 1):
        if first[j] > j:   # (its diagonal moved up from j + 1: nothing left of it)
            L[j, j] = 0.0
            first[j] = j
        a, b = L[j, j], L[j, j + 1]
        h = math.hypot(a, b)
        c, s = a / h, b / h
        L[j, j], L[j, j + 1] = h, 0.0
        for r in range(j + 1, nf - 1):
            if first[r] > j + 1:
                continue
            if first[r] == j + 1:
                L[r, j] = 0.0
                first[r] = j
            x, y = L[r, j], L[r, j + 1]
            L[r, j] = c * x + s * y
            L[r, j + 1] = c * y - s * x


@njit(cache=True)
def _chol_solve(L: np.ndarray, first: np.ndarray, nf: int, b: np.ndarray,
                x: np.ndarray) -> None:
    """Set ``x[:nf]`` to ``(L Lᵀ)⁻¹ b[:nf]`` (``x`` may be ``b``), over ``L``'s envelopes."""
    for a in range(nf):
        s = b[a]
        for k in range(first[a], a):
            s -= L[a, k] * x[k]
        x[a] = s / L[a, a]
    for a in range(nf - 1, -1, -1):
        x[a] /= L[a, a]
        xa = x[a]
        for k in range(first[a], a):
            x[k] -= L[a, k] * xa


@njit(cache=True)
def islands(D: tuple) -> tuple:
    """
    Return ``(label, count)``: each contact's island, as :func:`..contact_step.islands`.

    Contacts joined by a block of :func:`delassus`'s ``D`` with a non-zero (either way);
    islands numbered by their first contact. Union–find over the blocks: ``O(blocks)``.
    """
    ptr, col, blk = D
    c = ptr.shape[0] - 1
    work = np.empty(2 * c, dtype=np.int64)   # (parent and label: one allocation)
    parent, label = work[:c], work[c:]
    for k in range(c):
        parent[k] = k
    for k in range(c):
        for e in range(ptr[k], ptr[k + 1]):
            j = col[e]
            if j == k:
                continue
            joined = False
            for a in range(3):
                for b in range(3):
                    if blk[e, a, b] != 0.0:
                        joined = True
            if joined:
                rk, rj = k, j
                while parent[rk] != rk:
                    rk = parent[rk]
                while parent[rj] != rj:
                    rj = parent[rj]
                if rk != rj:
                    parent[max(rk, rj)] = min(rk, rj)
    label[:] = -1
    count = 0
    for k in range(c):
        r = k
        while parent[r] != r:
            r = parent[r]
        if label[r] < 0:
            label[r] = count
            count += 1
        label[k] = label[r]
    return label, count


@njit(cache=True)
def solve_rows(D: tuple, q: np.ndarray, mu: np.ndarray, start: np.ndarray,
               normal_only: bool, equal: np.ndarray, has_equal: bool, sliding: np.ndarray,
               prm: np.ndarray, cnt: np.ndarray) -> tuple:
    """
    Return ``(p, ok)``: :func:`solve_island` on each island (``ContactSteps.solve``).

    ``D``: the rows' operator by its blocks (:func:`delassus`). Each island's symmetric
    part (``normal_only``: of its normal rows alone) is gathered from its blocks straight
    into the dense matrix its solve factors, ``O(blocks)`` beside that matrix's zeroing.
    """
    # (Its arguments, alive for the call, passed on uncounted; p is a new array.)
    D, q, mu, start, equal, sliding = raw_tree((D, q, mu, start, equal, sliding))
    ptr, col, blk = D
    c = ptr.shape[0] - 1
    m = q.shape[0]
    step3 = 1 if normal_only else 3
    if c == 1:   # (one contact: one island, no union-find's array)
        label, count = ptr[:1], 1
    else:
        label, count = islands(D)
    if count == 0:   # (no rows: the empty solve, counted as the Python path's)
        return solve_island(np.zeros((0, 0)), np.zeros(0), mu, np.zeros(0), normal_only,
                            equal, has_equal, sliding, prm, cnt)
    if count == 1 and not normal_only and c <= prm[P_SPARSE_CONTACTS]:
        # One island of every contact (a body on the ground, a stack): the general path
        # below with the identity for its index arrays, which it does not make (five
        # allocations fewer, and the island's solution is the rows' own).
        Ar = np.zeros((m, m))
        for k in range(c):
            for e in range(ptr[k], ptr[k + 1]):
                _gather_block(Ar, blk, e, k, col[e], 3)
        return solve_island(Ar, q, mu, start, normal_only, equal, has_equal, sliding, prm, cnt)
    # The contacts of each island, increasing: members[begin[g]:begin[g + 1]].
    begin = np.zeros(count + 1, dtype=np.int64)
    for k in range(c):
        begin[label[k] + 1] += 1
    for g in range(count):
        begin[g + 1] += begin[g]
    members = np.empty(c, dtype=np.int64)
    fill = begin[:count].copy()
    at = np.empty(c, dtype=np.int64)   # each contact's place in its island
    for k in range(c):
        g = label[k]
        members[fill[g]] = k
        at[k] = fill[g] - begin[g]
        fill[g] += 1
    out = np.zeros(m)
    for g in range(count):
        idx = members[begin[g]:begin[g + 1]]
        n = idx.shape[0]
        if n > prm[P_SPARSE_CONTACTS]:   # (too large to factor: by its blocks alone)
            p, ok = solve_large_island(_island_blocks(D, idx, label, at, g, normal_only),
                                       q, mu[idx], start, idx, normal_only, equal[idx],
                                       has_equal, sliding[idx], prm, cnt)
            if not ok:
                return np.zeros(m), False
            for x in range(n):
                for a in range(step3):
                    out[3 * idx[x] + a] = p[3 * x + a]
            continue
        nr = step3 * n
        # A_sym = (A + Aᵀ) / 2, gathered block by block (_gather_block).
        Ar = np.zeros((nr, nr))
        qr = np.empty(nr)
        sr = np.empty(nr)
        for x in range(n):
            k = idx[x]
            for a in range(step3):
                qr[step3 * x + a] = q[3 * k + a]
                sr[step3 * x + a] = start[3 * k + a]
            for e in range(ptr[k], ptr[k + 1]):
                if label[col[e]] != g:   # (a block of zeros)
                    continue
                _gather_block(Ar, blk, e, x, at[col[e]], step3)
        p, ok = solve_island(Ar, qr, mu[idx], sr, normal_only, equal[idx], has_equal,
                             sliding[idx], prm, cnt)
        if not ok:
            return np.zeros(m), False
        for x in range(n):
            for a in range(step3):
                out[3 * idx[x] + a] = p[step3 * x + a]
    return out, True


@njit(cache=True)
def _gather_block(Ar: np.ndarray, blk: np.ndarray, e: int, x: int, z: int, step3: int) -> None:
    """
    Add half of block ``e`` and half of its transpose to the dense ``Ar``.

    The block's rows are contact ``x``'s, its columns ``z``'s (their first ``step3``;
    ``Ar`` has ``step3`` rows a contact): ``(A + Aᵀ) / 2`` gathered block by block
    (halving is exact: the same values as halving the sum).
    """
    for a in range(step3):
        for b in range(step3):
            v = 0.5 * blk[e, a, b]
            Ar[step3 * x + a, step3 * z + b] += v
            Ar[step3 * z + b, step3 * x + a] += v


@njit(cache=True)
def _island_blocks(D: tuple, idx: np.ndarray, label: np.ndarray, at: np.ndarray, g: int,
                   normal_only: bool) -> tuple:
    """
    Return island ``g``'s symmetric part ``(A + Aᵀ) / 2`` by its blocks ``(ptr, col, blk)``.

    Its contacts ``idx`` (increasing; ``at`` each contact's place in its island) numbered
    by their place; each entry the dense path's (:func:`solve_rows`: the halves of a
    block and of its transpose added). ``normal_only``: the normal rows' entries alone,
    the friction rows' zero.
    """
    ptr, col, blk = D
    n = idx.shape[0]
    sptr = np.zeros(n + 1, dtype=np.int64)
    for x in range(n):
        k = idx[x]
        inside = 0
        for e in range(ptr[k], ptr[k + 1]):
            if label[col[e]] == g:
                inside += 1
        sptr[x + 1] = sptr[x] + inside
    scol = np.empty(sptr[n], dtype=np.int64)
    sblk = np.zeros((sptr[n], 3, 3))
    for x in range(n):
        k = idx[x]
        e2 = sptr[x]
        for e in range(ptr[k], ptr[k + 1]):
            j = col[e]
            if label[j] != g:   # (a block of zeros)
                continue
            # The block (j, k): contact j's columns increase, so by bisection.
            lo, hi = ptr[j], ptr[j + 1] - 1
            while lo < hi:
                mid = (lo + hi) // 2
                if col[mid] < k:
                    lo = mid + 1
                else:
                    hi = mid
            scol[e2] = at[j]
            for a in range(1 if normal_only else 3):
                for b in range(1 if normal_only else 3):
                    sblk[e2, a, b] = 0.5 * blk[e, a, b] + 0.5 * blk[lo, b, a]
            e2 += 1
    return sptr, scol, sblk


@njit(cache=True)
def _block_scale(ptr: np.ndarray, col: np.ndarray, blk: np.ndarray, q: np.ndarray,
                 p: np.ndarray) -> float:
    """Return :func:`_row_scale` of an operator by its blocks: the largest ``|A| |p| + |q|``."""
    out = 0.0
    for k in range(ptr.shape[0] - 1):
        for a in range(3):
            acc = abs(q[3 * k + a])
            for e in range(ptr[k], ptr[k + 1]):
                for b in range(3):
                    acc += abs(blk[e, a, b]) * abs(p[3 * col[e] + b])
            out = max(out, acc)
    return out


@njit(cache=True)
def _block_residual(ptr: np.ndarray, col: np.ndarray, blk: np.ndarray, diag: np.ndarray,
                    q: np.ndarray, p: np.ndarray, mu: np.ndarray, normal_only: bool,
                    sliding: np.ndarray, tol: float, equal: np.ndarray,
                    has_equal: bool) -> float:
    """Return :func:`residual` of an operator by its blocks (three rows a contact)."""
    w = np.empty(q.shape[0])
    block_product(ptr, col, blk, 0.0, p, w)
    for a in range(w.shape[0]):
        w[a] += q[a]
    if not normal_only:
        return _residual(w, diag, q, p, mu, False, sliding, tol, equal, has_equal)
    c = q.shape[0] // 3   # (the normal rows alone, one a contact)
    wn, dn, qn, pn = np.empty(c), np.empty(c), np.empty(c), np.empty(c)
    for k in range(c):
        wn[k], dn[k], qn[k], pn[k] = w[3 * k], diag[3 * k], q[3 * k], p[3 * k]
    return _residual(wn, dn, qn, pn, mu, True, sliding, tol, equal, has_equal)


@njit(cache=True)
def _friction_boxes(p: np.ndarray, mu: np.ndarray, sliding: np.ndarray, normal_only: bool,
                    lo: np.ndarray, hi: np.ndarray) -> None:
    """Set the friction rows' boxes ``±μ max(p_n, 0)`` (sliding: the second row's zero)."""
    for k in range(mu.shape[0]):
        half = 0.0 if normal_only else mu[k] * max(p[3 * k], 0.0)
        for col in range(1, 3):
            half_a = 0.0 if col == 2 and sliding[k] else half
            lo[3 * k + col], hi[3 * k + col] = -half_a, half_a


@njit(cache=True)
def solve_large_island(B: tuple, q: np.ndarray, mu: np.ndarray, start: np.ndarray,
                       idx: np.ndarray, normal_only: bool, equal: np.ndarray, has_equal: bool,
                       sliding: np.ndarray, prm: np.ndarray, cnt: np.ndarray) -> tuple:
    """
    Return ``(p, ok)``: an island too large to factor, by its blocks alone.

    ``B`` the island's symmetric operator by its blocks (:func:`_island_blocks`); ``q``,
    ``start`` all the rows' (the island's contacts ``idx``); ``mu``, ``equal``,
    ``sliding`` the island's; ``p`` its rows, three a contact (``normal_only``: the
    friction rows zero). The friction boxes' proximal fixed point as :func:`solve_island`,
    each iteration's box QP of ``A + ρ I`` by MPRGP (:func:`.sparse_box.mprgp`) to a
    tolerance tied to the iteration's last change (its error in ``p`` is at most the
    tolerance over ``ρ``), with ``ρ`` ``P_SPARSE_PROXIMAL`` of the largest diagonal (the
    dense path's ``P_PROXIMAL`` lets the fixed point diverge on a tall pile, whose fixed
    boxes leave directions only ``ρ`` bounds). It ends when the contact conditions hold
    to ``P_SPARSE_RESIDUAL`` of the rows' velocity scale (:func:`residual`, on the
    blocks); if ``P_SPARSE_ITERATIONS`` do not reach that, projected Gauss–Seidel on the
    blocks goes on from the iterate (``P_PGS_SWEEPS`` sweeps, counted ``C_PGS``), and
    what it leaves is a counted failure. ``ok`` False: a row no impulse moves (given back,
    as :func:`solve_island`).
    """
    ptr, col, blk = B
    n = idx.shape[0]
    nr = 3 * n
    diag = np.zeros(nr)
    for x in range(n):
        for e in range(ptr[x], ptr[x + 1]):
            if col[e] == x:
                for a in range(3):
                    diag[3 * x + a] = blk[e, a, a]
    dmax = 0.0
    for a in range(nr):
        dmax = max(dmax, diag[a])
    for a in range(nr):
        if (not normal_only or a % 3 == 0) and not diag[a] > 1e-12 * dmax:
            return np.zeros(nr), False
    qr, p, lo, hi, qp = np.empty(nr), np.empty(nr), np.empty(nr), np.empty(nr), np.empty(nr)
    for x in range(n):
        for a in range(3):
            qr[3 * x + a] = q[3 * idx[x] + a]
            p[3 * x + a] = 0.0 if normal_only and a else start[3 * idx[x] + a]
        lo[3 * x], hi[3 * x] = (-np.inf if has_equal and equal[x] else 0.0), np.inf
    qmax = 0.0
    for a in range(nr):
        qmax = max(qmax, abs(qr[a]))
    rho = prm[P_SPARSE_PROXIMAL] * dmax
    tol = prm[P_FRICTION_TOLERANCE]
    count = not has_equal
    cap = int(prm[P_SPARSE_INNER])
    last = qmax / dmax   # (the impulses' scale before the first change)
    converged, res, it = False, np.inf, 0
    # Anderson's acceleration of the fixed point p ↦ F(p) (F: the boxes set at p, the
    # proximal box QP solved): the last ``depth`` iterates and their images.
    depth = int(prm[P_SPARSE_HISTORY])
    X, FX = np.empty((depth + 1, nr)), np.empty((depth + 1, nr))
    held = 0
    while it < int(prm[P_SPARSE_ITERATIONS]):
        it += 1
        _friction_boxes(p, mu, sliding, normal_only, lo, hi)
        for a in range(nr):
            p[a] = min(max(p[a], lo[a]), hi[a])
            qp[a] = qr[a] - rho * p[a]
        target = prm[P_SPARSE_RESIDUAL] * _block_scale(ptr, col, blk, qr, p)
        f, _, _, _ = mprgp(ptr, col, blk, rho, qp, lo, hi, p, max(0.25 * target, 0.1 * rho *
                                                                  last), cap)
        last = 0.0
        for a in range(nr):
            last = max(last, abs(f[a] - p[a]))
        res = _block_residual(ptr, col, blk, diag, qr, f, mu, normal_only, sliding, tol,
                              equal, has_equal)
        if depth > 0:
            if held == depth + 1:
                for j in range(depth):
                    X[j], FX[j] = X[j + 1], FX[j + 1]
            else:
                held += 1
            X[held - 1], FX[held - 1] = p, f
            if held > 1:
                cand = _anderson(X[:held], FX[:held])
                _into_boxes(cand, lo, mu, sliding, normal_only)
                r_cand = _block_residual(ptr, col, blk, diag, qr, cand, mu, normal_only,
                                         sliding, tol, equal, has_equal)
                if r_cand < res:   # (kept only where it is nearer a solution)
                    f, res = cand, r_cand
        for a in range(nr):
            p[a] = f[a]
        if res <= prm[P_SPARSE_RESIDUAL] * _block_scale(ptr, col, blk, qr, p):
            converged = True
            break
    if not converged:
        cnt[C_PGS] += 1
        sweeps = int(prm[P_PGS_SWEEPS])
        for sweep in range(sweeps):
            _pgs_sweep(ptr, col, blk, diag, qr, p, mu, sliding, normal_only, lo)
            if sweep % 10 == 9 or sweep == sweeps - 1:
                res = _block_residual(ptr, col, blk, diag, qr, p, mu, normal_only, sliding,
                                      tol, equal, has_equal)
                if res <= prm[P_SPARSE_RESIDUAL] * _block_scale(ptr, col, blk, qr, p):
                    converged = True
                    break
    cnt[C_SOLVES] += 1
    cnt[C_SPARSE] += 1
    cnt[C_ITERATIONS_MAX] = max(cnt[C_ITERATIONS_MAX], it)
    if not converged:
        cnt[C_FAILURES] += 1
    if count:
        cnt[C_COMPLEMENTARITY] = max(cnt[C_COMPLEMENTARITY], res)
    return p, True


@njit(cache=True)
def _anderson(X: np.ndarray, FX: np.ndarray) -> np.ndarray:
    """
    Return Anderson's extrapolation of the fixed point's last iterates ``X`` and images ``FX``.

    ``F(x_k) − Σ γ_j ΔF_j`` with ``γ`` the least-squares fit of the residuals' differences
    ``Δ(F(x) − x)`` to the last residual (Walker and Ni, SIAM J. Numer. Anal. 49, 2011);
    the last image itself where that fit fails.
    """
    k, n = X.shape[0] - 1, X.shape[1]
    dG, dF = np.empty((n, k)), np.empty((n, k))
    g = np.empty(n)
    for i in range(n):
        g[i] = FX[k, i] - X[k, i]
        for j in range(k):
            dG[i, j] = (FX[j + 1, i] - X[j + 1, i]) - (FX[j, i] - X[j, i])
            dF[i, j] = FX[j + 1, i] - FX[j, i]
    out = FX[k].copy()
    try:
        gamma = np.linalg.lstsq(dG, g)[0]
    except Exception:   # (LAPACK's SVD did not converge: no extrapolation)
        return out
    for i in range(n):
        for j in range(k):
            out[i] -= dF[i, j] * gamma[j]
    return out


@njit(cache=True)
def _into_boxes(p: np.ndarray, lo: np.ndarray, mu: np.ndarray, sliding: np.ndarray,
                normal_only: bool) -> None:
    """Project ``p`` into the contact rows' boxes: normals above ``lo``, friction ``±μ p_n``."""
    for k in range(mu.shape[0]):
        p[3 * k] = max(p[3 * k], lo[3 * k])
        half = 0.0 if normal_only else mu[k] * max(p[3 * k], 0.0)
        for col in range(1, 3):
            half_a = 0.0 if col == 2 and sliding[k] else half
            p[3 * k + col] = min(max(p[3 * k + col], -half_a), half_a)


@njit(cache=True)
def _pgs_sweep(ptr: np.ndarray, col: np.ndarray, blk: np.ndarray, diag: np.ndarray,
               q: np.ndarray, p: np.ndarray, mu: np.ndarray, sliding: np.ndarray,
               normal_only: bool, lo: np.ndarray) -> None:
    """
    Take one projected Gauss–Seidel sweep of the contact rows on their blocks, in place.

    Each row in turn moved to where its velocity ``w = A p + q`` vanishes, projected into
    its box (the normal rows' lower bounds ``lo``; the friction rows' ``±μ p_n`` at the
    sweep's own ``p_n``).
    """
    for x in range(ptr.shape[0] - 1):
        for a in range(1 if normal_only else 3):
            i = 3 * x + a
            w = q[i]
            for e in range(ptr[x], ptr[x + 1]):
                for b in range(3):
                    w += blk[e, a, b] * p[3 * col[e] + b]
            v = p[i] - w / diag[i]
            if a == 0:
                p[i] = max(v, lo[i])
            else:
                half = 0.0 if a == 2 and sliding[x] else mu[x] * max(p[3 * x], 0.0)
                p[i] = min(max(v, -half), half)


#: :func:`pattern` of a dense 3 × 3 matrix (:func:`_one_contact`).
_DENSE3 = np.array([4, 7, 10, 13, 0, 1, 2, 0, 1, 2, 0, 1, 2], dtype=np.int64)


@njit(cache=True)
def _one_contact(A: np.ndarray, q: np.ndarray, mu: float, sliding: bool, prm: np.ndarray,
                 cnt: np.ndarray) -> tuple:
    """
    Return ``(p, ok)``: one contact's three rows solved exactly, by their cases.

    The cases: apart (``p = 0``, where ``q_n ≥ 0``), and pressed (``w_n = 0``) with
    each friction row inside its bound (``w_t = 0``) or on it (``p_t = ±μ p_n``,
    ``w_t`` opposing it; ``sliding``: ``t₂`` held at zero). Each is a linear system
    of at most three unknowns (Cramer's rule). Of those whose impulses meet the
    contact conditions to :data:`RESIDUAL_TOLERANCE` of the rows' scale
    (:func:`residual`, the fixed point's own exit) the one of least normal impulse is
    taken: a large ``μ`` with the friction rows coupled to the normal one through
    the lever can admit two (a body pressed and sticking, or barely pressed and
    sliding on the pyramid's corner), where the fixed point from zero reaches the
    least (measured on random contacts). ``ok`` False: none does (a system singular
    to rounding), and the fixed point solves it. Counted as one iteration of a solve.
    """
    # (one float and one flag array: p, the best p, w = A p + q, A's diagonal, μ; the
    # equality flag and the sliding flag)
    fl = np.zeros(13)
    p, best, wv, diag, mus = fl[:3], fl[3:6], fl[6:9], fl[9:12], fl[12:]
    flags = np.zeros(2, dtype=np.bool_)
    no, sl = flags[:1], flags[1:]
    mus[0], sl[0] = mu, sliding
    for a in range(3):
        diag[a] = A[a, a]
    best_left, found = 0.0, False
    pat = _DENSE3   # (A dense: its zeros add nothing to the sums)
    tol, bar = prm[P_FRICTION_TOLERANCE], prm[P_RESIDUAL_TOLERANCE]
    n2 = 1 if sliding else 3
    for case in range(1 + 3 * n2):
        if case > 0:
            # statuses: 0 inside its bound, 1 on +μ p_n, 2 on −μ p_n
            s1, s2 = (case - 1) // n2, (case - 1) % n2
            v1 = 0.0 if s1 == 0 else (mu if s1 == 1 else -mu)
            v2 = 0.0 if s2 == 0 or sliding else (mu if s2 == 1 else -mu)
            free1, free2 = s1 == 0, s2 == 0 and not sliding
            # Unknowns p_n (its column A e_n + v₁ A e₁ + v₂ A e₂) and the free rows' p_t;
            # equations: w_n = 0 and w_t = 0 of the free rows.
            c00 = A[0, 0] + v1 * A[0, 1] + v2 * A[0, 2]
            c10 = A[1, 0] + v1 * A[1, 1] + v2 * A[1, 2]
            c20 = A[2, 0] + v1 * A[2, 1] + v2 * A[2, 2]
            if free1 and free2:
                det = (c00 * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
                       - A[0, 1] * (c10 * A[2, 2] - A[1, 2] * c20)
                       + A[0, 2] * (c10 * A[2, 1] - A[1, 1] * c20))
                if det == 0.0:
                    continue
                b0, b1, b2 = -q[0], -q[1], -q[2]
                pn = (b0 * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
                      - A[0, 1] * (b1 * A[2, 2] - A[1, 2] * b2)
                      + A[0, 2] * (b1 * A[2, 1] - A[1, 1] * b2)) / det
                x1 = (c00 * (b1 * A[2, 2] - A[1, 2] * b2)
                      - b0 * (c10 * A[2, 2] - A[1, 2] * c20)
                      + A[0, 2] * (c10 * b2 - b1 * c20)) / det
                x2 = (c00 * (A[1, 1] * b2 - b1 * A[2, 1])
                      - A[0, 1] * (c10 * b2 - b1 * c20)
                      + b0 * (c10 * A[2, 1] - A[1, 1] * c20)) / det
                p[0], p[1], p[2] = pn, x1, x2
            elif free1 or free2:
                t = 1 if free1 else 2
                ct0 = A[0, t]
                ctt = A[t, t]
                cr0 = c10 if t == 1 else c20
                det = c00 * ctt - ct0 * cr0
                if det == 0.0:
                    continue
                pn = (-q[0] * ctt + ct0 * q[t]) / det
                xt = (-c00 * q[t] + cr0 * q[0]) / det
                p[0] = pn
                p[1] = xt if t == 1 else v1 * pn
                p[2] = xt if t == 2 else v2 * pn
            else:
                if c00 == 0.0:
                    continue
                pn = -q[0] / c00
                p[0], p[1], p[2] = pn, v1 * pn, v2 * pn
            if not 0.0 < p[0] or (found and not p[0] < best[0]):
                continue
            # A plain look before the residual: a free row within 1e-6 of its bound, a
            # row on its bound not slipping along it by more than 1e-6 of the scale.
            loose = 0.0
            for a in range(3):
                loose = max(loose, abs(q[a]) + abs(A[a, 0] * p[0]) + abs(A[a, 1] * p[1])
                            + abs(A[a, 2] * p[2]))
            loose *= 1e-6
            bound = mu * p[0] * (1.0 + 1e-6)
            plain = True
            for a, v, free in ((1, v1, free1), (2, v2, free2)):
                if free:
                    plain = plain and abs(p[a]) <= bound + loose / A[a, a]
                elif v != 0.0:
                    w = A[a, 0] * p[0] + A[a, 1] * p[1] + A[a, 2] * p[2] + q[a]
                    plain = plain and (w if v > 0.0 else -w) <= loose
            if not plain:
                continue
        # (:func:`residual`, its arrays this function's)
        for a in range(3):
            wv[a] = A[a, 0] * p[0] + A[a, 1] * p[1] + A[a, 2] * p[2] + q[a]
        left = _residual(wv, diag, q, p, mus, False, sl, tol, no, False)
        if left <= bar * _row_scale(A, q, p, pat):
            best[:] = p
            best_left, found = left, True
            if case == 0:
                break   # (apart: no impulse is less)
    if found:
        cnt[C_SOLVES] += 1
        cnt[C_ITERATIONS_MAX] = max(cnt[C_ITERATIONS_MAX], 1.0)
        cnt[C_COMPLEMENTARITY] = max(cnt[C_COMPLEMENTARITY], best_left)
    return best, found   # (a view of fl: fl lives as long as it)


@njit(cache=True)
def solve_island(Ar: np.ndarray, qr: np.ndarray, mu: np.ndarray, start: np.ndarray,
                 normal_only: bool, equal: np.ndarray, has_equal: bool, sliding: np.ndarray,
                 prm: np.ndarray, cnt: np.ndarray) -> tuple:
    """
    Return ``(p, ok)``: the rows' impulses as :meth:`..contact_step.ContactSteps.solve_island`.

    ``Ar`` the island's rows' operator, symmetric (:func:`solve_rows` gathers it;
    ``normal_only``: the normal rows' alone, one a contact), ``qr``, ``start`` (the warm
    start) its rows'; ``p`` the same rows'. ``equal`` (c,): the contacts whose normal row
    is an equality (the projections; ``has_equal`` False: none, and the residual is
    counted); ``sliding`` (c,) contacts with one friction row. ``ok`` False: a row no
    impulse moves (the Python path's case, given back). An island of one contact is
    solved by its cases where one holds (:func:`_one_contact`).
    """
    nr = qr.shape[0]
    dmax = 0.0
    for k in range(nr):
        dmax = max(dmax, Ar[k, k])
    for k in range(nr):
        if not Ar[k, k] > 1e-12 * dmax:
            return np.zeros(nr), False
    if nr == 3 and not normal_only and not has_equal:
        # One contact (a body alone on the ground): its cases, exact (``_one_contact``).
        p1, ok1 = _one_contact(Ar, qr, mu[0], sliding[0], prm, cnt)
        if ok1:
            return p1, True
    # The work arrays, three allocations (a small island's solve is mostly their cost).
    mats = np.empty((2, nr, nr))
    vecs = np.empty((11, nr))
    ints = np.empty((5, nr), dtype=np.int64)
    Ap, L = mats[0], mats[1]
    p, lo, hi, qp, sp = vecs[0], vecs[1], vecs[2], vecs[3], vecs[4]
    work = vecs[5:]
    order, first, marks = ints[0], ints[1], ints[2:]
    qmax = 0.0
    for a in range(nr):
        qmax = max(qmax, abs(qr[a]))
    rho = prm[P_PROXIMAL] * dmax
    floor = 64.0 * EPS * qmax / dmax
    for a in range(nr):
        for b in range(nr):
            Ap[a, b] = Ar[a, b]
        Ap[a, a] += rho
    pat = pattern(Ap)   # (the box solves' sums run over its non-zeros)
    perm = envelope_order(pat)
    for a in range(nr):
        p[a] = start[a]
        lo[a], hi[a] = 0.0, np.inf
    step3 = 1 if normal_only else 3
    for a in range(0, nr, step3):
        if has_equal and equal[a // step3]:
            lo[a] = -np.inf
        p[a] = max(p[a], lo[a])
    # Where the rows have no equalities, a fixed point that stalls gives way to Newton's
    # method, then to pivoting, and goes on if both fail (``solve_island``).
    pivots = not normal_only and not has_equal
    converged, it, stalled, last, early, pivot_tried = False, 0, 0, np.inf, pivots, False
    newton_tried = False
    tol = prm[P_FRICTION_TOLERANCE]
    # The active-set solves' factor (L, order, first, meta), kept from one iteration's
    # solve to the next.
    meta = np.zeros(3, dtype=np.int64)
    iterations, stall = int(prm[P_FRICTION_ITERATIONS]), int(prm[P_STALL_ITERATIONS])
    while True:
        exited = False
        while it < iterations:
            it += 1
            for a in range(nr):
                sp[a] = p[a]
            if not normal_only:
                for k in range(nr // 3):
                    half = mu[k] * max(p[3 * k], 0.0)
                    for col in range(1, 3):
                        a = 3 * k + col
                        half_a = 0.0 if col == 2 and sliding[k] else half
                        # A friction row the last solve left on its bound starts on its
                        # new bound (where it slid, it most likely slides on), not inside
                        # a box that grew (each such row a blocking move to its bound).
                        if it > 1 and hi[a] > lo[a]:
                            if p[a] >= hi[a]:
                                sp[a] = half_a
                            elif p[a] <= lo[a]:
                                sp[a] = -half_a
                        lo[a], hi[a] = -half_a, half_a
                for a in range(nr):
                    p[a] = min(max(p[a], lo[a]), hi[a])
                    sp[a] = min(max(sp[a], lo[a]), hi[a])
            for a in range(nr):
                qp[a] = qr[a] - rho * p[a]
            # (The proximal centre is the last iterate, p; sp only where the solve starts.)
            f, ok, _ = _solve_box(Ap, qp, lo, hi, sp, L, order, first, meta, work, marks,
                                  pat, perm)
            change, scale = 0.0, 0.0
            for a in range(nr):
                change = max(change, abs(f[a] - p[a]))
                p[a] = f[a]
            for a in range(nr):
                scale = max(scale, abs(p[a]))
            scale = max(scale, 1e-300)
            ratio = change / last if last > 0.0 else np.inf
            stalled = stalled + 1 if ratio > 0.5 else 0
            last = change
            target = tol * scale + floor
            if ok and change <= target:
                converged = True
                break
            if ok and stalled >= 2:
                left = residual(Ar, qr, p, mu, normal_only, sliding, tol, equal, has_equal,
                                pat)
                if left <= prm[P_RESIDUAL_TOLERANCE] * _row_scale(Ar, qr, p, pat) \
                        + 2.0 * rho * change:
                    converged = True
                    break
            if early and ok and stalled >= stall:
                if not newton_tried:
                    newton_tried = True
                    solved, solved_ok = _newton(Ar, qr, mu, sliding, p, prm, pat)
                    if solved_ok:
                        p, converged = solved, True
                        cnt[C_NEWTON] += 1
                        break
                if ratio >= 1.0 or it + math.log(target / change) / math.log(ratio) \
                        > iterations:
                    exited = True
                    break
        if converged or not pivots:
            break
        # An iterate within what a pivoted solve must reach stands (``solve_island``).
        converged = residual(Ar, qr, p, mu, False, sliding, tol, equal, False, pat) \
            <= prm[P_PIVOT_TOLERANCE] * _row_scale(Ar, qr, p, pat)
        if converged or pivot_tried:
            break
        pivot_tried = True
        if nr // 3 > prm[P_PIVOT_CONTACTS]:
            # Too large to pivot first (more than ``P_PIVOT_CONTACTS`` contacts: a pivoted
            # solve's cost grows as their cube, 0.37 s at 190): the fixed point by the
            # island's blocks, held to the bar a pivoted solve must meet
            # (``P_PIVOT_TOLERANCE``).
            p_b, converged = _by_blocks(Ar, qr, mu, p, equal, sliding, prm, pat, cnt)
            if converged:
                p = p_b
        if not converged and nr // 3 <= max(prm[P_PIVOT_CONTACTS],
                                            prm[P_PIVOT_LAST_CONTACTS]):
            # Lemke's pivoting on the pyramid (``_pyramid``): first, or where the blocks
            # failed, last.
            for reg in (prm[P_PIVOT_REGULARIZATION_1], prm[P_PIVOT_REGULARIZATION_2]):
                pivoted, ok = pyramid(Ar, qr, mu, sliding, reg)
                left = residual(Ar, qr, pivoted, mu, False, sliding, tol, equal, False, pat)
                if ok and left <= prm[P_PIVOT_TOLERANCE] * _row_scale(Ar, qr, pivoted, pat):
                    p, converged = pivoted, True
                    cnt[C_PIVOTED] += 1
                    break
        if converged or not exited:
            break
        early = False   # (the pivoting failed: the fixed point goes on from its iterate)
    cnt[C_SOLVES] += 1
    cnt[C_ITERATIONS_MAX] = max(cnt[C_ITERATIONS_MAX], it)
    if not converged:
        cnt[C_FAILURES] += 1
    if not has_equal:
        cnt[C_COMPLEMENTARITY] = max(cnt[C_COMPLEMENTARITY],
                                     residual(Ar, qr, p, mu, normal_only, sliding, tol,
                                              equal, False, pat))
    return p.copy(), True


@njit(cache=True)
def _by_blocks(Ar: np.ndarray, qr: np.ndarray, mu: np.ndarray, p: np.ndarray,
               equal: np.ndarray, sliding: np.ndarray, prm: np.ndarray, pat: np.ndarray,
               cnt: np.ndarray) -> tuple:
    """
    Return ``(p, ok)``: a dense island :func:`solve_island` may not pivot, by its blocks.

    :func:`solve_large_island` on :func:`blocks` of ``Ar`` from the fixed point's iterate
    ``p``; ``ok``: its result meets the bar a pivoted solve must (``P_PIVOT_TOLERANCE``
    of the rows' velocity scale, by the dense residual). Counted as a solve by blocks
    (``C_SPARSE``; ``C_PGS`` where it went on by projected Gauss–Seidel), not as a
    second solve or failure: the caller counts its own.
    """
    c = qr.shape[0] // 3
    own = np.zeros(cnt.shape[0])
    out, ok = solve_large_island(blocks(Ar), qr, mu, p, np.arange(c), False, equal, False,
                                 sliding, prm, own)
    cnt[C_SPARSE] += 1
    cnt[C_PGS] += own[C_PGS]
    if not ok:
        return p, False
    return out, residual(Ar, qr, out, mu, False, sliding, prm[P_FRICTION_TOLERANCE], equal,
                         False, pat) <= prm[P_PIVOT_TOLERANCE] * _row_scale(Ar, qr, out, pat)


@njit(cache=True)
def lu_factor(K: np.ndarray) -> tuple:
    """Return ``(LU, pivots, ok)``: ``K`` factored by partial pivoting (``ok``: no zero pivot)."""
    n = K.shape[0]
    LU = K.copy()
    piv = np.arange(n)
    for j in range(n):
        best, row = 0.0, j
        for i in range(j, n):
            if abs(LU[i, j]) > best:
                best, row = abs(LU[i, j]), i
        if best == 0.0:
            return LU, piv, False
        if row != j:
            for x in range(n):
                LU[j, x], LU[row, x] = LU[row, x], LU[j, x]
            piv[j], piv[row] = piv[row], piv[j]
        inv = 1.0 / LU[j, j]
        for i in range(j + 1, n):
            f = LU[i, j] * inv
            LU[i, j] = f
            if f != 0.0:
                for x in range(j + 1, n):
                    LU[i, x] -= f * LU[j, x]
    return LU, piv, True


@njit(cache=True)
def lu_solve(LU: np.ndarray, piv: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return ``x`` with ``K x = b`` from :func:`lu_factor`'s factors."""
    n = b.shape[0]
    x = np.empty(n)
    for i in range(n):
        x[i] = b[piv[i]]
    for i in range(n):
        for j in range(i):
            x[i] -= LU[i, j] * x[j]
    for i in range(n - 1, -1, -1):
        for j in range(i + 1, n):
            x[i] -= LU[i, j] * x[j]
        x[i] /= LU[i, i]
    return x


#: LAPACK's ``dgetrf`` (LU by partial pivoting, blocked), through numba's own binding of
#: scipy's LAPACK (the one ``np.linalg`` uses in compiled code; a symbol, not an address, so
#: the kernels that call it stay cached); ``ord('d')``: its double-precision kind.
_GETRF = _LAPACK().numba_xxgetrf(types.float64)
_DOUBLE = ord('d')


@njit(cache=True)
def lapack_lu(K: np.ndarray) -> tuple:
    """
    Return ``(F, pivots, ok)``: ``K = P L U`` by LAPACK's ``dgetrf`` (``ok``: ``U`` regular).

    ``F`` is the factors in LAPACK's column-major order read as a C array: ``F[j, i]`` is
    the factors' ``(i, j)`` entry (``L`` unit lower, ``U`` upper); ``pivots`` LAPACK's row
    interchanges, from 0 (for :func:`lapack_lu_solve`).
    """
    n = K.shape[0]
    F = K.T.copy()   # (C order of Kᵀ: column-major order of K)
    ipiv = np.empty(n, dtype=F_INT_nptype)
    if n == 0:
        return F, np.zeros(0, dtype=np.int64), True
    for a in range(n):
        for b in range(n):
            if not np.isfinite(F[a, b]):
                return F, np.zeros(n, dtype=np.int64), False
    info = _GETRF(_DOUBLE, n, n, F.ctypes, n, ipiv.ctypes)
    piv = np.empty(n, dtype=np.int64)
    for a in range(n):
        piv[a] = ipiv[a] - 1
    ok = info == 0
    for a in range(n):
        ok = ok and np.isfinite(F[a, a]) and F[a, a] != 0.0
    return F, piv, ok


@njit(cache=True)
def lapack_lu_solve(F: np.ndarray, piv: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return ``x`` with ``K x = b`` from :func:`lapack_lu`'s factors (by their columns)."""
    n = b.shape[0]
    x = b.copy()
    for i in range(n):
        j = piv[i]
        if j != i:
            x[i], x[j] = x[j], x[i]
    for j in range(n):   # (L: its column j is F[j, j + 1:])
        xj = x[j]
        if xj != 0.0:
            for i in range(j + 1, n):
                x[i] -= F[j, i] * xj
    for j in range(n - 1, -1, -1):   # (U: its column j is F[j, :j + 1])
        x[j] /= F[j, j]
        xj = x[j]
        if xj != 0.0:
            for i in range(j):
                x[i] -= F[j, i] * xj
    return x


@njit(cache=True)
def newton(A: np.ndarray, q: np.ndarray, mu: np.ndarray, sliding: np.ndarray,
           p0: np.ndarray, prm: np.ndarray) -> tuple:
    """Return :func:`_newton` (``A``'s :func:`pattern` found here)."""
    return _newton(A, q, mu, sliding, p0, prm, pattern(A))


@njit(cache=True)
def _newton(A: np.ndarray, q: np.ndarray, mu: np.ndarray, sliding: np.ndarray,
            p0: np.ndarray, prm: np.ndarray, pat: np.ndarray) -> tuple:
    """
    Return ``(p, ok)``: Newton's method on the rows' natural map, as ``_newton``.

    Each iteration guesses from ``y = p − w / diag(A)`` the loaded normal rows and the
    friction rows on their bounds ``±μ p_n`` or inside them, and solves that guess's
    linear system (``w = 0`` on the loaded normal rows and the friction rows inside)
    by a proximal LU solve, refined on its factors (beyond :data:`NEWTON_LAPACK_ROWS`
    unknowns LAPACK's, :func:`lapack_lu`, refined the same way). ``ok``: within
    ``P_PIVOT_TOLERANCE``. ``pat``: ``A``'s :func:`pattern` (its products run over it).
    """
    m = q.shape[0]
    c = m // 3
    p = p0.copy()
    kind = np.zeros(m, dtype=np.int64)
    previous = np.zeros(m, dtype=np.int64)
    column = np.full(m, -1, dtype=np.int64)
    forced = np.zeros(m, dtype=np.int64)
    first = 0   # (the first guess a repeat of which ends the method)
    tol, no_equal = prm[P_FRICTION_TOLERANCE], np.zeros(c, dtype=np.bool_)
    for guess in range(int(prm[P_NEWTON_ITERATIONS])):
        w = _sparse_affine(A, pat, p, q)
        for k in range(c):
            n = 3 * k
            yn = p[n] - w[n] / A[n, n]
            load = yn > 0.0
            kind[n] = 1 if load else 0
            bound = mu[k] * max(yn, 0.0)
            for col in range(1, 3):
                t = n + col
                if not load or not mu[k] > 0.0 or (col == 2 and sliding[k]):
                    kind[t] = 0
                else:
                    yt = p[t] - w[t] / A[t, t]
                    kind[t] = 2 if yt >= bound else (-2 if yt <= -bound else (
                        forced[t] if forced[t] != 0 else 1))
        nu = 0
        for j in range(m):
            if kind[j] == 1:
                column[j] = nu
                nu += 1
        unknown = _where(kind == 1)
        z = np.empty(nu)
        for a in range(nu):
            z[a] = p[unknown[a]]
        if nu:
            K = np.zeros((nu, nu))
            for a in range(nu):
                r = unknown[a]
                for j in range(m):
                    if kind[j] == 1:
                        K[a, column[j]] += A[r, j]
                    elif kind[j] != 0:
                        K[a, column[3 * (j // 3)]] += (1.0 if kind[j] > 0 else -1.0) \
                            * mu[j // 3] * A[r, j]
            dmax = 0.0
            for a in range(nu):
                dmax = max(dmax, abs(K[a, a]))
            Kp = K.copy()
            for a in range(nu):
                Kp[a, a] += prm[P_PROXIMAL] * dmax
            lapack = nu > NEWTON_LAPACK_ROWS
            if lapack:
                LU, piv, ok = lapack_lu(Kp)
            else:
                LU, piv, ok = lu_factor(Kp)
            if not ok:
                return p, False
            step = np.zeros(nu)
            for refinement in range(int(prm[P_NEWTON_REFINEMENTS]) + 1):
                zs = z + step
                rhs = np.empty(nu)
                for a in range(nu):
                    v = -q[unknown[a]]
                    for b in range(nu):
                        v -= K[a, b] * zs[b]
                    rhs[a] = v
                step = step + (lapack_lu_solve(LU, piv, rhs) if lapack
                               else lu_solve(LU, piv, rhs))
            z = z + step
        p = np.zeros(m)
        for j in range(m):
            if kind[j] == 1:
                p[j] = z[column[j]]
        for j in range(m):
            if kind[j] == 2 or kind[j] == -2:
                p[j] = (1.0 if kind[j] > 0 else -1.0) * mu[j // 3] * p[3 * (j // 3)]
        if residual(A, q, p, mu, False, sliding, tol, no_equal, False, pat) \
                <= prm[P_PIVOT_TOLERANCE] * _row_scale(A, q, p, pat):
            return p, True
        same = guess > first
        for j in range(m):
            if kind[j] != previous[j]:
                same = False
            previous[j] = kind[j]
        if same:
            # A repeated guess without an exact solution: its inside friction row that
            # keeps the most slip goes on the bound opposing it, as ``_newton``.
            w = _sparse_affine(A, pat, p, q)
            j_most, most = -1, 0.0
            for j in range(m):
                if kind[j] == 1 and j % 3 != 0 and forced[j] == 0 and abs(w[j]) > most:
                    j_most, most = j, abs(w[j])
            if j_most < 0:
                return p, False
            forced[j_most] = -2 if w[j_most] > 0.0 else 2
            first = guess + 1
    return p, False


@njit(cache=True)
def _row_scale(A: np.ndarray, q: np.ndarray, p: np.ndarray, pat: np.ndarray) -> float:
    """Return the rows' velocity scale at ``p``: the largest ``|A| |p| + |q|`` (``pat``: A's)."""
    out = 0.0
    for a in range(q.shape[0]):
        wa = abs(q[a])
        for t in range(pat[a], pat[a + 1]):
            wa += abs(A[a, pat[t]]) * abs(p[pat[t]])
        out = max(out, wa)
    return out


@njit(cache=True)
def pyramid(A: np.ndarray, q: np.ndarray, mu: np.ndarray, sliding: np.ndarray,
            regularization: float) -> tuple:
    """
    Return ``(p, ok)``: the rows by Lemke's pivoting on the pyramid, as ``_pyramid``.

    ``w = A p + q`` (normal, t₁, t₂ per contact; a sliding contact's t₁ alone) with
    ``p_t = p⁺ − p⁻``, ``w_t + β ≥ 0 ⊥ p⁺``, ``−w_t + β ≥ 0 ⊥ p⁻``, ``μ p_n − p⁺ − p⁻
    ≥ 0 ⊥ β``; ``A`` takes ``regularization`` of its largest diagonal on its diagonal.
    """
    m = q.shape[0]
    c = m // 3
    dmax = 0.0
    for a in range(m):
        dmax = max(dmax, A[a, a])
    r = 0
    for k in range(c):
        r += 1 if sliding[k] else 2
    f = np.empty(r, dtype=np.int64)
    j = 0
    for k in range(c):
        f[j] = 3 * k + 1
        j += 1
        if not sliding[k]:
            f[j] = 3 * k + 2
            j += 1
    n = c + 3 * r
    M = np.zeros((n, n))
    qq = np.zeros(n)
    for x in range(c):
        qq[x] = q[3 * x]
        for y in range(c):
            M[x, y] = A[3 * x, 3 * y] + (regularization * dmax if x == y else 0.0)
        for y in range(r):
            M[x, c + y] = A[3 * x, f[y]]
            M[x, c + r + y] = -A[3 * x, f[y]]
    for x in range(r):
        qq[c + x], qq[c + r + x] = q[f[x]], -q[f[x]]
        for y in range(c):
            M[c + x, y] = A[f[x], 3 * y]
            M[c + r + x, y] = -A[f[x], 3 * y]
        for y in range(r):
            a = A[f[x], f[y]] + (regularization * dmax if x == y else 0.0)
            M[c + x, c + y], M[c + x, c + r + y] = a, -a
            M[c + r + x, c + y], M[c + r + x, c + r + y] = -a, a
        M[c + x, c + 2 * r + x] = 1.0
        M[c + r + x, c + 2 * r + x] = 1.0
        own = f[x] // 3
        M[c + 2 * r + x, own] = mu[own]
        M[c + 2 * r + x, c + x] = -1.0
        M[c + 2 * r + x, c + r + x] = -1.0
    z, ok = lemke(M, qq)
    p = np.zeros(m)
    for x in range(c):
        p[3 * x] = z[x]
    for x in range(r):
        p[f[x]] = z[c + x] - z[c + r + x]
    return p, ok


@njit(cache=True)
def lemke(M: np.ndarray, q: np.ndarray) -> tuple:
    """
    Return ``(z, ok)``: the LCP ``w = M z + q ≥ 0 ⊥ z ≥ 0`` by Lemke's pivoting.

    As :func:`..complementarity.lemke`: the covering vector all ones, ties broken
    lexicographically, at most ``50 n`` pivots, the basic ``z`` solved again by least
    squares on their rows and kept if no worse; ``ok`` False on a secondary ray.
    """
    n = q.shape[0]
    if n == 0 or np.min(q) >= 0.0:
        return np.zeros(n), True
    T = np.zeros((n, 2 * n + 2))
    mmax = 0.0
    for i in range(n):
        T[i, i] = 1.0
        for j in range(n):
            T[i, n + j] = -M[i, j]
            mmax = max(mmax, abs(M[i, j]))
        T[i, 2 * n] = -1.0
        T[i, 2 * n + 1] = q[i]
    basis = np.arange(n)
    tol = 1e-12 * max(1.0, mmax)
    entering = 2 * n
    row = int(np.argmin(q))
    done = False
    cand = np.empty(n, dtype=np.int64)
    for _ in range(50 * n):
        # Gauss–Jordan pivot on (row, entering).
        piv = T[row, entering]
        for j in range(2 * n + 2):
            T[row, j] /= piv
        for i in range(n):
            if i != row:
                fac = T[i, entering]
                if fac != 0.0:
                    for j in range(2 * n + 2):
                        T[i, j] -= fac * T[row, j]
        leaving = basis[row]
        basis[row] = entering
        if leaving == 2 * n:
            done = True
            break
        entering = leaving + n if leaving < n else leaving - n
        best = np.inf
        nc = 0
        for i in range(n):
            if T[i, entering] > tol:
                ratio = max(T[i, 2 * n + 1], 0.0) / T[i, entering]
                best = min(best, ratio)
                cand[nc] = i
                nc += 1
        if nc == 0:
            return np.zeros(n), False
        k = 0
        for x in range(nc):
            i = cand[x]
            if max(T[i, 2 * n + 1], 0.0) / T[i, entering] <= best + tol * max(1.0, abs(best)):
                cand[k] = i
                k += 1
        nc = k
        for j in range(n):
            if nc == 1:
                break
            kmin = np.inf
            for x in range(nc):
                kmin = min(kmin, T[cand[x], j] / T[cand[x], entering])
            k = 0
            for x in range(nc):
                if T[cand[x], j] / T[cand[x], entering] <= kmin + tol:
                    cand[k] = cand[x]
                    k += 1
            nc = k
        row = cand[0]
    if not done:
        return np.zeros(n), False
    z = np.zeros(n)
    ns = 0
    for i in range(n):
        b = basis[i]
        if n <= b < 2 * n:
            z[b - n] = max(T[i, 2 * n + 1], 0.0)
            ns += 1
    if ns:
        support = np.empty(ns, dtype=np.int64)
        k = 0
        for j in range(n):
            for i in range(n):
                if basis[i] == n + j:
                    support[k] = j
                    k += 1
        Ms, rhs = np.empty((ns, ns)), np.empty(ns)
        for x in range(ns):
            rhs[x] = -q[support[x]]
            for y in range(ns):
                Ms[x, y] = M[support[x], support[y]]
        sol = np.linalg.lstsq(Ms, rhs, rcond=EPS * ns)[0]
        again = np.zeros(n)
        for x in range(ns):
            again[support[x]] = max(sol[x], 0.0)
        if _lcp_error(M, q, again) <= _lcp_error(M, q, z):
            z = again
    return z, True


@njit(cache=True)
def _lcp_error(M: np.ndarray, q: np.ndarray, z: np.ndarray) -> float:
    """Return the natural-map residual ``max |min(z, M z + q)|``."""
    w = M @ z + q
    out = 0.0
    for i in range(q.shape[0]):
        out = max(out, abs(min(z[i], w[i])))
    return out


@njit(cache=True)
def _sparse_affine(A: np.ndarray, pat: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Return ``A p + q`` over ``A``'s :func:`pattern` ``pat`` (its non-zeros, by column)."""
    m = q.shape[0]
    w = np.empty(m)
    for a in range(m):
        acc = 0.0
        for t in range(pat[a], pat[a + 1]):
            acc += A[a, pat[t]] * p[pat[t]]
        w[a] = acc + q[a]
    return w


@njit(cache=True)
def residual(A: np.ndarray, q: np.ndarray, p: np.ndarray, mu: np.ndarray, normal_only: bool,
             sliding: np.ndarray, tol: float, equal: np.ndarray, has_equal: bool,
             pat: np.ndarray) -> float:
    """
    Return how far the contact conditions are from holding (m/s), as the Python path.

    ``pat``: ``A``'s :func:`pattern`.
    """
    m = q.shape[0]
    if not m:
        return 0.0
    diag = np.empty(m)
    for a in range(m):
        diag[a] = A[a, a]
    return _residual(_sparse_affine(A, pat, p, q), diag, q, p, mu, normal_only, sliding,
                     tol, equal, has_equal)


@njit(cache=True)
def _residual(w: np.ndarray, diag: np.ndarray, q: np.ndarray, p: np.ndarray, mu: np.ndarray,
              normal_only: bool, sliding: np.ndarray, tol: float, equal: np.ndarray,
              has_equal: bool) -> float:
    """Return :func:`residual` of the rows' velocities ``w = A p + q`` and ``A``'s diagonal."""
    m = q.shape[0]
    pmax, qmax, dmax = 0.0, 0.0, 0.0
    for a in range(m):
        pmax, qmax, dmax = max(pmax, abs(p[a])), max(qmax, abs(q[a])), max(dmax, diag[a])
    out = 0.0
    step = 1 if normal_only else 3
    for k in range(m // step):
        a = step * k
        if has_equal and equal[k]:
            out = max(out, abs(w[a]))
        else:
            out = max(out, abs(min(p[a] * diag[a], w[a])))
    if normal_only:
        return out
    slack = 2.0 * (tol * pmax + 64.0 * EPS * qmax / dmax)
    for k in range(m // 3):
        bound = mu[k] * max(p[3 * k], 0.0)
        for col in range(1, 3):
            if col == 2 and sliding[k]:
                continue
            f, v = p[3 * k + col], w[3 * k + col]
            if abs(f) < bound - slack:   # (the natural map: its slip, or its force's gap)
                gap = bound + f if v > 0.0 else bound - f
                out = max(out, min(abs(v), gap * diag[3 * k + col]))
            elif bound > 0.0:
                out = max(out, max(f * v, 0.0) / bound)
            if abs(f) > bound + slack:
                out = max(out, (abs(f) - bound) * diag[3 * k + col])
    return out


@njit(cache=True)
def slip_turn(frame: np.ndarray, mu: np.ndarray, sliding: np.ndarray, p: np.ndarray,
              w: np.ndarray, rate: float, tol: float) -> tuple:
    """
    Return ``(turned, frame, sliding)``: the sticking contacts that begin to slip turned.

    As ``ContactSteps._slipping``: a sticking contact whose friction ends on a bound
    with its point slipping faster than ``rate``, or whose friction left Coulomb's
    cone inside the pyramid, slides, its ``t₁`` along the slip (or against its
    friction); where one turns, the frames and flags are new arrays (else the same).
    """
    c = mu.shape[0]
    pmax = 0.0
    for a in range(p.shape[0]):
        pmax = max(pmax, abs(p[a]))
    slack = 2.0 * tol * pmax
    frame2, sliding2 = frame, sliding   # (copied at the first turn)
    turned = False
    for k in range(c):
        if sliding[k]:
            continue
        bound = mu[k] * max(p[3 * k], 0.0)
        if not bound > 0.0:
            continue
        on = abs(p[3 * k + 1]) >= bound - slack or abs(p[3 * k + 2]) >= bound - slack
        # The slip s and the friction f in the world (scalars: no arrays a contact).
        s0, s1, s2 = (w[3 * k + 1] * frame[k, 1, 0] + w[3 * k + 2] * frame[k, 2, 0],
                      w[3 * k + 1] * frame[k, 1, 1] + w[3 * k + 2] * frame[k, 2, 1],
                      w[3 * k + 1] * frame[k, 1, 2] + w[3 * k + 2] * frame[k, 2, 2])
        f0, f1, f2 = (p[3 * k + 1] * frame[k, 1, 0] + p[3 * k + 2] * frame[k, 2, 0],
                      p[3 * k + 1] * frame[k, 1, 1] + p[3 * k + 2] * frame[k, 2, 1],
                      p[3 * k + 1] * frame[k, 1, 2] + p[3 * k + 2] * frame[k, 2, 2])
        speed = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        size = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
        beyond = size > bound + slack
        if beyond and speed <= rate:
            s0 = -f0 / max(size, 1e-300) * rate * 2.0
            s1 = -f1 / max(size, 1e-300) * rate * 2.0
            s2 = -f2 / max(size, 1e-300) * rate * 2.0
            speed = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        if not ((on and speed > rate) or beyond):
            continue
        if not turned:
            frame2, sliding2 = frame.copy(), sliding.copy()
        turned = True
        sliding2[k] = True
        nrm = frame[k, 0]
        frame2[k, 1, 0], frame2[k, 1, 1], frame2[k, 1, 2] = s0 / speed, s1 / speed, s2 / speed
        x0, x1, x2 = _cross(nrm[0], nrm[1], nrm[2], frame2[k, 1, 0], frame2[k, 1, 1],
                            frame2[k, 1, 2])
        frame2[k, 2, 0], frame2[k, 2, 1], frame2[k, 2, 2] = x0, x1, x2
    return turned, frame2, sliding2


# -- contacts found again -------------------------------------------------------------------

@njit(cache=True)
def _local(pt: np.ndarray, k: int, i: int, pos: np.ndarray, R: np.ndarray) -> tuple:
    """Return point ``pt[k]`` in body ``i``'s principal frame (the world's: as it is)."""
    if i >= pos.shape[0]:
        return pt[k, 0], pt[k, 1], pt[k, 2]
    d0, d1, d2 = pt[k, 0] - pos[i, 0], pt[k, 1] - pos[i, 1], pt[k, 2] - pos[i, 2]
    return (R[i, 0, 0] * d0 + R[i, 1, 0] * d1 + R[i, 2, 0] * d2,
            R[i, 0, 1] * d0 + R[i, 1, 1] * d1 + R[i, 2, 1] * d2,
            R[i, 0, 2] * d0 + R[i, 1, 2] * d1 + R[i, 2, 2] * d2)


#: Up to this many keys :func:`_by_key` sorts by insertion (no work array; numba's
#: mergesort allocates two): the same order, the only stable one.
INSERTION_KEYS = 16


@njit(cache=True)
def _by_key(keys: np.ndarray) -> tuple:
    """Return ``(order, keys[order])``: a stable sort (equal keys in their first order)."""
    c = keys.shape[0]
    if c > INSERTION_KEYS:
        order = np.argsort(keys, kind='mergesort')
        return order, keys[order]
    order = np.empty(c, dtype=np.int64)
    sorted_keys = np.empty(c, dtype=keys.dtype)
    for j in range(c):
        key = keys[j]
        u = j
        while u > 0 and sorted_keys[u - 1] > key:   # (strictly: equal keys keep their order)
            sorted_keys[u], order[u] = sorted_keys[u - 1], order[u - 1]
            u -= 1
        sorted_keys[u], order[u] = key, j
    return order, sorted_keys


@njit(cache=True)
def match(r_sel: np.ndarray, r_sa: np.ndarray, r_sb: np.ndarray, r_ba: np.ndarray,
          r_pt: np.ndarray, r_pos: np.ndarray, r_R: np.ndarray, which: np.ndarray,
          c_sa: np.ndarray, c_sb: np.ndarray, c_ba: np.ndarray, c_pt: np.ndarray,
          pos: np.ndarray, R: np.ndarray, radius: np.ndarray, count: int,
          also: np.ndarray) -> tuple:
    """
    Return the contacts continuing rows, as ``ContactSteps._match`` and ``_continuing``.

    The rows: the contacts ``r_sel`` of ``r_sa``, ``r_sb``, ``r_ba``, ``r_pt`` (at
    ``r_pos``, ``r_R``). ``(nearest, continuing, continuing_also)``: per row the nearest
    contact continuing it (−1: none), per contact whether it continues a row of ``which``
    (the same pair; its point in body a within its radius of the row's), and whether it
    continues a row of ``also`` (a second set of rows, matched in the same pass; an
    ``also`` of no rows: none, all False).
    """
    r, c = r_sel.shape[0], c_sa.shape[0]
    nearest = np.full(r, -1, dtype=np.int64)
    flags = np.zeros(2 * c, dtype=np.bool_)   # (both flags' arrays: one allocation)
    continuing, continuing_also = flags[:c], flags[c:]
    if r == 0 or c == 0:
        return nearest, continuing, continuing_also
    has_also = also.shape[0] == r
    few, order, keys = _pair_index(c_sa, c_sb, count)
    for i in range(r):
        in_also = has_also and also[i]
        if not which[i] and not in_also:
            continue
        g = r_sel[i]
        key = r_sa[g] * count + r_sb[g]
        s0, s1, s2 = _local(r_pt, g, r_ba[g], r_pos, r_R)
        best = np.inf
        t = _pair_first(key, few, keys)
        while True:   # (the same pair's, j increasing)
            j, t = _pair_next(key, t, few, order, keys, c_sa, c_sb, count)
            if j < 0:
                break
            n0, n1, n2 = _local(c_pt, j, c_ba[j], pos, R)
            d2 = (s0 - n0) ** 2 + (s1 - n1) ** 2 + (s2 - n2) ** 2
            rad = radius[c_sa[j]]
            if d2 <= rad * rad:
                if in_also:
                    continuing_also[j] = True
                if which[i]:
                    continuing[j] = True
                    if d2 < best:
                        best, nearest[i] = d2, j
    return nearest, continuing, continuing_also


@njit(cache=True, inline='always')
def _pair_index(sa: np.ndarray, sb: np.ndarray, count: int) -> tuple:
    """
    Return ``(few, order, keys)``: entries ``(sa, sb)`` by their pair's key ``sa count + sb``.

    A few (up to :data:`INSERTION_KEYS`) are scanned in their order, which gives the same
    pairs in the same order as the sorted keys, without the sort's two arrays
    (:func:`_pair_next`); more are sorted (:func:`_by_key`).
    """
    few = sa.shape[0] <= INSERTION_KEYS
    order, keys = (sa[:0], sa[:0]) if few else _by_key(sa * count + sb)
    return few, order, keys


@njit(cache=True, inline='always')
def _pair_first(key: int, few: bool, keys: np.ndarray) -> int:
    """Return where the scan for pair ``key`` of :func:`_pair_index` starts."""
    return 0 if few else np.searchsorted(keys, key)


@njit(cache=True, inline='always')
def _pair_next(key: int, t: int, few: bool, order: np.ndarray, keys: np.ndarray,
               sa: np.ndarray, sb: np.ndarray, count: int) -> tuple:
    """Return ``(j, t)``: the next entry of pair ``key`` from scan place ``t`` (−1: none)."""
    c = sa.shape[0]
    while t < c:
        if few:
            if sa[t] * count + sb[t] == key:
                return t, t + 1
            t += 1
        else:
            if keys[t] != key:
                return -1, c
            return order[t], t + 1
    return -1, c


# -- a step ---------------------------------------------------------------------------------

# The step's small helpers that take the context tuple or return tuples of arrays are
# inlined (``inline='always'``) into their callers: a compiled call counts a reference in
# and out for every array it is passed or returns, and zeroes its frame, which cost a
# resting sphere's step about 1 µs of 13 (measured, AMD EPYC). The large ones (``_held``,
# ``_accept``) stay calls: inlined, the step's frame and its counting grew and it took
# twice as long. An inlined helper makes no raw views (:func:`.views.raw_tree`) of its
# arguments: it has no call to keep them alive, and a caller's temporary (an argument
# computed in the call) is freed after its last use, which the view is not.

@njit(cache=True)
def _advance(method: int, y0: np.ndarray, h: float, model: tuple, nw: int, flags: int,
             kick: np.ndarray, counts: np.ndarray, steps_slot: int, ws: np.ndarray,
             frames: np.ndarray) -> tuple:
    """Return the integrator's step of ``h`` from ``y0`` (a new buffer), and if it is finite."""
    body, gforce, wbuf = model
    y = y0.copy()
    pos, quat, vel, om = state_parts(y)
    # (no error estimate and no outputs: empty views of ws, where np.zeros(0) would allocate)
    none = ws[:0]
    code = free_step(method, pos, quat, vel, om, h, body, gforce, wbuf[:nw], flags, kick,
                     False, counts, none, ws, frames, none.reshape((0, O_WIDTH)))
    counts[steps_slot] += 1
    return y, (code & FINITE) != 0


@njit(cache=True)
def contact_steps(n_steps: int, y0: np.ndarray, t0: float, base: float, steps0: int,
                  dt: float, method: int, model: tuple, n_applied: int, flags: int,
                  kick: np.ndarray, counts: np.ndarray, steps_slot: int, ws: np.ndarray,
                  frames: np.ndarray, out: np.ndarray, dtab: np.ndarray,
                  shape_mu: np.ndarray, shape_e: np.ndarray, radius: np.ndarray, warm: tuple,
                  prm: np.ndarray, cnt: np.ndarray, log: np.ndarray, minv: np.ndarray) -> tuple:
    """
    Take up to ``n_steps`` contact steps from ``y0`` at time ``t0``; stop at a ``BAIL``.

    Step ``k`` ends at ``base + (steps0 + k + 1) dt`` (the simulation's clock).
    ``model``: ``(body, gforce, wbuf)``, ``wbuf`` (k + n, W_WIDTH) the applied wrench
    rows (first ``n_applied``) and room for one contact wrench per body; ``dtab``:
    :func:`detect`'s ``det`` and ``buf`` as one table (:data:`DT_ARRAYS`); ``warm``:
    ``(shape_a, shape_b, point, p_n)`` of the last step's rows; ``log`` (L, 5): the
    impacts, a row each (time, shape a, shape b, approach, rebound). Returns ``(taken,
    code, y, warm, record, impacts)``: the steps taken (``y`` the state after them;
    ``y0`` when none), why they stopped (``DONE``, ``BAIL`` or ``GROW``: the detector's
    buffers are too small), the warm start for the next, the last held step's record
    ``(sel, force, contacts at its start, its start's state buffer, its time)`` and the
    rows of ``log`` written.
    """
    # (Every helper takes ctx: the call's numbers and two tables, of its arrays (its
    # arguments, alive for the call) and of the detector's, of which the helpers make
    # views where they read them, uncounted. None is returned.)
    ctx = (method, n_applied, flags, steps_slot, dt,
           _arrays_table(model, kick, counts, ws, frames, out, shape_mu, shape_e, radius, prm,
                         minv), raw_tree(dtab))
    cnt, log = raw_tree((cnt, log))
    y, t = y0, t0
    # (made once a call, not once a step: the record of no rows, and a step's counters)
    no_sel, no_force = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    no_flags = np.zeros(0, dtype=np.bool_)
    cnt_step = np.zeros(cnt.shape[0])
    record = (no_sel, no_force, _no_contacts(0), y0, t0)
    # A step's end's contacts are the next one's start's.
    found, have = _no_contacts(0), False
    n_log = 0
    for taken in range(n_steps):
        t_end = base + (steps0 + taken + 1) * dt
        if have and found[0] == 0:
            flew, y_new, con1 = _flight(ctx, y, cnt_step)
            if flew:
                _merge(cnt, cnt_step)
                record = (no_sel, no_force, found, y, t)
                y, t, found = y_new, t_end, con1
                continue
        res = _step(y, t, t_end, ctx, warm, cnt, found, have, log, n_log, no_sel, no_force,
                    no_flags, cnt_step)
        code, y_new, warm_new, rec, found, n_new = res
        if code != DONE:
            return taken, code, y, warm, record, n_log
        have = True
        y, t, warm, record, n_log = y_new, t_end, warm_new, rec, n_new
    return n_steps, DONE, y, warm, record, n_log


@njit(cache=True, inline='always')
def _advance_ctx(ctx: tuple, y0: np.ndarray, h: float, nw: int, flags: int) -> tuple:
    """Return :func:`_advance` with the arrays of ``ctx`` (by index: no name for the rest)."""
    return _advance(ctx[0], y0, h, _cx_model(ctx), nw, flags, _matrix(ctx, MT_KICK),
                    _cx_counts(ctx), ctx[3], _vector(ctx, MT_WS), _matrix(ctx, MT_FRAMES))


@njit(cache=True, inline='always')
def _detect_ctx(ctx: tuple, y: np.ndarray) -> tuple:
    """Return :func:`detect` at state buffer ``y`` with the arrays of ``ctx``."""
    det, buf = _detector(ctx[6])
    pos, quat, vel, om = state_parts(y)
    return detect(pos, quat, vel, om, det, buf, _matrix(ctx, MT_FRAMES), _matrix(ctx, MT_OUT))


@njit(cache=True, inline='always')
def _make_rows(ctx: tuple, y: np.ndarray, con: tuple, sel: np.ndarray) -> tuple:
    """Return the rows of contacts ``sel`` of ``con`` at ``y`` (:func:`rows`), and their bodies."""
    c0, sa, sb, ba, bb, pt, nr, dp = con
    pos, quat, vel, om = state_parts(y)
    R = rotations(quat)
    ba_s, bb_s = ba[sel], bb[sel]
    frame, la, lb, mu, e, sliding, vn, Ga, Gb = rows(pos, vel, om, R, sel, ba, bb, pt, nr, sa,
                                                     sb, _vector(ctx, MT_MU), _vector(ctx, MT_E),
                                                     _vector(ctx, MT_PRM)[P_RATE],
                                                     ba_s, bb_s)
    return sel, frame, la, lb, mu, e, sliding, vn, Ga, Gb, ba_s, bb_s


@njit(cache=True, inline='always')
def _subset(r: tuple, keep: np.ndarray) -> tuple:
    """Return rows ``r``'s contacts ``keep`` (increasing indices; all of them: ``r`` itself)."""
    sel, frame, la, lb, mu, e, sliding, vn, Ga, Gb, ba, bb = r
    if keep.shape[0] == sel.shape[0]:
        return r
    rows3 = np.empty(3 * keep.shape[0], dtype=np.int64)
    for k in range(keep.shape[0]):
        for a in range(3):
            rows3[3 * k + a] = 3 * keep[k] + a
    return (sel[keep], frame[keep], la[keep], lb[keep], mu[keep], e[keep], sliding[keep],
            vn[keep], Ga[rows3], Gb[rows3], ba[keep], bb[keep])


@njit(cache=True, inline='always')
def _where(mask: np.ndarray) -> np.ndarray:
    """Return the indices where ``mask`` holds."""
    k = 0
    for j in range(mask.shape[0]):
        if mask[j]:
            k += 1
    out = np.empty(k, dtype=np.int64)
    k = 0
    for j in range(mask.shape[0]):
        if mask[j]:
            out[k] = j
            k += 1
    return out


@njit(cache=True, inline='always')
def _continuing(ctx: tuple, r_con: tuple, r_sel: np.ndarray, r_y: np.ndarray,
                which: np.ndarray, con: tuple, y: np.ndarray, also: np.ndarray) -> tuple:
    """
    Return :func:`match` of the rows (``r_sel`` of ``r_con`` at ``r_y``) on ``con`` at ``y``.

    (A caller with no second set of rows passes ``which`` as ``also``.)
    """
    _, sa0, sb0, ba0, _, pt0, _, _ = r_con
    _, sa1, sb1, ba1, _, pt1, _, _ = con
    pos0, quat0, _, _ = state_parts(r_y)
    pos1, quat1, _, _ = state_parts(y)
    return match(r_sel, sa0, sb0, ba0, pt0, pos0, rotations(quat0),
                 which, sa1, sb1, ba1, pt1, pos1, rotations(quat1), _vector(ctx, MT_RADIUS),
                 _vector(ctx, MT_MU).shape[0] + 1, also)


@njit(cache=True, inline='always')
def _flight(ctx: tuple, y0: np.ndarray, cnt: np.ndarray) -> tuple:
    """
    Take a step that starts with no contact within the margin: ``(taken, y, contacts)``.

    No impact, no rows: the step is the free step and the detection at its end (as
    :func:`_held`'s with no rows, :func:`_accept` with nothing deep or held), unless
    that end overlaps deeper than the tolerance (an event to locate), is not finite or
    outgrows the detector's buffers: then not taken (``cnt`` untouched), and the general
    path takes the step. (Measured: a body in flight, 6 to 8 us a step through the
    general path; about the free step and the detection alone here.)
    """
    prm = _vector(ctx, MT_PRM)
    free, finite = _advance_ctx(ctx, y0, ctx[4], ctx[1], ctx[2])
    if not finite or prm[P_MAX_EVENTS] < 1.0:
        return False, free, _no_contacts(0)
    con1 = _detect_ctx(ctx, free)
    end = _deepest(con1[7])
    if con1[0] < 0 or end > prm[P_LOCATION]:
        return False, free, con1
    cnt[:] = 0.0
    cnt[C_END_DEPTH] = max(0.0, end)
    return True, free, con1


@njit(cache=True, inline='always')
def _stopped(code: int, y0: np.ndarray, t0: float, warm: tuple, found: tuple,
             n_log: int) -> tuple:
    """Return :func:`_step`'s result for a step not taken (``code``): nothing changed."""
    empty = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)), _no_contacts(0), y0, t0)
    return code, y0, warm, empty, found, n_log


@njit(cache=True)
def _step(y0: np.ndarray, t0: float, t_end: float, ctx: tuple, warm: tuple,
          cnt_total: np.ndarray, found: tuple, have: bool, log: np.ndarray,
          n_log: int, no_sel: np.ndarray, no_force: np.ndarray, no_flags: np.ndarray,
          cnt: np.ndarray) -> tuple:
    """
    Take one step, as ``ContactSteps.step``: ``(code, y, warm, record, contacts at y, n_log)``.

    ``found``: the contacts at ``y0`` when ``have`` (the last step's end's); ``no_sel``,
    ``no_force``, ``no_flags``: empty arrays (a record of no rows, no overlaps, no
    flags); ``cnt``: room for the step's counters (overwritten; added to ``cnt_total``
    when the step is taken).
    """
    prm, dt = _vector(ctx, MT_PRM), ctx[4]
    loc, unlocated = prm[P_LOCATION], prm[P_UNLOCATED]
    max_events, max_bounces = int(prm[P_MAX_EVENTS]), int(prm[P_MAX_BOUNCES])
    cnt[:] = 0.0
    con = found if have else _detect_ctx(ctx, y0)
    if con[0] < 0:
        return _stopped(GROW, y0, t0, warm, found, n_log)
    if con[0] == 0:
        taken, free, con1 = _flight(ctx, y0, cnt)
        if taken:
            _merge(cnt_total, cnt)
            return DONE, free, warm, (no_sel, no_force, con, y0, t0), con1, n_log
    state, t = y0, t0
    events, bounces = 0, 0
    first = True
    # (a record of no rows; the first pass's trial step sets it before it is read)
    record = (no_sel, no_force, con, y0, t0)
    while True:
        h = dt if first else t_end - t
        if not first and h <= 4.0 * EPS * abs(t_end):
            code, new, con_new = _accept(ctx, state, record, cnt, con, no_flags, False)
            break
        first = False
        near = _in_margin(ctx, state, con)
        touching = near if unlocated <= 0.0 else _touching(near, con, loc)
        if touching[0].shape[0] and events < max_events:
            code, state2, hit, n_log = _impact(ctx, state, t, con, touching,
                                               bounces >= max_bounces, cnt, log, n_log)
            if code == FULL:
                return _stopped(FULL, y0, t0, warm, found, n_log)
            if code != DONE:
                return _stopped(BAIL, y0, t0, warm, found, n_log)
            if hit:
                bounces += 1
                events += 1
                state = state2
                near = _in_margin(ctx, state, con)
        rows_ = _step_rows(ctx, con, near)
        # The overlaps the (partial) step starts from that are not rows (``_overlapping``;
        # none where no contact is deep: no arrays made).
        ov = no_sel
        if _deepest(con[7]) > loc:
            every = np.ones(rows_[0].shape[0], dtype=np.bool_)
            cont0 = _continuing(ctx, con, rows_[0], state, every, con, state, every)[1]
            deep0 = np.zeros(con[0], dtype=np.bool_)
            for j in range(con[0]):
                deep0[j] = con[7][j] > loc and not cont0[j]
            ov = _where(deep0)
        code, trial, nw, fl, warm, record, con_trial, matched = _held(ctx, state, t, con,
                                                                      rows_, h, warm, cnt)
        if code != DONE:
            return _stopped(GROW if code == GROW else BAIL, y0, t0, warm, found, n_log)
        held_sel = record[0]   # (the rows held: those apart that the step closes slowly)
        hit_depth = -np.inf
        # (the contacts at the trial's end that continue loaded rows, matched with the new
        # contacts' match and handed to _accept)
        held_end, have_held = no_flags, False   # (an array of its type, not read)
        if events < max_events:
            cont, held_end = _known(ctx, con, held_sel, ov, state, con_trial, trial,
                                    _loaded(record), matched)
            have_held = True
            for j in range(con_trial[0]):
                if not cont[j] and con_trial[7][j] > loc:
                    hit_depth = max(hit_depth, con_trial[7][j])
        else:
            cnt[C_CAPPED] += 1
        if hit_depth == -np.inf:
            code, new, con_new = _accept(ctx, trial, record, cnt, con_trial, held_end,
                                         have_held)
            break
        code, located, tau = _locate(ctx, state, con, held_sel, ov, h, hit_depth, nw, fl)
        if code != DONE:
            return _stopped(GROW if code == GROW else BAIL, y0, t0, warm, found, n_log)
        if tau <= 0.0:
            code, new, con_new = _accept(ctx, trial, record, cnt, con_trial, held_end,
                                         have_held)
            break
        cnt[C_LOCATED] += 1
        state, t = located, t + tau
        events += 1
        con = _detect_ctx(ctx, state)
        if con[0] < 0:
            return _stopped(GROW, y0, t0, warm, found, n_log)
    if code != DONE:
        return _stopped(GROW if code == GROW else BAIL, y0, t0, warm, found, n_log)
    _merge(cnt_total, cnt)
    return DONE, new, warm, record, con_new, n_log


@njit(cache=True, inline='always')
def _in_margin(ctx: tuple, y: np.ndarray, con: tuple) -> tuple:
    """
    Return the rows of the contacts a step may hold, as ``ContactSteps._in_margin``.

    Those touching while ``P_UNLOCATED`` is 0, else every contact of ``con``.
    """
    if _vector(ctx, MT_PRM)[P_UNLOCATED] <= 0.0:
        return _make_rows(ctx, y, con, _at_least(con[7], -_vector(ctx, MT_PRM)[P_LOCATION]))
    return _make_rows(ctx, y, con, np.arange(con[0]))


@njit(cache=True, inline='always')
def _at_least(x: np.ndarray, bound: float) -> np.ndarray:
    """Return the indices where ``x >= bound`` (no mask array made)."""
    k = 0
    for j in range(x.shape[0]):
        if x[j] >= bound:
            k += 1
    out = np.empty(k, dtype=np.int64)
    k = 0
    for j in range(x.shape[0]):
        if x[j] >= bound:
            out[k] = j
            k += 1
    return out


@njit(cache=True, inline='always')
def _touching(near: tuple, con: tuple, loc: float) -> tuple:
    """Return the rows ``near`` of contacts of ``con`` touching (depth ``>= −loc``)."""
    return _rows_within(near, con, loc, -np.inf)


@njit(cache=True, inline='always')
def _rows_within(near: tuple, con: tuple, loc: float, slow: float) -> tuple:
    """
    Return the rows ``near`` whose contact of ``con`` touches or closes slowly.

    Touching: depth ``>= −loc``; closing slowly: normal rate ``>= −slow`` (``slow``
    −inf: touching alone). All of them: ``near`` itself, no index array made.
    """
    sel, vn = near[0], near[7]
    kept = 0
    for k in range(sel.shape[0]):
        kept += con[7][sel[k]] >= -loc or vn[k] >= -slow
    if kept == sel.shape[0]:
        return near
    keep = np.empty(kept, dtype=np.int64)
    kept = 0
    for k in range(sel.shape[0]):
        if con[7][sel[k]] >= -loc or vn[k] >= -slow:
            keep[kept] = k
            kept += 1
    return _subset(near, keep)


@njit(cache=True, inline='always')
def _step_rows(ctx: tuple, con: tuple, near: tuple) -> tuple:
    """
    Return the rows a (partial) step holds, as ``ContactSteps._step_rows``.

    Of ``near`` (:func:`_in_margin`): the touching contacts (gap within the tolerance) and,
    while ``P_UNLOCATED`` is positive, the contacts apart within the margin that close
    slower than it (their rows ask the step to close at most their gap: ``_held``).
    """
    prm = _vector(ctx, MT_PRM)
    slow = prm[P_UNLOCATED]
    if slow <= 0.0:
        return _subset(near, _where(near[7] <= prm[P_RATE]))
    return _rows_within(near, con, prm[P_LOCATION], slow)


@njit(cache=True)
def _impact(ctx: tuple, y: np.ndarray, t: float, con: tuple, r: tuple, inelastic: bool,
            cnt: np.ndarray, log: np.ndarray, n_log: int) -> tuple:
    """
    Resolve the impacts at ``y``, as ``ContactSteps._impact``: ``(code, y, hit, n_log)``.

    ``code`` FULL: the log cannot take these impacts; BAIL: a row no impulse moves.
    """
    con, r = raw_tree((con, r))   # (y, which may be returned, is not borrowed)
    sel, frame, la, lb, mu, e, sliding, vn_, Ga, Gb, ba, bb = r
    prm, minv = _vector(ctx, MT_PRM), _matrix(ctx, MT_MINV)
    rate = prm[P_RATE]
    pos, quat, vel, om = state_parts(y)
    c = sel.shape[0]
    approaching = 0
    for k in range(c):   # (apply_rows' entries one row at a time: no array where none is)
        if _row_rate(Ga, Gb, ba, bb, vel, om, 3 * k) < -rate:
            approaching += 1
    if approaching == 0:
        return DONE, y, False, n_log
    rel = apply_rows(Ga, Gb, ba, bb, vel, om)
    if n_log + approaching > log.shape[0]:
        return FULL, y, False, n_log
    q = rel.copy()
    bounce = prm[P_BOUNCE]
    for k in range(c):
        if rel[3 * k] < -rate:
            q[3 * k] += (0.0 if inelastic or rel[3 * k] >= -bounce else e[k]) * rel[3 * k]
    D = delassus(Ga, Gb, ba, bb, minv)
    p, ok = solve_rows(D, q, mu, np.zeros(3 * c), False, np.zeros(c, dtype=np.bool_), False,
                       sliding, prm, cnt)
    if not ok:
        return BAIL, y, False, n_log
    dv = response(Ga, Gb, ba, bb, minv, p)
    new = y.copy()
    npos, nquat, nvel, nom = state_parts(new)
    for i in range(npos.shape[0]):
        for a in range(3):
            nvel[i, a] += dv[i, a]
            nom[i, a] += dv[i, 3 + a]
    after = rel + apply_rows(Ga, Gb, ba, bb, dv[:, :3].copy(), dv[:, 3:].copy())
    cnt[C_IMPACTS] += approaching
    sa, sb = con[1], con[2]
    for k in range(c):
        if rel[3 * k] < -rate:
            log[n_log, 0], log[n_log, 1], log[n_log, 2] = t, sa[sel[k]], sb[sel[k]]
            log[n_log, 3], log[n_log, 4] = rel[3 * k], after[3 * k]
            n_log += 1
    return DONE, new, True, n_log


@njit(cache=True, inline='always')
def _unheld(code: int, y0: np.ndarray, t: float, flags: int, warm: tuple) -> tuple:
    """Return :func:`_held`'s result for a step it could not take (``code``)."""
    none = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)), _no_contacts(0), y0, t)
    return code, y0, 0, flags, warm, none, _no_contacts(0), _unmatched()


@njit(cache=True, inline='always')
def _unmatched() -> tuple:
    """Return :func:`_held`'s ``matched`` of no match made."""
    none = np.zeros(0, dtype=np.bool_)
    return none, none, False


@njit(cache=True, inline='always')
def _located_later(depth: float, rate: float, prm: np.ndarray) -> bool:
    """
    Return if a row leaves the held step, to be located as an event (``_held_step``).

    Its contact is apart (``depth`` below ``−P_LOCATION``) and closes faster than twice
    ``P_UNLOCATED`` (``rate``, its normal velocity at the free step's end).
    """
    return depth < -prm[P_LOCATION] and not rate >= -2.0 * prm[P_UNLOCATED]


@njit(cache=True)
def _held(ctx: tuple, y0: np.ndarray, t: float, con: tuple, r: tuple, h: float, warm: tuple,
          cnt: np.ndarray) -> tuple:
    """
    Take the trial step with the rows' forces held, as ``ContactSteps._held_step``.

    Returns ``(code, new, nw, flags, warm, record, contacts at new, matched)``: ``nw`` and
    ``flags`` the wrench rows the forces left in ``wbuf`` (the location's partial steps
    hold them); ``matched`` :func:`_known`'s match of the rows on the contacts at ``new``
    where the model's check made it (``(known, held, True)``; else not made, False).
    """
    # (the entries of ctx this reads, by index: no name for the rest)
    model, n_applied, flags = _cx_model(ctx), ctx[1], ctx[2]
    shape_mu, radius = _vector(ctx, MT_MU), _vector(ctx, MT_RADIUS)
    prm, minv = _vector(ctx, MT_PRM), _matrix(ctx, MT_MINV)
    wbuf = model[2]
    # The arguments the result holds (con, y0, sel in the record; warm when the step is
    # not taken) stay counted; the rest are read through uncounted views (alive for the
    # call). A subset of the rows (below) is this function's own: counted.
    sel = r[0]
    _, frame, la, lb, mu, e, sliding, vn, Ga, Gb, ba, bb = raw_tree(r)
    cv = raw_tree(con)
    c = sel.shape[0]
    n = minv.shape[0]
    rate = prm[P_RATE]
    free, finite = _advance_ctx(ctx, y0, h, n_applied, flags)
    if not finite:
        return _unheld(BAIL, y0, t, flags, warm)
    fpos, fquat, fvel, fom = state_parts(free)
    # The rows' velocities at the free step's end.
    q = apply_rows(Ga, Gb, ba, bb, fvel, fom)
    if c:
        # A contact apart closing faster than twice P_UNLOCATED at the free step's end
        # is an event located (``_held_step``).
        drops = 0
        for k in range(c):
            drops += _located_later(cv[7][sel[k]], q[3 * k], prm)
        if drops:
            kept = np.empty(c - drops, dtype=np.int64)
            x = 0
            for k in range(c):
                if not _located_later(cv[7][sel[k]], q[3 * k], prm):
                    kept[x] = k
                    x += 1
            r = _subset(r, kept)
            sel, frame, la, lb, mu, e, sliding, vn, Ga, Gb, ba, bb = r
            c = sel.shape[0]
            q_kept = np.empty(3 * c)
            for x in range(c):
                for a in range(3):
                    q_kept[3 * x + a] = q[3 * kept[x] + a]
            q = q_kept
    if c == 0:
        con1 = _detect_ctx(ctx, free)
        code = GROW if con1[0] < 0 else DONE
        return (code, free, n_applied, flags, warm, (sel, np.zeros((0, 3)), con, y0, t), con1,
                _unmatched())
    D = delassus(Ga, Gb, ba, bb, minv)
    # A row of a contact apart by its gap g asks v_n⁺ ≥ min(0, −2 g / h − v_n): the step
    # closes at most g (``_held_step``). (shift, the warm start and q + shift: one
    # allocation.)
    vecs = np.zeros(9 * c)
    shift, start, q_shift = vecs[:3 * c], vecs[3 * c:6 * c], vecs[6 * c:]
    for k in range(c):
        if cv[7][sel[k]] < -prm[P_LOCATION]:
            shift[3 * k] = max(0.0, -2.0 * cv[7][sel[k]] / h + vn[k])
    for x in range(3 * c):
        q_shift[x] = q[x] + shift[x]
    w_sa, w_sb, w_pt, w_pn = raw_tree(warm)
    pt0 = cv[5]
    shapes = shape_mu.shape[0] + 1   # (as the pairs' keys of :func:`match`)
    few, order, keys = _pair_index(w_sa, w_sb, shapes)
    for k in range(c):
        j = sel[k]
        key = cv[1][j] * shapes + cv[2][j]
        u = _pair_first(key, few, keys)
        while True:   # (the first near)
            x, u = _pair_next(key, u, few, order, keys, w_sa, w_sb, shapes)
            if x < 0:
                break
            if ((w_pt[x, 0] - pt0[j, 0]) ** 2 + (w_pt[x, 1] - pt0[j, 1]) ** 2
                    + (w_pt[x, 2] - pt0[j, 2]) ** 2) <= WARM_RADIUS2:
                start[3 * k] = w_pn[x]
                break
    bools = np.zeros(2 * c, dtype=np.bool_)   # (no equal rows, the rows loaded)
    no_equal, loaded = bools[:c], bools[c:]
    p, ok = solve_rows(D, q_shift, mu, start, False, no_equal, False, sliding, prm, cnt)
    if not ok:
        return _unheld(BAIL, y0, t, flags, warm)
    w = block_affine(D, p, q)
    turned, frame2, sliding2 = slip_turn(frame, mu, sliding, p, w, rate,
                                         prm[P_FRICTION_TOLERANCE])
    if turned:
        pos0, quat0, _, _ = state_parts(y0)
        frame, sliding = frame2, sliding2
        Ga, Gb = jacobian(frame, ba, bb, la, lb, rotations(quat0), n)
        D = delassus(Ga, Gb, ba, bb, minv)
        q = apply_rows(Ga, Gb, ba, bb, fvel, fom)
        p, ok = solve_rows(D, q + shift, mu, p, False, no_equal, False, sliding, prm, cnt)
        if not ok:
            return _unheld(BAIL, y0, t, flags, warm)
    pos0, quat0, _, _ = state_parts(y0)
    R0 = rotations(quat0)
    count = shape_mu.shape[0] + 1
    new = free
    nw, fl = n_applied, flags
    force = np.zeros((c, 3))
    con1 = con   # (a placeholder of its type; set below before it is returned)
    have1 = False
    known1 = held1 = loaded   # (placeholders of their type, returned only with have1)
    corrections = int(prm[P_MODEL_CORRECTIONS])
    for correction in range(corrections + 1):
        any_p = False
        for k in range(c):
            for x in range(3):
                force[k, x] = (p[3 * k] * frame[k, 0, x] + p[3 * k + 1] * frame[k, 1, x]
                               + p[3 * k + 2] * frame[k, 2, x]) / h
                if p[3 * k + x] != 0.0:
                    any_p = True
        if not any_p:
            new, nw, fl, have1 = free, n_applied, flags, False
            break
        nw = _contact_wrenches(wbuf, n_applied, n, ba, bb, la, lb, force)
        fl = flags | HAS_POSITION_FORCES
        new, finite = _advance_ctx(ctx, y0, h, nw, fl)
        if not finite:
            return _unheld(BAIL, y0, t, flags, warm)
        con1 = _detect_ctx(ctx, new)
        if con1[0] < 0:
            return _unheld(GROW, y0, t, flags, warm)
        have1 = True
        npos, nquat, nvel, nom = state_parts(new)
        # (the rows loaded, as _loaded of the step's record: its forces are these)
        for k in range(c):
            j = sel[k]
            loaded[k] = (force[k, 0] * cv[6][j, 0] + force[k, 1] * cv[6][j, 1]
                         + force[k, 2] * cv[6][j, 2]) > 0.0
        G1a, G1b, known1, held1 = _rows_at(sel, cv, ba, bb, pos0, R0, frame, Ga, Gb, con1,
                                           npos, rotations(nquat), radius, count, loaded)
        w1 = apply_rows(G1a, G1b, ba, bb, nvel, nom)
        # (the first model is the slip turn's w where nothing turned: the same p and q)
        model_w = w if correction == 0 and not turned else block_affine(D, p, q)
        off, qmax = 0.0, 0.0
        for x in range(3 * c):
            off = max(off, abs(w1[x] - model_w[x]))
            qmax = max(qmax, abs(q[x]))
        if correction == corrections or off <= prm[P_MODEL_TOLERANCE] * max(qmax, rate):
            break
        cnt[C_CORRECTIONS] += 1
        q = q + (w1 - model_w)
        p, ok = solve_rows(D, q + shift, mu, p, False, no_equal, False, sliding, prm, cnt)
        if not ok:
            return _unheld(BAIL, y0, t, flags, warm)
    if not have1:
        con1 = _detect_ctx(ctx, new)
        if con1[0] < 0:
            return _unheld(GROW, y0, t, flags, warm)
    # The warm start of the next step, indexed by sel: arrays of their own (two
    # allocations).
    ints = np.empty(2 * c, dtype=np.int64)
    sa_r, sb_r = ints[:c], ints[c:]
    floats = np.empty(4 * c)
    pt_r, w_pn = floats[:3 * c].reshape((c, 3)), floats[3 * c:]
    for k in range(c):
        j = sel[k]
        sa_r[k], sb_r[k] = cv[1][j], cv[2][j]
        for a in range(3):
            pt_r[k, a] = cv[5][j, a]
        w_pn[k] = p[3 * k]
    warm = (sa_r, sb_r, pt_r, w_pn)
    return DONE, new, nw, fl, warm, (sel, force, con, y0, t), con1, (known1, held1, have1)


@njit(cache=True)
def _locate(ctx: tuple, y0: np.ndarray, con: tuple, sel: np.ndarray, ov: np.ndarray, h: float,
            hit_depth: float, nw: int, fl: int) -> tuple:
    """
    Return ``(code, state, τ)``: where the first new contact's depth crossed zero.

    As ``ContactSteps._locate``: regula falsi (Illinois) over partial steps from ``y0``
    with the forces held (``wbuf[:nw]``); ``τ = 0`` when the new contact overlaps at
    ``y0`` already; ``ov``: the overlaps ``y0`` has that are not rows (not new).
    """
    prm = _vector(ctx, MT_PRM)
    con, sel, ov = raw_tree((con, sel, ov))   # (y0, which may be returned, is not borrowed)
    loc, rate = prm[P_LOCATION], prm[P_RATE]
    margin = pinned(ctx[6], 14, (1,))[0]
    g0, code = _new_depth(ctx, con, sel, ov, y0, con, y0, margin)
    if code != DONE:
        return code, y0, 0.0
    if g0 > loc:
        return DONE, y0, 0.0
    lo_t, lo_g = 0.0, min(g0, -loc)
    hi_t, hi_g = h, hit_depth
    side = 0
    best, best_t, have_best = y0, 0.0, False
    for _ in range(int(prm[P_MAX_LOCATION_ITERATIONS])):
        tau = (lo_t * hi_g - hi_t * lo_g) / (hi_g - lo_g)
        if not lo_t < tau < hi_t:
            tau = 0.5 * (lo_t + hi_t)
        trial, finite = _advance_ctx(ctx, y0, tau, nw, fl)
        if not finite:
            return BAIL, y0, 0.0
        con_t = _detect_ctx(ctx, trial)
        if con_t[0] < 0:
            return GROW, y0, 0.0
        g, code = _new_depth(ctx, con, sel, ov, y0, con_t, trial, margin)
        if abs(g) <= loc:
            cont = _known(ctx, con, sel, ov, y0, con_t, trial, np.zeros(0, dtype=np.bool_),
                          _unmatched())[0]
            fresh = np.zeros(con_t[0], dtype=np.bool_)
            for j in range(con_t[0]):
                fresh[j] = con_t[7][j] >= -loc and not cont[j]
            idx = _where(fresh)
            if idx.shape[0]:
                rt = _make_rows(ctx, trial, con_t, idx)
                for k in range(idx.shape[0]):
                    if rt[7][k] < -rate:
                        return DONE, trial, tau
            g = -loc
        if g > 0.0:
            hi_t, hi_g = tau, g
            if side == 1:
                lo_g *= 0.5
            side = 1
        else:
            lo_t, lo_g = tau, g
            if side == -1:
                hi_g *= 0.5
            side = -1
            best, best_t, have_best = trial, tau, True
    if not have_best:
        return DONE, y0, 0.0
    return DONE, best, best_t


@njit(cache=True, inline='always')
def _known(ctx: tuple, r_con: tuple, r_sel: np.ndarray, ov: np.ndarray, r_y: np.ndarray,
           con: tuple, y: np.ndarray, loaded: np.ndarray, matched: tuple) -> tuple:
    """
    Tell per contact of ``con`` at ``y`` whether it continues a row or an overlap ``ov``.

    Returns ``(known, held)``: ``held`` per contact whether it continues a row of
    ``loaded`` (:func:`_loaded`; :func:`_accept`'s held contacts, matched in the same
    pass; ``loaded`` of no rows: none). ``matched``: the rows' match made already
    (:func:`_held`'s), or not (:func:`_unmatched`).
    """
    if matched[2]:
        known, held = matched[0], matched[1]
    else:
        every = np.ones(r_sel.shape[0], dtype=np.bool_)
        _, known, held = _continuing(ctx, r_con, r_sel, r_y, every, con, y, loaded)
    if ov.shape[0]:
        every = np.ones(ov.shape[0], dtype=np.bool_)
        also = _continuing(ctx, r_con, ov, r_y, every, con, y, every)[1]
        for j in range(known.shape[0]):
            known[j] = known[j] or also[j]
    return known, held


@njit(cache=True)
def _new_depth(ctx: tuple, r_con: tuple, r_sel: np.ndarray, ov: np.ndarray, r_y: np.ndarray,
               con: tuple, y: np.ndarray, margin: float) -> tuple:
    """Return the deepest depth of new contacts (−margin: none), and DONE."""
    r_con, r_sel, ov, r_y, con, y = raw_tree((r_con, r_sel, ov, r_y, con, y))
    cont = _known(ctx, r_con, r_sel, ov, r_y, con, y, np.zeros(0, dtype=np.bool_),
                  _unmatched())[0]
    out = -np.inf
    for j in range(con[0]):
        if not cont[j]:
            out = max(out, con[7][j])
    return (-margin if out == -np.inf else out), DONE


@njit(cache=True)
def _accept(ctx: tuple, y: np.ndarray, record: tuple, cnt: np.ndarray, con: tuple,
            held0: np.ndarray, have_held: bool) -> tuple:
    """
    Correct the step's end, as ``ContactSteps._settle``: ``(code, y, contacts at y)``.

    ``con``: the contacts at ``y`` (the trial's, found by :func:`_held`; not found again);
    ``held0`` where ``have_held``: which of them continue a loaded row of ``record``
    (:func:`_known`'s, matched with the new contacts), else matched here.

    Depth beyond the tolerance and loaded contacts left apart are projected out
    (positions: the smallest pushes, loaded contacts held at zero depth; up to
    ``PROJECTION_PASSES`` linearized passes, until none is left; what they leave is
    counted); the loaded
    contacts' normal rates within ``HOLD_RATE`` of zero are set to zero.
    """
    prm, minv = _vector(ctx, MT_PRM), _matrix(ctx, MT_MINV)
    loc = prm[P_LOCATION]
    # (record and held0 are read, never returned: passed on uncounted; y and con may be)
    record, held0 = raw_tree((record, held0))
    sel, force, r_con, r_y, _ = record
    # (the loaded rows, made where a match needs them: not where held0 is given and
    # nothing is projected)
    active, have_active = held0, False
    if not have_held:
        active, have_active = _loaded(record), True
    held = held0 if have_held else _continuing(ctx, r_con, sel, r_y, active, con, y, active)[1]
    passes = int(prm[P_PROJECTION_PASSES])
    for pas in range(passes + 1):
        deep = lifted = False
        dmax, left = -np.inf, 0.0
        for j in range(con[0]):
            if con[7][j] > loc:
                deep = True
                left = max(left, con[7][j])
            if held[j] and con[7][j] < -loc:
                lifted = True
                left = max(left, -con[7][j])
            dmax = max(dmax, con[7][j])
        if not (deep or lifted):
            break
        if pas == passes:   # what the passes left (counted)
            cnt[C_PROJECTION_LEFT] = max(cnt[C_PROJECTION_LEFT], left)
            break
        if pas == 0 and deep:
            cnt[C_MAX_DEPTH] = max(cnt[C_MAX_DEPTH], dmax)
        pick = np.zeros(con[0], dtype=np.bool_)
        # (those apart by less than the deepest overlap or the widest lift: ``_settle``)
        reach = max(loc, dmax, left)
        for j in range(con[0]):
            pick[j] = held[j] or con[7][j] >= -reach
        idx = _where(pick)
        pr = _make_rows(ctx, y, con, idx)
        m = idx.shape[0]
        D = delassus(pr[8], pr[9], pr[10], pr[11], minv)
        q3 = np.zeros(3 * m)
        biggest = 0.0
        for k in range(m):
            q3[3 * k] = -con[7][idx[k]]
            biggest = max(biggest, abs(con[7][idx[k]]))
        lift = np.zeros(m, dtype=np.bool_)
        for k in range(m):
            lift[k] = held[idx[k]] and con[7][idx[k]] < -loc
        p, ok = solve_rows(D, q3, pr[4], np.zeros(3 * m), True, lift, True, pr[6], prm, cnt)
        if not ok:
            return BAIL, y, con
        moved = False
        for k in range(p.shape[0]):
            if p[k] != 0.0:
                moved = True
        if not moved:   # no push takes it out (a row no force moves: left, counted)
            cnt[C_PROJECTION_LEFT] = max(cnt[C_PROJECTION_LEFT], left)
            break
        if pas == 0:
            cnt[C_PROJECTIONS] += 1
        dq = response(pr[8], pr[9], pr[10], pr[11], minv, p)
        cnt[C_MAX_PROJECTED] = max(cnt[C_MAX_PROJECTED], biggest)
        y = y.copy()
        pos, quat, vel, om = state_parts(y)
        for i in range(pos.shape[0]):
            for a in range(3):
                pos[i, a] += dq[i, a]
            quat_exp_multiply(quat[i], dq[i, 3], dq[i, 4], dq[i, 5], quat[i])
        con = _detect_ctx(ctx, y)
        if con[0] < 0:
            return GROW, y, con
        if not have_active:
            active, have_active = _loaded(record), True
        held = _continuing(ctx, r_con, sel, r_y, active, con, y, active)[1]
    cnt[C_END_DEPTH] = max(cnt[C_END_DEPTH], _deepest(con[7]))
    if not _hold_needed(y, con, held, prm):
        return DONE, y, con
    hs = _where(held)
    nh = hs.shape[0]
    hvn = _normal_rates(y, con, hs)
    hr = _make_rows(ctx, y, con, hs)
    near = np.zeros(nh, dtype=np.bool_)
    for k in range(nh):
        near[k] = abs(hvn[k]) <= prm[P_HOLD_RATE]
    sr = _subset(hr, _where(near))
    nn = sr[0].shape[0]
    D2 = delassus(sr[8], sr[9], sr[10], sr[11], minv)
    q3 = np.zeros(3 * nn)
    for x in range(nn):
        q3[3 * x] = sr[7][x]
    p2, ok = solve_rows(D2, q3, sr[4], np.zeros(3 * nn), True, np.ones(nn, dtype=np.bool_),
                        True, sr[6], prm, cnt)
    if not ok:
        return BAIL, y, con
    dv = response(sr[8], sr[9], sr[10], sr[11], minv, p2)
    y = y.copy()
    pos, quat, vel, om = state_parts(y)
    for i in range(pos.shape[0]):
        for a in range(3):
            vel[i, a] += dv[i, a]
            om[i, a] += dv[i, 3 + a]
    cnt[C_HELD] += 1
    return DONE, y, con


@njit(cache=True, inline='always')
def _loaded(record: tuple) -> np.ndarray:
    """Return per row of a step's ``record`` whether its force pushes (its contact loaded)."""
    sel, force, r_con, _, _ = record
    nr = r_con[6]
    active = np.zeros(sel.shape[0], dtype=np.bool_)
    for k in range(sel.shape[0]):
        active[k] = (force[k, 0] * nr[sel[k], 0] + force[k, 1] * nr[sel[k], 1]
                     + force[k, 2] * nr[sel[k], 2]) > 0.0
    return active


@njit(cache=True)
def _normal_rates(y: np.ndarray, con: tuple, sel: np.ndarray) -> np.ndarray:
    """Return the normal rates of contacts ``sel`` of ``con`` at ``y`` (:func:`rows`'s ``vn``)."""
    _, _, _, ba, bb, pt, nr, _ = raw_tree(con)
    sel = raw_tree(sel)
    pos, quat, vel, om = state_parts(y)
    R = rotations(quat)
    vn = np.empty(sel.shape[0])
    for k in range(sel.shape[0]):
        j = sel[k]
        va0, va1, va2, _, _, _ = point_velocity(pos, vel, om, R, ba[j], pt[j])
        vb0, vb1, vb2, _, _, _ = point_velocity(pos, vel, om, R, bb[j], pt[j])
        vn[k] = (va0 - vb0) * nr[j, 0] + (va1 - vb1) * nr[j, 1] + (va2 - vb2) * nr[j, 2]
    return vn


@njit(cache=True)
def _hold_needed(y: np.ndarray, con: tuple, held: np.ndarray, prm: np.ndarray) -> bool:
    """
    Return if a contact ``held`` of ``con`` at ``y`` has a normal rate to hold.

    Off zero by at most ``P_HOLD_RATE`` and more than ``P_RATE_FLOOR``: :func:`_normal_rates`'
    rates, one at a time (no index or rate arrays: the common answer is no).
    """
    _, _, _, ba, bb, pt, nr, _ = raw_tree(con)
    held = raw_tree(held)
    if not np.any(held):
        return False
    pos, quat, vel, om = state_parts(y)
    R = rotations(quat)
    for j in range(held.shape[0]):
        if not held[j]:
            continue
        va0, va1, va2, _, _, _ = point_velocity(pos, vel, om, R, ba[j], pt[j])
        vb0, vb1, vb2, _, _, _ = point_velocity(pos, vel, om, R, bb[j], pt[j])
        vn = (va0 - vb0) * nr[j, 0] + (va1 - vb1) * nr[j, 1] + (va2 - vb2) * nr[j, 2]
        if abs(vn) <= prm[P_HOLD_RATE] and abs(vn) > prm[P_RATE_FLOOR]:
            return True
    return False


@njit(cache=True)
def _deepest(depth: np.ndarray) -> float:
    """Return the largest of ``depth`` (−inf: none)."""
    out = -np.inf
    for j in range(depth.shape[0]):
        out = max(out, depth[j])
    return out


@njit(cache=True)
def _merge(total: np.ndarray, cnt: np.ndarray) -> None:
    """Add a step's counters to ``total`` (the largest of the maxima)."""
    for x in range(cnt.shape[0]):
        if x in (C_ITERATIONS_MAX, C_COMPLEMENTARITY, C_MAX_DEPTH, C_MAX_PROJECTED,
                 C_PROJECTION_LEFT, C_END_DEPTH):
            total[x] = max(total[x], cnt[x])
        else:
            total[x] += cnt[x]


@njit(cache=True)
def _contact_wrenches(wbuf: np.ndarray, k: int, n: int, ba: np.ndarray, bb: np.ndarray,
                      la: np.ndarray, lb: np.ndarray, force: np.ndarray) -> int:
    """Write the contact forces as world wrenches after the ``k`` applied rows; return the rows."""
    ft = np.zeros((2, n + 1, 3))   # (forces and torques: one allocation)
    f, t = ft[0], ft[1]
    for c in range(force.shape[0]):
        a, b = ba[c], bb[c]
        x0, x1, x2 = _cross(la[c, 0], la[c, 1], la[c, 2], force[c, 0], force[c, 1], force[c, 2])
        y0, y1, y2 = _cross(lb[c, 0], lb[c, 1], lb[c, 2], force[c, 0], force[c, 1], force[c, 2])
        for x in range(3):
            f[a, x] += force[c, x]
            f[b, x] -= force[c, x]
        t[a, 0] += x0
        t[a, 1] += x1
        t[a, 2] += x2
        t[b, 0] -= y0
        t[b, 1] -= y1
        t[b, 2] -= y2
    rows_out = k
    for i in range(n):
        if f[i, 0] == 0.0 and f[i, 1] == 0.0 and f[i, 2] == 0.0 and t[i, 0] == 0.0 \
                and t[i, 1] == 0.0 and t[i, 2] == 0.0:
            continue
        wbuf[rows_out, :] = 0.0
        wbuf[rows_out, W_BODY] = i
        wbuf[rows_out, W_IN_BODY] = 0.0
        wbuf[rows_out, W_KIND] = WRENCH_APPLIED
        for x in range(3):
            wbuf[rows_out, W_FORCE + x] = f[i, x]
            wbuf[rows_out, W_TORQUE + x] = t[i, x]
            wbuf[rows_out, W_POINT + x] = 0.0
        rows_out += 1
    return rows_out


@njit(cache=True)
def _rows_at(sel: np.ndarray, con: tuple, ba: np.ndarray, bb: np.ndarray,
             pos0: np.ndarray, R0: np.ndarray, frame: np.ndarray, Ga: np.ndarray,
             Gb: np.ndarray, con1: tuple, pos: np.ndarray, R: np.ndarray, radius: np.ndarray,
             count: int, also: np.ndarray) -> tuple:
    """
    Return the rows' ``G`` at the end's geometry, as ``ContactSteps.rows_at``.

    The rows: contacts ``sel`` of ``con`` (at ``pos0``, ``R0``), on bodies ``ba``,
    ``bb``. With their ``G``, per contact of ``con1`` whether it continues a row, and a
    row of ``also`` (:func:`match`'s; what :func:`_known` would match of the same rows
    and contacts).
    """
    # (the rows' G are new arrays: every argument passed on uncounted)
    (sel, con, ba, bb, pos0, R0, frame, Ga, Gb, con1, pos, R, radius, also) = raw_tree(
        (sel, con, ba, bb, pos0, R0, frame, Ga, Gb, con1, pos, R, radius, also))
    c1, sa1, sb1, ba1, bb1, pt1, nr1, dp1 = con1
    c = sel.shape[0]
    n = pos.shape[0]
    every = np.ones(c, dtype=np.bool_)
    nearest, known, held = match(sel, con[1], con[2], con[3], con[5], pos0, R0, every, sa1,
                                 sb1, ba1, pt1, pos, R, radius, count, also)
    G1 = np.empty((2, 3 * c, 6))   # (both copies: one allocation)
    G1a, G1b = G1[0], G1[1]
    G1a[:] = Ga
    G1b[:] = Gb
    for k in range(c):
        j = nearest[k]
        if j < 0:
            continue
        b = bb[k]
        nrm = nr1[j]
        # t₁ turned with body b (the world: as it was), then onto the new normal.
        u = frame[k, 1]
        v0 = R0[b, 0, 0] * u[0] + R0[b, 1, 0] * u[1] + R0[b, 2, 0] * u[2]
        v1 = R0[b, 0, 1] * u[0] + R0[b, 1, 1] * u[1] + R0[b, 2, 1] * u[2]
        v2 = R0[b, 0, 2] * u[0] + R0[b, 1, 2] * u[1] + R0[b, 2, 2] * u[2]
        t0 = R[b, 0, 0] * v0 + R[b, 0, 1] * v1 + R[b, 0, 2] * v2
        t1 = R[b, 1, 0] * v0 + R[b, 1, 1] * v1 + R[b, 1, 2] * v2
        t2 = R[b, 2, 0] * v0 + R[b, 2, 1] * v1 + R[b, 2, 2] * v2
        s = t0 * nrm[0] + t1 * nrm[1] + t2 * nrm[2]
        t0, t1, t2 = t0 - s * nrm[0], t1 - s * nrm[1], t2 - s * nrm[2]
        s = math.sqrt(t0 ** 2 + t1 ** 2 + t2 ** 2)
        t0, t1, t2 = t0 / s, t1 / s, t2 / s
        x0, x1, x2 = _cross(nrm[0], nrm[1], nrm[2], t0, t1, t2)
        # The three rows (n, t₁, t₂) on each body, as :func:`jacobian` writes them (in
        # place: no arrays a contact).
        for side in range(2):
            i = ba[k] if side == 0 else b
            G = G1a if side == 0 else G1b
            if i >= n:
                for a in range(3):
                    G[3 * k + a] = 0.0
                continue
            sign = 1.0 if side == 0 else -1.0
            r0, r1, r2 = pt1[j, 0] - pos[i, 0], pt1[j, 1] - pos[i, 1], pt1[j, 2] - pos[i, 2]
            _jacobian_row(G, 3 * k, sign, nrm[0], nrm[1], nrm[2], r0, r1, r2, R, i)
            _jacobian_row(G, 3 * k + 1, sign, t0, t1, t2, r0, r1, r2, R, i)
            _jacobian_row(G, 3 * k + 2, sign, x0, x1, x2, r0, r1, r2, R, i)
    return G1a, G1b, known, held
