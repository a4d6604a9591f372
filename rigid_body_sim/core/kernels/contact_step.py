"""
Compiled kernels: contact steps of bodies no joint couples, whole, until an event.

:class:`..contact_step.ContactSteps` takes a step with contact in Python over
compiled detection and integration: some sixty numpy calls and up to four
integrator calls a step, about a millisecond. Most steps of a scene of free bodies
have no event in them (no impact, no contact beginning to slip, no depth to
project): for those the same arithmetic runs here, in one compiled call, for as
many steps as the caller asks (:func:`contact_steps`). A step that meets anything
else is given back untouched (``BAIL``) and the Python path takes it: it is the
reference, and this is its common case, compiled. Per step, as
:meth:`..contact_step.ContactSteps.step` with its docstring's names:

1. detection at the start; the touching contacts' rows (``G`` as two (3c, 6)
   blocks, on body ``a`` and body ``b``); one approaching faster than the rate
   tolerance is an impact: ``BAIL``;
2. the free trial step; with rows, the LCP ``w = A p + q`` (``A = G M⁻¹ Gᵀ``, ``q =
   G ṽ``) by the friction boxes' fixed point over a proximal active-set solve
   (:func:`solve_direct`, :func:`solve_rows`), warm-started from the last step's
   normal impulses of the same contacts; a sticking contact that begins to slip:
   ``BAIL``;
3. the step with the forces held (world wrenches), the model checked at the end's
   geometry (each contact found again: :func:`match`) and corrected up to
   ``MODEL_CORRECTIONS`` times;
4. a new contact deeper than the tolerance (an impact inside the step): ``BAIL``;
5. the end: a contact deeper than the tolerance or a loaded contact left apart
   (a projection): ``BAIL``; the loaded contacts' normal rates within ``HOLD_RATE``
   of zero are set to zero by the same mass-weighted projection.

The results agree with the Python path's to rounding (the tests run both). The
counters a step adds are written to ``cnt`` (:data:`COUNTERS`); a step given back
adds nothing there (its work is counted by the Python path that takes it).
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

from .contact import all_bounds, broad_phase, narrow_phase, plane_pairs, shape_frames
from .free_step import FINITE, free_step, HAS_POSITION_FORCES, outputs, state_parts
from .layout import O_WIDTH, W_BODY, W_FORCE, W_IN_BODY, W_KIND, W_POINT, W_TORQUE, WRENCH_APPLIED
from .so3 import quat_matrix

#: Slots of the tolerances ``prm`` (the constants of :mod:`..contact_step`).
(P_LOCATION, P_RATE, P_FRICTION_TOLERANCE, P_FRICTION_ITERATIONS, P_PROXIMAL,
 P_MODEL_TOLERANCE, P_MODEL_CORRECTIONS, P_HOLD_RATE, P_RATE_FLOOR, P_WIDTH) = range(10)
#: The counters of :class:`..contact_step.ContactSteps` this kernel adds to, in ``cnt``'s order.
COUNTERS = ('lcp_solves', 'lcp_iterations_max', 'lcp_failures', 'complementarity_max',
            'model_corrections', 'held_rates')
C_SOLVES, C_ITERATIONS_MAX, C_FAILURES, C_COMPLEMENTARITY, C_CORRECTIONS, C_HELD = range(6)
#: Why :func:`contact_steps` stopped: every step taken; an event (the Python path's);
#: the detector's buffers too small (grow them and call again).
DONE, BAIL, GROW = 0, 1, 2
#: Per row of a box LCP: at its lower bound, free, at its upper bound.
AT_LOWER, FREE, AT_UPPER = -1, 0, 1
ROUNDING_ULPS = 64.0
EPS = 2.220446049250313e-16
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
    solids, planes, solid_body, solid_group, solid_mask, excluded, live, margin)``;
    ``buf``: its buffers ``(pairs, plane_pairs, points, normals, depths, owner, lo, hi,
    c, R)``; ``out`` (n, O_WIDTH) is overwritten with the bodies' outputs.
    """
    (kind, size, c_body, R_body, body, group, mask, solids, planes, solid_body, solid_group,
     solid_mask, excluded, live, margin) = det
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
    count = narrow_phase(every, kind, c, R, size, margin, points, normals, depths, owner)
    if count > depths.shape[0]:
        return _no_contacts(-1)
    sa, sb = np.empty(count, dtype=np.int64), np.empty(count, dtype=np.int64)
    ba, bb = np.empty(count, dtype=np.int64), np.empty(count, dtype=np.int64)
    for j in range(count):
        a, b = every[owner[j], 0], every[owner[j], 1]
        sa[j], sb[j], ba[j], bb[j] = live[a], live[b], body[a], body[b]
    return (count, sa, sb, ba, bb, points[:count].copy(), normals[:count].copy(),
            depths[:count].copy())


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
         rate: float) -> tuple:
    """
    Return the rows of contacts ``sel`` at the state, as ``ContactSteps.rows``.

    ``(frame, lever_a, lever_b, mu, e, sliding, vn, Ga, Gb)``.

    ``frame`` (c, 3, 3) rows ``n, t₁, t₂``; ``Ga``, ``Gb`` (3c, 6): each row on body
    a's and body b's velocities (``v`` world, ``Ω`` principal; ``Gb`` zero for the world).
    """
    c = sel.shape[0]
    frame = np.empty((c, 3, 3))
    la, lb = np.zeros((c, 3)), np.zeros((c, 3))
    mu, e, vn = np.empty(c), np.empty(c), np.empty(c)
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
    Ga, Gb = jacobian(frame, ba_all[sel], bb_all[sel], la, lb, R, pos.shape[0])
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
def jacobian(frame: np.ndarray, ba: np.ndarray, bb: np.ndarray, la: np.ndarray,
             lb: np.ndarray, R: np.ndarray, n: int) -> tuple:
    """Return ``Ga``, ``Gb`` (3c, 6): row ``d``, lever ``r``: ``(d, Rᵀ (r × d))``, b's negated."""
    c = frame.shape[0]
    Ga, Gb = np.zeros((3 * c, 6)), np.zeros((3 * c, 6))
    for k in range(c):
        for side in range(2):
            i = ba[k] if side == 0 else bb[k]
            if i >= n:
                continue
            r = la[k] if side == 0 else lb[k]
            G = Ga if side == 0 else Gb
            sign = 1.0 if side == 0 else -1.0
            for a in range(3):
                d = frame[k, a]
                x0, x1, x2 = _cross(r[0], r[1], r[2], d[0], d[1], d[2])
                row = 3 * k + a
                for m in range(3):
                    G[row, m] = sign * d[m]
                    G[row, 3 + m] = sign * (R[i, 0, m] * x0 + R[i, 1, m] * x1 + R[i, 2, m] * x2)
    return Ga, Gb


@njit(cache=True)
def apply_rows(Ga: np.ndarray, Gb: np.ndarray, ba: np.ndarray, bb: np.ndarray,
               vel: np.ndarray, om: np.ndarray) -> np.ndarray:
    """Return ``G ν`` (3c,) for the bodies' velocities ``vel`` (world), ``om`` (principal)."""
    n = vel.shape[0]
    w = np.zeros(Ga.shape[0])
    for row in range(Ga.shape[0]):
        k = row // 3
        for side in range(2):
            i = ba[k] if side == 0 else bb[k]
            if i >= n:
                continue
            G = Ga if side == 0 else Gb
            s = 0.0
            for m in range(3):
                s += G[row, m] * vel[i, m] + G[row, 3 + m] * om[i, m]
            w[row] += s
    return w


@njit(cache=True)
def delassus(Ga: np.ndarray, Gb: np.ndarray, ba: np.ndarray, bb: np.ndarray,
             minv: np.ndarray) -> np.ndarray:
    """
    Return ``A = G M⁻¹ Gᵀ`` (3c, 3c); ``minv`` (n, 6) per body ``1/m`` (3) and ``1/J`` (3).

    Only the blocks of two contacts on a common body are non-zero (a stack's contacts
    meet those of the interfaces next to them alone): those are the ones computed.
    """
    n = minv.shape[0]
    c = ba.shape[0]
    A = np.zeros((3 * c, 3 * c))
    for k in range(c):
        for side_k in range(2):
            i = ba[k] if side_k == 0 else bb[k]
            if i >= n:
                continue
            Gk = Ga if side_k == 0 else Gb
            for m in range(c):
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
                            A[r, s] += acc
    return A


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
def solve_direct(S: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 start: np.ndarray) -> tuple:
    """
    Return ``(f, converged, iterations)``: :func:`..complementarity.solve_direct`, compiled.

    The same primal active-set method, its cap ``10 (n + 1)``, its rounding test.
    """
    n = q.shape[0]
    f = np.empty(n)
    state = np.zeros(n, dtype=np.int64)
    for i in range(n):
        x = start[i] if math.isfinite(start[i]) else 0.0
        f[i] = min(max(x, lo[i]), hi[i])
        state[i] = AT_LOWER if f[i] <= lo[i] else (AT_UPPER if f[i] >= hi[i] else FREE)
    cap = 10 * (n + 1)
    for it in range(1, cap + 1):
        nf = 0
        for i in range(n):
            if state[i] == FREE:
                nf += 1
        free = np.empty(nf, dtype=np.int64)
        k = 0
        for i in range(n):
            if state[i] == FREE:
                free[k] = i
                k += 1
        target = f.copy()
        if nf:
            Sf = np.empty((nf, nf))
            rhs = np.empty(nf)
            for a in range(nf):
                i = free[a]
                s = q[i]
                for j in range(n):
                    if state[j] != FREE:
                        s += S[i, j] * f[j]
                rhs[a] = -s
                for b in range(nf):
                    Sf[a, b] = S[i, free[b]]
            x = spd_solve(Sf, rhs)
            for a in range(nf):
                target[free[a]] = x[a]
        hit, best, side = -1, np.inf, FREE
        for a in range(nf):
            i = free[a]
            step = target[i] - f[i]
            if target[i] < lo[i]:
                ratio = (lo[i] - f[i]) / step
                if ratio < best or hit < 0:
                    hit, best, side = i, ratio, AT_LOWER
            elif target[i] > hi[i]:
                ratio = (hi[i] - f[i]) / step
                if ratio < best or hit < 0:
                    hit, best, side = i, ratio, AT_UPPER
        if hit >= 0:
            alpha = min(max(best, 0.0), 1.0)
            for a in range(nf):
                i = free[a]
                f[i] += alpha * (target[i] - f[i])
            f[hit] = lo[hit] if side == AT_LOWER else hi[hit]
            state[hit] = side
            for i in range(n):
                f[i] = min(max(f[i], lo[i]), hi[i])
            continue
        f = target
        worst, kw = -np.inf, -1
        for i in range(n):
            w, mag = q[i], abs(q[i])
            for j in range(n):
                w += S[i, j] * f[j]
                mag += abs(S[i, j]) * abs(f[j])
            if state[i] == AT_LOWER:
                wrong = -w
            elif state[i] == AT_UPPER:
                wrong = w
            else:
                wrong = -np.inf
            wrong -= ROUNDING_ULPS * EPS * mag
            if kw < 0 or wrong > worst:
                worst, kw = wrong, i
        if n == 0 or worst <= 0.0:
            return f, True, it
        state[kw] = FREE
    return f, False, cap


@njit(cache=True)
def spd_solve(S: np.ndarray, b: np.ndarray) -> np.ndarray:
    """
    Return ``S⁻¹ b`` for ``S`` symmetric positive definite, by Cholesky.

    The free rows' systems are ``A + ρ I`` restricted (``ρ > 0``): positive definite. A
    pivot that rounding made non-positive falls back to LAPACK's LU (of the original).
    """
    n = b.shape[0]
    # Each row's first non-zero column: L keeps the envelope (a stack's rows are banded).
    first = np.empty(n, dtype=np.int64)
    for i in range(n):
        first[i] = i
        for j in range(i):
            if S[i, j] != 0.0:
                first[i] = j
                break
    L = S.copy()
    for j in range(n):
        d = L[j, j]
        for k in range(first[j], j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return np.linalg.solve(S, b)
        d = math.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, n):
            if first[i] > j:
                L[i, j] = 0.0
                continue
            s = L[i, j]
            for k in range(max(first[i], first[j]), j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    x = b.copy()
    for i in range(n):
        s = x[i]
        for k in range(first[i], i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return x


@njit(cache=True)
def solve_rows(A: np.ndarray, q: np.ndarray, mu: np.ndarray, start: np.ndarray,
               normal_only: bool, equal: bool, sliding: np.ndarray, prm: np.ndarray,
               cnt: np.ndarray) -> tuple:
    """
    Return ``(p, ok)``: the rows' impulses as :meth:`..contact_step.ContactSteps.solve`.

    ``start`` (3c,) the warm start; ``equal``: every normal row an equality (the
    projections); ``sliding`` (c,) contacts with one friction row. ``ok`` False: a
    row no impulse moves (the Python path's case, given back).
    """
    m = q.shape[0]
    nr = m // 3 if normal_only else m
    idx = np.empty(nr, dtype=np.int64)
    for k in range(nr):
        idx[k] = 3 * k if normal_only else k
    dmax = 0.0
    for k in range(nr):
        dmax = max(dmax, A[idx[k], idx[k]])
    for k in range(nr):
        if not A[idx[k], idx[k]] > 1e-12 * dmax:
            return np.zeros(m), False
    Ar = np.empty((nr, nr))
    qr = np.empty(nr)
    for a in range(nr):
        qr[a] = q[idx[a]]
        for b in range(nr):
            Ar[a, b] = 0.5 * (A[idx[a], idx[b]] + A[idx[b], idx[a]])
    dmax, qmax = 0.0, 0.0
    for a in range(nr):
        dmax = max(dmax, Ar[a, a])
        qmax = max(qmax, abs(qr[a]))
    rho = prm[P_PROXIMAL] * dmax
    floor = 64.0 * EPS * qmax / dmax
    Ap = Ar.copy()
    for a in range(nr):
        Ap[a, a] += rho
    p = np.empty(nr)
    for a in range(nr):
        p[a] = start[idx[a]]
    lo, hi = np.zeros(nr), np.full(nr, np.inf)
    step3 = 1 if normal_only else 3
    for a in range(0, nr, step3):
        if equal:
            lo[a] = -np.inf
        p[a] = max(p[a], lo[a])
    converged, it = False, 0
    tol = prm[P_FRICTION_TOLERANCE]
    for it in range(1, int(prm[P_FRICTION_ITERATIONS]) + 1):
        if not normal_only:
            for k in range(nr // 3):
                half = mu[k] * max(p[3 * k], 0.0)
                lo[3 * k + 1], hi[3 * k + 1] = -half, half
                half2 = 0.0 if sliding[k] else half
                lo[3 * k + 2], hi[3 * k + 2] = -half2, half2
            for a in range(nr):
                p[a] = min(max(p[a], lo[a]), hi[a])
        nf = 0
        for a in range(nr):
            if hi[a] > lo[a]:
                nf += 1
        fr = np.empty(nf, dtype=np.int64)
        k = 0
        for a in range(nr):
            if hi[a] > lo[a]:
                fr[k] = a
                k += 1
        Sf, qf = np.empty((nf, nf)), np.empty(nf)
        lof, hif, sf = np.empty(nf), np.empty(nf), np.empty(nf)
        for x in range(nf):
            a = fr[x]
            shift = 0.0
            for b in range(nr):
                if not hi[b] > lo[b]:
                    shift += Ap[a, b] * p[b]
            qf[x] = qr[a] - rho * p[a] + shift
            lof[x], hif[x], sf[x] = lo[a], hi[a], p[a]
            for y in range(nf):
                Sf[x, y] = Ap[a, fr[y]]
        f, ok, _ = solve_direct(Sf, qf, lof, hif, sf)
        change, scale = 0.0, 0.0
        for x in range(nf):
            change = max(change, abs(f[x] - p[fr[x]]))
            p[fr[x]] = f[x]
        for a in range(nr):
            scale = max(scale, abs(p[a]))
        scale = max(scale, 1e-300)
        if ok and change <= tol * scale + floor:
            converged = True
            break
    cnt[C_SOLVES] += 1
    cnt[C_ITERATIONS_MAX] = max(cnt[C_ITERATIONS_MAX], it)
    if not converged:
        cnt[C_FAILURES] += 1
    if not equal:
        cnt[C_COMPLEMENTARITY] = max(cnt[C_COMPLEMENTARITY],
                                     residual(Ar, qr, p, mu, normal_only, sliding, tol))
    out = np.zeros(m)
    for a in range(nr):
        out[idx[a]] = p[a]
    return out, True


@njit(cache=True)
def residual(A: np.ndarray, q: np.ndarray, p: np.ndarray, mu: np.ndarray, normal_only: bool,
             sliding: np.ndarray, tol: float) -> float:
    """Return how far the contact conditions are from holding (m/s), as the Python path."""
    m = q.shape[0]
    if not m:
        return 0.0
    w = A @ p + q
    pmax, qmax, dmax = 0.0, 0.0, 0.0
    for a in range(m):
        pmax, qmax, dmax = max(pmax, abs(p[a])), max(qmax, abs(q[a])), max(dmax, A[a, a])
    out = 0.0
    if normal_only:
        for a in range(m):
            out = max(out, abs(min(p[a] * A[a, a], w[a])))
        return out
    slack = 2.0 * (tol * pmax + 64.0 * EPS * qmax / dmax)
    for k in range(m // 3):
        out = max(out, abs(min(p[3 * k] * A[3 * k, 3 * k], w[3 * k])))
        bound = mu[k] * max(p[3 * k], 0.0)
        for col in range(1, 3):
            if col == 2 and sliding[k]:
                continue
            f, v = p[3 * k + col], w[3 * k + col]
            if abs(f) < bound - slack:
                out = max(out, abs(v))
            elif bound > 0.0:
                out = max(out, max(f * v, 0.0) / bound)
    return out


@njit(cache=True)
def slipping(frame: np.ndarray, mu: np.ndarray, sliding: np.ndarray, p: np.ndarray,
             w: np.ndarray, rate: float, tol: float) -> bool:
    """Tell whether a sticking contact begins to slip (``_slipping`` would turn one)."""
    c = mu.shape[0]
    pmax = 0.0
    for a in range(p.shape[0]):
        pmax = max(pmax, abs(p[a]))
    slack = 2.0 * tol * pmax
    for k in range(c):
        if sliding[k]:
            continue
        bound = mu[k] * max(p[3 * k], 0.0)
        if not bound > 0.0:
            continue
        on = abs(p[3 * k + 1]) >= bound - slack or abs(p[3 * k + 2]) >= bound - slack
        s = np.zeros(3)
        fr = np.zeros(3)
        for x in range(3):
            s[x] = w[3 * k + 1] * frame[k, 1, x] + w[3 * k + 2] * frame[k, 2, x]
            fr[x] = p[3 * k + 1] * frame[k, 1, x] + p[3 * k + 2] * frame[k, 2, x]
        speed = math.sqrt(s[0] ** 2 + s[1] ** 2 + s[2] ** 2)
        size = math.sqrt(fr[0] ** 2 + fr[1] ** 2 + fr[2] ** 2)
        if size > bound + slack:
            return True
        if on and speed > rate:
            return True
    return False


# -- contacts found again -------------------------------------------------------------------

@njit(cache=True)
def in_body(pts: np.ndarray, body: np.ndarray, pos: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Return world points (k, 3) in their bodies' principal frames (the world's: as they are)."""
    n = pos.shape[0]
    out = pts.copy()
    for k in range(pts.shape[0]):
        i = body[k]
        if i >= n:
            continue
        d0, d1, d2 = pts[k, 0] - pos[i, 0], pts[k, 1] - pos[i, 1], pts[k, 2] - pos[i, 2]
        for a in range(3):
            out[k, a] = R[i, 0, a] * d0 + R[i, 1, a] * d1 + R[i, 2, a] * d2
    return out


@njit(cache=True)
def match(r_sa: np.ndarray, r_sb: np.ndarray, r_ba: np.ndarray, r_pt: np.ndarray,
          r_pos: np.ndarray, r_R: np.ndarray, which: np.ndarray, c_sa: np.ndarray,
          c_sb: np.ndarray, c_ba: np.ndarray, c_pt: np.ndarray, pos: np.ndarray,
          R: np.ndarray, radius: np.ndarray, count: int) -> tuple:
    """
    Return the contacts continuing rows, as ``ContactSteps._match`` and ``_continuing``.

    ``(nearest, continuing)``: per row the nearest contact continuing it (−1: none),
    per contact whether it continues a row of ``which`` (the same pair; its point in
    body a within its radius of the row's).
    """
    r, c = r_sa.shape[0], c_sa.shape[0]
    nearest = np.full(r, -1, dtype=np.int64)
    continuing = np.zeros(c, dtype=np.bool_)
    if r == 0 or c == 0:
        return nearest, continuing
    ls = in_body(r_pt, r_ba, r_pos, r_R)
    ln = in_body(c_pt, c_ba, pos, R)
    for i in range(r):
        if not which[i]:
            continue
        key = r_sa[i] * count + r_sb[i]
        best = np.inf
        for j in range(c):
            if c_sa[j] * count + c_sb[j] != key:
                continue
            d2 = ((ls[i, 0] - ln[j, 0]) ** 2 + (ls[i, 1] - ln[j, 1]) ** 2
                  + (ls[i, 2] - ln[j, 2]) ** 2)
            rad = radius[c_sa[j]]
            if d2 <= rad * rad:
                continuing[j] = True
                if d2 < best:
                    best, nearest[i] = d2, j
    return nearest, continuing


# -- a step ---------------------------------------------------------------------------------

@njit(cache=True)
def _advance(method: int, y0: np.ndarray, h: float, model: tuple, nw: int, flags: int,
             kick: np.ndarray, counts: np.ndarray, steps_slot: int, ws: np.ndarray,
             frames: np.ndarray) -> tuple:
    """Return the integrator's step of ``h`` from ``y0`` (a new buffer), and if it is finite."""
    body, gforce, wbuf = model
    y = y0.copy()
    pos, quat, vel, om = state_parts(y)
    code = free_step(method, pos, quat, vel, om, h, body, gforce, wbuf[:nw], flags, kick,
                     False, counts, np.zeros(0), ws, frames, np.zeros((0, O_WIDTH)))
    counts[steps_slot] += 1
    return y, (code & FINITE) != 0


@njit(cache=True)
def contact_steps(n_steps: int, y0: np.ndarray, dt: float, method: int, model: tuple,
                  n_applied: int, flags: int, kick: np.ndarray, counts: np.ndarray,
                  steps_slot: int, ws: np.ndarray, frames: np.ndarray, out: np.ndarray,
                  det: tuple, buf: tuple, shape_mu: np.ndarray, shape_e: np.ndarray,
                  radius: np.ndarray, warm: tuple, prm: np.ndarray, cnt: np.ndarray) -> tuple:
    """
    Take up to ``n_steps`` contact steps from ``y0`` (the module docstring); stop at a ``BAIL``.

    ``model``: ``(body, gforce, wbuf)``, ``wbuf`` (k + n, W_WIDTH) the applied wrench
    rows (first ``n_applied``) and room for one contact wrench per body; ``warm``:
    ``(shape_a, shape_b, point, p_n)`` of the last step's rows. Returns ``(taken,
    code, y, warm, record)``: the steps taken (``y`` the state after them; ``y0``
    when none), why they stopped (``DONE``, ``BAIL`` or ``GROW``: the detector's
    buffers are too small), the warm start for the next, and the last step's record
    ``(sel, force, contacts at its start, its start's state buffer)``.
    """
    y = y0
    record = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)), _no_contacts(0), y0)
    # A step's end's contacts are the next one's start's (the end's rates held change no
    # position).
    found, have = _no_contacts(0), False
    for taken in range(n_steps):
        res = _one_step(y, dt, method, model, n_applied, flags, kick, counts, steps_slot, ws,
                        frames, out, det, buf, shape_mu, shape_e, radius, warm, prm, cnt,
                        found, have)
        code, y_new, warm_new, rec, found = res
        if code != DONE:
            return taken, code, y, warm, record
        have = True
        y, warm, record = y_new, warm_new, (rec[0], rec[1], rec[2], y)
    return n_steps, DONE, y, warm, record


@njit(cache=True)
def _one_step(y0: np.ndarray, h: float, method: int, model: tuple, n_applied: int, flags: int,
              kick: np.ndarray, counts: np.ndarray, steps_slot: int, ws: np.ndarray,
              frames: np.ndarray, out: np.ndarray, det: tuple, buf: tuple,
              shape_mu: np.ndarray, shape_e: np.ndarray, radius: np.ndarray, warm: tuple,
              prm: np.ndarray, cnt_total: np.ndarray, found: tuple, have: bool) -> tuple:
    """
    Take one step of :func:`contact_steps`: ``(code, y, warm, record, contacts at y)``.

    ``found``: the contacts at ``y0`` when ``have`` (the last step's end's).
    """
    body, gforce, wbuf = model
    loc, rate = prm[P_LOCATION], prm[P_RATE]
    cnt = np.zeros(cnt_total.shape[0])
    pos0, quat0, vel0, om0 = state_parts(y0)
    n = pos0.shape[0]
    count = shape_mu.shape[0] + 1
    fail = (BAIL, y0, warm, (np.zeros(0, dtype=np.int64), np.zeros((0, 3)), _no_contacts(0)),
            found)
    grow = (GROW, y0, warm, (np.zeros(0, dtype=np.int64), np.zeros((0, 3)), _no_contacts(0)),
            found)
    con0 = found if have else detect(pos0, quat0, vel0, om0, det, buf, frames, out)
    c0, sa0, sb0, ba0, bb0, pt0, nr0, dp0 = con0
    if c0 < 0:
        return grow
    R0 = rotations(quat0)
    touching = np.empty(c0, dtype=np.int64)
    nt = 0
    for j in range(c0):
        if dp0[j] >= -loc:
            touching[nt] = j
            nt += 1
    touching = touching[:nt]
    frame, la, lb, mu, e, sliding, vn, Ga, Gb = rows(pos0, vel0, om0, R0, touching, ba0, bb0,
                                                     pt0, nr0, sa0, sb0, shape_mu, shape_e,
                                                     rate)
    keep = np.empty(nt, dtype=np.int64)
    c = 0
    for k in range(nt):
        if vn[k] < -rate:
            return fail   # an impact
        if vn[k] <= rate:
            keep[c] = k
            c += 1
    keep = keep[:c]
    sel = touching[keep]
    frame, la, lb, mu, sliding = frame[keep], la[keep], lb[keep], mu[keep], sliding[keep]
    rows3 = np.empty(3 * c, dtype=np.int64)
    for k in range(c):
        for a in range(3):
            rows3[3 * k + a] = 3 * keep[k] + a
    Ga, Gb = Ga[rows3], Gb[rows3]
    ba, bb = ba0[sel], bb0[sel]
    minv = np.empty((n, 6))
    for i in range(n):
        for a in range(3):
            minv[i, a] = body[i, 1]
            minv[i, 3 + a] = 1.0 / body[i, 2 + a]
    # The free trial step.
    free, finite = _advance(method, y0, h, model, n_applied, flags, kick, counts, steps_slot,
                            ws, frames)
    if not finite:
        return fail
    new = free
    force = np.zeros((c, 3))
    p = np.zeros(3 * c)
    con1 = _no_contacts(0)
    have1 = False
    if c:
        fpos, fquat, fvel, fom = state_parts(free)
        A = delassus(Ga, Gb, ba, bb, minv)
        q = apply_rows(Ga, Gb, ba, bb, fvel, fom)
        start = np.zeros(3 * c)
        w_sa, w_sb, w_pt, w_pn = warm
        for k in range(c):
            j = sel[k]
            for x in range(w_pn.shape[0]):
                if w_sa[x] == sa0[j] and w_sb[x] == sb0[j] and (
                        (w_pt[x, 0] - pt0[j, 0]) ** 2 + (w_pt[x, 1] - pt0[j, 1]) ** 2
                        + (w_pt[x, 2] - pt0[j, 2]) ** 2) <= WARM_RADIUS2:
                    start[3 * k] = w_pn[x]
                    break
        p, ok = solve_rows(A, q, mu, start, False, False, sliding, prm, cnt)
        if not ok:
            return fail
        if slipping(frame, mu, sliding, p, A @ p + q, rate, prm[P_FRICTION_TOLERANCE]):
            return fail
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
                new = free
                have1 = False
                break
            nw = _contact_wrenches(wbuf, n_applied, n, ba, bb, la, lb, force)
            new, finite = _advance(method, y0, h, model, nw, flags | HAS_POSITION_FORCES,
                                   kick, counts, steps_slot, ws, frames)
            if not finite:
                return fail
            npos, nquat, nvel, nom = state_parts(new)
            con1 = detect(npos, nquat, nvel, nom, det, buf, frames, out)
            if con1[0] < 0:
                return grow
            have1 = True
            R1 = rotations(nquat)
            G1a, G1b = _rows_at(sa0[sel], sb0[sel], ba, bb, pt0[sel], pos0, R0, frame, Ga, Gb,
                                con1, npos, R1, radius, count)
            w = apply_rows(G1a, G1b, ba, bb, nvel, nom)
            model_w = A @ p + q
            off, qmax = 0.0, 0.0
            for r in range(3 * c):
                off = max(off, abs(w[r] - model_w[r]))
                qmax = max(qmax, abs(q[r]))
            if correction == corrections or off <= prm[P_MODEL_TOLERANCE] * max(qmax, rate):
                break
            cnt[C_CORRECTIONS] += 1
            q = q + (w - model_w)
            p, ok = solve_rows(A, q, mu, p, False, False, sliding, prm, cnt)
            if not ok:
                return fail
    npos, nquat, nvel, nom = state_parts(new)
    if not have1:
        con1 = detect(npos, nquat, nvel, nom, det, buf, frames, out)
        if con1[0] < 0:
            return grow
    c1, sa1, sb1, ba1, bb1, pt1, nr1, dp1 = con1
    R1 = rotations(nquat)
    # A new contact overlapping beyond the tolerance: an impact inside the step.
    every = np.ones(c, dtype=np.bool_)
    _, cont = match(sa0[sel], sb0[sel], ba, pt0[sel], pos0, R0, every, sa1, sb1, ba1, pt1,
                    npos, R1, radius, count)
    for j in range(c1):
        if not cont[j] and dp1[j] > loc:
            return fail
    # The end: the loaded contacts held to zero normal rate (depth to project: given back).
    active = np.zeros(c, dtype=np.bool_)
    for k in range(c):
        active[k] = (force[k, 0] * nr0[sel[k], 0] + force[k, 1] * nr0[sel[k], 1]
                     + force[k, 2] * nr0[sel[k], 2]) > 0.0
    _, held = match(sa0[sel], sb0[sel], ba, pt0[sel], pos0, R0, active, sa1, sb1, ba1, pt1,
                    npos, R1, radius, count)
    nh = 0
    for j in range(c1):
        if dp1[j] > loc or (held[j] and dp1[j] < -loc):
            return fail
        if held[j]:
            nh += 1
    if nh:
        hs = np.empty(nh, dtype=np.int64)
        k = 0
        for j in range(c1):
            if held[j]:
                hs[k] = j
                k += 1
        hframe, hla, hlb, hmu, he, hsl, hvn, hGa, hGb = rows(npos, nvel, nom, R1, hs, ba1, bb1,
                                                             pt1, nr1, sa1, sb1, shape_mu,
                                                             shape_e, rate)
        needed = False
        nn = 0
        for k in range(nh):
            if abs(hvn[k]) <= prm[P_HOLD_RATE]:
                nn += 1
                if abs(hvn[k]) > prm[P_RATE_FLOOR]:
                    needed = True
        if needed:
            near = np.empty(nn, dtype=np.int64)
            k = 0
            for x in range(nh):
                if abs(hvn[x]) <= prm[P_HOLD_RATE]:
                    near[k] = x
                    k += 1
            r3 = np.empty(3 * nn, dtype=np.int64)
            for x in range(nn):
                for a in range(3):
                    r3[3 * x + a] = 3 * near[x] + a
            sGa, sGb = hGa[r3], hGb[r3]
            sba, sbb = ba1[hs[near]], bb1[hs[near]]
            A2 = delassus(sGa, sGb, sba, sbb, minv)
            q3 = np.zeros(3 * nn)
            for x in range(nn):
                q3[3 * x] = hvn[near[x]]
            p2, ok = solve_rows(A2, q3, hmu[near], np.zeros(3 * nn), True, True, hsl[near],
                                prm, cnt)
            if not ok:
                return fail
            dv = response(sGa, sGb, sba, sbb, minv, p2)
            new = new.copy()
            npos, nquat, nvel, nom = state_parts(new)
            for i in range(n):
                for a in range(3):
                    nvel[i, a] += dv[i, a]
                    nom[i, a] += dv[i, 3 + a]
            cnt[C_HELD] += 1
    # The warm start of the next step: these rows' normal impulses (none: as it was).
    if not c:
        _merge(cnt_total, cnt)
        return DONE, new, warm, (sel, force, con0), con1
    w_sa, w_sb = sa0[sel].copy(), sb0[sel].copy()
    w_pt = pt0[sel].copy()
    w_pn = np.empty(c)
    for k in range(c):
        w_pn[k] = p[3 * k]
    _merge(cnt_total, cnt)
    return DONE, new, (w_sa, w_sb, w_pt, w_pn), (sel, force, con0), con1


@njit(cache=True)
def _merge(total: np.ndarray, cnt: np.ndarray) -> None:
    """Add a step's counters to ``total`` (the largest of the maxima)."""
    for x in range(cnt.shape[0]):
        if x == C_ITERATIONS_MAX or x == C_COMPLEMENTARITY:
            total[x] = max(total[x], cnt[x])
        else:
            total[x] += cnt[x]


@njit(cache=True)
def _contact_wrenches(wbuf: np.ndarray, k: int, n: int, ba: np.ndarray, bb: np.ndarray,
                      la: np.ndarray, lb: np.ndarray, force: np.ndarray) -> int:
    """Write the contact forces as world wrenches after the ``k`` applied rows; return the rows."""
    f, t = np.zeros((n + 1, 3)), np.zeros((n + 1, 3))
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
def _rows_at(sa: np.ndarray, sb: np.ndarray, ba: np.ndarray, bb: np.ndarray, pt: np.ndarray,
             pos0: np.ndarray, R0: np.ndarray, frame: np.ndarray, Ga: np.ndarray,
             Gb: np.ndarray, con1: tuple, pos: np.ndarray, R: np.ndarray, radius: np.ndarray,
             count: int) -> tuple:
    """Return the rows' ``G`` at the end's geometry, as ``ContactSteps.rows_at``."""
    c1, sa1, sb1, ba1, bb1, pt1, nr1, dp1 = con1
    c = sa.shape[0]
    n = pos.shape[0]
    every = np.ones(c, dtype=np.bool_)
    nearest, _ = match(sa, sb, ba, pt, pos0, R0, every, sa1, sb1, ba1, pt1, pos, R, radius,
                       count)
    G1a, G1b = Ga.copy(), Gb.copy()
    for k in range(c):
        j = nearest[k]
        if j < 0:
            continue
        b = bb[k]
        nrm = nr1[j]
        # t₁ turned with body b (the world: as it was), then onto the new normal.
        u = frame[k, 1]
        v = np.empty(3)
        for x in range(3):
            v[x] = R0[b, 0, x] * u[0] + R0[b, 1, x] * u[1] + R0[b, 2, x] * u[2]
        t = np.empty(3)
        for x in range(3):
            t[x] = R[b, x, 0] * v[0] + R[b, x, 1] * v[1] + R[b, x, 2] * v[2]
        s = t[0] * nrm[0] + t[1] * nrm[1] + t[2] * nrm[2]
        for x in range(3):
            t[x] -= s * nrm[x]
        s = math.sqrt(t[0] ** 2 + t[1] ** 2 + t[2] ** 2)
        fr = np.empty((1, 3, 3))
        for x in range(3):
            fr[0, 0, x], fr[0, 1, x] = nrm[x], t[x] / s
        fr[0, 2, 0], fr[0, 2, 1], fr[0, 2, 2] = _cross(nrm[0], nrm[1], nrm[2], fr[0, 1, 0],
                                                       fr[0, 1, 1], fr[0, 1, 2])
        la, lb = np.zeros((1, 3)), np.zeros((1, 3))
        for x in range(3):
            la[0, x] = pt1[j, x] - pos[ba[k], x]
            if b < n:
                lb[0, x] = pt1[j, x] - pos[b, x]
        ga, gb = jacobian(fr, ba[k:k + 1], bb[k:k + 1], la, lb, R, n)
        for a in range(3):
            G1a[3 * k + a], G1b[3 * k + a] = ga[a], gb[a]
    return G1a, G1b
