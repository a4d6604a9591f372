"""
Collision detection (issue 21, first part): narrow phases and the broad phase.

References: closed forms (a shape at a known height over a plane, two spheres),
brute force (the segments' closest points by minimizing over a fine grid and
then by scipy, the box's nearest point by bounded minimization, every pair of
boxes tested), and the symmetries every contact must have (the pair swapped gives
the same points and the opposite normals). Tolerances: the arithmetic is a few
dozen operations on numbers of order 1, so rounding stays below 1e-14; 1e-12 is
the bound with room for another CPU's last bits.
"""

import numpy as np
import pytest
from rigid_body_sim.core.kernels.contact import (bounds, BOX, broad_phase, CAPSULE, collide,
                                                 CYLINDER, MANIFOLD, PLANE, segment_closest,
                                                 SPHERE, supported)
from rigid_body_sim.core.rotation import exp_quat, quat_to_matrix
from scipy.optimize import minimize, minimize_scalar

TOL = 1e-12


def rotation(rotvec):
    """Rotation matrix of a rotation vector (rad)."""
    return quat_to_matrix(exp_quat(np.asarray(rotvec, dtype=float)))


def contacts(kind_a, ca, Ra, sa, kind_b, cb, Rb, sb, margin=0.0, cap=8):
    """Run the narrow phase; return (points, normals, depths) of the contacts found."""
    points, normals, depths = np.zeros((cap, 3)), np.zeros((cap, 3)), np.zeros(cap)
    k = collide(kind_a, np.asarray(ca, float), np.asarray(Ra, float), np.asarray(sa, float),
                kind_b, np.asarray(cb, float), np.asarray(Rb, float), np.asarray(sb, float),
                margin, points, normals, depths, 0)
    assert 0 <= k <= cap
    return points[:k], normals[:k], depths[:k]


def ground(rotvec=(0.0, 0.0, 0.0), height=0.0):
    """Return a plane through (0, 0, height) rotated by rotvec: (kind, centre, R, size)."""
    R = rotation(rotvec)
    return PLANE, R @ np.array([0.0, 0.0, height]), R, np.zeros(3)


def on_ground(shape, R_plane):
    """Return the shape, its frame given in the plane's frame, in the world."""
    kind, c, R, size = shape
    return kind, R_plane @ c, R_plane @ R, size


def check_swapped(a, b, margin=0.0):
    """Both orders give the same points and depths and opposite normals; return a's order."""
    p, n, d = contacts(*a, *b, margin)
    q, m, e = contacts(*b, *a, margin)
    assert len(q) == len(p)
    # The same points, maybe in another order (a box's faces are clipped the other way).
    order = [int(np.argmin(np.linalg.norm(q - x, axis=1))) for x in p]
    q, m, e = q[order], m[order], e[order]
    np.testing.assert_allclose(q, p, atol=TOL)
    np.testing.assert_allclose(m, -n, atol=TOL)
    np.testing.assert_allclose(e, d, atol=TOL)
    return p, n, d


# -- on a plane -------------------------------------------------------------------------------

PLANES = [(0.0, 0.0, 0.0), (0.3, -0.2, 0.1), (np.pi / 2, 0.0, 0.0), (2.0, 1.0, -0.5)]


@pytest.mark.parametrize('plane', PLANES)
@pytest.mark.parametrize('height', [0.45, 0.5, 0.53])
def test_a_sphere_over_a_plane_touches_at_its_lowest_point_to_its_depth(plane, height):
    R = rotation(plane)
    sphere = on_ground((SPHERE, np.array([0.2, -0.1, height]), rotation((1, 2, 3)),
                        np.array([0.5, 0, 0])), R)
    p, n, d = check_swapped(sphere, ground(plane), margin=0.05)
    normal = R[:, 2]
    np.testing.assert_allclose(n, [normal], atol=TOL)
    np.testing.assert_allclose(d, [0.5 - height], atol=TOL)
    # Midway between the sphere's lowest point and the plane (height (h − r)/2 over it).
    np.testing.assert_allclose(p, [R @ [0.2, -0.1, (height - 0.5) / 2]], atol=TOL)
    # Beyond the margin, nothing.
    far = on_ground((SPHERE, np.array([0.0, 0.0, 0.5 + 0.05 + 1e-9]), np.eye(3),
                     np.array([0.5, 0, 0])), R)
    assert len(contacts(*far, *ground(plane), 0.05)[2]) == 0


@pytest.mark.parametrize('plane', PLANES)
def test_a_box_flat_on_a_plane_rests_on_its_four_corners(plane):
    R = rotation(plane)
    h = np.array([0.3, 0.2, 0.1])
    yaw = rotation((0.0, 0.0, 0.7))
    box = on_ground((BOX, np.array([1.0, 2.0, 0.1 - 1e-3]), yaw, h), R)
    p, n, d = check_swapped(box, ground(plane))
    assert len(d) == MANIFOLD
    np.testing.assert_allclose(d, 1e-3, atol=TOL)
    np.testing.assert_allclose(n, np.tile(R[:, 2], (4, 1)), atol=TOL)
    corners = [R @ (np.array([1.0, 2.0, -5e-4]) + yaw @ [sx * 0.3, sy * 0.2, 0.0])
               for sx in (-1, 1) for sy in (-1, 1)]
    assert sorted(map(tuple, np.round(p, 10))) == sorted(map(tuple, np.round(corners, 10)))


@pytest.mark.parametrize('attitude, expected', [((np.pi / 4, 0.0, 0.0), 2),
                                                ((np.pi / 4, np.arctan(1 / np.sqrt(2)), 0.0),
                                                 1)])
def test_a_box_on_an_edge_touches_twice_and_on_a_corner_once(attitude, expected):
    h = np.array([0.1, 0.1, 0.1])
    R = rotation((0.0, attitude[1], 0.0)) @ rotation((attitude[0], 0.0, 0.0))
    lowest = min((R @ (h * [sx, sy, sz]))[2] for sx in (-1, 1) for sy in (-1, 1)
                 for sz in (-1, 1))
    box = (BOX, np.array([0.0, 0.0, -lowest - 1e-4]), R, h)
    p, n, d = check_swapped(box, ground())
    assert len(d) == expected
    np.testing.assert_allclose(d, 1e-4, atol=TOL)


def test_a_deep_box_keeps_its_four_deepest_corners():
    box = (BOX, np.array([0.0, 0.0, 0.0]), rotation((0.1, 0.05, 0.0)), np.array([0.1, 0.2, 0.3]))
    p, n, d = contacts(*box, *ground(), 0.0)
    corners = [(box[2] @ (box[3] * [sx, sy, sz]))[2] for sx in (-1, 1) for sy in (-1, 1)
               for sz in (-1, 1)]
    np.testing.assert_allclose(np.sort(d)[::-1], -np.sort(corners)[:MANIFOLD], atol=TOL)


@pytest.mark.parametrize('kind', [CAPSULE, CYLINDER])
def test_a_capsule_or_cylinder_lying_touches_at_both_ends(kind):
    r, hl = 0.05, 0.2
    lying = rotation((np.pi / 2, 0.0, 0.0))   # axis along world −y
    shape = (kind, np.array([0.3, 0.0, r - 2e-4]), lying, np.array([r, hl, 0.0]))
    p, n, d = check_swapped(shape, ground())
    assert len(d) == 2
    np.testing.assert_allclose(d, 2e-4, atol=TOL)
    np.testing.assert_allclose(np.sort(p[:, 1]), [-hl, hl], atol=TOL)
    np.testing.assert_allclose(p[:, 2], -1e-4, atol=TOL)


def test_a_standing_cylinder_rests_on_four_rim_points_and_a_capsule_on_one():
    r, hl = 0.05, 0.2
    cyl = (CYLINDER, np.array([0.0, 0.0, hl - 3e-4]), rotation((0.0, 0.0, 0.4)),
           np.array([r, hl, 0.0]))
    p, n, d = check_swapped(cyl, ground())
    assert len(d) == 4
    np.testing.assert_allclose(np.hypot(p[:, 0], p[:, 1]), r, atol=TOL)
    np.testing.assert_allclose(d, 3e-4, atol=TOL)
    cap = (CAPSULE, np.array([0.0, 0.0, hl + r - 3e-4]), np.eye(3), np.array([r, hl, 0.0]))
    p, n, d = check_swapped(cap, ground())
    np.testing.assert_allclose(p, [[0.0, 0.0, -1.5e-4]], atol=TOL)
    np.testing.assert_allclose(d, [3e-4], atol=TOL)


def test_a_tilted_cylinder_touches_at_its_lowest_rim_point():
    r, hl, tilt = 0.05, 0.2, 0.3
    R = rotation((tilt, 0.0, 0.0))
    # The lowest rim point of the lower cap: centre − hl a + r u, u across the axis downwards.
    a = R[:, 2]
    u = -(np.array([0, 0, 1.0]) - a[2] * a)
    u /= np.linalg.norm(u)
    low = -hl * a + r * u
    cyl = (CYLINDER, np.array([0.0, 0.0, -low[2] - 1e-4]), R, np.array([r, hl, 0.0]))
    p, n, d = check_swapped(cyl, ground())
    assert len(d) == 1
    np.testing.assert_allclose(d, [1e-4], atol=TOL)
    np.testing.assert_allclose(p[0, :2], low[:2], atol=TOL)


# -- round shapes on each other ---------------------------------------------------------------


def test_two_spheres_touch_on_their_line_of_centres():
    a = (SPHERE, np.array([0.1, 0.2, 0.3]), np.eye(3), np.array([0.2, 0, 0]))
    direction = np.array([2.0, -1.0, 2.0]) / 3.0
    b = (SPHERE, a[1] - 0.49 * direction, rotation((1, 0, 0)), np.array([0.3, 0, 0]))
    p, n, d = check_swapped(a, b)
    np.testing.assert_allclose(n, [direction], atol=TOL)
    np.testing.assert_allclose(d, [0.01], atol=TOL)
    # Midway between b's surface point (0.3 from b) and a's (0.2 from a).
    np.testing.assert_allclose(p, [b[1] + (0.3 - 0.005) * direction], atol=TOL)


def test_concentric_spheres_still_have_a_normal():
    a = (SPHERE, np.zeros(3), np.eye(3), np.array([0.2, 0, 0]))
    p, n, d = contacts(*a, *a)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=TOL)
    np.testing.assert_allclose(d, [0.4], atol=TOL)


def brute_segments(p, u, q, v):
    """Closest parameters of two segments: a 201² grid, then bounded minimization from its best."""
    s = np.linspace(0.0, 1.0, 201)
    P = p + s[:, None] * u
    Q = q + s[:, None] * v
    D = np.linalg.norm(P[:, None, :] - Q[None, :, :], axis=2)
    i, j = np.unravel_index(np.argmin(D), D.shape)
    res = minimize(lambda x: np.sum((p + x[0] * u - q - x[1] * v) ** 2), [s[i], s[j]],
                   bounds=[(0, 1), (0, 1)], method='L-BFGS-B',
                   options={'ftol': 1e-15, 'gtol': 1e-12})
    return np.sqrt(res.fun)


def test_segments_closest_points_match_brute_force():
    rng = np.random.default_rng(3)
    for trial in range(200):
        p, u, q, v = rng.normal(size=(4, 3))
        if trial % 4 == 1:
            v = u * rng.uniform(-2, 2)           # parallel
        elif trial % 4 == 2:
            v = np.zeros(3)                      # a point
        elif trial % 4 == 3:
            q = p + u * 0.5 + np.cross(u, rng.normal(size=3)) * 0.1   # crossing near
        s, t = segment_closest(p, u, q, v)
        assert 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0
        dist = np.linalg.norm(p + s * u - q - t * v)
        # bound: the minimizer's distance is at best the true minimum; ours within
        # rounding of it (the grid start and L-BFGS-B's tolerances put it within 1e-7).
        assert dist <= brute_segments(p, u, q, v) + 1e-7


def test_crossing_capsules_touch_once_and_parallel_ones_along_their_overlap():
    r = 0.1
    a = (CAPSULE, np.zeros(3), np.eye(3), np.array([r, 0.5, 0.0]))             # along z
    b = (CAPSULE, np.array([0.19, 0.0, 0.1]), rotation((np.pi / 2, 0, 0)),
         np.array([r, 0.5, 0.0]))                                             # along y
    p, n, d = check_swapped(b, a)
    np.testing.assert_allclose(d, [0.01], atol=TOL)
    np.testing.assert_allclose(n, [[1.0, 0.0, 0.0]], atol=TOL)
    np.testing.assert_allclose(p, [[0.095, 0.0, 0.1]], atol=TOL)
    c = (CAPSULE, np.array([0.19, 0.0, 0.7]), np.eye(3), np.array([r, 0.5, 0.0]))  # side by side
    p, n, d = check_swapped(c, a)
    assert len(d) == 2
    np.testing.assert_allclose(np.sort(p[:, 2]), [0.2, 0.5], atol=TOL)
    np.testing.assert_allclose(d, 0.01, atol=TOL)


def test_a_sphere_on_a_capsule_meets_its_axis_nearest_point():
    a = (CAPSULE, np.zeros(3), rotation((0.3, 0.2, 0.0)), np.array([0.1, 0.5, 0.0]))
    axis = a[2][:, 2]
    side = np.cross(axis, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    b = (SPHERE, 0.2 * axis + 0.25 * side, np.eye(3), np.array([0.16, 0, 0]))
    p, n, d = check_swapped(b, a)
    np.testing.assert_allclose(n, [side], atol=TOL)
    np.testing.assert_allclose(d, [0.01], atol=TOL)


# -- solids: boxes and cylinders ---------------------------------------------------------------


def sdf(kind, c, R, size, x):
    """Signed distance of x to a box or cylinder by minimization (outside) or faces (inside)."""
    xl = R.T @ (x - c)
    if kind == BOX:
        lo, hi = -size, size
        inside = np.all(np.abs(xl) <= size)
        if inside:
            return -np.min(size - np.abs(xl))
        res = minimize(lambda y: np.sum((y - xl) ** 2), np.clip(xl, lo, hi),
                       bounds=list(zip(lo, hi)), method='L-BFGS-B',
                       options={'ftol': 1e-16, 'gtol': 1e-12})
        return np.sqrt(res.fun)
    r, hl = size[0], size[1]
    rho = np.hypot(xl[0], xl[1])
    if rho <= r and abs(xl[2]) <= hl:
        return -min(r - rho, hl - abs(xl[2]))
    # Outside: the nearest point in (radial, axial) coordinates, by bounded minimization.
    res = minimize(lambda y: (y[0] - rho) ** 2 + (y[1] - xl[2]) ** 2,
                   [min(rho, r), np.clip(xl[2], -hl, hl)], bounds=[(0, r), (-hl, hl)],
                   method='L-BFGS-B', options={'ftol': 1e-16, 'gtol': 1e-12})
    return np.sqrt(res.fun)


@pytest.mark.parametrize('kind', [BOX, CYLINDER])
def test_a_sphere_on_a_solid_matches_its_distance_by_minimization(kind):
    rng = np.random.default_rng(5 + kind)
    size = np.array([0.3, 0.2, 0.1])
    R = rotation((0.4, -0.3, 1.1))
    c = np.array([0.5, -0.2, 0.1])
    solid = (kind, c, R, size)
    found = 0
    for _ in range(60):
        centre = c + R @ rng.uniform(-0.6, 0.6, size=3)
        r = 0.25
        sphere = (SPHERE, centre, np.eye(3), np.array([r, 0, 0]))
        p, n, d = check_swapped(sphere, solid, margin=0.1)
        dist = sdf(kind, c, R, size, centre)
        if dist - r > 0.1:
            assert len(d) == 0
            continue
        found += 1
        # bound: L-BFGS-B's distance to 1e-7 (its tolerances on a smooth quadratic);
        # inside, the faces' distances are exact.
        np.testing.assert_allclose(d, [r - dist], atol=1e-7)
        # Moving the sphere by its depth along the normal leaves it just touching.
        moved = (SPHERE, centre + d[0] * n[0], np.eye(3), np.array([r, 0, 0]))
        np.testing.assert_allclose(contacts(*moved, *solid, 1.0)[2], [0.0], atol=TOL)
    assert found > 10


def capsule(centre, R, r=0.05, hl=0.3):
    """Return a capsule: (kind, centre, R, size)."""
    return CAPSULE, np.asarray(centre, float), R, np.array([r, hl, 0.0])


def test_a_capsule_lying_on_a_box_touches_at_both_ends():
    box = (BOX, np.zeros(3), np.eye(3), np.array([1.0, 1.0, 0.1]))
    lying = rotation((0.0, np.pi / 2, 0.0)) @ rotation((0.0, 0.0, 0.3))   # axis along x
    p, n, d = check_swapped(capsule((0.1, 0.2, 0.1 + 0.05 - 1e-4), lying), box)
    assert len(d) == 2
    np.testing.assert_allclose(d, 1e-4, atol=TOL)
    np.testing.assert_allclose(n, [[0, 0, 1.0]] * 2, atol=TOL)
    np.testing.assert_allclose(np.sort(p[:, 0]), [0.1 - 0.3, 0.1 + 0.3], atol=TOL)


@pytest.mark.parametrize('kind', [BOX, CYLINDER])
@pytest.mark.parametrize('tilt', [0.0, np.pi / 3])
def test_a_capsule_standing_or_tilted_on_its_end_touches_once(kind, tilt):
    # Its deepest point is its lower end: one contact (the end ball), not that and the
    # end of its deepest stretch again.
    solid = (kind, np.zeros(3), np.eye(3), np.array([1.0, 1.0, 0.1]) if kind == BOX
             else np.array([1.0, 0.1, 0.0]))
    R = rotation((tilt, 0.0, 0.0))
    low = -0.3 * R[:, 2]                       # the lower end of the axis, from the centre
    cap = capsule(np.array([0.0, 0.0, 0.1 + 0.05 - 1e-4]) - low, R)
    p, n, d = check_swapped(cap, solid)
    assert len(d) == 1
    np.testing.assert_allclose(d, [1e-4], atol=TOL)


@pytest.mark.parametrize('hl', [0.01, 0.05, 0.3])
def test_a_short_capsule_across_an_edge_or_a_lying_cylinder_touches_once(hl):
    # A strict minimum of the distance along the axis: one contact, however short the
    # capsule (the tolerance's width is a length, not a fraction of the axis).
    out = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)
    box = (BOX, np.zeros(3), np.eye(3), np.array([1.0, 1.0, 0.1]))
    cap = capsule(np.array([1.0, 0.3, 0.1]) + (0.05 - 2e-4) * out,
                  rotation((0, -np.pi / 4, 0)), hl=hl)
    assert len(check_swapped(cap, box)[2]) == 1
    # Across a lying cylinder of radius 0.5 m, 1e-6 m deep: its ends stay clear (they
    # are higher by hl²/(2 (0.5 + r)), 9e-5 m at the shortest).
    lying = (CYLINDER, np.zeros(3), rotation((np.pi / 2, 0.0, 0.0)), np.array([0.5, 1.0, 0.0]))
    across = capsule((0.0, 0.0, 0.55 - 1e-6), rotation((0.0, np.pi / 2, 0.0)), hl=hl)
    p, n, d = check_swapped(across, lying)
    assert len(d) == 1
    np.testing.assert_allclose(d, [1e-6], atol=1e-11)


def test_a_capsule_over_a_boxs_edge_touches_at_its_end_and_over_the_edge():
    box = (BOX, np.zeros(3), np.eye(3), np.array([1.0, 1.0, 0.1]))
    lying = rotation((0.0, np.pi / 2, 0.0))   # axis along x, from x = 0.9 to 1.5
    p, n, d = check_swapped(capsule((1.2, 0.0, 0.15 - 1e-4), lying), box)
    assert len(d) == 2
    np.testing.assert_allclose(np.sort(p[:, 0]), [0.9, 1.0], atol=1e-9)
    np.testing.assert_allclose(d, 1e-4, atol=1e-9)


def test_a_capsule_across_a_boxs_edge_touches_once_at_the_edge():
    box = (BOX, np.zeros(3), np.eye(3), np.array([1.0, 1.0, 0.1]))
    # Axis in the x-z plane at 45°, its middle just over the edge (x = 1, z = 0.1).
    out = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)
    centre = np.array([1.0, 0.3, 0.1]) + (0.05 - 2e-4) * out
    p, n, d = check_swapped(capsule(centre, rotation((0, -np.pi / 4, 0))), box)
    assert len(d) == 1
    # bound: over the edge the distance is smooth, δ + t²/(2δ) along the axis (δ = 0.05
    # m): the search's 1e-12 m on it leaves t within sqrt(2 δ 1e-12) = 3e-7 m of the
    # edge, the depth within 1e-12 m and the normal within t/δ = 6e-6 (the middle of
    # the interval, here symmetric, does better).
    np.testing.assert_allclose(d, [2e-4], atol=1e-11)
    np.testing.assert_allclose(n, [out], atol=6e-6)
    np.testing.assert_allclose(p, [[1.0, 0.3, 0.1] - 1e-4 * out], atol=3e-7)


@pytest.mark.parametrize('kind', [BOX, CYLINDER])
def test_a_capsules_depth_on_a_solid_matches_the_deepest_point_of_its_axis(kind):
    rng = np.random.default_rng(11 + kind)
    size = np.array([0.3, 0.2, 0.15])
    solid = (kind, np.array([0.1, 0.0, -0.2]), rotation((0.2, 0.5, -0.4)), size)
    found = 0
    for _ in range(40):
        cap = capsule(solid[1] + rng.uniform(-0.5, 0.5, size=3), rotation(rng.normal(size=3)),
                      r=0.08, hl=0.25)
        axis = cap[2][:, 2]
        p, n, d = check_swapped(cap, solid, margin=0.05)
        # The axis's deepest point: a 5 mm grid, then a bounded scalar search around its
        # best (the distance is convex along the axis, so the bracket holds the minimum).
        s = np.linspace(-0.25, 0.25, 101)
        grid = [sdf(kind, *solid[1:], cap[1] + t * axis) for t in s]
        j = int(np.argmin(grid))
        res = minimize_scalar(lambda t: sdf(kind, *solid[1:], cap[1] + t * axis),
                              bounds=(s[max(j - 1, 0)], s[min(j + 1, 100)]), method='bounded',
                              options={'xatol': 1e-10})
        deepest = min(res.fun, grid[j])
        if deepest - 0.08 > 0.05:
            assert len(d) == 0
            continue
        found += 1
        # bound: the reference's distances by L-BFGS-B to 1e-7; ours to 1e-12.
        assert abs(np.max(d) - (0.08 - deepest)) <= 1e-6
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=TOL)
        # No contact twice: the points of a manifold lie apart.
        gaps = [np.linalg.norm(p[i] - p[j]) for i in range(len(p)) for j in range(i)]
        assert min(gaps, default=1.0) > 1e-4
    assert found > 5


# -- box on box --------------------------------------------------------------------------------


def box(centre, R=np.eye(3), h=(0.1, 0.1, 0.1)):
    """Return a box: (kind, centre, R, half extents)."""
    return BOX, np.asarray(centre, float), R, np.asarray(h, float)


def test_a_box_resting_on_a_box_touches_at_its_four_corners():
    base = box((0.0, 0.0, 0.0), h=(0.5, 0.5, 0.1))
    yaw = rotation((0.0, 0.0, np.pi / 4))
    top = box((0.05, -0.02, 0.2 - 1e-4), yaw)
    p, n, d = check_swapped(top, base)
    assert len(d) == 4
    np.testing.assert_allclose(d, 1e-4, atol=TOL)
    np.testing.assert_allclose(n, [[0, 0, 1.0]] * 4, atol=TOL)
    corners = [np.array([0.05, -0.02, 0.1 - 5e-5]) + yaw @ [sx * 0.1, sy * 0.1, 0]
               for sx in (-1, 1) for sy in (-1, 1)]
    assert sorted(map(tuple, np.round(p, 10))) == sorted(map(tuple, np.round(corners, 10)))


def test_a_big_box_on_a_small_one_keeps_four_points_of_the_clipped_octagon():
    base = box((0.0, 0.0, 0.0), h=(0.1, 0.1, 0.1))
    top = box((0.0, 0.0, 0.2 - 1e-4), rotation((0.0, 0.0, np.pi / 4)), h=(0.12, 0.12, 0.1))
    # The octagon where the two faces overlap: its corners.
    t = 0.12 * np.sqrt(2.0) - 0.1   # where the top's rotated edges cut the base's edges
    octagon = [(sx * 0.1, sy * t) for sx in (-1, 1) for sy in (-1, 1)] \
        + [(sx * t, sy * 0.1) for sx in (-1, 1) for sy in (-1, 1)]
    for a, b, sign in ((top, base, 1.0), (base, top, -1.0)):
        # (Four of eight points at one depth: which four depends on the order; each
        # order's four are corners of the octagon, spanning it.)
        p, n, d = contacts(*a, *b)
        assert len(d) == MANIFOLD
        np.testing.assert_allclose(d, 1e-4, atol=TOL)
        np.testing.assert_allclose(n, [[0, 0, sign]] * 4, atol=TOL)
        for x in p:
            assert min(np.hypot(x[0] - u, x[1] - v) for u, v in octagon) <= TOL
        assert np.ptp(p[:, 0]) > 0.13 and np.ptp(p[:, 1]) > 0.13


def test_a_box_on_a_box_turned_and_tilted_a_little_rests_on_four_points():
    # Each turned about the vertical at random and the top one tilted by up to 1e-4 rad,
    # its lowest corner 1e-5 m into the lower one's top face: faces resting on faces. An
    # edge pair's axis (within the tilt of vertical) can overlap less than the face by
    # the tilt times the size; it is not taken (FACE_EDGE): four points, not one,
    # spanning the faces, along one box's face normal (within the tilt of vertical). Moved
    # along it by the deepest point's depth, the top box is clear of the lower one.
    rng = np.random.default_rng(7)
    for _ in range(100):
        yaw = rotation((0.0, 0.0, rng.uniform(0, 2 * np.pi)))
        R = rotation(rng.normal(size=3) * 1e-4 / np.sqrt(3)) @ yaw
        corners = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1)
                            for z in (-0.1, 0.1)]) @ R.T
        lower = box((0.0, 0.0, 0.0), rotation((0.0, 0.0, rng.uniform(0, 2 * np.pi))))
        top = box((0.0, 0.0, 0.1 - 1e-5 - corners[:, 2].min()), R)
        p, n, d = check_swapped(top, lower, margin=1e-3)
        assert len(d) == MANIFOLD
        np.testing.assert_allclose(n, np.tile(n[0], (4, 1)), atol=TOL)
        assert max(abs(n[0] @ R[:, 2]), abs(n[0] @ lower[2][:, 2])) >= 1.0 - TOL
        assert n[0][2] >= np.cos(1.5e-4)
        assert 0.0 < d.max() <= 1e-5 + TOL
        assert np.ptp(p[:, 0]) > 0.1 and np.ptp(p[:, 1]) > 0.1
        moved = (BOX, top[1] + (d.max() + 1e-9) * n[0], top[2], top[3])
        assert len(contacts(*moved, *lower)[2]) == 0


def _least_overlap(a, b):
    """Return the separating axis test's least overlap of two boxes and its axis."""
    (_, ca, Ra, ha), (_, cb, Rb, hb) = a, b
    axes = [Ra[:, i] for i in range(3)] + [Rb[:, i] for i in range(3)]
    axes += [np.cross(Ra[:, i], Rb[:, j]) for i in range(3) for j in range(3)]
    best = (np.inf, None)
    for L in axes:
        if np.linalg.norm(L) > 1e-6:
            L = L / np.linalg.norm(L)
            overlap = np.abs(Ra.T @ L) @ ha + np.abs(Rb.T @ L) @ hb - abs((ca - cb) @ L)
            best = min(best, (overlap, L), key=lambda x: x[0])
    return best


def test_a_tilted_box_overhanging_another_reports_the_least_overlap():
    # Tilted by up to 1 mrad and turned, the top box overhangs the lower one's edge or
    # corner, up to 2e-4 m deep. Where the least-overlap edge pair lies within FACE_EDGE
    # of a face normal no edge pair is taken (the next one's could overlap twice as
    # much): the deepest point is the least overlap over the 15 axes, to second order in
    # the angle θ between the normal given and that axis (ov θ², twice the cosine's
    # ov θ²/2), and moved along the normal by it the boxes are clear.
    rng = np.random.default_rng(1)
    seen = 0
    for _ in range(400):
        hl, ht = rng.uniform(0.05, 0.2, 3), rng.uniform(0.05, 0.2, 3)
        Rl = rotation((0.0, 0.0, rng.uniform(0, 2 * np.pi)))
        axis = rng.normal(size=3)
        axis[2] = 0.0
        Rt = rotation(axis / np.linalg.norm(axis) * rng.uniform(0, 1e-3)) @ rotation(
            (0.0, 0.0, rng.uniform(0, 2 * np.pi)))
        xy = Rl[:2, :2] @ (hl[:2] * rng.uniform(0.5, 1.5, 2) * rng.choice([-1, 1], 2))
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1)
                            for z in (-1, 1)]) * ht @ Rt.T
        lower = (BOX, np.zeros(3), Rl, hl)
        top = (BOX, np.array([xy[0], xy[1], hl[2] - corners[:, 2].min()
                              - rng.uniform(0, 2e-4)]), Rt, ht)
        overlap, L = _least_overlap(top, lower)
        if overlap <= 1e-9:
            continue
        seen += 1
        p, n, d = contacts(*top, *lower)
        theta = np.arccos(min(1.0, abs(n[0] @ L)))
        assert abs(d.max() - overlap) <= overlap * theta ** 2 + 1e-12
        moved = (BOX, top[1] + (d.max() + 1e-9) * n[0], top[2], top[3])
        assert len(contacts(*moved, *lower)[2]) == 0
    assert seen > 250


def test_crossed_edges_touch_once():
    low = box((0.0, 0.0, 0.0), rotation((np.pi / 4, 0.0, 0.0)))   # an edge along x on top
    high = box((0.0, 0.0, 2 * 0.1 * np.sqrt(2.0) - 1e-4),
               rotation((0.0, np.pi / 4, 0.0)))                   # an edge along y below
    p, n, d = check_swapped(high, low)
    assert len(d) == 1
    np.testing.assert_allclose(d, [1e-4], atol=TOL)
    np.testing.assert_allclose(n, [[0, 0, 1.0]], atol=TOL)
    np.testing.assert_allclose(p, [[0.0, 0.0, 0.1 * np.sqrt(2.0) - 5e-5]], atol=TOL)


def test_random_boxes_separate_by_their_depth_along_their_normal_and_not_by_much_less():
    rng = np.random.default_rng(13)
    seen = 0
    for _ in range(300):
        a, b = (box(rng.uniform(-0.15, 0.15, 3), rotation(rng.normal(size=3)),
                    rng.uniform(0.05, 0.2, 3)) for _ in range(2))
        p, n, d = check_swapped(a, b)
        if not len(d):
            continue
        seen += 1
        depth, normal = np.max(d), n[0]
        np.testing.assert_allclose(n, np.tile(normal, (len(d), 1)), atol=TOL)
        # Moved along the normal by the depth (and a hair), the boxes are apart: the
        # normal is a separating direction and the depth how far to go along it.
        moved = (BOX, a[1] + (depth + 1e-9) * normal, a[2], a[3])
        assert len(contacts(*moved, *b)[2]) == 0
        # And by less than the depth over 1.06 (the face's 5% preference, with room),
        # they still overlap: no direction separates them by so little.
        moved = (BOX, a[1] + (depth / 1.06 - 1e-9) * normal, a[2], a[3])
        assert len(contacts(*moved, *b)[2]) > 0
    assert seen > 100


# -- what is and is not supported ---------------------------------------------------------------


def test_pairs_without_a_narrow_phase_say_so():
    missing = {(PLANE, PLANE)}   # (the world's two planes never meet)
    for a in (SPHERE, CAPSULE, BOX, CYLINDER, PLANE):
        for b in (SPHERE, CAPSULE, BOX, CYLINDER, PLANE):
            assert supported(a, b) == ((a, b) not in missing)
            if (a, b) in missing:
                pts = np.zeros((4, 3))
                assert collide(a, np.zeros(3), np.eye(3), np.ones(3), b, np.zeros(3),
                               np.eye(3), np.ones(3), 0.0, pts, pts.copy(), np.zeros(4), 0) == -1


def test_a_full_buffer_reports_the_room_it_needed():
    box = (BOX, np.array([0.0, 0.0, 0.05]), np.eye(3), np.array([0.1, 0.1, 0.1]))
    points, normals, depths = np.zeros((2, 3)), np.zeros((2, 3)), np.zeros(2)
    k = collide(*box, *ground(), 0.0, points, normals, depths, 0)
    assert k == 4   # four contacts, two written


# -- bounds and the broad phase -----------------------------------------------------------------


@pytest.mark.parametrize('kind', [SPHERE, CAPSULE, BOX, CYLINDER])
def test_a_shapes_bounds_hold_it_and_touch_it(kind):
    rng = np.random.default_rng(kind)
    size = np.array([0.1, 0.3, 0.2])
    for _ in range(20):
        R = rotation(rng.normal(size=3))
        c = rng.normal(size=3)
        lo, hi = np.empty(3), np.empty(3)
        bounds(kind, c, R, size, 0.0, lo, hi)
        # The support of the shape along ±e_i by planes: a plane at lo_i facing +e_i
        # touches the shape (depth 0 within rounding) from below, and so from above.
        for i in range(3):
            for sign, level in ((1.0, lo[i]), (-1.0, hi[i])):
                e = np.zeros(3)
                e[i] = sign
                # A rotation taking z to e, for the plane's frame.
                axis = np.cross([0, 0, 1.0], e)
                ang = np.arccos(np.clip(e[2], -1, 1))
                Rp = rotation(axis / np.linalg.norm(axis) * ang) if np.linalg.norm(axis) \
                    else (np.eye(3) if sign > 0 or i != 2 else rotation((np.pi, 0, 0)))
                cp = np.zeros(3)
                cp[i] = level
                _, _, d = contacts(kind, c, R, size, PLANE, cp, Rp, np.zeros(3), 1.0)
                assert len(d) and abs(np.max(d)) <= TOL


def brute_pairs(lo, hi, body, group, mask, n_bodies, excluded):
    """Every pair whose boxes overlap and that the filters keep."""
    out = set()
    ex = set(excluded.tolist())
    for i in range(len(lo)):
        for j in range(i + 1, len(lo)):
            if np.any(lo[j] > hi[i]) or np.any(lo[i] > hi[j]) or body[i] == body[j]:
                continue
            if not (group[i] & mask[j] or group[j] & mask[i]):
                continue
            a, b = sorted((body[i], body[j]))
            if a * (n_bodies + 1) + b in ex:
                continue
            out.add((i, j))
    return out


@pytest.mark.parametrize('m', [0, 1, 2, 50, 400])
def test_the_broad_phase_finds_exactly_the_overlapping_pairs(m):
    rng = np.random.default_rng(m)
    n_bodies = max(m // 2, 1)
    centre = rng.uniform(0.0, 3.0, size=(m, 3))
    half = rng.uniform(0.01, 0.3, size=(m, 3))
    half[:m // 40] = 2.0   # a few shapes much bigger than the rest (tested against all)
    centre[m // 40:m // 20] += 1e7   # a few far away (cells beyond the keys' span)
    lo, hi = centre - half, centre + half
    body = rng.integers(0, n_bodies + 1, size=m)   # n_bodies: the world's shapes
    group = rng.integers(1, 4, size=m)
    mask = rng.integers(0, 4, size=m)
    pairs_all = [(a, b) for a in range(n_bodies + 1) for b in range(a + 1, n_bodies + 1)]
    pick = rng.choice(len(pairs_all), size=min(len(pairs_all), 10), replace=False) \
        if pairs_all else []
    excluded = np.sort(np.array([pairs_all[i][0] * (n_bodies + 1) + pairs_all[i][1]
                                 for i in pick], dtype=np.int64))
    pairs = np.zeros((m + 4, 2), dtype=np.int64)
    k = broad_phase(lo, hi, body, group, mask, n_bodies, excluded, pairs)
    if k > len(pairs):   # the room it needed, then all of them
        pairs = np.zeros((k, 2), dtype=np.int64)
        assert broad_phase(lo, hi, body, group, mask, n_bodies, excluded, pairs) == k
    got = set(map(tuple, pairs[:k].tolist()))
    assert len(got) == k
    assert got == brute_pairs(lo, hi, body, group, mask, n_bodies, excluded)
