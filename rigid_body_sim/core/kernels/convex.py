"""
Convex pairs without a closed form here (a cylinder or a hull on a shape): GJK, EPA, features.

The shapes' conventions are :mod:`.contact`'s (kind, centre ``c``, rotation ``R``,
size; a cylinder's axis is its z axis). A hull (a mesh's convex hull) takes its packed
record (:mod:`..hulls`: ``H_*`` below) in place of a size. Each shape is known here by
its support point, the point farthest along a direction (:func:`support`).

**Depth and normal.** With ``D = A − B`` (the Minkowski difference), the signed
overlap of ``A`` and ``B`` (negative: their gap) is the least of ``D``'s support
function over unit directions, and its minimizer is the normal. The expanding
polytope algorithm (EPA) finds that least value for a body that holds the origin;
``D`` holds it only when the shapes overlap, so EPA runs on ``D' = (A ⊕ ε-ball) − B``
(``ε``: the margin plus :data:`INFLATE` of the shapes' size), which holds the origin
whenever the gap is below ``ε``: its least support is the overlap plus ``ε``, with the
same normal. GJK first tells whether ``D'`` holds the origin (if not, the gap passes
the margin: no contact) and gives EPA its first tetrahedron (where its iterations run
out undecided, the origin within ``ε`` of its simplex, EPA from that simplex decides:
its polytope holds the origin only where ``D'`` does). Inflating keeps ``D'`` a
solid (never flat), so EPA starts and ends well conditioned even for shapes exactly
touching, where GJK's own normal would come from a vector of rounding size.

Where the shapes touch along flat features (a box's face, a cylinder's cap, a
cylinder's mantle line, a box's edge), ``D'`` is flat there and EPA's face lies in
it: its normal is exact to rounding. On curved parts (a cylinder's rim on an edge
or on a rim, a mantle on a corner or on a parallel mantle) EPA refines until its
face's distance and the support along its normal agree within :data:`EPA_TOLERANCE`
of the shapes' size: the depth is that close, the normal within about
``sqrt(2 tol / ρ)`` (``ρ`` the curvature radius), measured at 1e-7 rad. A nearest face
that comes nearer than the last one ends it (rounding broke the polytope: nearly flat
faces seen from both sides), keeping the last sound face.

**Manifold.** Each shape's feature facing the other (:func:`feature`): a box's
vertex, edge or face, a cylinder's rim point, mantle line or cap disc, each spanning
the directions along which the shape's height changes by at most the margin (a face
tilted by less than the margin over its width is a face: all its corners touch, each
at its own gap). Two flat features (face or disc, or a line lying across the normal)
overlap in a region seen along the normal; its corners (each feature's corners inside
the other, and where their edges and circles cross; a disc's corners: four rim
points, the first its deepest) are the contacts, each at the gap between the two
features along the normal (each lifted onto its own feature's plane or line), at
most :data:`.contact.MANIFOLD` of them (the contact module's reduction). A point on a
flat feature is that point at its gap to the feature's plane; a point on a line, or two
crossed lines, where they pass closest along the normal; two lines side by side (a
capsule's or a mantle's on an edge), the ends of their overlap and where their sights
along the normal cross, each the curved side's point seen along the normal from the
other line's (two edges whose sights cross: where they pass closest); two points (a
rim on a rim), the shapes' support points along it. A cylinder's mantle on a box's corner or on a
line along its axis takes the radial normal through it (exact where EPA's is only
near it).
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

#: EPA ends when the support along its nearest face's normal passes that face by at most
#: this fraction of the shapes' size (flat contacts end exactly).
EPA_TOLERANCE = 1e-13
#: Most vertices EPA adds (and iterations: one each).
EPA_VERTICES = 160
#: Most GJK iterations.
GJK_ITERATIONS = 64
#: The inflating ball's radius beyond the margin, as a fraction of the shapes' size.
INFLATE = 1e-3
#: The inflating ball's radius for a sphere's or capsule's core inside a hull (its EPA:
#: :func:`_rounded`), as a fraction of the shapes' size: the depth's error at most.
CORE_INFLATE = 1e-9
#: Kinds, as :class:`.contact.Shape` (repeated: this module must not import contact's).
SPHERE, CAPSULE, BOX, CYLINDER, HULL = 0, 1, 2, 3, 5
#: A hull's record (:func:`..hulls.hull_record`): its half extents about its origin
#: (0:3), vertex count, face count, then from ``H_VERTS`` its vertices (3 each), its
#: faces' starts, and each face (outward normal, corner count k, k vertex indices).
H_NV, H_NF, H_VERTS = 3, 4, 6
#: Most corners of a feature (a hull's face).
CORNERS = 64
#: Most corners of the overlap of two features (theirs, and where their outlines cross).
CANDIDATES = 2 * CORNERS + 8
#: A sine below which two directions count as parallel (:data:`.contact.PARALLEL`).
PARALLEL = 1e-6
#: Feature kinds.
F_POINT, F_SEGMENT, F_POLYGON, F_DISC = 0, 1, 2, 3


@njit(cache=True)
def support(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray, d0: float, d1: float,
            d2: float, out: np.ndarray) -> None:
    """
    Write into ``out`` a point of the shape farthest along ``d`` (not necessarily unit).

    Ties (a face or a cap along ``d``) go to the positive side of the shape's axes:
    any point of the tie is a support point.
    """
    for i in range(3):
        out[i] = c[i]
    if kind == BOX:
        for j in range(3):
            s = 1.0 if R[0, j] * d0 + R[1, j] * d1 + R[2, j] * d2 >= 0.0 else -1.0
            for i in range(3):
                out[i] += s * size[j] * R[i, j]
        return
    if kind == HULL:   # its vertex highest along d (the first of a tie)
        v = size[H_VERTS + 3 * _top(R, size, d0, d1, d2):]
        for i in range(3):
            out[i] += R[i, 0] * v[0] + R[i, 1] * v[1] + R[i, 2] * v[2]
        return
    norm = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    if kind == SPHERE:
        if norm > 0.0:
            out[0] += size[0] * d0 / norm
            out[1] += size[0] * d1 / norm
            out[2] += size[0] * d2 / norm
        return
    a0, a1, a2 = R[0, 2], R[1, 2], R[2, 2]
    ad = a0 * d0 + a1 * d1 + a2 * d2
    s = 1.0 if ad >= 0.0 else -1.0
    r, hl = size[0], size[1]
    if kind == CAPSULE:
        if norm > 0.0:
            out[0] += s * hl * a0 + r * d0 / norm
            out[1] += s * hl * a1 + r * d1 / norm
            out[2] += s * hl * a2 + r * d2 / norm
        return
    # A cylinder: the cap's end of the axis, then the radius across it. The part of d
    # across the axis is taken out twice (d nearly along the axis leaves a part of
    # rounding size whose direction one pass does not keep across it).
    p0, p1, p2 = d0 - ad * a0, d1 - ad * a1, d2 - ad * a2
    pa = p0 * a0 + p1 * a1 + p2 * a2
    p0, p1, p2 = p0 - pa * a0, p1 - pa * a1, p2 - pa * a2
    pn = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    out[0] += s * hl * a0
    out[1] += s * hl * a1
    out[2] += s * hl * a2
    if pn > 1e-12 * norm:   # (a part of rounding size: the cap's centre is a support point)
        out[0] += r * p0 / pn
        out[1] += r * p1 / pn
        out[2] += r * p2 / pn


@njit(cache=True)
def _top(R: np.ndarray, rec: np.ndarray, d0: float, d1: float, d2: float) -> int:
    """Return the index of a hull's vertex highest along the world direction ``d``."""
    l0 = R[0, 0] * d0 + R[1, 0] * d1 + R[2, 0] * d2   # d in the hull's frame
    l1 = R[0, 1] * d0 + R[1, 1] * d1 + R[2, 1] * d2
    l2 = R[0, 2] * d0 + R[1, 2] * d1 + R[2, 2] * d2
    best, high = 0, -math.inf
    for i in range(int(rec[H_NV])):
        o = H_VERTS + 3 * i
        h = rec[o] * l0 + rec[o + 1] * l1 + rec[o + 2] * l2
        if h > high:
            best, high = i, h
    return best


@njit(cache=True)
def _support_d(ka: int, ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, kb: int,
               cb: np.ndarray, Rb: np.ndarray, sb: np.ndarray, eps: float, d0: float,
               d1: float, d2: float, V: np.ndarray, PA: np.ndarray, PB: np.ndarray,
               i: int) -> None:
    """Write vertex ``i`` of ``D' = (A ⊕ eps-ball) − B`` along ``d``: ``V[i]``, A's, B's points."""
    support(ka, ca, Ra, sa, d0, d1, d2, PA[i])
    support(kb, cb, Rb, sb, -d0, -d1, -d2, PB[i])
    norm = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    for r in range(3):
        V[i, r] = PA[i, r] - PB[i, r]
    if norm > 0.0:
        V[i, 0] += eps * d0 / norm
        V[i, 1] += eps * d1 / norm
        V[i, 2] += eps * d2 / norm


@njit(cache=True)
def _closest_subset(V: np.ndarray, idx: np.ndarray, m: int, lam: np.ndarray,
                    v: np.ndarray) -> int:
    """
    Find the point of the simplex ``V[idx[:m]]`` nearest the origin (GJK's sub-problem).

    Tries every face of the simplex (every subset of its vertices) whose own nearest
    point of its affine hull lies inside it, and keeps the nearest: written into
    ``v``, its barycentric weights into ``lam`` (by position in ``idx``). Returns the
    bit mask of the subset kept (the simplex shrinks to it).
    """
    best, best_mask = math.inf, 0
    G = np.empty((3, 3))
    rhs = np.empty(3)
    mu = np.empty(3)
    for mask in range(1, 1 << m):
        sub = np.empty(4, dtype=np.int64)
        ns = 0
        for j in range(m):
            if mask & (1 << j):
                sub[ns] = j
                ns += 1
        p0 = V[idx[sub[0]]]
        q = ns - 1
        for a in range(q):
            ea = V[idx[sub[a + 1]]]
            rhs[a] = -((ea[0] - p0[0]) * p0[0] + (ea[1] - p0[1]) * p0[1]
                       + (ea[2] - p0[2]) * p0[2])
            for b in range(q):
                eb = V[idx[sub[b + 1]]]
                G[a, b] = ((ea[0] - p0[0]) * (eb[0] - p0[0]) + (ea[1] - p0[1]) * (eb[1] - p0[1])
                           + (ea[2] - p0[2]) * (eb[2] - p0[2]))
        ok = _solve_small(G, rhs, q, mu)
        if not ok:
            continue
        lam0 = 1.0
        inside = True
        for a in range(q):
            lam0 -= mu[a]
            if mu[a] < 0.0:
                inside = False
        if lam0 < 0.0 or not inside:
            continue
        x0, x1, x2 = p0[0], p0[1], p0[2]
        for a in range(q):
            ea = V[idx[sub[a + 1]]]
            x0 += mu[a] * (ea[0] - p0[0])
            x1 += mu[a] * (ea[1] - p0[1])
            x2 += mu[a] * (ea[2] - p0[2])
        dist = x0 * x0 + x1 * x1 + x2 * x2
        if dist < best:
            best, best_mask = dist, mask
            v[0], v[1], v[2] = x0, x1, x2
            for j in range(m):
                lam[j] = 0.0
            lam[sub[0]] = lam0
            for a in range(q):
                lam[sub[a + 1]] = mu[a]
    return best_mask


@njit(cache=True)
def _solve_small(G: np.ndarray, rhs: np.ndarray, q: int, mu: np.ndarray) -> bool:
    """Solve the q×q (q ≤ 3) Gram system ``G mu = rhs``; False if singular to rounding."""
    if q == 0:
        return True
    if q == 1:
        if G[0, 0] <= 0.0:
            return False
        mu[0] = rhs[0] / G[0, 0]
        return True
    if q == 2:
        det = G[0, 0] * G[1, 1] - G[0, 1] * G[1, 0]
        if det <= 1e-14 * G[0, 0] * G[1, 1]:
            return False
        mu[0] = (rhs[0] * G[1, 1] - G[0, 1] * rhs[1]) / det
        mu[1] = (G[0, 0] * rhs[1] - G[1, 0] * rhs[0]) / det
        return True
    c00 = G[1, 1] * G[2, 2] - G[1, 2] * G[2, 1]
    c01 = G[1, 2] * G[2, 0] - G[1, 0] * G[2, 2]
    c02 = G[1, 0] * G[2, 1] - G[1, 1] * G[2, 0]
    det = G[0, 0] * c00 + G[0, 1] * c01 + G[0, 2] * c02
    if det <= 1e-14 * G[0, 0] * G[1, 1] * G[2, 2]:
        return False
    for a in range(3):   # Cramer's rule, column a replaced by rhs
        H = G.copy()
        for r in range(3):
            H[r, a] = rhs[r]
        mu[a] = (H[0, 0] * (H[1, 1] * H[2, 2] - H[1, 2] * H[2, 1])
                 - H[0, 1] * (H[1, 0] * H[2, 2] - H[1, 2] * H[2, 0])
                 + H[0, 2] * (H[1, 0] * H[2, 1] - H[1, 1] * H[2, 0])) / det
    return True


@njit(cache=True)
def _face(V: np.ndarray, a: int, b: int, c: np.ndarray, F: np.ndarray, FN: np.ndarray,
          f: int, cc: int) -> None:
    """Write face ``f`` = (a, b, cc) of the polytope ``V``: its unit normal and its distance."""
    F[f, 0], F[f, 1], F[f, 2] = a, b, cc
    e0, e1, e2 = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
    g0, g1, g2 = V[cc, 0] - V[a, 0], V[cc, 1] - V[a, 1], V[cc, 2] - V[a, 2]
    n0, n1, n2 = e1 * g2 - e2 * g1, e2 * g0 - e0 * g2, e0 * g1 - e1 * g0
    norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if norm > 0.0:
        n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
    FN[f, 0], FN[f, 1], FN[f, 2] = n0, n1, n2
    FN[f, 3] = n0 * V[a, 0] + n1 * V[a, 1] + n2 * V[a, 2]
    c[f] = 1 if norm > 0.0 else 0


@njit(cache=True)
def _gjk(ka: int, ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, kb: int, cb: np.ndarray,
         Rb: np.ndarray, sb: np.ndarray, eps: float, reach: float, V: np.ndarray,
         PA: np.ndarray, PB: np.ndarray, idx: np.ndarray, lam: np.ndarray,
         v: np.ndarray) -> tuple:
    """
    Run GJK on ``D' = (A ⊕ eps-ball) − B``: whether it holds the origin, or how far it is.

    Returns (status, m): status 0 when ``D'`` lies beyond ``reach`` of the origin, 1
    when it holds the origin (the simplex ``idx[:m]`` of ``V``'s rows then holds it, or
    has it on its boundary), 2 when it lies within ``reach``: ``v`` is then its point
    nearest the origin, the simplex ``idx[:m]`` with weights ``lam`` the support points
    it combines. 3 when :data:`GJK_ITERATIONS` ran out undecided: ``v`` and the simplex
    are its last (``D'`` lies within ``|v|``, or holds the origin).
    """
    scale = max(sa[0], sa[1], sa[2], sb[0], sb[1], sb[2])
    d0, d1, d2 = ca[0] - cb[0], ca[1] - cb[1], ca[2] - cb[2]
    if d0 * d0 + d1 * d1 + d2 * d2 == 0.0:
        d0 = 1.0
    _support_d(ka, ca, Ra, sa, kb, cb, Rb, sb, eps, d0, d1, d2, V, PA, PB, 0)
    idx[0] = 0
    lam[0] = 1.0
    m, used = 1, 1
    for r in range(3):
        v[r] = V[0, r]
    tiny = 1e-13 * (scale + eps)
    for _ in range(GJK_ITERATIONS):
        vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        if vv <= tiny * tiny:
            return 1, m
        # Recycle the slots of the vertices dropped from the simplex.
        slot = used
        for q in range(used):
            free = True
            for j in range(m):
                if idx[j] == q:
                    free = False
            if free:
                slot = q
                break
        _support_d(ka, ca, Ra, sa, kb, cb, Rb, sb, eps, -v[0], -v[1], -v[2], V, PA, PB, slot)
        w = V[slot]
        vw = v[0] * w[0] + v[1] * w[1] + v[2] * w[2]
        if vw > reach * math.sqrt(vv):
            return 0, m   # the plane through w across v parts D' from the origin by > reach
        if vv - vw <= 1e-12 * vv + tiny * tiny:
            # No progress: v is D''s nearest point (to rounding), or the origin is on
            # its boundary.
            return (2 if vv > tiny * tiny else 1), m
        if slot == used:
            used += 1
        idx[m] = slot
        m += 1
        mask = _closest_subset(V, idx, m, lam, v)
        if mask == 0:
            return 1, m - 1
        if m == 4 and mask == 15:
            return 1, m   # the tetrahedron holds the origin
        keep = 0
        for j in range(m):
            if mask & (1 << j):
                idx[keep] = idx[j]
                lam[keep] = lam[j]
                keep += 1
        m = keep
    return 3, m


@njit(cache=True)
def penetration(ka: int, ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, kb: int,
                cb: np.ndarray, Rb: np.ndarray, sb: np.ndarray, margin: float,
                result: np.ndarray) -> bool:
    """
    Find the signed overlap of shapes ``a`` and ``b``, its normal and witnesses (GJK, EPA).

    Returns False when the gap passes ``margin`` (no contact). Else writes ``result``
    (11,): the unit normal from ``b`` to ``a`` (0:3), the overlap (3; negative: a gap),
    ``a``'s surface point (4:7) and ``b``'s (7:10), and EPA's iterations (10).

    GJK on ``D'`` inflated by the margin plus :data:`INFLATE` of the shapes' size:
    a gap past that is no contact; any other pair is EPA's, from GJK's simplex (so
    every contact's normal comes from EPA, never from a GJK vector of rounding size).
    A sphere or a capsule on a shape that is neither: first GJK's distance between its
    core (its centre or axis) and the other shape, exact where the core is outside
    (:func:`_rounded`); EPA only when the core is inside.
    """
    scale = max(sa[0], sa[1], sa[2], sb[0], sb[1], sb[2])
    eps = margin + INFLATE * scale
    nv = EPA_VERTICES + 4
    V, PA, PB = np.empty((nv, 3)), np.empty((nv, 3)), np.empty((nv, 3))
    idx = np.zeros(4, dtype=np.int64)
    lam = np.zeros(4)
    v = np.empty(3)
    round_a, round_b = ka == SPHERE or ka == CAPSULE, kb == SPHERE or kb == CAPSULE
    if round_a != round_b:
        got = _rounded(ka, ca, Ra, sa, kb, cb, Rb, sb, margin, round_a, V, PA, PB, idx, lam,
                       v, result)
        if got >= 0:
            return got == 1
    status, m = _gjk(ka, ca, Ra, sa, kb, cb, Rb, sb, eps, 0.0, V, PA, PB, idx, lam, v)
    if status == 3 and v[0] * v[0] + v[1] * v[1] + v[2] * v[2] <= eps * eps:
        # GJK ran out of iterations within eps of the origin, undecided: EPA from its
        # simplex. Its polytope lies in D', so it holds the origin (a contact) only where
        # D' does; else a face of it passes the origin (a negative distance) and EPA
        # finds no contact.
        status = 1
    if status != 1:   # D' lies off the origin: the gap passes eps > margin
        return False
    return _epa(ka, ca, Ra, sa, kb, cb, Rb, sb, eps, margin, V, PA, PB, idx, m, result)


@njit(cache=True)
def _rounded(ka: int, ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, kb: int,
             cb: np.ndarray, Rb: np.ndarray, sb: np.ndarray, margin: float, round_a: bool,
             V: np.ndarray, PA: np.ndarray, PB: np.ndarray, idx: np.ndarray, lam: np.ndarray,
             v: np.ndarray, result: np.ndarray) -> int:
    """
    :func:`penetration` of a sphere or capsule (a if ``round_a``, else b) on another shape.

    GJK's nearest points of its core (radius 0) and the other shape: the normal along
    them and the depth ``r − distance`` are exact to rounding (a polytope's nearest
    simplex is found exactly; no curved surface is sampled), the normal's error about
    1e-17 m over the distance. Where the core touches or enters the other shape, EPA
    on the core and that shape, the radius added. Returns 1 (``result`` written), 0
    (the gap passes ``margin``) or −1 (neither resolved it: EPA on the whole shapes).
    """
    r = sa[0] if round_a else sb[0]
    core = np.zeros(3)
    core[1] = sa[1] if round_a else sb[1]   # (a capsule's half length; a sphere's 0)
    ka_, sa_ = (ka, core) if round_a else (ka, sa)
    kb_, sb_ = (kb, sb) if round_a else (kb, core)
    status, m = _gjk(ka_, ca, Ra, sa_, kb_, cb, Rb, sb_, 0.0, r + margin, V, PA, PB, idx,
                     lam, v)
    if status == 0:
        return 0
    if status == 3:   # (its distance undecided: EPA on the whole shapes)
        return -1
    dist = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    scale = max(sa[0], sa[1], sa[2], sb[0], sb[1], sb[2])
    if status == 1 or dist <= 1e-9 * scale:
        # The core touches or enters: EPA on the core and the other shape (no curved
        # surface in the pair when the other is a hull), then out by the radius. Its
        # ball of CORE_INFLATE of the size keeps GJK's simplex a solid where the core
        # only touches; EPA's polytope of that small ball is within it of the ball.
        eps = CORE_INFLATE * scale
        status, m = _gjk(ka_, ca, Ra, sa_, kb_, cb, Rb, sb_, eps, 0.0, V, PA, PB, idx, lam,
                         v)
        if status != 1 or not _epa(ka_, ca, Ra, sa_, kb_, cb, Rb, sb_, eps, margin + r, V,
                                   PA, PB, idx, m, result):
            return -1
        result[3] += r
        for x in range(3):
            if round_a:
                result[4 + x] -= r * result[x]
            else:
                result[7 + x] += r * result[x]
        return 1
    if r - dist < -margin:
        return 0
    for x in range(3):   # v runs from b's nearest point to a's: the normal, b to a
        result[x] = v[x] / dist
    result[3] = r - dist
    for x in range(3):
        pa, pb = 0.0, 0.0
        for j in range(m):
            pa += lam[j] * PA[idx[j], x]
            pb += lam[j] * PB[idx[j], x]
        if round_a:
            pa -= r * result[x]
        else:
            pb += r * result[x]
        result[4 + x], result[7 + x] = pa, pb
    result[10] = 0.0
    return 1


@njit(cache=True)
def _epa(ka: int, ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, kb: int, cb: np.ndarray,
         Rb: np.ndarray, sb: np.ndarray, eps: float, margin: float, V: np.ndarray,
         PA: np.ndarray, PB: np.ndarray, idx: np.ndarray, m: int,
         result: np.ndarray) -> bool:
    """EPA on ``D'`` from GJK's simplex ``idx[:m]`` holding the origin (:func:`penetration`)."""
    scale = max(sa[0], sa[1], sa[2], sb[0], sb[1], sb[2])
    # EPA's first tetrahedron: the simplex, blown up along directions across it.
    # Gather the simplex into slots 0..m-1.
    T, TA, TB = np.empty((4, 3)), np.empty((4, 3)), np.empty((4, 3))
    for j in range(m):
        for r in range(3):
            T[j, r], TA[j, r], TB[j, r] = V[idx[j], r], PA[idx[j], r], PB[idx[j], r]
    for j in range(m):
        for r in range(3):
            V[j, r], PA[j, r], PB[j, r] = T[j, r], TA[j, r], TB[j, r]
    dirs = np.empty(3)
    while m < 4:
        if m == 1:
            dirs[0], dirs[1], dirs[2] = 1.0, 0.0, 0.0
        elif m == 2:   # across the segment: its direction crossed with the axis least along it
            e0, e1, e2 = V[1, 0] - V[0, 0], V[1, 1] - V[0, 1], V[1, 2] - V[0, 2]
            if abs(e0) <= abs(e1) and abs(e0) <= abs(e2):
                dirs[0], dirs[1], dirs[2] = 0.0, e2, -e1
            elif abs(e1) <= abs(e2):
                dirs[0], dirs[1], dirs[2] = -e2, 0.0, e0
            else:
                dirs[0], dirs[1], dirs[2] = e1, -e0, 0.0
        else:   # the triangle's normal
            e0, e1, e2 = V[1, 0] - V[0, 0], V[1, 1] - V[0, 1], V[1, 2] - V[0, 2]
            g0, g1, g2 = V[2, 0] - V[0, 0], V[2, 1] - V[0, 1], V[2, 2] - V[0, 2]
            dirs[0], dirs[1], dirs[2] = e1 * g2 - e2 * g1, e2 * g0 - e0 * g2, e0 * g1 - e1 * g0
        # The side whose support lies farther from the simplex's span (D' is a solid).
        best, bs = -1.0, 1.0
        for sg in (1.0, -1.0):
            _support_d(ka, ca, Ra, sa, kb, cb, Rb, sb, eps, sg * dirs[0], sg * dirs[1],
                       sg * dirs[2], V, PA, PB, m)
            h = sg * (dirs[0] * (V[m, 0] - V[0, 0]) + dirs[1] * (V[m, 1] - V[0, 1])
                      + dirs[2] * (V[m, 2] - V[0, 2]))
            if h > best:
                best, bs = h, sg
        _support_d(ka, ca, Ra, sa, kb, cb, Rb, sb, eps, bs * dirs[0], bs * dirs[1],
                   bs * dirs[2], V, PA, PB, m)
        m += 1
    nvert = 4
    mf = 2 * (EPA_VERTICES + 4)
    F = np.empty((mf, 3), dtype=np.int64)
    FN = np.empty((mf, 4))
    alive = np.zeros(mf, dtype=np.int64)
    ok = np.zeros(mf, dtype=np.int64)
    nf = 0
    for a, b, cc, o in ((0, 1, 2, 3), (0, 3, 1, 2), (0, 2, 3, 1), (1, 3, 2, 0)):
        _face(V, a, b, ok, F, FN, nf, cc)
        side = (FN[nf, 0] * (V[o, 0] - V[a, 0]) + FN[nf, 1] * (V[o, 1] - V[a, 1])
                + FN[nf, 2] * (V[o, 2] - V[a, 2]))
        if side > 0.0:   # the fourth vertex in front: turn the face round
            _face(V, a, cc, ok, F, FN, nf, b)
        alive[nf] = 1
        nf += 1
    edges = np.empty((3 * mf, 2), dtype=np.int64)
    stack = np.empty(mf, dtype=np.int64)
    tol = EPA_TOLERANCE * (scale + eps)
    best = 0
    iterations = 0
    keep_f = np.full(3, -1, dtype=np.int64)
    keep_n = np.empty(3)
    keep_d = -math.inf
    while True:
        best, bd = -1, math.inf
        for f in range(nf):
            if alive[f] and ok[f] and FN[f, 3] < bd:
                best, bd = f, FN[f, 3]
        if best < 0:
            break
        if bd < keep_d - tol:
            # The nearest face came nearer: rounding broke the polytope (nearly flat
            # faces seen from both sides). Keep the last sound face.
            break
        keep_f[0], keep_f[1], keep_f[2] = F[best, 0], F[best, 1], F[best, 2]
        keep_d = bd
        for r in range(3):
            keep_n[r] = FN[best, r]
        if nvert >= V.shape[0]:
            break
        n0, n1, n2 = FN[best, 0], FN[best, 1], FN[best, 2]
        _support_d(ka, ca, Ra, sa, kb, cb, Rb, sb, eps, n0, n1, n2, V, PA, PB, nvert)
        gain = n0 * V[nvert, 0] + n1 * V[nvert, 1] + n2 * V[nvert, 2] - bd
        if gain <= tol:
            break
        iterations += 1
        # Remove the faces the new vertex sees, grown from the nearest face across shared
        # edges (a connected cap however rounding tilts near-flat faces); the cap's
        # outline (the horizon) remains.
        alive[best] = 0
        stack[0] = best
        ns = 1
        while ns > 0:
            ns -= 1
            f = stack[ns]
            for e in range(3):
                p, q = F[f, e], F[f, (e + 1) % 3]
                g = _across(F, alive, nf, p, q)
                if g < 0:
                    continue
                a = F[g, 0]
                if (FN[g, 0] * (V[nvert, 0] - V[a, 0]) + FN[g, 1] * (V[nvert, 1] - V[a, 1])
                        + FN[g, 2] * (V[nvert, 2] - V[a, 2])) > 0.0:
                    alive[g] = 0
                    stack[ns] = g
                    ns += 1
        ne = 0
        for f in range(nf):
            if alive[f]:
                continue
            for e in range(3):
                p, q = F[f, e], F[f, (e + 1) % 3]
                if _across(F, alive, nf, p, q) >= 0:   # a kept face beyond: the horizon
                    edges[ne, 0], edges[ne, 1] = p, q
                    ne += 1
        # Compact the face list, then close the hole with faces on the new vertex.
        live = 0
        for f in range(nf):
            if alive[f]:
                for r in range(3):
                    F[live, r] = F[f, r]
                for r in range(4):
                    FN[live, r] = FN[f, r]
                ok[live] = ok[f]
                alive[live] = 1
                live += 1
        nf = live
        if nf + ne > mf:
            break
        for g in range(ne):
            _face(V, edges[g, 0], edges[g, 1], ok, F, FN, nf, nvert)
            alive[nf] = 1
            nf += 1
        nvert += 1
    if keep_f[0] < 0:
        return False
    # The origin's foot on the nearest face, in its barycentric weights.
    a, b, cc = keep_f[0], keep_f[1], keep_f[2]
    n0, n1, n2 = keep_n[0], keep_n[1], keep_n[2]
    dist = keep_d
    x0, x1, x2 = dist * n0, dist * n1, dist * n2
    w = np.empty(3)
    _barycentric(V[a], V[b], V[cc], x0, x1, x2, w)
    overlap = dist - eps
    if -overlap > margin:
        return False
    # The normal from b to a is −(EPA's normal): D''s nearest face faces from A into B.
    result[0], result[1], result[2] = -n0, -n1, -n2
    result[3] = overlap
    for r in range(3):
        result[4 + r] = w[0] * PA[a, r] + w[1] * PA[b, r] + w[2] * PA[cc, r]
        result[7 + r] = w[0] * PB[a, r] + w[1] * PB[b, r] + w[2] * PB[cc, r]
    result[10] = iterations
    return True


@njit(cache=True)
def _across(F: np.ndarray, alive: np.ndarray, nf: int, p: int, q: int) -> int:
    """Return the live face with the directed edge (q, p), across (p, q); −1 if none."""
    for g in range(nf):
        if alive[g]:
            for e in range(3):
                if F[g, e] == q and F[g, (e + 1) % 3] == p:
                    return g
    return -1


@njit(cache=True)
def _barycentric(p: np.ndarray, q: np.ndarray, s: np.ndarray, x0: float, x1: float, x2: float,
                 w: np.ndarray) -> None:
    """Write the barycentric weights of the triangle (p, q, s)'s point nearest x."""
    # The regions of the triangle's vertices, edges and face in turn (Ericson, Real-Time
    # Collision Detection, 5.1.5).
    ab0, ab1, ab2 = q[0] - p[0], q[1] - p[1], q[2] - p[2]
    ac0, ac1, ac2 = s[0] - p[0], s[1] - p[1], s[2] - p[2]
    ap0, ap1, ap2 = x0 - p[0], x1 - p[1], x2 - p[2]
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    if d1 <= 0.0 and d2 <= 0.0:
        w[0], w[1], w[2] = 1.0, 0.0, 0.0
        return
    bp0, bp1, bp2 = x0 - q[0], x1 - q[1], x2 - q[2]
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    if d3 >= 0.0 and d4 <= d3:
        w[0], w[1], w[2] = 0.0, 1.0, 0.0
        return
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        w[0], w[1], w[2] = 1.0 - v, v, 0.0
        return
    cp0, cp1, cp2 = x0 - s[0], x1 - s[1], x2 - s[2]
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    if d6 >= 0.0 and d5 <= d6:
        w[0], w[1], w[2] = 0.0, 0.0, 1.0
        return
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        w[0], w[1], w[2] = 1.0 - t, 0.0, t
        return
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        w[0], w[1], w[2] = 0.0, 1.0 - t, t
        return
    den = va + vb + vc
    if den <= 0.0:
        w[0], w[1], w[2] = 1.0, 0.0, 0.0
        return
    v, t = vb / den, vc / den
    w[0], w[1], w[2] = 1.0 - v - t, v, t


@njit(cache=True)
def feature(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray, d: np.ndarray,
            tol: float, pts: np.ndarray, normal: np.ndarray) -> tuple:
    """
    Return the shape's feature farthest along the unit direction ``d``: (kind, count, radius).

    A feature spans every direction along which the shape's extent changes its height
    along ``d`` by at most ``tol`` (the margin: what a contact may be apart), so a
    slightly tilted face or line still touches at all its corners, each at its own gap.
    A box: its vertex, edge (2 points) or face (4 corners in order; the axis most along
    ``d`` is never spanned). A hull: likewise (:func:`_hull_feature`). A sphere: its
    point along ``d``; a capsule: its end's or its axis' (2 points), out by the radius.
    A cylinder: its rim point, its mantle line (2 points) or
    its cap (a disc: its centre, and in ``pts[1]``, ``pts[2]`` two axes across the
    shape's axis, the first towards ``d``'s part across it, or the shape's x axis when
    that part is below :data:`PARALLEL`). ``normal``: a face's or a cap's outward normal.
    """
    for r in range(3):
        normal[r] = 0.0
    if kind == HULL:
        return _hull_feature(c, R, size, d, tol, pts, normal)
    if kind == SPHERE:
        for r in range(3):
            pts[0, r] = c[r] + size[0] * d[r]
        return F_POINT, 1, 0.0
    if kind == CAPSULE:   # its axis' end (or the axis, lying across d), out by the radius
        ad = R[0, 2] * d[0] + R[1, 2] * d[1] + R[2, 2] * d[2]
        hl = size[1]
        if abs(ad) * 2.0 * hl <= tol:
            for r in range(3):
                pts[0, r] = c[r] - hl * R[r, 2] + size[0] * d[r]
                pts[1, r] = c[r] + hl * R[r, 2] + size[0] * d[r]
            return F_SEGMENT, 2, 0.0
        s = 1.0 if ad >= 0.0 else -1.0
        for r in range(3):
            pts[0, r] = c[r] + s * hl * R[r, 2] + size[0] * d[r]
        return F_POINT, 1, 0.0
    if kind == BOX:
        most, big = 0, -1.0
        for j in range(3):
            dj = abs(R[0, j] * d[0] + R[1, j] * d[1] + R[2, j] * d[2])
            if dj > big:
                most, big = j, dj
        free = np.empty(3, dtype=np.int64)
        nfree = 0
        base = pts[3]
        for r in range(3):
            base[r] = c[r]
        for j in range(3):
            dj = R[0, j] * d[0] + R[1, j] * d[1] + R[2, j] * d[2]
            if j != most and abs(dj) * 2.0 * size[j] <= tol:
                free[nfree] = j
                nfree += 1
            else:
                s = 1.0 if dj > 0.0 else -1.0
                for r in range(3):
                    base[r] += s * size[j] * R[r, j]
                if j == most:   # a face's normal: its one fixed axis
                    for r in range(3):
                        normal[r] = s * R[r, j]
        if nfree == 0:
            for r in range(3):
                pts[0, r] = base[r]
            return F_POINT, 1, 0.0
        if nfree == 1:
            j = free[0]
            for r in range(3):
                pts[0, r] = base[r] - size[j] * R[r, j]
                pts[1, r] = base[r] + size[j] * R[r, j]
            return F_SEGMENT, 2, 0.0
        i, j = free[0], free[1]
        b0, b1, b2 = base[0], base[1], base[2]
        q = 0
        for si, sj in ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)):
            pts[q, 0] = b0 + si * size[i] * R[0, i] + sj * size[j] * R[0, j]
            pts[q, 1] = b1 + si * size[i] * R[1, i] + sj * size[j] * R[1, j]
            pts[q, 2] = b2 + si * size[i] * R[2, i] + sj * size[j] * R[2, j]
            q += 1
        return F_POLYGON, 4, 0.0
    # A cylinder.
    r_, hl = size[0], size[1]
    a0, a1, a2 = R[0, 2], R[1, 2], R[2, 2]
    ad = a0 * d[0] + a1 * d[1] + a2 * d[2]
    p0, p1, p2 = d[0] - ad * a0, d[1] - ad * a1, d[2] - ad * a2
    pa_ = p0 * a0 + p1 * a1 + p2 * a2   # (twice, as in :func:`support`)
    p0, p1, p2 = p0 - pa_ * a0, p1 - pa_ * a1, p2 - pa_ * a2
    pn = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    s = 1.0 if ad >= 0.0 else -1.0
    if pn > PARALLEL:
        u0, u1, u2 = p0 / pn, p1 / pn, p2 / pn
    else:
        u0, u1, u2 = R[0, 0], R[1, 0], R[2, 0]
    if pn * 2.0 * r_ <= tol and pn <= abs(ad):   # the cap
        w0, w1, w2 = a1 * u2 - a2 * u1, a2 * u0 - a0 * u2, a0 * u1 - a1 * u0
        for r in range(3):
            pts[0, r] = c[r] + s * hl * R[r, 2]
            normal[r] = s * R[r, 2]
        pts[1, 0], pts[1, 1], pts[1, 2] = u0, u1, u2
        pts[2, 0], pts[2, 1], pts[2, 2] = w0, w1, w2
        return F_DISC, 1, r_
    if abs(ad) * 2.0 * hl <= tol:   # the mantle line
        for r in range(3):
            pts[0, r] = c[r] - hl * R[r, 2]
            pts[1, r] = c[r] + hl * R[r, 2]
        pts[0, 0] += r_ * u0
        pts[0, 1] += r_ * u1
        pts[0, 2] += r_ * u2
        pts[1, 0] += r_ * u0
        pts[1, 1] += r_ * u1
        pts[1, 2] += r_ * u2
        return F_SEGMENT, 2, 0.0
    pts[0, 0] = c[0] + s * hl * a0 + r_ * u0
    pts[0, 1] = c[1] + s * hl * a1 + r_ * u1
    pts[0, 2] = c[2] + s * hl * a2 + r_ * u2
    return F_POINT, 1, 0.0


@njit(cache=True)
def _hull_feature(c: np.ndarray, R: np.ndarray, rec: np.ndarray, d: np.ndarray, tol: float,
                  pts: np.ndarray, normal: np.ndarray) -> tuple:
    """
    Return :func:`feature` of a hull (its record ``rec``).

    The part of the hull within ``tol`` of its top along ``d``, seen through the faces
    at its top vertex: the one most along ``d`` if three or more of its corners lie
    within it, by those corners (a face tilted past ``tol`` over its width keeps the
    corners that touch, in order: a convex polygon still); else the edge from the top
    vertex to its highest neighbour, if within it; else the top vertex. As a box's
    feature: a face other than the one most along ``d`` is never a polygon, though it
    lie within ``tol`` (a side thinner than ``tol``: its plane, far from ``d``, would
    turn a small error of the normal into a large one of the gap; its edge at the top
    is the feature). (A face elsewhere may lie more along ``d`` and still not hold the
    deepest point.)
    """
    nv, nf = int(rec[H_NV]), int(rec[H_NF])
    l0 = R[0, 0] * d[0] + R[1, 0] * d[1] + R[2, 0] * d[2]   # d in the hull's frame
    l1 = R[0, 1] * d[0] + R[1, 1] * d[1] + R[2, 1] * d[2]
    l2 = R[0, 2] * d[0] + R[1, 2] * d[1] + R[2, 2] * d[2]
    top = _top(R, rec, d[0], d[1], d[2])
    o = H_VERTS + 3 * top
    high = rec[o] * l0 + rec[o + 1] * l1 + rec[o + 2] * l2
    starts = H_VERTS + 3 * nv
    best, most = -1, -math.inf   # the face at the top vertex most along d
    side, side_h = -1, -math.inf   # the top vertex's highest neighbour along a face's edge
    for f in range(nf):
        o = int(rec[starts + f])
        k = int(rec[o + 3])
        at = -1
        for q in range(k):
            if int(rec[o + 4 + q]) == top:
                at = q
        if at < 0:
            continue
        for q in ((at + 1) % k, (at + k - 1) % k):
            i = int(rec[o + 4 + q])
            v = H_VERTS + 3 * i
            h = rec[v] * l0 + rec[v + 1] * l1 + rec[v + 2] * l2
            if h > side_h:
                side, side_h = i, h
        nd = rec[o] * l0 + rec[o + 1] * l1 + rec[o + 2] * l2
        if nd > most:
            best, most = f, nd
    near = 0
    if best >= 0:
        o = int(rec[starts + best])
        for q in range(int(rec[o + 3])):
            v = H_VERTS + 3 * int(rec[o + 4 + q])
            if rec[v] * l0 + rec[v + 1] * l1 + rec[v + 2] * l2 >= high - tol:
                near += 1
    if near < 3:
        m = 1 if side < 0 or side_h < high - tol else 2
        for q in range(m):
            v = rec[H_VERTS + 3 * (top if q == 0 else side):]
            for r in range(3):
                pts[q, r] = c[r] + R[r, 0] * v[0] + R[r, 1] * v[1] + R[r, 2] * v[2]
        return (F_POINT if m == 1 else F_SEGMENT), m, 0.0
    o = int(rec[starts + best])
    m = 0
    for q in range(int(rec[o + 3])):
        v = rec[H_VERTS + 3 * int(rec[o + 4 + q]):]
        if v[0] * l0 + v[1] * l1 + v[2] * l2 >= high - tol and m < pts.shape[0]:
            for r in range(3):
                pts[m, r] = c[r] + R[r, 0] * v[0] + R[r, 1] * v[1] + R[r, 2] * v[2]
            m += 1
    for r in range(3):
        normal[r] = R[r, 0] * rec[o] + R[r, 1] * rec[o + 1] + R[r, 2] * rec[o + 2]
    return F_POLYGON, m, 0.0


@njit(cache=True)
def _region(ft: int, npts: int, pts: np.ndarray, rad: float, o: np.ndarray, t1: np.ndarray,
            t2: np.ndarray, xy: np.ndarray) -> int:
    """
    Write a feature seen along the normal: its corners in the plane (t1, t2) through ``o``.

    A polygon's corners counter-clockwise; a segment's two ends; a disc's four rim
    points along its shape's x and y axes (its centre goes to ``xy[4]``). Returns the
    count of corners.
    """
    if ft == F_DISC:
        q = 0
        for ax in (1, 2):
            for sg in (1.0, -1.0):
                x0 = pts[0, 0] + sg * rad * pts[ax, 0] - o[0]
                x1 = pts[0, 1] + sg * rad * pts[ax, 1] - o[1]
                x2 = pts[0, 2] + sg * rad * pts[ax, 2] - o[2]
                xy[q, 0] = x0 * t1[0] + x1 * t1[1] + x2 * t1[2]
                xy[q, 1] = x0 * t2[0] + x1 * t2[1] + x2 * t2[2]
                q += 1
        x0, x1, x2 = pts[0, 0] - o[0], pts[0, 1] - o[1], pts[0, 2] - o[2]
        xy[4, 0] = x0 * t1[0] + x1 * t1[1] + x2 * t1[2]
        xy[4, 1] = x0 * t2[0] + x1 * t2[1] + x2 * t2[2]
        # rim points in order round the disc: +x, +y, −x, −y
        xy[1, 0], xy[2, 0] = xy[2, 0], xy[1, 0]
        xy[1, 1], xy[2, 1] = xy[2, 1], xy[1, 1]
        return 4
    for q in range(npts):
        x0, x1, x2 = pts[q, 0] - o[0], pts[q, 1] - o[1], pts[q, 2] - o[2]
        xy[q, 0] = x0 * t1[0] + x1 * t1[1] + x2 * t1[2]
        xy[q, 1] = x0 * t2[0] + x1 * t2[1] + x2 * t2[2]
    if ft == F_POLYGON:
        area = 0.0
        for q in range(npts):
            p = (q + 1) % npts
            area += xy[q, 0] * xy[p, 1] - xy[p, 0] * xy[q, 1]
        if area < 0.0:   # turn it counter-clockwise (its 3-D corners with it)
            for q in range(npts // 2):
                p = npts - 1 - q
                for r in range(2):
                    xy[q, r], xy[p, r] = xy[p, r], xy[q, r]
                for r in range(3):
                    pts[q, r], pts[p, r] = pts[p, r], pts[q, r]
    return npts


@njit(cache=True)
def _inside(ft: int, xy: np.ndarray, m: int, rad: float, x: float, y: float,
            tol: float) -> bool:
    """Tell whether the plane point (x, y) lies in a flat feature's region (within tol)."""
    if ft == F_DISC:
        dx, dy = x - xy[4, 0], y - xy[4, 1]
        return math.sqrt(dx * dx + dy * dy) <= rad + tol
    if ft != F_POLYGON:
        return False
    for q in range(m):
        p = (q + 1) % m
        ex, ey = xy[p, 0] - xy[q, 0], xy[p, 1] - xy[q, 1]
        le = math.sqrt(ex * ex + ey * ey)
        if ex * (y - xy[q, 1]) - ey * (x - xy[q, 0]) < -tol * le:
            return False
    return True


@njit(cache=True)
def _add(cand: np.ndarray, nc: int, x: float, y: float) -> int:
    """Append the plane point (x, y) to ``cand`` (columns 0, 1) if there is room."""
    if nc < cand.shape[0]:
        cand[nc, 0], cand[nc, 1] = x, y
        return nc + 1
    return nc


@njit(cache=True)
def _crossings(fa: int, xa: np.ndarray, ma: int, ra: float, fb: int, xb: np.ndarray, mb: int,
               rb: float, cand: np.ndarray, nc: int) -> int:
    """Append where the outlines of two regions cross (edges, segments and circles)."""
    # Each outline as straight edges (a polygon's sides, a segment) or a circle.
    if fa == F_DISC and fb == F_DISC:
        dx, dy = xb[4, 0] - xa[4, 0], xb[4, 1] - xa[4, 1]
        d = math.sqrt(dx * dx + dy * dy)
        if d <= 0.0 or d > ra + rb or d < abs(ra - rb):
            return nc
        al = (ra * ra - rb * rb + d * d) / (2.0 * d)
        h = math.sqrt(max(ra * ra - al * al, 0.0))
        mx, my = xa[4, 0] + al * dx / d, xa[4, 1] + al * dy / d
        nc = _add(cand, nc, mx - h * dy / d, my + h * dx / d)
        return _add(cand, nc, mx + h * dy / d, my - h * dx / d)
    if fa == F_DISC or fb == F_DISC:
        if fa == F_DISC:
            fa, xa, ma, ra, fb, xb, mb, rb = fb, xb, mb, rb, fa, xa, ma, ra
        cx, cy, rr = xb[4, 0], xb[4, 1], rb
        edges = ma if fa == F_POLYGON else 1
        for q in range(edges):
            p = (q + 1) % ma
            px, py = xa[q, 0] - cx, xa[q, 1] - cy
            ex, ey = xa[p, 0] - xa[q, 0], xa[p, 1] - xa[q, 1]
            aa = ex * ex + ey * ey
            bb = 2.0 * (px * ex + py * ey)
            cc = px * px + py * py - rr * rr
            disc = bb * bb - 4.0 * aa * cc
            if aa <= 0.0 or disc < 0.0:
                continue
            sq = math.sqrt(disc)
            for t in ((-bb - sq) / (2.0 * aa), (-bb + sq) / (2.0 * aa)):
                if 0.0 <= t <= 1.0:
                    nc = _add(cand, nc, xa[q, 0] + t * ex, xa[q, 1] + t * ey)
        return nc
    ea = ma if fa == F_POLYGON else 1
    eb = mb if fb == F_POLYGON else 1
    for q in range(ea):
        qp = (q + 1) % ma
        ux, uy = xa[qp, 0] - xa[q, 0], xa[qp, 1] - xa[q, 1]
        for s in range(eb):
            sp = (s + 1) % mb
            vx, vy = xb[sp, 0] - xb[s, 0], xb[sp, 1] - xb[s, 1]
            den = ux * vy - uy * vx
            if den == 0.0:
                continue
            wx, wy = xb[s, 0] - xa[q, 0], xb[s, 1] - xa[q, 1]
            t = (wx * vy - wy * vx) / den
            u = (wx * uy - wy * ux) / den
            if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0:
                nc = _add(cand, nc, xa[q, 0] + t * ux, xa[q, 1] + t * uy)
    return nc


@njit(cache=True)
def _corner(ft: int, pts: np.ndarray, rad: float, q: int, out: np.ndarray) -> None:
    """Write a feature's corner ``q`` in 3-D (a disc's: +x, +y, −x, −y as :func:`_region`)."""
    if ft == F_DISC:
        ax = 1 if q % 2 == 0 else 2
        sg = 1.0 if q < 2 else -1.0
        for r in range(3):
            out[r] = pts[0, r] + sg * rad * pts[ax, r]
        return
    for r in range(3):
        out[r] = pts[q, r]


@njit(cache=True)
def _onto(ft: int, pts: np.ndarray, normal: np.ndarray, p: np.ndarray, n: np.ndarray,
          out: np.ndarray) -> None:
    """Write the point of a feature (a plane, or a line) seen from ``p`` along ``n``."""
    if ft == F_SEGMENT:   # the line's point x with x − p along n
        e0, e1, e2 = pts[1, 0] - pts[0, 0], pts[1, 1] - pts[0, 1], pts[1, 2] - pts[0, 2]
        en = e0 * n[0] + e1 * n[1] + e2 * n[2]
        f0, f1, f2 = e0 - en * n[0], e1 - en * n[1], e2 - en * n[2]   # across n
        h0, h1, h2 = p[0] - pts[0, 0], p[1] - pts[0, 1], p[2] - pts[0, 2]
        ff = f0 * f0 + f1 * f1 + f2 * f2
        s = (h0 * f0 + h1 * f1 + h2 * f2) / ff if ff > 0.0 else 0.0
        s = min(max(s, 0.0), 1.0)
        for r in range(3):
            out[r] = pts[0, r] + s * (pts[1, r] - pts[0, r])
        return
    mn = normal[0] * n[0] + normal[1] * n[1] + normal[2] * n[2]
    t = (normal[0] * (pts[0, 0] - p[0]) + normal[1] * (pts[0, 1] - p[1])
         + normal[2] * (pts[0, 2] - p[2])) / mn
    for r in range(3):
        out[r] = p[r] + t * n[r]


@njit(cache=True)
def _onto_round(kind: int, c: np.ndarray, R: np.ndarray, size: np.ndarray, p: np.ndarray,
                n: np.ndarray, side: float, out: np.ndarray) -> bool:
    """
    Write the point of a capsule's or a cylinder's curved side seen from ``p`` along ``n``.

    ``side``: +1 when the shape lies beyond ``p`` along ``n`` (it is shape ``a``: its
    side facing −n, the nearer crossing), −1 when it lies behind (``b``: the farther
    one). A capsule's point past its axis' end is on that end's ball. Returns False,
    ``out`` untouched, when the line through ``p`` along ``n`` misses the side (a
    cylinder's: past its rim).
    """
    r, hl = size[0], size[1]
    u0, u1, u2 = R[0, 2], R[1, 2], R[2, 2]
    e0, e1, e2 = c[0], c[1], c[2]
    for end in range(2):   # the mantle (about the infinite axis), then an end's ball
        w0, w1, w2 = p[0] - e0, p[1] - e1, p[2] - e2
        m0, m1, m2 = n[0], n[1], n[2]
        if end == 0:   # across the axis
            wu = w0 * u0 + w1 * u1 + w2 * u2
            mu = m0 * u0 + m1 * u1 + m2 * u2
            w0, w1, w2 = w0 - wu * u0, w1 - wu * u1, w2 - wu * u2
            m0, m1, m2 = m0 - mu * u0, m1 - mu * u1, m2 - mu * u2
        # |w + t m| = r: a t² + 2 b t + cc = 0, its roots in the stable form.
        a = m0 * m0 + m1 * m1 + m2 * m2
        b = w0 * m0 + w1 * m1 + w2 * m2
        cc = w0 * w0 + w1 * w1 + w2 * w2 - r * r
        disc = b * b - a * cc
        if a <= 0.0 or disc < 0.0:
            return False
        q = -(b + math.copysign(math.sqrt(disc), b))
        if q == 0.0:
            return False
        t1, t2 = q / a, cc / q
        t = min(t1, t2) if side > 0.0 else max(t1, t2)
        x0, x1, x2 = p[0] + t * n[0], p[1] + t * n[1], p[2] + t * n[2]
        s = (x0 - c[0]) * u0 + (x1 - c[1]) * u1 + (x2 - c[2]) * u2
        if end == 1 or abs(s) <= hl:
            out[0], out[1], out[2] = x0, x1, x2
            return True
        if kind != CAPSULE:
            return False
        sg = 1.0 if s >= 0.0 else -1.0
        e0, e1, e2 = e0 + sg * hl * u0, e1 + sg * hl * u1, e2 + sg * hl * u2
    return False


@njit(cache=True)
def _lift(ft: int, pts: np.ndarray, normal: np.ndarray, xy: np.ndarray, x: float, y: float,
          o: np.ndarray, t1: np.ndarray, t2: np.ndarray, n: np.ndarray,
          out: np.ndarray) -> None:
    """Write the point of a feature seen at the plane point (x, y) along the normal ``n``."""
    for r in range(3):
        out[r] = o[r] + x * t1[r] + y * t2[r]
    if ft == F_SEGMENT:   # its point at (x, y)'s place along it
        ex, ey = xy[1, 0] - xy[0, 0], xy[1, 1] - xy[0, 1]
        ee = ex * ex + ey * ey
        s = ((x - xy[0, 0]) * ex + (y - xy[0, 1]) * ey) / ee if ee > 0.0 else 0.0
        s = min(max(s, 0.0), 1.0)
        for r in range(3):
            out[r] = pts[0, r] + s * (pts[1, r] - pts[0, r])
        return
    # A face or a disc: along n onto its own plane.
    mn = normal[0] * n[0] + normal[1] * n[1] + normal[2] * n[2]
    t = (normal[0] * (pts[0, 0] - out[0]) + normal[1] * (pts[0, 1] - out[1])
         + normal[2] * (pts[0, 2] - out[2])) / mn
    for r in range(3):
        out[r] += t * n[r]


@njit(cache=True)
def _over(ft: int, pts: np.ndarray, m: int, rad: float, nf: np.ndarray, p: np.ndarray,
          t: float, n: np.ndarray, tol: float) -> bool:
    """Tell whether ``p + t n`` (on a flat feature's plane) lies on the feature, within tol."""
    x0, x1, x2 = p[0] + t * n[0], p[1] + t * n[1], p[2] + t * n[2]
    if ft == F_DISC:
        return math.sqrt((x0 - pts[0, 0]) ** 2 + (x1 - pts[0, 1]) ** 2
                         + (x2 - pts[0, 2]) ** 2) <= rad + tol
    sign = 0.0   # (either order round the normal: every turn the same way)
    for q in range(m):
        a, b = pts[q], pts[(q + 1) % m]
        e0, e1, e2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
        f0, f1, f2 = x0 - a[0], x1 - a[1], x2 - a[2]
        turn = (nf[0] * (e1 * f2 - e2 * f1) + nf[1] * (e2 * f0 - e0 * f2)
                + nf[2] * (e0 * f1 - e1 * f0))
        le = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        if abs(turn) <= tol * le:
            continue
        s = 1.0 if turn > 0.0 else -1.0
        if sign == 0.0:
            sign = s
        elif s != sign:
            return False
    return True


@njit(cache=True)
def _one(xa: np.ndarray, xb: np.ndarray, n: np.ndarray, margin: float,
         cand: np.ndarray) -> int:
    """Write the one contact of a's point ``xa`` and b's ``xb`` (within the margin)."""
    gap = n[0] * (xa[0] - xb[0]) + n[1] * (xa[1] - xb[1]) + n[2] * (xa[2] - xb[2])
    if gap > margin:
        return 0
    for r in range(3):
        cand[0, r] = 0.5 * (xa[r] + xb[r])
    cand[0, 3] = gap
    return 1


@njit(cache=True)
def _closest_lines(pa: np.ndarray, ua: np.ndarray, pb: np.ndarray, ub: np.ndarray,
                   xa: np.ndarray, xb: np.ndarray) -> None:
    """Write the closest points of the segments ``pa[0] + s ua`` and ``pb[0] + t ub``."""
    r0, r1, r2 = pa[0, 0] - pb[0, 0], pa[0, 1] - pb[0, 1], pa[0, 2] - pb[0, 2]
    a = ua[0] * ua[0] + ua[1] * ua[1] + ua[2] * ua[2]
    e = ub[0] * ub[0] + ub[1] * ub[1] + ub[2] * ub[2]
    b = ua[0] * ub[0] + ua[1] * ub[1] + ua[2] * ub[2]
    c = ua[0] * r0 + ua[1] * r1 + ua[2] * r2
    f = ub[0] * r0 + ub[1] * r1 + ub[2] * r2
    den = a * e - b * b
    s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 0.0 else 0.0
    t = (b * s + f) / e if e > 0.0 else 0.0
    if t < 0.0 or t > 1.0:
        t = min(max(t, 0.0), 1.0)
        s = min(max((b * t - c) / a, 0.0), 1.0) if a > 0.0 else 0.0
    for r in range(3):
        xa[r] = pa[0, r] + s * ua[r]
        xb[r] = pb[0, r] + t * ub[r]


@njit(cache=True)
def _radial(c: np.ndarray, R: np.ndarray, fo: int, ko: int, po: np.ndarray, x: np.ndarray,
            margin: float, sign: float, n: np.ndarray) -> bool:
    """
    Put into ``n`` the radial direction from a cylinder's axis through the point ``x``.

    ``x``: the other feature's point (``po``), or the other cylinder's centre when the
    other feature is its mantle. Only for a corner, or a line along the axis (within
    ``margin`` over its length), and
    only where that direction lies within 1e-3 rad of ``n`` (EPA's); ``sign``: +1 when
    the cylinder is shape ``b`` (n points from it), −1 when it is ``a``. Returns
    whether it did.
    """
    if fo == F_SEGMENT:
        e0, e1, e2 = po[1, 0] - po[0, 0], po[1, 1] - po[0, 1], po[1, 2] - po[0, 2]
        le = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        ea = e0 * R[0, 2] + e1 * R[1, 2] + e2 * R[2, 2]
        if le == 0.0 or math.sqrt(max(le * le - ea * ea, 0.0)) > margin:
            return False
    elif fo != F_POINT or ko != BOX and ko != HULL:   # (a rim point is no corner: it curves)
        return False
    x0, x1, x2 = x[0] - c[0], x[1] - c[1], x[2] - c[2]
    t = x0 * R[0, 2] + x1 * R[1, 2] + x2 * R[2, 2]
    x0, x1, x2 = x0 - t * R[0, 2], x1 - t * R[1, 2], x2 - t * R[2, 2]
    rho = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    if rho == 0.0:
        return False
    x0, x1, x2 = sign * x0 / rho, sign * x1 / rho, sign * x2 / rho
    if x0 * n[0] + x1 * n[1] + x2 * n[2] < 1.0 - 5e-7:   # (1e-3 rad)
        return False
    n[0], n[1], n[2] = x0, x1, x2
    return True


@njit(cache=True)
def manifold(ka: int, ca: np.ndarray, Ra: np.ndarray, sa: np.ndarray, kb: int,
             cb: np.ndarray, Rb: np.ndarray, sb: np.ndarray, result: np.ndarray,
             margin: float, cand: np.ndarray) -> int:
    """
    Write the contacts of two flat features facing each other: rows (x, y, z, gap).

    ``result`` is :func:`penetration`'s. Returns how many rows of ``cand``
    (:data:`CANDIDATES`, 4) it wrote (each within ``margin``), or −1 when the features
    are not both flat (one contact: :func:`penetration`'s).
    """
    n = result[0:3]
    d = np.empty(3)
    for r in range(3):
        d[r] = -n[r]
    pa, pb = np.empty((CORNERS, 3)), np.empty((CORNERS, 3))
    na, nb = np.empty(3), np.empty(3)
    fa, ma, ra = feature(ka, ca, Ra, sa, d, margin, pa, na)
    fb, mb, rb = feature(kb, cb, Rb, sb, n, margin, pb, nb)
    # A cylinder's mantle line on a corner or on a line along its axis: the surface is
    # curved across, and EPA's normal only near the radial one through the other
    # feature, which is exact: take it (the features along it are the same).
    # (Another cylinder's mantle: the radial line through its axis.)
    xb = cb if kb == CYLINDER and fb == F_SEGMENT else pb[0]
    xa = ca if ka == CYLINDER and fa == F_SEGMENT else pa[0]
    if ka == CYLINDER and fa == F_SEGMENT \
            and _radial(ca, Ra, fb, kb, pb, xb, margin, -1.0, n) \
            or kb == CYLINDER and fb == F_SEGMENT \
            and _radial(cb, Rb, fa, ka, pa, xa, margin, 1.0, n):
        for r in range(3):
            d[r] = -n[r]
        fa, ma, ra = feature(ka, ca, Ra, sa, d, margin, pa, na)
        fb, mb, rb = feature(kb, cb, Rb, sb, n, margin, pb, nb)
        if fa == F_POINT or fb == F_POINT:   # a corner on the mantle: one contact
            x = pa[0] if fa == F_POINT else pb[0]
            cc, Rc, sc = (cb, Rb, sb) if fa == F_POINT else (ca, Ra, sa)
            t = ((x[0] - cc[0]) * Rc[0, 2] + (x[1] - cc[1]) * Rc[1, 2]
                 + (x[2] - cc[2]) * Rc[2, 2])
            rho = 0.0
            for r in range(3):
                rho += (x[r] - cc[r] - t * Rc[r, 2]) ** 2
            gap = math.sqrt(rho) - sc[0]   # the corner's height over the mantle
            if gap > margin:
                return 0
            s = -1.0 if fa == F_POINT else 1.0   # from the corner towards the axis: ∓n
            for r in range(3):
                cand[0, r] = x[r] + s * 0.5 * gap * n[r]
            cand[0, 3] = gap
            return 1
    # EPA's normal on a face or a cap is that face's normal but for rounding (its face's
    # vertices move with the shapes: last bits that change from step to step). Take
    # the flat feature's own where they agree within 1e-12 (not a tilted cap's: EPA's
    # then lies off it).
    for side in range(2):
        f_, nf_ = (fb, nb) if side == 0 else (fa, na)
        sg = 1.0 if side == 0 else -1.0
        if f_ == F_POLYGON or f_ == F_DISC:
            off = 0.0
            for r in range(3):
                off += (sg * nf_[r] - n[r]) ** 2
            if off <= 1e-24:
                for r in range(3):
                    n[r] = sg * nf_[r]
                    d[r] = -n[r]
                break
    if fa == F_POINT and fb == F_POINT:   # the two support points along n (on the surfaces)
        return _one(pa[0], pb[0], n, margin, cand)
    if fa == F_POINT or fb == F_POINT:
        # A point on a flat feature: the point itself, its gap along n to the other's
        # plane (a rim point's EPA witness lies on a chord of the rim, not on it).
        flat_a = fa == F_POLYGON or fa == F_DISC
        flat_b = fb == F_POLYGON or fb == F_DISC
        if not (flat_a or flat_b):   # a point on a line: the line's point seen along n
            xa_, xb_ = np.empty(3), np.empty(3)
            if fa == F_POINT:
                for r in range(3):
                    xa_[r] = pa[0, r]
                _onto(F_SEGMENT, pb, nb, xa_, n, xb_)
            else:
                for r in range(3):
                    xb_[r] = pb[0, r]
                _onto(F_SEGMENT, pa, na, xb_, n, xa_)
            return _one(xa_, xb_, n, margin, cand)
        x = np.empty(3)
        if flat_b:   # a's point over b's plane
            mn = nb[0] * n[0] + nb[1] * n[1] + nb[2] * n[2]
            t = (nb[0] * (pb[0, 0] - pa[0, 0]) + nb[1] * (pb[0, 1] - pa[0, 1])
                 + nb[2] * (pb[0, 2] - pa[0, 2])) / mn
            for r in range(3):
                x[r] = pa[0, r] + 0.5 * t * n[r]
            gap = -t
            over = _over(fb, pb, mb, rb, nb, pa[0], t, n, margin)
        else:   # b's point under a's plane
            mn = na[0] * n[0] + na[1] * n[1] + na[2] * n[2]
            t = (na[0] * (pa[0, 0] - pb[0, 0]) + na[1] * (pa[0, 1] - pb[0, 1])
                 + na[2] * (pa[0, 2] - pb[0, 2])) / mn
            for r in range(3):
                x[r] = pb[0, r] + 0.5 * t * n[r]
            gap = t
            over = _over(fa, pa, ma, ra, na, pb[0], t, n, margin)
        if not over:   # its foot off the feature: not this pair's point (GJK's or EPA's)
            return -1
        if gap > margin:
            return 0
        for r in range(3):
            cand[0, r] = x[r]
        cand[0, 3] = gap
        return 1
    scale = max(sa[0], sa[1], sa[2], sb[0], sb[1], sb[2])
    # A line curved across (a capsule's side, a cylinder's mantle) beside another line.
    round_a = fa == F_SEGMENT and fb == F_SEGMENT and (ka == CAPSULE or ka == CYLINDER)
    round_b = fa == F_SEGMENT and fb == F_SEGMENT and (kb == CAPSULE or kb == CYLINDER)
    sight = False
    if fa == F_SEGMENT and fb == F_SEGMENT:
        ua = np.empty(3)
        ub = np.empty(3)
        for r in range(3):
            ua[r] = pa[1, r] - pa[0, r]
            ub[r] = pb[1, r] - pb[0, r]
        c0 = ua[1] * ub[2] - ua[2] * ub[1]
        c1 = ua[2] * ub[0] - ua[0] * ub[2]
        c2 = ua[0] * ub[1] - ua[1] * ub[0]
        la = math.sqrt(ua[0] ** 2 + ua[1] ** 2 + ua[2] ** 2)
        lb = math.sqrt(ub[0] ** 2 + ub[1] ** 2 + ub[2] ** 2)
        # Their sights along n cross past rounding (over the shorter's length).
        sight = abs(c0 * n[0] + c1 * n[1] + c2 * n[2]) * min(la, lb) > 1e-12 * scale * la * lb
        if math.sqrt(c0 * c0 + c1 * c1 + c2 * c2) * min(la, lb) > margin * la * lb \
                or sight and not (round_a or round_b):
            # Crossed lines (their ends' heights differ past the margin): one point, where
            # they pass closest. So too two sharp lines (edges) whose sight along n
            # crosses past rounding: their ends meet along n nowhere on the surfaces.
            xa_, xb_ = np.empty(3), np.empty(3)
            _closest_lines(pa, ua, pb, ub, xa_, xb_)
            return _one(xa_, xb_, n, margin, cand)
    # The plane across n through EPA's point.
    o = np.empty(3)
    for r in range(3):
        o[r] = 0.5 * (result[4 + r] + result[7 + r])
    t1, t2 = np.empty(3), np.empty(3)
    if abs(n[0]) <= abs(n[1]) and abs(n[0]) <= abs(n[2]):
        t1[0], t1[1], t1[2] = 0.0, n[2], -n[1]
    elif abs(n[1]) <= abs(n[2]):
        t1[0], t1[1], t1[2] = -n[2], 0.0, n[0]
    else:
        t1[0], t1[1], t1[2] = n[1], -n[0], 0.0
    tn = math.sqrt(t1[0] ** 2 + t1[1] ** 2 + t1[2] ** 2)
    for r in range(3):
        t1[r] /= tn
    t2[0] = n[1] * t1[2] - n[2] * t1[1]
    t2[1] = n[2] * t1[0] - n[0] * t1[2]
    t2[2] = n[0] * t1[1] - n[1] * t1[0]
    xa, xb = np.empty((CORNERS + 1, 2)), np.empty((CORNERS + 1, 2))
    ma = _region(fa, ma, pa, ra, o, t1, t2, xa)
    mb = _region(fb, mb, pb, rb, o, t1, t2, xb)
    tol = 1e-12 * scale
    xy = np.empty((CANDIDATES, 2))
    src = np.zeros(CANDIDATES, dtype=np.int64)   # +k: a's corner k − 1; −k: b's; 0: a crossing
    nc = 0
    if fa == F_SEGMENT and fb == F_SEGMENT:
        # Parallel lines: the ends of their overlap along a's.
        ex, ey = xa[1, 0] - xa[0, 0], xa[1, 1] - xa[0, 1]
        ee = ex * ex + ey * ey
        if ee <= 0.0:
            return -1
        s0 = ((xb[0, 0] - xa[0, 0]) * ex + (xb[0, 1] - xa[0, 1]) * ey) / ee
        s1 = ((xb[1, 0] - xa[0, 0]) * ex + (xb[1, 1] - xa[0, 1]) * ey) / ee
        lo, hi = max(min(s0, s1), 0.0), min(max(s0, s1), 1.0)
        if hi < lo:
            return 0
        for s in (lo, hi):
            nc = _add(xy, nc, xa[0, 0] + s * ex, xa[0, 1] + s * ey)
        if sight:   # where their sights cross, the lines meet along n: the deepest
            nc = _crossings(fa, xa, ma, ra, fb, xb, mb, rb, xy, nc)
    else:
        for q in range(ma):   # a's corners in b's region (a segment's ends included)
            if _inside(fb, xb, mb, rb, xa[q, 0], xa[q, 1], tol):
                if nc < xy.shape[0]:
                    src[nc] = q + 1
                nc = _add(xy, nc, xa[q, 0], xa[q, 1])
        for q in range(mb):
            if _inside(fa, xa, ma, ra, xb[q, 0], xb[q, 1], tol):
                if nc < xy.shape[0]:
                    src[nc] = -(q + 1)
                nc = _add(xy, nc, xb[q, 0], xb[q, 1])
        nc = _crossings(fa, xa, ma, ra, fb, xb, mb, rb, xy, nc)
    xa3, xb3 = np.empty(3), np.empty(3)
    kept = 0
    for q in range(nc):
        # A corner is its own point and the other's seen from it along n (one rounding
        # of a plane's distance); where outlines cross, both from the plane point.
        if src[q] > 0:
            _corner(fa, pa, ra, src[q] - 1, xa3)
            _onto(fb, pb, nb, xa3, n, xb3)
        elif src[q] < 0:
            _corner(fb, pb, rb, -src[q] - 1, xb3)
            _onto(fa, pa, na, xb3, n, xa3)
        else:
            _lift(fa, pa, na, xa, xy[q, 0], xy[q, 1], o, t1, t2, n, xa3)
            _lift(fb, pb, nb, xb, xy[q, 0], xy[q, 1], o, t1, t2, n, xb3)
            # Two lines side by side meet along n only where their sights cross: at an
            # end of their overlap the curved shape's own surface, seen along n from the
            # other line's point, is the point (its line is only where it touches). (Where
            # that misses it, past a cylinder's rim, the line's point.)
            if round_a:
                _onto_round(ka, ca, Ra, sa, xb3, n, 1.0, xa3)
            elif round_b:
                _onto_round(kb, cb, Rb, sb, xa3, n, -1.0, xb3)
        gap = n[0] * (xa3[0] - xb3[0]) + n[1] * (xa3[1] - xb3[1]) + n[2] * (xa3[2] - xb3[2])
        if gap > margin:
            continue
        # Drop a repeat (a corner on an outline found twice).
        dup = False
        for j in range(kept):
            if (abs(cand[j, 0] - 0.5 * (xa3[0] + xb3[0]))
                    + abs(cand[j, 1] - 0.5 * (xa3[1] + xb3[1]))
                    + abs(cand[j, 2] - 0.5 * (xa3[2] + xb3[2]))) <= tol:
                dup = True
                break
        if dup:
            continue
        for r in range(3):
            cand[kept, r] = 0.5 * (xa3[r] + xb3[r])
        cand[kept, 3] = gap
        kept += 1
    return kept if kept > 0 else -1   # (no overlap seen: EPA's point)
