"""
A cylinder on a box and on a cylinder (:mod:`.kernels.convex`: GJK, EPA and features).

References. The signed overlap of two convex shapes is the least, over unit
directions ``m``, of ``h_A(m) + h_B(−m)`` (their support functions; negative: their
gap), so an independent minimization of that closed form (support functions written
here again, minimized from many starts) checks the depth in any pose to 1e-8 of the
shapes' size: the reference's own accuracy is about 1e-10 of it (Nelder–Mead stalls
near the function's kinks), EPA's bound 1e-13 of it, and a gap past the inflation
(GJK's distance, which stops after 64 iterations on curved pairs) was measured within
2e-10 m. Manifolds of
flat features (a cap or a face, a lying mantle) are checked against their corners in
closed form, to rounding; the dynamics against a cylinder rolling without slip,
``a = (2/3) g sin θ``.

Tolerances. Depths and points of flat features: rounding of coordinates of order 1 m
over tens of operations, about 1e-14 m, written as 1e-8 or 1e-9 of the set depth (1e-6
to 1e-4 m) or 1e-12 m on points and normals. The rolling cylinder: its step (RKMK4)
is exact for a constant acceleration, and the contact LCP (two points on one body)
ends at its exact solution to rounding (complementarity 1e-18 measured), so only
rounding over 500 steps: relative 1e-9 on the travel and on ``v = ω r``. At rest:
rounding of 1000 steps of a body held still, 1e-13 m; its forces to the LCP's
tolerance and rounding, 1e-9 of ``m g``.
"""

import math

import numpy as np
import pytest
from rigid_body_sim.core import Gravity, RigidBody, Simulation
from rigid_body_sim.core.kernels.contact import BOX, collide, CYLINDER
from rigid_body_sim.core.shapes import CollisionShape
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

G = 9.81
I3 = np.eye(3)
LYING_Y = Rotation.from_euler('x', 90, degrees=True).as_matrix()   # axis along −y
LYING_X = Rotation.from_euler('y', 90, degrees=True).as_matrix()   # axis along +x
#: The world box the cylinders meet: 2 m × 2 m × 1 m, its top face at z = 0.
GROUND_BOX = (BOX, np.array([0.0, 0.0, -0.5]), I3, np.array([1.0, 1.0, 0.5]))


def _collide(a, b, margin=1e-3):
    """Return the contacts (points, normals, depths) of shapes a and b."""
    points, normals, depths = np.zeros((16, 3)), np.zeros((16, 3)), np.zeros(16)
    k = collide(a[0], np.asarray(a[1], float), np.asarray(a[2], float), np.asarray(a[3], float),
                b[0], np.asarray(b[1], float), np.asarray(b[2], float), np.asarray(b[3], float),
                margin, points, normals, depths, 0)
    assert 0 <= k <= 16
    return points[:k], normals[:k], depths[:k]


def _cyl(centre, R=I3, r=0.1, hl=0.2):
    return (CYLINDER, np.asarray(centre, float), R, np.array([r, hl, 0.0]))


def _support_value(shape, m):
    """Return the support function h(m) of a box or a cylinder, from its definition."""
    kind, c, R, size = shape
    if kind == BOX:
        return m @ c + sum(size[j] * abs(R[:, j] @ m) for j in range(3))
    a = R[:, 2]
    return m @ c + size[1] * abs(a @ m) + size[0] * np.linalg.norm(np.cross(a, m))


def _signed_distance(shape, x):
    """Return the signed distance of x to a box or a cylinder (negative inside)."""
    kind, c, R, size = shape
    local = R.T @ (np.asarray(x) - c)
    if kind == BOX:
        q = np.abs(local) - size
    else:
        q = np.array([math.hypot(local[0], local[1]) - size[0], abs(local[2]) - size[1]])
    return float(np.linalg.norm(np.maximum(q, 0.0)) + min(np.max(q), 0.0))


def _on_both_surfaces(a, b, points, normals, depths, tol):
    """Assert each contact's two surface points (point ∓ depth/2 n) lie on a's and b's."""
    for p, n, d in zip(points, normals, depths):
        assert abs(_signed_distance(a, p - 0.5 * d * n)) <= tol
        assert abs(_signed_distance(b, p + 0.5 * d * n)) <= tol


def _reference_overlap(a, b, rng, support=None):
    """Return the least over unit m of h_a(m) + h_b(−m): many starts, then Nelder–Mead."""
    support = support or _support_value

    def f(m):
        return support(a, m) + support(b, -m)

    def g(x):
        return f(np.array([math.sin(x[0]) * math.cos(x[1]), math.sin(x[0]) * math.sin(x[1]),
                           math.cos(x[0])]))
    starts = sorted(((f(v), tuple(v)) for v in
                     (u / np.linalg.norm(u) for u in rng.normal(size=(400, 3)))))
    best = math.inf
    for _, v in starts[:4]:
        x = np.array([math.acos(max(-1.0, min(1.0, v[2]))), math.atan2(v[1], v[0])])
        for _ in range(3):
            res = minimize(g, x, method='Nelder-Mead',
                           options={'xatol': 1e-14, 'fatol': 1e-17, 'maxiter': 2000})
            x = res.x + rng.normal(size=2) * 1e-7
        best = min(best, res.fun)
    return best


@pytest.mark.parametrize('seed', range(4))
def test_epa_depth_matches_the_support_function_minimum_in_random_poses(seed):
    # Random cylinders against random boxes and cylinders, placed along a random
    # direction at a target overlap (bisection on the depth found here, none past the
    # margin counting as below), from 5e-4 m apart to 0.05 m deep; then the reference,
    # computed independently, at that pose.
    rng = np.random.default_rng(seed)
    for trial in range(6):
        a_size = np.array([rng.uniform(0.05, 0.3), rng.uniform(0.05, 0.3), 0.0])
        if trial % 2 == 0:
            b = (BOX, np.zeros(3), Rotation.random(random_state=rng.integers(1 << 30))
                 .as_matrix(), rng.uniform(0.05, 0.3, 3))
        else:
            b = (CYLINDER, np.zeros(3), Rotation.random(random_state=rng.integers(1 << 30))
                 .as_matrix(), np.array([rng.uniform(0.05, 0.3), rng.uniform(0.05, 0.3), 0.0]))
        Ra = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        target = [-5e-4, -1e-9, 0.0, 1e-9, 1e-6, 1e-3, 0.05][rng.integers(7)]
        lo, hi = 0.0, 2.0
        for _ in range(60):
            t = 0.5 * (lo + hi)
            _, _, depths = _collide((CYLINDER, t * direction, Ra, a_size), b)
            if len(depths) and depths.max() > target:
                lo = t
            else:
                hi = t
        a = (CYLINDER, t * direction, Ra, a_size)
        scale = max(a_size.max(), b[3].max())
        _, normals, depths = _collide(a, b)
        reference = _reference_overlap(a, b, rng)
        assert len(depths) > 0 and -reference <= 1e-3
        assert depths.max() == pytest.approx(reference, abs=1e-8 * scale)
        # Each contact's points lie on both surfaces: a corner of one flat feature and its
        # foot on the other to rounding; curved pairs (a rim on a rim or an edge) within
        # 2e-6 of the size, as their normal's error (EPA on a curved surface) moves the
        # points along the surfaces: measured up to 7.6e-8 m (3.5e-7 of the size).
        points, normals, depths = _collide(a, b)
        _on_both_surfaces(a, b, points, normals, depths, 2e-6 * scale)
        # The normal is the minimizer: the support sum along it is the overlap.
        n = normals[0]
        assert _support_value(a, -n) + _support_value(b, n) == \
            pytest.approx(reference, abs=1e-8 * scale)


def test_a_standing_cylinder_touches_a_box_at_four_rim_points():
    for gap in (-1e-4, 5e-4):   # 0.1 mm deep, and 0.5 mm apart (within the margin)
        points, normals, depths = _collide(_cyl((0.3, 0.2, 0.2 + gap)), GROUND_BOX)
        assert len(depths) == 4
        np.testing.assert_allclose(normals, np.tile([0, 0, 1.0], (4, 1)), atol=1e-12)
        np.testing.assert_allclose(depths, -gap, rtol=1e-9)
        rim = {(round(x, 9), round(y, 9)) for x, y in points[:, :2]}
        assert rim == {(0.4, 0.2), (0.2, 0.2), (0.3, 0.3), (0.3, 0.1)}
        np.testing.assert_allclose(points[:, 2], 0.5 * gap, atol=1e-15)
    assert len(_collide(_cyl((0.3, 0.2, 0.2 + 2e-3)), GROUND_BOX)[2]) == 0   # beyond


def test_a_cylinder_over_the_boxs_corner_touches_inside_both():
    # Its axis over (0.95, 0.95): the disc overhangs two edges; the contacts are the
    # corners of disc ∩ face: the face's corner, two rim points, where the rim crosses
    # the edges (0.95 ∓ sqrt(0.1² − 0.05²) along each edge).
    points, normals, depths = _collide(_cyl((0.95, 0.95, 0.2 - 1e-4)), GROUND_BOX)
    np.testing.assert_allclose(depths, 1e-4, rtol=1e-9)
    found = {(round(x, 9), round(y, 9)) for x, y in points[:, :2]}
    cross = round(0.95 - math.sqrt(0.1 ** 2 - 0.05 ** 2), 9)
    expected = {(1.0, 1.0), (0.85, 0.95), (0.95, 0.85), (1.0, cross), (cross, 1.0)}
    assert len(found) == 4 and found <= expected
    assert (1.0, 1.0) in found


def test_a_lying_cylinder_touches_a_box_along_its_line_at_both_ends():
    points, normals, depths = _collide(_cyl((0, 0, 0.1 - 1e-5), LYING_Y), GROUND_BOX)
    assert len(depths) == 2
    np.testing.assert_allclose(depths, 1e-5, rtol=1e-9)
    np.testing.assert_allclose(normals, np.tile([0, 0, 1.0], (2, 1)), atol=1e-12)
    np.testing.assert_allclose(sorted(points[:, 1]), [-0.2, 0.2], atol=1e-12)
    np.testing.assert_allclose(points[:, 0], 0.0, atol=1e-12)


def test_a_tilted_cylinder_touches_at_its_lowest_rim_point():
    theta = math.pi / 6
    R = Rotation.from_euler('x', theta).as_matrix()
    low = 0.2 * math.cos(theta) + 0.1 * math.sin(theta)
    points, normals, depths = _collide(_cyl((0, 0, low - 1e-6), R), GROUND_BOX)
    assert len(depths) == 1
    assert depths[0] == pytest.approx(1e-6, abs=1e-15)
    # The lowest rim point: the bottom cap's centre, r along the tilt's downhill side.
    rim = np.array([0.0, 0.2 * math.sin(theta) - 0.1 * math.cos(theta), -1e-6])
    np.testing.assert_allclose(points[0], rim + [0, 0, 0.5e-6], atol=1e-12)


@pytest.mark.parametrize('theta', [0.3, 0.5, 0.7, 1.0])
def test_a_rim_near_the_inflated_reach_of_a_face_is_decided_by_its_gap(theta):
    # A cylinder tilted by theta over the box's top face, its lowest rim point (h cos θ +
    # r sin θ below its centre) at a gap about eps = margin + 1e-3 of the size (2e-3 m):
    # the inflated difference's boundary passes within 4e-8 m of the origin, where GJK
    # may run out of its iterations undecided (in 22 of these 164 poses, on an Intel
    # Xeon); EPA from its last simplex then decides. Past the margin: no contact. Within
    # it (5e-4 m apart, 1e-6 m deep), one at the rim point's gap, to rounding of
    # coordinates of order 1 m (3.5e-17 measured; 1e-15 m, as for the rim 1e-6 deep).
    R = Rotation.from_euler('x', theta).as_matrix()
    low = 0.2 * math.cos(theta) + 0.1 * math.sin(theta)
    for k in range(-20, 21):
        assert len(_collide(_cyl((0, 0, low + 2e-3 + k * 2e-9), R), GROUND_BOX)[2]) == 0, k
    for gap in (5e-4, -1e-6):
        _, _, depths = _collide(_cyl((0, 0, low + gap), R), GROUND_BOX)
        assert len(depths) == 1
        assert depths[0] == pytest.approx(-gap, abs=1e-15)


def test_a_cap_on_a_cap_touches_at_the_corners_of_their_lens():
    d = 0.15   # axes 0.15 apart: the lens between x = 0.05 and x = 0.1
    points, normals, depths = _collide(_cyl((d, 0, 0.4 - 1e-6)), _cyl((0, 0, 0)))
    np.testing.assert_allclose(depths, 1e-6, rtol=1e-8)
    found = {(round(x, 9), round(y, 9)) for x, y in points[:, :2]}
    h = round(math.sqrt(0.1 ** 2 - (d / 2) ** 2), 9)
    assert found == {(0.05, 0.0), (0.1, 0.0), (0.075, h), (0.075, -h)}


def test_crossed_and_parallel_lying_cylinders():
    crossed = _collide(_cyl((0, 0, 0.2 - 1e-6), LYING_X, hl=0.3),
                       _cyl((0, 0, 0), LYING_Y, hl=0.3))
    assert len(crossed[2]) == 1
    assert crossed[2][0] == pytest.approx(1e-6, abs=1e-15)
    np.testing.assert_allclose(crossed[1][0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(crossed[0][0], [0, 0, 0.1 - 0.5e-6], atol=1e-12)
    # Side by side, offset 0.1 along their axes: two contacts at the overlap's ends, the
    # normal the radial line between the axes (EPA's alone is within about 1e-7 rad
    # there: the mantles' sum is curved across).
    parallel = _collide(_cyl((0, 0, 0.2 - 1e-6), LYING_X, hl=0.3),
                        _cyl((0.1, 0, 0), LYING_X, hl=0.3))
    assert len(parallel[2]) == 2
    np.testing.assert_allclose(parallel[2], 1e-6, rtol=1e-9)
    np.testing.assert_allclose(sorted(parallel[0][:, 0]), [-0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(parallel[1], np.tile([0, 0, 1.0], (2, 1)), atol=1e-15)


def test_a_box_corner_on_a_lying_cylinder_pushes_along_the_radius():
    # A cube standing on a corner (its diagonal vertical) over a lying cylinder's
    # axis, off the top line by 0.03 m across: the normal is the radius through the
    # corner, the depth the radius minus the corner's distance from the axis.
    diagonal = Rotation.align_vectors([[0, 0, -1.0]], [[-1.0, -1.0, -1.0]])[0]
    corner_off = np.array([0.0, 0.03, 0.0])
    axis_to_corner = math.sqrt(0.1 ** 2 - 0.03 ** 2) - 1e-6   # 1e-6 m inside the radius
    corner = corner_off + [0, 0, axis_to_corner]
    centre = corner + diagonal.apply([0.05, 0.05, 0.05])
    box = (BOX, centre, diagonal.as_matrix(), np.array([0.05, 0.05, 0.05]))
    rho = math.hypot(0.03, axis_to_corner)
    points, normals, depths = _collide(box, _cyl((0, 0, 0), LYING_X, hl=0.3))
    assert len(depths) == 1
    assert depths[0] == pytest.approx(0.1 - rho, abs=1e-15)
    np.testing.assert_allclose(normals[0], np.array([0, 0.03, axis_to_corner]) / rho,
                               atol=1e-15)


def test_a_slightly_tilted_lying_cylinder_still_touches_at_both_ends():
    # Tilted 1e-4 rad about y: its far end 4e-5 m higher, within the margin (1e-3 m), so
    # both ends are contacts, each at its own gap (the lower 1e-6 m deep).
    tilt = 1e-4
    R = Rotation.from_euler('y', tilt).as_matrix() @ LYING_X
    low = 0.1 * math.cos(tilt) + 0.2 * math.sin(tilt)
    points, normals, depths = _collide(_cyl((0, 0, low - 1e-6), R), GROUND_BOX)
    assert len(depths) == 2
    np.testing.assert_allclose(sorted(depths), [1e-6 - 0.4 * math.sin(tilt), 1e-6],
                               rtol=1e-9)
    np.testing.assert_allclose(normals, np.tile([0, 0, 1.0], (2, 1)), atol=1e-15)


def test_a_small_box_on_a_cap_touches_at_its_four_corners_and_swapping_flips_the_normal():
    box = (BOX, np.array([0.01, 0.02, 0.2 + 0.05 - 1e-6]), I3, np.array([0.05, 0.04, 0.05]))
    cyl = _cyl((0, 0, 0))
    points, normals, depths = _collide(box, cyl)
    assert len(depths) == 4
    np.testing.assert_allclose(depths, 1e-6, rtol=1e-8)
    corners = {(round(x, 9), round(y, 9)) for x, y in points[:, :2]}
    assert corners == {(round(0.01 + sx * 0.05, 9), round(0.02 + sy * 0.04, 9))
                       for sx in (-1, 1) for sy in (-1, 1)}
    np.testing.assert_allclose(normals, np.tile([0, 0, 1.0], (4, 1)), atol=1e-12)
    swapped = _collide(cyl, box)
    np.testing.assert_allclose(swapped[1], -normals, atol=1e-12)
    np.testing.assert_allclose(sorted(map(tuple, swapped[0])), sorted(map(tuple, points)),
                               atol=1e-12)
    np.testing.assert_allclose(swapped[2], depths, rtol=1e-12)


def test_rotations_that_are_not_exactly_orthonormal_keep_the_cylinder_on_its_shape():
    # Turned by 90° three times (columns off unit length by rounding): along its axis the
    # part of a direction across it is rounding; taken as a direction, it put the support
    # point r off the shape (a depth of +0.14 for a 5e-4 gap). Two such cylinders end to
    # end, 5e-4 m apart: their caps face each other.
    R = Rotation.from_euler('xyz', (90, 90, 90), degrees=True).as_matrix()
    axis = R[:, 2]
    a, b = _cyl(axis * (0.4 + 5e-4), R), _cyl((0, 0, 0), R)
    points, normals, depths = _collide(a, b)
    assert len(depths) == 4
    np.testing.assert_allclose(depths, -5e-4, rtol=1e-9)
    np.testing.assert_allclose(normals, np.tile(axis, (4, 1)), atol=1e-12)
    _on_both_surfaces(a, b, points, normals, depths, 1e-12)


def test_a_box_face_over_a_cap_keeps_its_corners_in_order_whichever_way_it_turns():
    # A wide box lying over a cap's edge, box first and cylinder first: every contact
    # inside both the disc and the face (a face whose corners turn clockwise seen along
    # the normal once put its 3-D corners out of step with their projections).
    box = (BOX, np.array([0.55, 0.55, 0.25 - 1e-5]), I3, np.array([0.5, 0.5, 0.05]))
    cyl = _cyl((0, 0, 0))
    for a, b in ((cyl, box), (box, cyl)):
        points, normals, depths = _collide(a, b)
        assert len(depths) >= 3
        np.testing.assert_allclose(depths, 1e-5, rtol=1e-9)
        _on_both_surfaces(a, b, points, normals, depths, 1e-12)
        assert np.all(np.hypot(points[:, 0], points[:, 1]) <= 0.1 + 1e-12)
        assert np.all(points[:, :2] >= 0.05 - 1e-12)


def test_a_cylinder_deep_inside_a_box_is_pushed_out_the_shortest_way():
    # Its bottom 0.5 m below the top face, 0.9 m from the nearest side: up by 0.5.
    _, normals, depths = _collide(_cyl((0.2, 0, -0.3)), GROUND_BOX)
    np.testing.assert_allclose(depths, 0.5, rtol=1e-12)
    np.testing.assert_allclose(normals[0], [0, 0, 1], atol=1e-12)


def _on_box_incline(theta, shape, mass=2.0, r=0.1, hl=0.2, mu=1.0):
    """Return a cylinder on the top face of a world box tilted by ``theta`` about x."""
    rot = Rotation.from_euler('x', theta)
    normal = rot.apply([0, 0, 1.0])
    down = rot.apply([0, -1.0, 0])
    if shape == 'lying':   # its axis along the incline's x: it rolls down
        inertia = (0.5 * mass * r * r, mass * (3 * r * r + 4 * hl * hl) / 12,
                   mass * (3 * r * r + 4 * hl * hl) / 12)
        quat = (rot * Rotation.from_euler('y', 90, degrees=True)).as_quat()
        lift = r
        inertia = (inertia[1], inertia[2], inertia[0])   # body z: the axis
    else:   # standing on its cap
        inertia = (mass * (3 * r * r + 4 * hl * hl) / 12,) * 2 + (0.5 * mass * r * r,)
        quat = rot.as_quat()
        lift = hl
    body = RigidBody('c', mass, inertia, position_world=tuple(lift * normal),
                     orientation_xyzw=tuple(quat))
    ground = CollisionShape('box', None, size=(4.0, 4.0, 1.0), friction=mu,
                            position_body=tuple(-0.5 * normal),
                            orientation_xyzw=tuple(rot.as_quat()))
    cyl = CollisionShape('cylinder', 'c', radius=r, length=2 * hl, friction=mu)
    return Simulation([body], [Gravity()], integrator='rkmk4', dt=1e-3,
                      shapes=[ground, cyl]), down


def test_a_lying_cylinder_rolls_down_a_box_incline_at_two_thirds_g_sin_theta():
    theta = 0.3
    sim, down = _on_box_incline(theta, 'lying')
    p0 = sim.state.pos_com_world[0].copy()
    sim.step(500)
    travel = sim.state.pos_com_world[0] - p0
    np.testing.assert_allclose(travel, 0.5 * 2.0 / 3.0 * G * math.sin(theta) * 0.25 * down,
                               rtol=1e-9, atol=1e-12)
    v, w = sim.twist('c')
    assert np.linalg.norm(v) == pytest.approx(np.linalg.norm(w) * 0.1, rel=1e-9)
    assert sim.contact.counters['lcp_failures'] == 0


def test_a_standing_cylinder_rests_on_a_box_incline_carrying_its_weight():
    sim, _ = _on_box_incline(0.3, 'standing')
    p0 = sim.state.pos_com_world.copy()
    sim.step(1000)
    assert np.max(np.abs(sim.state.pos_com_world - p0)) <= 1e-13
    rep = sim.contacts()
    assert len(rep['normal_force']) == 4
    # The ground's forces on the cylinder (normals from b to a) sum to its weight.
    sign = np.array([1.0 if b == 'world' else -1.0 for b in rep['body_b']])
    total = np.sum(sign[:, None] * (rep['normal'] * rep['normal_force'][:, None]
                                    + rep['friction_force']), axis=0)
    np.testing.assert_allclose(total, [0, 0, 2.0 * G], atol=1e-9 * 2.0 * G)
    assert sim.contact.counters['lcp_failures'] == 0
