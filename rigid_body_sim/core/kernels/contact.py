"""
Collision detection of convex primitives, compiled: the broad phase and the narrow phases.

Conventions. A shape is its kind (:class:`Shape`), its frame in the world (centre
``c`` (3,), rotation ``R`` (3, 3) whose columns are the shape's axes in the world)
and its size (3,): a sphere's radius; a box's half extents along its axes; a capsule's
and a cylinder's radius and the half length of its axis, the shape's z axis; a plane
(a half-space, solid below) passes through ``c`` with its outward normal ``R[:, 2]``.
A hull (a mesh's convex hull) takes its packed record (:func:`..hulls.hull_record`)
where a narrow phase takes a size; its size (3,) is the half extents of a box about
its origin that holds it (the broad phase bounds it as that box).

A contact of shapes ``a`` and ``b`` is a point (3,), a unit normal (3,) from ``b`` to
``a`` (a pushes along ``+n``), and a depth (m): how far the surfaces overlap along the
normal, negative for a gap. The point lies midway between the two surface points
along the normal. The narrow phases report every contact whose gap is at most
``margin`` (m), so a contact about to close is seen a step early; a pair's points
form its manifold: a face on a face gives up to 4 (a box on the ground has four,
its corners), an edge on a face 2, a corner or a curved surface 1.

The writers take the output arrays ``points`` (cap, 3), ``normals`` (cap, 3),
``depths`` (cap,) and the count ``k`` so far, write at ``k`` while there is room and
return the new count: a count beyond ``cap`` says how much room was needed (the
caller grows the buffers and runs again), never a silent drop.
"""

from __future__ import annotations

from enum import IntEnum
import math

from numba import njit
import numpy as np

from .convex import CANDIDATES, H_NV, H_VERTS, manifold, penetration
from .layout import O_ORIGIN_WORLD, O_QUAT_BODY_WORLD
from .so3 import quat_matrix
from .views import raw, raw_slice


class Shape(IntEnum):
    """The primitive kinds (the code the kernels read)."""

    SPHERE = 0
    CAPSULE = 1
    BOX = 2
    CYLINDER = 3
    PLANE = 4
    HULL = 5


SPHERE, CAPSULE, BOX, CYLINDER, PLANE, HULL = (int(s) for s in Shape)
#: Most points of one pair's manifold.
MANIFOLD = 4
#: Below this sine of the angle between two axes (or a normal and an axis) they count as
#: parallel: a capsule lying on a capsule, a cylinder standing on a plane.
PARALLEL = 1e-6
#: rad: box on box, when the edge pair of least overlap has its axis within this of a
#: face normal, the contact is a face on a face (the two boxes' faces within it of
#: parallel, resting on each other): the face's manifold, its normal within this of the
#: edge pair's, each point's depth its distance to the reference face; no edge pair is
#: taken (the next one's axis is further off). An edge pair can overlap less than the
#: face by the tilt times the size, and would give one point where the faces rest on four.
FACE_EDGE = 1e-3
FACE_EDGE_COS = math.cos(FACE_EDGE)


@njit(cache=True)
def _emit(points: np.ndarray, normals: np.ndarray, depths: np.ndarray, k: int,
          p0: float, p1: float, p2: float, n0: float, n1: float, n2: float,
          depth: float) -> int:
    """Write one contact at ``k`` if there is room; return ``k + 1``."""
    if k < points.shape[0]:
        points[k, 0], points[k, 1], points[k, 2] = p0, p1, p2
        normals[k, 0], normals[k, 1], normals[k, 2] = n0, n1, n2
        depths[k] = depth
    return k + 1


@njit(cache=True)
def _deepest(cand: np.ndarray, m: int, keep: int) -> int:
    """Order the first ``m`` rows of ``cand`` (x, y, z, gap) by gap; return how many to keep."""
    for i in range(1, m):   # insertion sort: m ≤ 8
        j = i
        while j > 0 and cand[j, 3] < cand[j - 1, 3]:
            for c in range(4):
                cand[j, c], cand[j - 1, c] = cand[j - 1, c], cand[j, c]
            j -= 1
    return min(m, keep)


@njit(cache=True)
def _points_on_plane(cand: np.ndarray, m: int, c0: np.ndarray, n: np.ndarray, flip: bool,
                     margin: float, points: np.ndarray, normals: np.ndarray,
                     depths: np.ndarray, k: int) -> int:
    """
    Emit the candidate surface points ``cand[:m, :3]`` of a shape within ``margin`` of a plane.

    Each one's gap is its height over the plane; the deepest :data:`MANIFOLD` are kept.
    ``flip``: the plane is shape ``a`` (the normal then points from the other shape to it).
    """
    w = 0
    for i in range(m):
        gap = (n[0] * (cand[i, 0] - c0[0]) + n[1] * (cand[i, 1] - c0[1])
               + n[2] * (cand[i, 2] - c0[2]))
        if gap <= margin:
            for c in range(3):
                cand[w, c] = cand[i, c]
            cand[w, 3] = gap
            w += 1
    keep = _deepest(cand, w, MANIFOLD)
    s = -1.0 if flip else 1.0
    for i in range(keep):
        gap = cand[i, 3]
        k = _emit(points, normals, depths, k, cand[i, 0] - 0.5 * gap * n[0],
                  cand[i, 1] - 0.5 * gap * n[1], cand[i, 2] - 0.5 * gap * n[2],
                  s * n[0], s * n[1], s * n[2], -gap)
    return k


@njit(cache=True)
def _spheres(ca: np.ndarray, ra: float, cb: np.ndarray, rb: float, margin: float,
             points: np.ndarray, normals: np.ndarray, depths: np.ndarray, k: int) -> int:
    """Sphere ``a`` (centre, radius) on sphere ``b``: one contact if the gap ≤ margin."""
    d0, d1, d2 = ca[0] - cb[0], ca[1] - cb[1], ca[2] - cb[2]
    dist = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    gap = dist - ra - rb
    if gap > margin:
        return k
    if dist > 0.0:
        n0, n1, n2 = d0 / dist, d1 / dist, d2 / dist
    else:   # concentric: any direction separates them; the world's z
        n0, n1, n2 = 0.0, 0.0, 1.0
    t = rb + 0.5 * gap   # from b's centre to the midpoint of the surface points
    return _emit(points, normals, depths, k, cb[0] + t * n0, cb[1] + t * n1,
                 cb[2] + t * n2, n0, n1, n2, -gap)


@njit(cache=True)
def segment_closest(p: np.ndarray, u: np.ndarray, q: np.ndarray, v: np.ndarray) -> tuple:
    """
    Closest points of the segments ``p + s u`` and ``q + t v``, ``s, t`` in [0, 1].

    Returns ``(s, t)``. The distance squared ``|p + s u − q − t v|²`` is a convex
    quadratic on the unit square: its minimum lies where its gradient vanishes, or on
    an edge of the square (each edge's minimum in closed form, clamped), and the
    smallest of those is taken. A degenerate segment (zero length) is a point.
    """
    r0, r1, r2 = p[0] - q[0], p[1] - q[1], p[2] - q[2]
    a = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    b = u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
    c = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    d = u[0] * r0 + u[1] * r1 + u[2] * r2
    e = v[0] * r0 + v[1] * r1 + v[2] * r2
    # f(s, t) = a s² − 2 b s t + c t² + 2 d s − 2 e t + |r|²
    best_s, best_t, best = 0.0, 0.0, math.inf
    det = a * c - b * b
    if det > 1e-14 * a * c:
        s = (b * e - c * d) / det
        t = (a * e - b * d) / det
        if 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0:
            return s, t
    # The four edges of the square: s fixed at 0 or 1 (t free), t fixed at 0 or 1.
    for edge in range(4):
        if edge < 2:
            s = float(edge)
            t = (b * s + e) / c if c > 0.0 else 0.0
            t = min(max(t, 0.0), 1.0)
        else:
            t = float(edge - 2)
            s = (b * t - d) / a if a > 0.0 else 0.0
            s = min(max(s, 0.0), 1.0)
        f = a * s * s - 2.0 * b * s * t + c * t * t + 2.0 * d * s - 2.0 * e * t
        if f < best:
            best_s, best_t, best = s, t, f
    return best_s, best_t


@njit(cache=True)
def _nearest(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray, x: np.ndarray,
             y: np.ndarray, n: np.ndarray, w: np.ndarray) -> float:
    """
    Signed distance from the point ``x`` to a box or a cylinder; its nearest surface point.

    Writes the surface point nearest ``x`` into ``y`` and the outward normal there
    (towards ``x``) into ``n``; returns the distance, negative inside. Outside, the
    nearest point of the solid (each local coordinate clamped: a box's three, a
    cylinder's radial and axial); inside, the nearest face (a box's six, a
    cylinder's mantle or caps): the least push that takes ``x`` out.
    """
    xl = w[0:3]
    for i in range(3):   # x in the shape's frame
        xl[i] = (R[0, i] * (x[0] - c[0]) + R[1, i] * (x[1] - c[1])
                 + R[2, i] * (x[2] - c[2]))
    yl, nl = w[3:6], w[6:9]
    for i in range(3):
        yl[i] = nl[i] = 0.0
    if kind == BOX:
        h = size
        outside = False
        for i in range(3):
            yl[i] = min(max(xl[i], -h[i]), h[i])
            if yl[i] != xl[i]:
                outside = True
        if outside:
            dist = math.sqrt((xl[0] - yl[0]) ** 2 + (xl[1] - yl[1]) ** 2
                             + (xl[2] - yl[2]) ** 2)
            for i in range(3):
                nl[i] = (xl[i] - yl[i]) / dist
        else:
            axis, side, dist = 0, 1.0, -math.inf
            for i in range(3):
                for sd in (-1.0, 1.0):
                    d = sd * xl[i] - h[i]   # ≤ 0: how far inside face (i, sd), negated
                    if d > dist:
                        axis, side, dist = i, sd, d
            yl[axis] = side * h[axis]
            nl[axis] = side
    else:   # a cylinder: radius size[0], half length size[1] along z
        r, hl = size[0], size[1]
        rho = math.sqrt(xl[0] * xl[0] + xl[1] * xl[1])
        ex, ey = (xl[0] / rho, xl[1] / rho) if rho > 0.0 else (1.0, 0.0)
        out_r, out_z = rho - r, abs(xl[2]) - hl
        sz = 1.0 if xl[2] >= 0.0 else -1.0
        if out_r > 0.0 or out_z > 0.0:
            rc, zc = min(rho, r), min(max(xl[2], -hl), hl)
            yl[0], yl[1], yl[2] = rc * ex, rc * ey, zc
            dr, dz = max(out_r, 0.0), max(out_z, 0.0)
            dist = math.sqrt(dr * dr + dz * dz)
            nl[0], nl[1], nl[2] = dr * ex / dist, dr * ey / dist, dz * sz / dist
        elif out_r >= out_z:   # nearer the mantle
            yl[0], yl[1], yl[2] = r * ex, r * ey, xl[2]
            nl[0], nl[1] = ex, ey
            dist = out_r
        else:   # nearer a cap
            yl[0], yl[1], yl[2] = xl[0], xl[1], sz * hl
            nl[2] = sz
            dist = out_z
    for i in range(3):   # back to the world
        y[i] = c[i] + R[i, 0] * yl[0] + R[i, 1] * yl[1] + R[i, 2] * yl[2]
        n[i] = R[i, 0] * nl[0] + R[i, 1] * nl[1] + R[i, 2] * nl[2]
    return dist


@njit(cache=True)
def _ball_on(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray, x: np.ndarray,
             r: float, flip: bool, margin: float, points: np.ndarray, normals: np.ndarray,
             depths: np.ndarray, k: int, w: np.ndarray) -> int:
    """
    Emit a ball (centre ``x``, radius ``r``) on a box or a cylinder: one contact, within margin.

    The normal is the solid's outward normal at its point nearest the centre (the
    nearest face's when the centre is inside). ``flip``: the solid is shape ``a``.
    """
    y, n = w[9:12], w[12:15]
    gap = _nearest(kind, c, R, size, x, y, n, w) - r
    if gap > margin:
        return k
    s = -1.0 if flip else 1.0
    return _emit(points, normals, depths, k, y[0] + 0.5 * gap * n[0],
                 y[1] + 0.5 * gap * n[1], y[2] + 0.5 * gap * n[2],
                 s * n[0], s * n[1], s * n[2], -gap)


@njit(cache=True)
def _axis_distance(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray,
                   p0: np.ndarray, u: np.ndarray, s: float, x: np.ndarray,
                   w: np.ndarray) -> float:
    """Signed distance to a box or a cylinder of the axis point ``x = p0 + s u`` (written)."""
    y, n = w[9:12], w[12:15]
    for i in range(3):
        x[i] = p0[i] + s * u[i]
    return _nearest(kind, c, R, size, x, y, n, w)


@njit(cache=True)
def _capsule_on(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray,
                cc: np.ndarray, Rc: np.ndarray, sc: np.ndarray, flip: bool, margin: float,
                points: np.ndarray, normals: np.ndarray, depths: np.ndarray, k: int,
                w: np.ndarray) -> int:
    """
    Emit a capsule on a box or a cylinder: its end balls and the ends of its deepest stretch.

    The signed distance to a convex solid is convex along the capsule's axis: its
    minimum is an interval ``[s_a, s_b]`` of the axis (a point where the axis crosses
    over an edge, a stretch where it lies along a face). A point of it is found by
    golden-section search (64 iterations: 1e-13 of the axis), its ends by bisection
    (to within 1e-12 m of the least distance); each end inside the axis is a contact
    (one, their middle, where the two lie within ``4 sqrt(2 ρ 1e-12)`` of each other:
    a strict minimum that the tolerance widened, ``ρ`` the distance's curvature
    radius, at most the solid's size plus ``r``: 6e-6 m for 1 m; none where that lies
    within as much of an end, whose ball is a contact already), and each end ball
    within the margin is one. So a capsule lying on a face touches
    at its two ends, one lying over the face's edge at its end on the face and over
    the edge, one across an edge once, one standing on an end at that end.
    ``flip``: the solid is shape ``a``.
    """
    hl, r = sc[1], sc[0]
    p0, u, x = w[16:19], w[19:22], w[22:25]
    for i in range(3):
        u[i] = 2.0 * hl * Rc[i, 2]
        p0[i] = cc[i] - 0.5 * u[i]
    for e in (0.0, 1.0):
        _axis_distance(kind, c, R, size, p0, u, e, x, w)
        k = _ball_on(kind, c, R, size, x, r, flip, margin, points, normals, depths, k, w)
    if hl <= 0.0:
        return k
    inv = 0.5 * (math.sqrt(5.0) - 1.0)
    lo, hi = 0.0, 1.0
    s1, s2 = hi - inv * (hi - lo), lo + inv * (hi - lo)
    f1 = _axis_distance(kind, c, R, size, p0, u, s1, x, w)
    f2 = _axis_distance(kind, c, R, size, p0, u, s2, x, w)
    for _ in range(64):
        if f1 <= f2:
            hi, s2, f2 = s2, s1, f1
            s1 = hi - inv * (hi - lo)
            f1 = _axis_distance(kind, c, R, size, p0, u, s1, x, w)
        else:
            lo, s1, f1 = s1, s2, f2
            s2 = lo + inv * (hi - lo)
            f2 = _axis_distance(kind, c, R, size, p0, u, s2, x, w)
    best = 0.5 * (lo + hi)
    least = _axis_distance(kind, c, R, size, p0, u, best, x, w)
    tol = 1e-12
    found = w[25:27]
    for side in range(2):   # the interval's end towards s = 0, then towards s = 1
        end = 0.0 if side == 0 else 1.0
        if _axis_distance(kind, c, R, size, p0, u, end, x, w) <= least + tol:
            found[side] = end
            continue
        inner, outer = best, end   # f(inner) within tol of the least, f(outer) beyond
        for _ in range(60):
            mid = 0.5 * (inner + outer)
            if _axis_distance(kind, c, R, size, p0, u, mid, x, w) <= least + tol:
                inner = mid
            else:
                outer = mid
        found[side] = inner
    # What the tolerance leaves around a strict minimum, as a fraction of the axis:
    # sqrt(2 ρ tol), ρ the distance's curvature radius (at most the solid's size plus
    # r), four times over.
    rho = max(size[0], size[1], size[2]) + r
    apart = 4.0 * math.sqrt(2.0 * rho * tol) / (2.0 * hl)
    if found[1] - found[0] <= apart:   # one point: the middle of what the tolerance left
        found[0] = found[1] = 0.5 * (found[0] + found[1])
    for side in range(2):
        sv = found[side]
        if sv <= apart or sv >= 1.0 - apart or (side == 1 and found[1] == found[0]):
            continue   # at an end (its ball is in already), or the same point twice
        _axis_distance(kind, c, R, size, p0, u, sv, x, w)
        k = _ball_on(kind, c, R, size, x, r, flip, margin, points, normals, depths, k, w)
    return k


@njit(cache=True)
def _reduce(cand: np.ndarray, m: int, tmp: np.ndarray) -> int:
    """
    Keep at most :data:`MANIFOLD` of ``cand[:m]`` (x, y, z, gap), moved to the first rows.

    The deepest, the one farthest from it, and the two farthest on either side of the
    line through those (the manifold that spans the most); returns how many. ``tmp``
    (4, 4): scratch.
    """
    if m <= MANIFOLD:
        return m
    best = 0
    for i in range(1, m):
        if cand[i, 3] < cand[best, 3]:
            best = i
    far, fd = -1, -1.0
    for i in range(m):
        d = ((cand[i, 0] - cand[best, 0]) ** 2 + (cand[i, 1] - cand[best, 1]) ** 2
             + (cand[i, 2] - cand[best, 2]) ** 2)
        if i != best and d > fd:
            far, fd = i, d
    # The sides of the line p0 p1: the signed area with p0, p1 along the normal of the
    # best plane through the points (the cross product of the line and the farthest).
    e0, e1, e2 = (cand[far, 0] - cand[best, 0], cand[far, 1] - cand[best, 1],
                  cand[far, 2] - cand[best, 2])
    n0 = n1 = n2 = 0.0
    big = -1.0
    for i in range(m):
        f0, f1, f2 = (cand[i, 0] - cand[best, 0], cand[i, 1] - cand[best, 1],
                      cand[i, 2] - cand[best, 2])
        c0, c1, c2 = e1 * f2 - e2 * f1, e2 * f0 - e0 * f2, e0 * f1 - e1 * f0
        a = c0 * c0 + c1 * c1 + c2 * c2
        if a > big:
            big = a
            n0, n1, n2 = c0, c1, c2
    lo_i, hi_i, lo_a, hi_a = -1, -1, 0.0, 0.0
    for i in range(m):
        if i == best or i == far:
            continue
        f0, f1, f2 = (cand[i, 0] - cand[best, 0], cand[i, 1] - cand[best, 1],
                      cand[i, 2] - cand[best, 2])
        a = (n0 * (e1 * f2 - e2 * f1) + n1 * (e2 * f0 - e0 * f2)
             + n2 * (e0 * f1 - e1 * f0))
        if a > hi_a or hi_i < 0:
            hi_i, hi_a = i, a
        if a < lo_a or lo_i < 0:
            lo_i, lo_a = i, a
    kept = 2
    for col in range(4):
        tmp[0, col], tmp[1, col] = cand[best, col], cand[far, col]
    if hi_i >= 0:
        for col in range(4):
            tmp[kept, col] = cand[hi_i, col]
        kept += 1
    if lo_i >= 0 and lo_i != hi_i:
        for col in range(4):
            tmp[kept, col] = cand[lo_i, col]
        kept += 1
    for j in range(kept):
        for col in range(4):
            cand[j, col] = tmp[j, col]
    return kept


@njit(cache=True)
def _box_box(ca: np.ndarray, Ra: np.ndarray, ha: np.ndarray, cb: np.ndarray,
             Rb: np.ndarray, hb: np.ndarray, margin: float, points: np.ndarray,
             normals: np.ndarray, depths: np.ndarray, k: int, w: np.ndarray) -> int:
    """
    Emit box on box: the separating axis test (15 axes), then the manifold.

    The axis of least overlap is the normal (a face axis unless an edge pair's
    overlap is smaller by more than 5% of the face's plus 1e-9 of the boxes' size, and
    the least-overlap edge pair's axis is not within :data:`FACE_EDGE` of a face normal:
    a resting face keeps its normal; then no edge pair is taken, not the next one). A
    face: the other box's face most against it (the incident face) is clipped by the
    reference face's four sides, and its corners below the reference plane (within the
    margin) are the contacts, at most
    :data:`MANIFOLD` (:func:`_reduce`). An edge pair: the closest points of the two
    edges, one contact.
    """
    t = w[64:67]
    for i in range(3):
        t[i] = ca[i] - cb[i]   # from b to a
    size = max(ha[0], ha[1], ha[2], hb[0], hb[1], hb[2])
    best_face, face_sep, face_axis = -1, -math.inf, w[67:70]
    best_edge, edge_sep, edge_axis = -1, -math.inf, w[70:73]
    edge_flat = False
    L = w[73:76]
    for ax in range(15):
        if ax < 3:
            for r in range(3):
                L[r] = Ra[r, ax]
        elif ax < 6:
            for r in range(3):
                L[r] = Rb[r, ax - 3]
        else:
            i, j = (ax - 6) // 3, (ax - 6) % 3
            L[0] = Ra[1, i] * Rb[2, j] - Ra[2, i] * Rb[1, j]
            L[1] = Ra[2, i] * Rb[0, j] - Ra[0, i] * Rb[2, j]
            L[2] = Ra[0, i] * Rb[1, j] - Ra[1, i] * Rb[0, j]
            norm = math.sqrt(L[0] * L[0] + L[1] * L[1] + L[2] * L[2])
            if norm <= PARALLEL:
                continue   # parallel edges: a face axis covers them
            for r in range(3):
                L[r] /= norm
        ra = 0.0
        rb = 0.0
        for q in range(3):
            ra += ha[q] * abs(Ra[0, q] * L[0] + Ra[1, q] * L[1] + Ra[2, q] * L[2])
            rb += hb[q] * abs(Rb[0, q] * L[0] + Rb[1, q] * L[1] + Rb[2, q] * L[2])
        tl = t[0] * L[0] + t[1] * L[1] + t[2] * L[2]
        sep = abs(tl) - ra - rb
        if sep > margin:
            return k   # a separating axis
        sg = 1.0 if tl >= 0.0 else -1.0
        if ax < 6:
            if sep > face_sep:
                best_face, face_sep = ax, sep
                for r in range(3):
                    face_axis[r] = sg * L[r]
        elif sep > edge_sep:
            best_edge, edge_sep = ax, sep
            for r in range(3):
                edge_axis[r] = sg * L[r]
            # Edges in nearly parallel planes (L within FACE_EDGE of a face normal):
            # faces resting on each other, whose manifold is the face's.
            near = 0.0
            for q in range(3):
                near = max(near, abs(Ra[0, q] * L[0] + Ra[1, q] * L[1] + Ra[2, q] * L[2]),
                           abs(Rb[0, q] * L[0] + Rb[1, q] * L[1] + Rb[2, q] * L[2]))
            edge_flat = near >= FACE_EDGE_COS
    if best_edge >= 0 and not edge_flat \
            and edge_sep > face_sep + 0.05 * abs(face_sep) + 1e-9 * size:
        # Edge on edge: the edge of a most against b, of b most against a.
        i, j = (best_edge - 6) // 3, (best_edge - 6) % 3
        n = edge_axis
        pa, pb = w[76:79], w[79:82]
        for r in range(3):
            pa[r], pb[r] = ca[r], cb[r]
        for q in range(3):
            if q != i:
                sa = -1.0 if (Ra[0, q] * n[0] + Ra[1, q] * n[1] + Ra[2, q] * n[2]) > 0.0 \
                    else 1.0
                for r in range(3):
                    pa[r] += sa * ha[q] * Ra[r, q]
            if q != j:
                sb = 1.0 if (Rb[0, q] * n[0] + Rb[1, q] * n[1] + Rb[2, q] * n[2]) > 0.0 \
                    else -1.0
                for r in range(3):
                    pb[r] += sb * hb[q] * Rb[r, q]
        u, v = w[82:85], w[85:88]
        for r in range(3):
            u[r] = 2.0 * ha[i] * Ra[r, i]
            v[r] = 2.0 * hb[j] * Rb[r, j]
            pa[r] -= 0.5 * u[r]
            pb[r] -= 0.5 * v[r]
        s, tt = segment_closest(pa, u, pb, v)
        x, y = w[88:91], w[91:94]
        for r in range(3):
            x[r] = pa[r] + s * u[r]
            y[r] = pb[r] + tt * v[r]
        gap = n[0] * (x[0] - y[0]) + n[1] * (x[1] - y[1]) + n[2] * (x[2] - y[2])
        if gap > margin:
            return k
        return _emit(points, normals, depths, k, 0.5 * (x[0] + y[0]), 0.5 * (x[1] + y[1]),
                     0.5 * (x[2] + y[2]), n[0], n[1], n[2], -gap)
    # A face. The reference box and its outward face normal m; the incident box.
    n = face_axis   # from b to a
    if best_face < 3:   # a's face, facing b: m = −n
        cr, Rr, hr, ci, Ri, hi = ca, Ra, ha, cb, Rb, hb
        fa, m_sign = best_face, -1.0
    else:
        cr, Rr, hr, ci, Ri, hi = cb, Rb, hb, ca, Ra, ha
        fa, m_sign = best_face - 3, 1.0
    m = w[94:97]
    for r in range(3):
        m[r] = m_sign * n[r]
    # The reference face: its centre, its two in-plane axes and half widths.
    sr = 1.0 if (Rr[0, fa] * m[0] + Rr[1, fa] * m[1] + Rr[2, fa] * m[2]) > 0.0 else -1.0
    fc = w[97:100]
    for r in range(3):
        fc[r] = cr[r] + sr * hr[fa] * Rr[r, fa]
    a1, a2 = (fa + 1) % 3, (fa + 2) % 3
    # The incident face: the incident box's face whose normal is most against m.
    fi, si, most = 0, 1.0, math.inf
    for q in range(3):
        d = Ri[0, q] * m[0] + Ri[1, q] * m[1] + Ri[2, q] * m[2]
        for sd in (-1.0, 1.0):
            if sd * d < most:
                fi, si, most = q, sd, sd * d
    b1, b2 = (fi + 1) % 3, (fi + 2) % 3
    poly = w[112:160].reshape((16, 3))
    npoly = 0
    for c1, c2 in ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)):
        for r in range(3):
            poly[npoly, r] = (ci[r] + si * hi[fi] * Ri[r, fi] + c1 * hi[b1] * Ri[r, b1]
                              + c2 * hi[b2] * Ri[r, b2])
        npoly += 1
    # Clip by the reference face's four sides: e · (p − fc) ≤ h_e for e = ±a1, ±a2.
    clipped = w[160:208].reshape((16, 3))
    for side in range(4):
        ax = a1 if side < 2 else a2
        sg = 1.0 if side % 2 == 0 else -1.0
        lim = hr[ax]
        nc = 0
        for p0 in range(npoly):
            p1 = (p0 + 1) % npoly
            dv = sg * (Rr[0, ax] * (poly[p0, 0] - fc[0]) + Rr[1, ax] * (poly[p0, 1] - fc[1])
                       + Rr[2, ax] * (poly[p0, 2] - fc[2])) - lim
            dw = sg * (Rr[0, ax] * (poly[p1, 0] - fc[0]) + Rr[1, ax] * (poly[p1, 1] - fc[1])
                       + Rr[2, ax] * (poly[p1, 2] - fc[2])) - lim
            if dv <= 0.0:
                for r in range(3):
                    clipped[nc, r] = poly[p0, r]
                nc += 1
            if (dv < 0.0 < dw) or (dw < 0.0 < dv):
                f = dv / (dv - dw)
                for r in range(3):
                    clipped[nc, r] = poly[p0, r] + f * (poly[p1, r] - poly[p0, r])
                nc += 1
        npoly = nc
        for p0 in range(nc):
            for r in range(3):
                poly[p0, r] = clipped[p0, r]
        if npoly == 0:
            return k
    cand = w[208:272].reshape((16, 4))
    nk = 0
    for p0 in range(npoly):
        gap = (m[0] * (poly[p0, 0] - fc[0]) + m[1] * (poly[p0, 1] - fc[1])
               + m[2] * (poly[p0, 2] - fc[2]))
        if gap <= margin:
            for r in range(3):
                cand[nk, r] = poly[p0, r] - 0.5 * gap * m[r]   # midway to the reference face
            cand[nk, 3] = gap
            nk += 1
    nk = _reduce(cand, nk, w[28:44].reshape((4, 4)))
    for v in range(nk):
        k = _emit(points, normals, depths, k, cand[v, 0], cand[v, 1], cand[v, 2],
                  n[0], n[1], n[2], -cand[v, 3])
    return k


@njit(cache=True)
def _surface_candidates(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray,
                        n: np.ndarray, cand: np.ndarray) -> int:
    """
    Write the points of a shape that may be deepest below a plane of normal ``n``.

    A sphere: its lowest point. A capsule: the lowest points of its two end spheres.
    A box: its 8 corners. A cylinder: on each cap's rim, the lowest point, the highest,
    and the two between (a standing cylinder rests on four of them; a lying one on
    the lowest of each cap). Returns how many (rows of ``cand``, columns x, y, z).
    """
    if kind == SPHERE or kind == CAPSULE:
        r = size[0]
        m = 1 if kind == SPHERE else 2
        for e in range(m):
            t = 0.0 if kind == SPHERE else (size[1] if e == 0 else -size[1])
            for i in range(3):
                cand[e, i] = c[i] + t * R[i, 2] - r * n[i]
        return m
    if kind == BOX:
        m = 0
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                for sz in (-1.0, 1.0):
                    for i in range(3):
                        cand[m, i] = (c[i] + sx * size[0] * R[i, 0] + sy * size[1] * R[i, 1]
                                      + sz * size[2] * R[i, 2])
                    m += 1
        return m
    # A cylinder: u, the direction of −n across the axis; w = axis × u.
    a0, a1, a2 = R[0, 2], R[1, 2], R[2, 2]
    na = n[0] * a0 + n[1] * a1 + n[2] * a2
    u0, u1, u2 = -(n[0] - na * a0), -(n[1] - na * a1), -(n[2] - na * a2)
    norm = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    if norm <= PARALLEL:   # the normal along the axis: any direction across it
        u0, u1, u2 = R[0, 0], R[1, 0], R[2, 0]
    else:
        u0, u1, u2 = u0 / norm, u1 / norm, u2 / norm
    w0, w1, w2 = a1 * u2 - a2 * u1, a2 * u0 - a0 * u2, a0 * u1 - a1 * u0
    r, hl = size[0], size[1]
    m = 0
    for e in (1.0, -1.0):
        for cu, cw in ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)):
            cand[m, 0] = c[0] + e * hl * a0 + r * (cu * u0 + cw * w0)
            cand[m, 1] = c[1] + e * hl * a1 + r * (cu * u1 + cw * w1)
            cand[m, 2] = c[2] + e * hl * a2 + r * (cu * u2 + cw * w2)
            m += 1
    return m


@njit(cache=True)
def _on_plane(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray, cp: np.ndarray,
              Rp: np.ndarray, flip: bool, margin: float, points: np.ndarray,
              normals: np.ndarray, depths: np.ndarray, k: int, w: np.ndarray) -> int:
    """Emit a shape's contacts with the plane through ``cp`` of normal ``Rp[:, 2]``."""
    n = w[280:283]
    for i in range(3):
        n[i] = Rp[i, 2]
    if kind == HULL:
        return _hull_on_plane(c, R, size, cp, n, flip, margin, points, normals, depths, k,
                              w[28:44].reshape((4, 4)))
    cand = w[288:320].reshape((8, 4))
    m = _surface_candidates(kind, c, R, size, n, cand)
    return _points_on_plane(cand, m, cp, n, flip, margin, points, normals, depths, k)


@njit(cache=True)
def _hull_on_plane(c: np.ndarray, R: np.ndarray, rec: np.ndarray, cp: np.ndarray,
                   n: np.ndarray, flip: bool, margin: float, points: np.ndarray,
                   normals: np.ndarray, depths: np.ndarray, k: int, tmp: np.ndarray) -> int:
    """
    Emit a hull's vertices within ``margin`` of a plane: the :data:`MANIFOLD` that span most.

    (:func:`_reduce`: a hull's face on the plane has as many corners as it has, all at
    one depth; the deepest four alone might be neighbours on one side.)
    """
    nv = int(rec[H_NV])
    cand = np.empty((nv, 4))
    m = 0
    for i in range(nv):
        v = rec[H_VERTS + 3 * i:]
        for r in range(3):
            cand[m, r] = c[r] + R[r, 0] * v[0] + R[r, 1] * v[1] + R[r, 2] * v[2]
        gap = (n[0] * (cand[m, 0] - cp[0]) + n[1] * (cand[m, 1] - cp[1])
               + n[2] * (cand[m, 2] - cp[2]))
        if gap <= margin:
            cand[m, 3] = gap
            m += 1
    m = _reduce(cand, m, tmp)
    s = -1.0 if flip else 1.0
    for i in range(m):
        gap = cand[i, 3]
        k = _emit(points, normals, depths, k, cand[i, 0] - 0.5 * gap * n[0],
                  cand[i, 1] - 0.5 * gap * n[1], cand[i, 2] - 0.5 * gap * n[2],
                  s * n[0], s * n[1], s * n[2], -gap)
    return k


@njit(cache=True)
def _capsule_capsule(ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, cb: np.ndarray,
                     Rb: np.ndarray, sb: np.ndarray, margin: float, points: np.ndarray,
                     normals: np.ndarray, depths: np.ndarray, k: int, w: np.ndarray) -> int:
    """
    Emit capsule on capsule (a sphere: a capsule of length 0): the axes' closest points.

    Two segments side by side (parallel within :data:`PARALLEL`) touch along a line:
    the two ends of their overlap, each as two spheres, make the manifold.
    """
    p, u, q, v = w[320:323], w[323:326], w[326:329], w[329:332]
    for i in range(3):
        u[i] = 2.0 * sa[1] * Ra[i, 2]
        v[i] = 2.0 * sb[1] * Rb[i, 2]
        p[i] = ca[i] - 0.5 * u[i]
        q[i] = cb[i] - 0.5 * v[i]
    x, y = w[332:335], w[335:338]
    lu = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    lv = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if lu > 0.0 and lv > 0.0:
        cx0 = (u[1] * v[2] - u[2] * v[1]) / (lu * lv)
        cx1 = (u[2] * v[0] - u[0] * v[2]) / (lu * lv)
        cx2 = (u[0] * v[1] - u[1] * v[0]) / (lu * lv)
        if math.sqrt(cx0 * cx0 + cx1 * cx1 + cx2 * cx2) <= PARALLEL:
            # Parallel: b's segment over a's axis, s in [0, 1] along u.
            uu = lu * lu
            s0 = ((q[0] - p[0]) * u[0] + (q[1] - p[1]) * u[1] + (q[2] - p[2]) * u[2]) / uu
            s1 = s0 + (v[0] * u[0] + v[1] * u[1] + v[2] * u[2]) / uu
            lo, hi = max(min(s0, s1), 0.0), min(max(s0, s1), 1.0)
            if (hi - lo) * lu > 1e-6 * (lu + lv):   # an overlap of some length: its ends
                for s in (lo, hi):
                    for i in range(3):
                        x[i] = p[i] + s * u[i]
                    # b's axis point nearest x
                    t = ((x[0] - q[0]) * v[0] + (x[1] - q[1]) * v[1]
                         + (x[2] - q[2]) * v[2]) / (lv * lv)
                    t = min(max(t, 0.0), 1.0)
                    for i in range(3):
                        y[i] = q[i] + t * v[i]
                    k = _spheres(x, sa[0], y, sb[0], margin, points, normals, depths, k)
                return k
    s, t = segment_closest(p, u, q, v)
    for i in range(3):
        x[i] = p[i] + s * u[i]
        y[i] = q[i] + t * v[i]
    return _spheres(x, sa[0], y, sb[0], margin, points, normals, depths, k)


@njit(cache=True)
def collide(kind_a: int, ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, kind_b: int,
            cb: np.ndarray, Rb: np.ndarray, sb: np.ndarray, margin: float,
            points: np.ndarray, normals: np.ndarray, depths: np.ndarray, k: int) -> int:
    """
    Write the contacts of shapes ``a`` and ``b`` within ``margin`` from ``k``.

    Returns the new count, or −1 for a pair without a narrow phase here (the caller
    refuses such a pair when the scene is built: :func:`supported`).
    """
    return _collide(kind_a, ca, Ra, sa, kind_b, cb, Rb, sb, margin, points, normals, depths,
                    k, np.empty(SCRATCH))


#: Floats of scratch a narrow phase uses (its small vectors and polygons: views into one
#: buffer, allocated once a batch, not once a pair).
SCRATCH = 352 + 4 * CANDIDATES


@njit(cache=True)
def _collide(kind_a: int, ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, kind_b: int,
             cb: np.ndarray, Rb: np.ndarray, sb: np.ndarray, margin: float,
             points: np.ndarray, normals: np.ndarray, depths: np.ndarray, k: int,
             w: np.ndarray) -> int:
    """:func:`collide` with the scratch ``w`` (:data:`SCRATCH`,) given."""
    if not supported(kind_a, kind_b):
        return -1
    if kind_b == PLANE:
        return _on_plane(kind_a, ca, Ra, sa, cb, Rb, False, margin, points, normals, depths, k,
                         w)
    if kind_a == PLANE:
        return _on_plane(kind_b, cb, Rb, sb, ca, Ra, True, margin, points, normals, depths, k,
                         w)
    if kind_a == HULL or kind_b == HULL:
        return _convex(kind_a, ca, Ra, sa, kind_b, cb, Rb, sb, margin, points, normals,
                       depths, k, w)
    round_a = kind_a == SPHERE or kind_a == CAPSULE
    round_b = kind_b == SPHERE or kind_b == CAPSULE
    if round_a and round_b:
        za, zb = w[340:343], w[343:346]   # a sphere: a capsule of length 0
        za[0], za[1], za[2] = sa[0], 0.0, 0.0
        zb[0], zb[1], zb[2] = sb[0], 0.0, 0.0
        return _capsule_capsule(ca, Ra, sa if kind_a == CAPSULE else za, cb, Rb,
                                sb if kind_b == CAPSULE else zb, margin, points, normals,
                                depths, k, w)
    if kind_a == SPHERE:
        return _ball_on(kind_b, cb, Rb, sb, ca, sa[0], False, margin, points, normals,
                        depths, k, w)
    if kind_b == SPHERE:
        return _ball_on(kind_a, ca, Ra, sa, cb, sb[0], True, margin, points, normals,
                        depths, k, w)
    if kind_a == CAPSULE:
        return _capsule_on(kind_b, cb, Rb, sb, ca, Ra, sa, False, margin, points, normals,
                           depths, k, w)
    if kind_b == CAPSULE:
        return _capsule_on(kind_a, ca, Ra, sa, cb, Rb, sb, True, margin, points, normals,
                           depths, k, w)
    if kind_a == CYLINDER or kind_b == CYLINDER:
        return _convex(kind_a, ca, Ra, sa, kind_b, cb, Rb, sb, margin, points, normals,
                       depths, k, w)
    return _box_box(ca, Ra, sa, cb, Rb, sb, margin, points, normals, depths, k, w)


@njit(cache=True)
def _convex(kind_a: int, ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, kind_b: int,
            cb: np.ndarray, Rb: np.ndarray, sb: np.ndarray, margin: float,
            points: np.ndarray, normals: np.ndarray, depths: np.ndarray, k: int,
            w: np.ndarray) -> int:
    """
    Emit a convex pair (a cylinder or a hull): EPA's normal and depth, then the manifold.

    (:mod:`.convex`.) Two flat features facing each other (a cap or a face, a line
    lying across the normal) give the corners of their overlap, at most
    :data:`MANIFOLD` (:func:`_reduce`); any other pair EPA's one point.
    """
    result = w[0:11]
    if not penetration(kind_a, ca, Ra, sa, kind_b, cb, Rb, sb, margin, result):
        return k
    cand = w[352:352 + 4 * CANDIDATES].reshape((CANDIDATES, 4))
    m = manifold(kind_a, ca, Ra, sa, kind_b, cb, Rb, sb, result, margin, cand)
    n0, n1, n2 = result[0], result[1], result[2]   # (the manifold may refine it)
    if m < 0:
        return _emit(points, normals, depths, k, 0.5 * (result[4] + result[7]),
                     0.5 * (result[5] + result[8]), 0.5 * (result[6] + result[9]),
                     n0, n1, n2, result[3])
    m = _reduce(cand, m, w[28:44].reshape((4, 4)))
    for v in range(m):
        k = _emit(points, normals, depths, k, cand[v, 0], cand[v, 1], cand[v, 2], n0, n1, n2,
                  -cand[v, 3])
    return k


@njit(cache=True)
def supported(kind_a: int, kind_b: int) -> bool:
    """
    Tell whether :func:`collide` has a narrow phase for this pair of kinds.

    Every pair but a plane on a plane (the world's: never met).
    """
    return not (kind_a == PLANE and kind_b == PLANE)


@njit(cache=True)
def bounds(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray, margin: float,
           lo: np.ndarray, hi: np.ndarray) -> None:
    """
    Write the world axis-aligned box around a shape, widened by ``margin``: ``lo``, ``hi``.

    A box's half width along world axis ``i`` is ``Σ_j |R_ij| h_j``; a capsule's and a
    cylinder's follow from their axis and radius (a cylinder's: its caps' discs); a
    plane's is the whole space.
    """
    for i in range(3):
        if kind == PLANE:
            half = math.inf
        elif kind == SPHERE:
            half = size[0]
        elif kind == CAPSULE:
            half = abs(R[i, 2]) * size[1] + size[0]
        elif kind == BOX or kind == HULL:   # (a hull: the box about its origin that holds it)
            half = abs(R[i, 0]) * size[0] + abs(R[i, 1]) * size[1] + abs(R[i, 2]) * size[2]
        else:   # a disc of radius r across axis a reaches r sqrt(1 − a_i²) along axis i
            a = R[i, 2]
            half = abs(a) * size[1] + size[0] * math.sqrt(max(1.0 - a * a, 0.0))
        lo[i] = c[i] - half - margin
        hi[i] = c[i] + half + margin


@njit(cache=True)
def _candidate(i: int, j: int, lo: np.ndarray, hi: np.ndarray, body: np.ndarray,
               group: np.ndarray, mask: np.ndarray, nb: int, excluded: np.ndarray) -> bool:
    """Tell whether shapes i and j overlap in their boxes and their filters let them meet."""
    for r in range(3):
        if lo[j, r] > hi[i, r] or lo[i, r] > hi[j, r]:
            return False
    if body[i] == body[j]:
        return False
    if (group[i] & mask[j]) == 0 and (group[j] & mask[i]) == 0:
        return False
    if excluded.shape[0] == 0:
        return True
    code = min(body[i], body[j]) * nb + max(body[i], body[j])
    e = np.searchsorted(excluded, code)
    return not (e < excluded.shape[0] and excluded[e] == code)


#: Most grid cells a shape's box may cover; a bigger shape is tested against every other.
BIG_CELLS = 64


@njit(cache=True)
def broad_phase(lo: np.ndarray, hi: np.ndarray, body: np.ndarray, group: np.ndarray,
                mask: np.ndarray, n_bodies: int, excluded: np.ndarray,
                pairs: np.ndarray) -> int:
    """
    Find the pairs of shapes whose boxes ``lo``, ``hi`` (m, 3) overlap: a sorted uniform grid.

    The cells are cubes of twice the median box's largest side. Each shape is listed in
    every cell its box covers (at most :data:`BIG_CELLS`; a bigger one is set apart
    and tested against every shape), hashed by cell and sorted by hash (a counting
    sort, ``O(1)`` an entry), and the shapes of each cell paired; a pair is kept in the one cell
    that holds the lower corner of the two boxes' overlap (never twice), when the
    boxes overlap and the filters let it: not one body, one's ``group`` bits meeting the other's
    ``mask``, the bodies' pair ``min (n + 1) + max`` (``n`` = ``n_bodies``, the
    world body ``n``) not in the sorted array ``excluded`` (bodies joined by a
    joint, pairs switched off). For shapes of like sizes at a bounded density (a
    pile) each cell holds a bounded number, so the cost is ``O(m)`` (the median's
    ``O(m log m)`` at most). Planes
    (unbounded) are not here: the caller pairs them with every shape. Writes
    ``pairs`` (cap, 2) (i < j) and returns the count, which may pass ``cap`` (then
    the caller grows ``pairs`` and runs again).
    """
    m = lo.shape[0]
    if m < 2:
        return 0
    # (views without reference counts for the calls of _candidate: :func:`.views.raw`)
    lo, hi, body, group, mask = raw(lo), raw(hi), raw(body), raw(group), raw(mask)
    excluded = raw(excluded)
    nb = n_bodies + 1
    ext = np.empty(m)
    origin = np.full(3, np.inf)
    for s in range(m):
        e = 0.0
        for r in range(3):
            e = max(e, hi[s, r] - lo[s, r])
            origin[r] = min(origin[r], lo[s, r])
        ext[s] = e
    h = 2.0 * np.median(ext)
    if not h > 0.0:
        h = 1.0
    # Each shape's cell range; shapes covering too many cells are set apart.
    cells = np.empty((m, 6), dtype=np.int64)
    big = np.zeros(m, dtype=np.bool_)
    total = 0
    for s in range(m):
        count = 1
        for r in range(3):
            # (clamped: an int64 holds it; a span beyond BIG_CELLS makes the shape big
            # before the product could overflow)
            c0 = int(math.floor(min((lo[s, r] - origin[r]) / h, 1e15)))
            c1 = int(math.floor(min((hi[s, r] - origin[r]) / h, 1e15)))
            cells[s, r], cells[s, 3 + r] = c0, c1
            if c1 - c0 >= BIG_CELLS:
                count = BIG_CELLS + 1
            elif count <= BIG_CELLS:
                count *= c1 - c0 + 1
        if count > BIG_CELLS or count < 1:
            big[s] = True
        else:
            total += count
    # Each entry (shape, cell) hashed to a bucket, then the entries sorted by bucket
    # (counting sort: O(entries + buckets)) with their boxes copied alongside, so that
    # each bucket's entries, and the data its pairs read, lie together in memory.
    size = 1
    while size < 2 * total:
        size *= 2
    bucket_of = np.empty(total, dtype=np.int64)
    start = np.zeros(size + 1, dtype=np.int64)
    w = 0
    for s in range(m):
        if big[s]:
            continue
        for x in range(cells[s, 0], cells[s, 3] + 1):
            for y in range(cells[s, 1], cells[s, 4] + 1):
                for z in range(cells[s, 2], cells[s, 5] + 1):
                    bk = ((x * 73856093) ^ (y * 19349663) ^ (z * 83492791)) & (size - 1)
                    bucket_of[w] = bk
                    start[bk + 1] += 1
                    w += 1
    for bk in range(size):
        start[bk + 1] += start[bk]
    fill = start[:size].copy()
    owner = np.empty(total, dtype=np.int64)
    where = np.empty((total, 6), dtype=np.int64)   # each entry's cell, its shape's first
    box = np.empty((total, 6))                     # each entry's shape's box
    w = 0
    for s in range(m):
        if big[s]:
            continue
        for x in range(cells[s, 0], cells[s, 3] + 1):
            for y in range(cells[s, 1], cells[s, 4] + 1):
                for z in range(cells[s, 2], cells[s, 5] + 1):
                    pos = fill[bucket_of[w]]
                    fill[bucket_of[w]] = pos + 1
                    owner[pos] = s
                    where[pos, 0], where[pos, 1], where[pos, 2] = x, y, z
                    for r in range(3):
                        where[pos, 3 + r] = cells[s, r]
                        box[pos, r], box[pos, 3 + r] = lo[s, r], hi[s, r]
                    w += 1
    count = 0
    for bk in range(size):
        for u in range(start[bk], start[bk + 1]):
            for v in range(u + 1, start[bk + 1]):
                if where[u, 0] != where[v, 0] or where[u, 1] != where[v, 1] \
                        or where[u, 2] != where[v, 2]:
                    continue   # another cell in the same bucket
                # The overlap's lower corner lies in the cell of the two shapes' larger
                # first cells (floor is monotonic): keep the pair in that cell only
                # (both boxes cover it, and a shape has one entry in a cell).
                if max(where[u, 3], where[v, 3]) != where[u, 0] \
                        or max(where[u, 4], where[v, 4]) != where[u, 1] \
                        or max(where[u, 5], where[v, 5]) != where[u, 2]:
                    continue
                apart = False
                for r in range(3):
                    if box[v, r] > box[u, 3 + r] or box[u, r] > box[v, 3 + r]:
                        apart = True
                if apart:
                    continue
                i, j = owner[u], owner[v]
                if not _candidate(i, j, lo, hi, body, group, mask, nb, excluded):
                    continue
                if count < pairs.shape[0]:
                    pairs[count, 0], pairs[count, 1] = min(i, j), max(i, j)
                count += 1
    # The big shapes, against every other: a big and a listed one from the big one's
    # side, two big ones once (the first with the second).
    for i in range(m):
        if not big[i]:
            continue
        for j in range(m):
            if j == i or (big[j] and j < i):
                continue
            if not _candidate(i, j, lo, hi, body, group, mask, nb, excluded):
                continue
            if count < pairs.shape[0]:
                pairs[count, 0], pairs[count, 1] = min(i, j), max(i, j)
            count += 1
    return count


@njit(cache=True)
def shape_frames(out: np.ndarray, body: np.ndarray, c_body: np.ndarray, R_body: np.ndarray,
                 c: np.ndarray, R: np.ndarray) -> None:
    """
    Write the shapes' frames in the world, from their bodies' frames (outputs ``out``).

    ``c = p + Q c_body``, ``R = Q R_body`` with ``p``, ``Q`` the body frame's origin
    and rotation (:data:`.layout.OUTPUT`); a shape of body ``n`` (the world) keeps
    its own. ``c`` (m, 3), ``R`` (m, 3, 3) written.
    """
    Q = np.empty((3, 3))
    n = out.shape[0]
    for s in range(body.shape[0]):
        b = body[s]
        if b >= n:
            for i in range(3):
                c[s, i] = c_body[s, i]
                for j in range(3):
                    R[s, i, j] = R_body[s, i, j]
            continue
        quat_matrix(out[b, O_QUAT_BODY_WORLD:O_QUAT_BODY_WORLD + 4], Q)
        for i in range(3):
            c[s, i] = (out[b, O_ORIGIN_WORLD + i] + Q[i, 0] * c_body[s, 0]
                       + Q[i, 1] * c_body[s, 1] + Q[i, 2] * c_body[s, 2])
            for j in range(3):
                R[s, i, j] = (Q[i, 0] * R_body[s, 0, j] + Q[i, 1] * R_body[s, 1, j]
                              + Q[i, 2] * R_body[s, 2, j])


@njit(cache=True)
def narrow_phase(pairs: np.ndarray, kind: np.ndarray, c: np.ndarray, R: np.ndarray,
                 size: np.ndarray, hulls: np.ndarray, hull_at: np.ndarray, margin: float,
                 points: np.ndarray, normals: np.ndarray, depths: np.ndarray,
                 owner: np.ndarray) -> int:
    """
    Write the contacts of every pair ``(a, b)`` of ``pairs`` (p, 2), one after another.

    Writes each contact and, in ``owner``, the row of ``pairs`` it is of; returns the
    count, which may pass the buffers' room (then grow them and run again). ``hulls``:
    the hulls' records one after another; ``hull_at`` (m,): where shape ``s``'s starts
    (−1: not a hull).
    """
    k = 0
    w = np.empty(SCRATCH)
    # Views without reference counts (:func:`.views.raw`): the narrow phases pass rows
    # and slices of these down their calls, each counted twice otherwise.
    ws, c, R, size = raw(w), raw(c), raw(R), raw(size)
    points, normals, depths = raw(points), raw(normals), raw(depths)
    nh = hulls.shape[0]
    for q in range(pairs.shape[0]):
        a, b = pairs[q, 0], pairs[q, 1]
        start = k
        # A hull's record in place of its size (the rest of ``hulls`` from its start).
        sa = raw_slice(size, 3 * a, (3,)) if hull_at[a] < 0 else \
            raw_slice(hulls, hull_at[a], (nh - hull_at[a],))
        sb = raw_slice(size, 3 * b, (3,)) if hull_at[b] < 0 else \
            raw_slice(hulls, hull_at[b], (nh - hull_at[b],))
        k = _collide(kind[a], c[a], R[a], sa, kind[b], c[b], R[b], sb, margin, points,
                     normals, depths, k, ws)
        if k < 0:   # no narrow phase (the detector refuses such pairs when it is built)
            k = start
            continue
        for j in range(start, min(k, owner.shape[0])):
            owner[j] = q
    # ``ws`` counts no reference to ``w``: numba frees a local after its last use, so
    # without this use ``w`` would be freed before the loop and the narrow phases' own
    # arrays allocated over the scratch they are writing (runs then differ).
    w[0] = 0.0
    return k


@njit(cache=True)
def all_bounds(kind: np.ndarray, c: np.ndarray, R: np.ndarray, size: np.ndarray,
               rows: np.ndarray, margin: float, lo: np.ndarray, hi: np.ndarray) -> None:
    """Write :func:`bounds` of the shapes ``rows`` into ``lo``, ``hi`` (len(rows), 3)."""
    for j in range(rows.shape[0]):
        s = rows[j]
        bounds(kind[s], c[s], R[s], size[s], margin, lo[j], hi[j])


@njit(cache=True)
def plane_pairs(solids: np.ndarray, planes: np.ndarray, body: np.ndarray, group: np.ndarray,
                mask: np.ndarray, n_bodies: int, excluded: np.ndarray,
                pairs: np.ndarray) -> int:
    """
    Write the pairs (shape, plane) that the filters let meet, as :func:`broad_phase` does.

    Every shape is tested against every plane (a plane's box is the whole space); the
    same rules: not one body, one's group in the other's mask, the bodies' pair not
    in ``excluded``. Returns the count (may pass the room of ``pairs``).
    """
    nb = n_bodies + 1
    count = 0
    for p in range(planes.shape[0]):
        j = planes[p]
        for q in range(solids.shape[0]):
            i = solids[q]
            if body[i] == body[j]:
                continue
            if (group[i] & mask[j]) == 0 and (group[j] & mask[i]) == 0:
                continue
            code = min(body[i], body[j]) * nb + max(body[i], body[j])
            e = np.searchsorted(excluded, code)
            if e < excluded.shape[0] and excluded[e] == code:
                continue
            if count < pairs.shape[0]:
                pairs[count, 0], pairs[count, 1] = i, j
            count += 1
    return count
