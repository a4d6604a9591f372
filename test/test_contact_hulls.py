"""
Meshes as convex hulls (:mod:`.hulls`, and the hull's narrow phases in :mod:`.kernels.convex`).

References. A hull's support function is the largest ``v · m`` over its vertices, so
the signed overlap of a hull and a shape is the least over unit ``m`` of
``h_hull(m) + h_B(−m)``: minimized here independently, as in ``test_contact_convex``
(support functions written again in this file; the reference's own accuracy is about
1e-10 of the size). A box's eight corners make a hull that is that box: its contacts
with a plane, and its steps sliding and resting, must be those of the box primitive
(their closed forms are tested in ``test_contact_dynamics``). A hexagonal prism on the
ground has a closed-form rest: six corners on the ground, weight ``m g``.

Tolerances. Depths and normals: 1e-8 of the size against the reference (its own
accuracy 1e-10, EPA's 1e-13). A sphere's normal on a face or at a corner comes from
GJK's nearest point of its centre, exact to rounding of O(1) coordinates: 1e-12. Hull
against box primitive over 1000 steps: the same contacts to rounding, so states within
1e-12 (as the compiled and Python paths: ``test_contact_compiled``). At rest: rounding
of 1000 steps of a body held still, 1e-13 m; forces to 1e-9 of ``m g``.
"""

import itertools
import math
import struct

import numpy as np
import pytest
from rigid_body_sim.core import Gravity, RigidBody, Simulation, SpecError
from rigid_body_sim.core.hulls import hull_record, hull_triangles, read_vertices
from rigid_body_sim.core.kernels.contact import BOX, CAPSULE, collide, CYLINDER, HULL, PLANE, \
    SPHERE
from rigid_body_sim.core.kernels.convex import CORNERS as CORNERS_MOST, H_NF, H_NV, H_VERTS
from rigid_body_sim.core.shapes import CollisionShape
from scipy.spatial.transform import Rotation
from test_contact_convex import _reference_overlap, _signed_distance

G = 9.81
CORNERS = np.array(list(itertools.product([-0.1, 0.1], [-0.2, 0.2], [-0.05, 0.05])))
HALF = np.array([0.1, 0.2, 0.05])


def _faces(rec):
    """Return a record's faces as (normal, vertex index array)."""
    nv, nf = int(rec[H_NV]), int(rec[H_NF])
    out = []
    for f in range(nf):
        o = int(rec[H_VERTS + 3 * nv + f])
        k = int(rec[o + 3])
        out.append((rec[o:o + 3], rec[o + 4:o + 4 + k].astype(int)))
    return out


def _vertices(rec):
    nv = int(rec[H_NV])
    return rec[H_VERTS:H_VERTS + 3 * nv].reshape(nv, 3)


def test_a_boxs_corners_make_a_hull_of_six_four_cornered_faces_in_order():
    rec = hull_record(CORNERS)
    np.testing.assert_array_equal(rec[:3], HALF)
    assert int(rec[H_NV]) == 8
    v = _vertices(rec)
    faces = _faces(rec)
    assert len(faces) == 6
    for normal, idx in faces:
        assert len(idx) == 4
        axis = int(np.argmax(np.abs(normal)))
        assert abs(normal[axis]) == pytest.approx(1.0, abs=1e-15)
        # Every corner on the face's plane, and counter-clockwise about its normal.
        np.testing.assert_allclose(v[idx] @ normal, HALF[axis], atol=1e-15)
        pts = v[idx]
        for q in range(4):
            turn = np.cross(pts[(q + 1) % 4] - pts[q], pts[(q + 2) % 4] - pts[(q + 1) % 4])
            assert turn @ normal > 0.0


def test_a_rotated_float32_mesh_keeps_its_faces_whole():
    # A cube whose faces are 5 x 5 grids, turned and stored as float32 (as a binary STL
    # of a CAD part holds it): its faces are coplanar only to float32's rounding (6e-8
    # of its size), and merged within 1e-6 of it: 6 faces of 4 corners, 8 vertices (the
    # grid's inner points none), and on a box it rests on its 4 corners.
    g = np.linspace(-0.1, 0.1, 5)
    grid = np.array([p for p in itertools.product(g, repeat=3) if np.max(np.abs(p)) == 0.1])
    for seed in range(5):
        R = Rotation.random(random_state=seed).as_matrix()
        rec = hull_record((grid @ R.T).astype(np.float32))
        assert int(rec[H_NV]) == 8 and int(rec[H_NF]) == 6
        assert all(len(idx) == 4 for _, idx in _faces(rec))
        box = (BOX, np.array([0.0, 0.0, -0.5]), np.eye(3), np.array([1.0, 1.0, 0.5]))
        low = -np.min((_vertices(rec) @ R)[:, 2])   # (turned back: its face down)
        points, normals, depths = _collide((HULL, np.array([0, 0, low - 1e-5]), R.T, rec),
                                           box)
        assert len(depths) == 4
        np.testing.assert_allclose(depths, 1e-5, atol=1e-7)   # (float32 corners: 1e-8)


def test_a_face_of_more_corners_than_the_kernels_take_keeps_them_evenly():
    # A 100-sided prism: its caps keep 64 of their corners (a polygon inside the cap),
    # its sides are 100 faces of 4; it stands on the ground on 4 of its cap's corners.
    rec = hull_record(_prism(100, 0.1, 0.05))
    caps = [idx for normal, idx in _faces(rec) if abs(normal[2]) > 0.5]
    assert [len(idx) for idx in caps] == [CORNERS_MOST] * 2
    assert int(rec[H_NF]) == 102
    ground = (PLANE, np.zeros(3), np.eye(3), np.zeros(3))
    _, _, depths = _collide((HULL, np.array([0, 0, 0.05 - 1e-5]), np.eye(3), rec), ground)
    assert len(depths) == 4


def test_interior_points_and_repeats_are_not_vertices():
    pts = np.vstack([CORNERS, CORNERS, np.random.default_rng(0).uniform(-0.05, 0.05, (50, 3))])
    rec = hull_record(pts)
    assert int(rec[H_NV]) == 8 and int(rec[H_NF]) == 6


@pytest.mark.parametrize('bad, words', [
    (np.zeros((4, 3)), 'no volume'),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]]), 'no volume'),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]]), 'at least 4'),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, np.nan]]), 'finite'),
    ('nothing', 'expected a file name or vertices'),
])
def test_a_mesh_without_a_solid_hull_is_refused_naming_the_field(bad, words):
    with pytest.raises(SpecError, match=words) as err:
        CollisionShape('mesh', 'b', mesh=bad if not isinstance(bad, str) else [bad])
    assert err.value.field == 'mesh'


def test_a_meshs_scale_must_be_non_zero_and_scales_its_hull():
    with pytest.raises(SpecError) as err:
        CollisionShape('mesh', 'b', mesh=CORNERS, scale=(1, 0, 1))
    assert err.value.field == 'scale'
    s = CollisionShape('mesh', 'b', mesh=CORNERS, scale=(2, 1, 3))
    np.testing.assert_array_equal(s.dimensions(), HALF * (2, 1, 3))
    # A negative scale mirrors it (URDF's mirrored parts): its hull, mirrored.
    shifted = CORNERS + (0.3, 0, 0)
    s = CollisionShape('mesh', 'b', mesh=shifted, scale=(-1, 1, 1))
    np.testing.assert_allclose(np.sort(_vertices(s.hull)[:, 0]), np.sort(-shifted[:, 0]))
    with pytest.raises(SpecError) as err:
        CollisionShape('box', 'b', size=(1, 1, 1), scale=(1, 1, 1))
    assert err.value.field == 'scale'


def test_a_part_far_from_its_links_origin_is_bounded_and_sized_by_its_own_box():
    # A 2 cm cube drawn 0.5 m from its link's origin along each axis (a URDF mesh in its
    # link's frame). Its size was measured about that origin: half extents of 0.51 m,
    # a broad-phase box 50 times the part's, and contacts counted as one within 0.13 m.
    # Now: its own half extents (0.01 m) about its own centre, its hull as given still
    # (what bounds and users read), no broad-phase pair with a sphere 0.3 m away, and
    # the contacts of the same cube made about its centre and placed there, to the
    # rounding of 0.5 m coordinates (1e-15 m).
    from rigid_body_sim.core.bodies import RigidBody as Body
    from rigid_body_sim.core.shapes import ContactDetector
    from test_contact_detection import outputs
    cube = np.array(list(itertools.product([-0.01, 0.01], repeat=3)))
    off = np.array([0.5, 0.5, 0.5])
    far = CollisionShape('mesh', 'a', mesh=cube + off)
    np.testing.assert_allclose(far.dimensions(), [0.01] * 3, rtol=0, atol=1e-15)
    np.testing.assert_allclose(far.hull_centre, off, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(far.hull, hull_record(cube + off))
    sphere = CollisionShape('sphere', 'b', radius=0.05, position_body=(0.3, 0.3, 0.3))
    det = ContactDetector([far, sphere], ['a', 'b'])
    out = outputs([Body('a', 1.0, (1, 1, 1)), Body('b', 1.0, (1, 1, 1))])
    assert len(det.detect(out).depth) == 0
    assert det.counters['pairs_tested'] == 0
    # Turned in its link and the link turned, resting 1 mm into the ground on a corner.
    turn = Rotation.from_rotvec([0.3, -0.2, 0.5])
    link = Rotation.from_rotvec([-0.1, 0.4, 0.2])
    where = np.array([0.1, -0.2, 0.05])
    made = [CollisionShape('mesh', 'a', mesh=cube + off, position_body=where,
                           orientation_xyzw=turn.as_quat()),
            CollisionShape('mesh', 'a', mesh=cube, position_body=where + turn.apply(off),
                           orientation_xyzw=turn.as_quat())]
    corners = link.apply(turn.apply(cube + off) + where)
    height = -1e-3 - float(np.min(corners[:, 2]))
    body = Body('a', 1.0, (1, 1, 1), position_world=(0.0, 0.0, height),
                orientation_xyzw=link.as_quat())
    found = [ContactDetector([s, CollisionShape('plane', None)], ['a']).detect(outputs([body]))
             for s in made]
    assert len(found[0].depth) == 1
    for field in ('point', 'normal', 'depth'):
        np.testing.assert_allclose(getattr(found[0], field), getattr(found[1], field),
                                   rtol=0, atol=1e-15)
    np.testing.assert_allclose(found[0].depth, [1e-3], rtol=0, atol=1e-15)


def test_stl_binary_and_ascii_and_obj_files_give_the_same_hull(tmp_path):
    tri = hull_triangles(hull_record(CORNERS))
    binary = bytearray(b'\0' * 80 + struct.pack('<I', len(tri)))
    for t in tri:
        binary += struct.pack('<12fH', 0, 0, 0, *t.ravel(), 0)
    (tmp_path / 'b.stl').write_bytes(bytes(binary))
    (tmp_path / 'padded.stl').write_bytes(bytes(binary) + b'\0\0')   # (trailing bytes)
    ascii_ = ['solid b'] + [line for t in tri for line in
                            ['facet normal 0 0 0', 'outer loop',
                             *(f'vertex {x:.17g} {y:.17g} {z:.17g}' for x, y, z in t),
                             'endloop', 'endfacet']] + ['endsolid b']
    (tmp_path / 'a.STL').write_text('\n'.join(ascii_))
    (tmp_path / 'o.obj').write_text('# a box\n' + ''.join(f'v {x:.17g} {y:.17g} {z:.17g}\n'
                                                          for x, y, z in CORNERS)
                                    + 'f 1 2 3\n')
    want = hull_record(CORNERS)
    for name in ('b.stl', 'padded.stl', 'a.STL', 'o.obj'):
        got = CollisionShape('mesh', 'b', mesh=str(tmp_path / name)).hull
        # (binary STL holds float32: 0.2 to 1.5e-8)
        np.testing.assert_allclose(np.sort(_vertices(got), axis=0),
                                   np.sort(_vertices(want), axis=0), rtol=0, atol=2e-8)
    (tmp_path / 'x.dae').write_text('<COLLADA/>')
    for name, words in (('x.dae', "format '.dae' not read"), ('none.stl', 'No such file')):
        with pytest.raises(SpecError, match=words) as err:
            read_vertices(tmp_path / name)
        assert err.value.field == 'mesh'
    (tmp_path / 'empty.stl').write_text('solid nothing\nendsolid nothing\n')
    with pytest.raises(SpecError, match='no vertices'):
        read_vertices(tmp_path / 'empty.stl')


# -- narrow phases against an independent support-function minimum --------------------------

def _support_value(shape, m):
    """Return the support function h(m) of a shape, from its definition."""
    kind, c, R, size = shape
    if kind == HULL:
        return m @ c + np.max(_vertices(size) @ (R.T @ m))
    if kind == BOX:
        return m @ c + sum(size[j] * abs(R[:, j] @ m) for j in range(3))
    if kind == SPHERE:
        return m @ c + size[0] * np.linalg.norm(m)
    a = R[:, 2]
    if kind == CAPSULE:
        return m @ c + size[1] * abs(a @ m) + size[0] * np.linalg.norm(m)
    return m @ c + size[1] * abs(a @ m) + size[0] * np.linalg.norm(np.cross(a, m))


def _axes(shape):
    """Return a polytope's face normals and edge directions in the world (a box's: its axes)."""
    kind, c, R, size = shape
    if kind == BOX:
        return R.T, R.T
    if kind != HULL:
        return np.zeros((0, 3)), np.zeros((0, 3))
    v = _vertices(size)
    normals, edges = [], []
    for normal, idx in _faces(size):
        normals.append(R @ normal)
        edges.extend(R @ (v[idx[(q + 1) % len(idx)]] - v[idx[q]]) for q in range(len(idx)))
    return np.array(normals), np.array(edges)


def _separating_axes_minimum(a, b):
    """
    Return the least support sum over the separating axes of two polytopes (inf if not both).

    Where they overlap, the least over all unit m is attained at one of them: a face
    normal of either, or a cross product of an edge of each (the faces of A − B).
    """
    if a[0] not in (BOX, HULL) or b[0] not in (BOX, HULL):
        return math.inf
    (na, ea), (nb, eb) = _axes(a), _axes(b)
    cand = list(na) + list(nb)
    for e in ea:
        for f in eb:
            x = np.cross(e, f)
            if np.linalg.norm(x) > 1e-9 * np.linalg.norm(e) * np.linalg.norm(f):
                cand.append(x / np.linalg.norm(x))
    return min(min(_support_value(a, m) + _support_value(b, -m),
                   _support_value(a, -m) + _support_value(b, m)) for m in cand)


def _collide(a, b, margin=1e-3):
    points, normals, depths = np.zeros((16, 3)), np.zeros((16, 3)), np.zeros(16)
    k = collide(a[0], np.asarray(a[1], float), np.asarray(a[2], float), np.asarray(a[3], float),
                b[0], np.asarray(b[1], float), np.asarray(b[2], float), np.asarray(b[3], float),
                margin, points, normals, depths, 0)
    assert 0 <= k <= 16
    return points[:k], normals[:k], depths[:k]


def _prism(n=6, r=0.1, hl=0.08):
    """Return an n-sided prism's corners about its z axis (radius r, half height hl)."""
    ang = 2 * math.pi * np.arange(n) / n
    ring = np.c_[r * np.cos(ang), r * np.sin(ang)]
    return np.vstack([np.c_[ring, np.full(n, -hl)], np.c_[ring, np.full(n, hl)]])


@pytest.mark.parametrize('seed', range(3))
def test_hull_depths_and_normals_match_the_support_function_minimum(seed):
    # A random hull (a box's corners or a prism's, or random points) against every kind,
    # placed along a random direction at a target overlap (bisection), 5e-4 m apart to
    # 0.02 m deep.
    rng = np.random.default_rng(seed)
    hulls = [hull_record(CORNERS), hull_record(_prism()),
             hull_record(rng.normal(size=(30, 3)) * 0.1)]
    others = [(SPHERE, np.array([0.08, 0, 0])), (CAPSULE, np.array([0.05, 0.12, 0])),
              (BOX, np.array([0.1, 0.15, 0.07])), (CYLINDER, np.array([0.08, 0.1, 0])),
              (HULL, hull_record(_prism(5, 0.12, 0.05)))]
    for trial in range(10):
        rec = hulls[trial % 3]
        kb, sb = others[trial % 5]
        b = (kb, np.zeros(3), Rotation.random(random_state=rng.integers(1 << 30)).as_matrix(),
             sb)
        Ra = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        target = [-5e-4, 0.0, 1e-6, 1e-3, 0.02][rng.integers(5)]
        lo, hi = 0.0, 2.0
        for _ in range(60):
            t = 0.5 * (lo + hi)
            _, _, depths = _collide((HULL, t * u, Ra, rec), b)
            if len(depths) and depths.max() > target:
                lo = t
            else:
                hi = t
        a = (HULL, t * u, Ra, rec)
        scale = max(np.max(rec[:3]), np.max(sb[:3]))
        _, normals, depths = _collide(a, b)
        reference = min(_reference_overlap(a, b, rng, _support_value),
                        _separating_axes_minimum(a, b))
        assert len(depths) > 0
        # The depth is the support sum along the normal (so at least the true least), and
        # no more than the least the reference found (Nelder–Mead stalls on a polytope
        # pair's kinks: the separating axes give their overlap exactly). Bound: EPA's
        # stop, its gain below EPA_TOLERANCE (1e-13 of the size), or, where rounding
        # broke the polytope first (nearly flat faces seen from both sides), the last
        # sound face's gap: rounding of a size over those faces' flatness, 1e-13 to 1e-12
        # of the size (measured: 1.9e-12 on an AMD EPYC, a rim on a box's corners, and
        # below 1e-12 elsewhere); 1e-11 of the size allows for it.
        n = normals[0]
        assert _support_value(a, -n) + _support_value(b, n) == \
            pytest.approx(depths.max(), abs=1e-11 * scale), (trial, kb)
        assert depths.max() <= reference + 1e-8 * scale, (trial, kb)
        if kb not in (BOX, HULL):   # (a curved shape: Nelder–Mead's minimum is sharp)
            assert depths.max() == pytest.approx(reference, abs=1e-8 * scale), (trial, kb)
        # Swapping a and b: the same depth, the normal flipped.
        _, normals2, depths2 = _collide(b, a)
        assert depths2.max() == pytest.approx(depths.max(), abs=1e-10 * scale)
        np.testing.assert_allclose(normals2[0], -n, atol=1e-6)


def test_a_sphere_on_a_hulls_face_and_corner_takes_the_exact_normal():
    rec = hull_record(CORNERS)
    R = Rotation.from_euler('xyz', [0.3, -0.2, 0.7]).as_matrix()
    # Over the top face's inside, 1e-4 deep: the face normal, depth exact.
    centre = R @ np.array([0.03, -0.05, 0.05 + 0.08 - 1e-4])
    points, normals, depths = _collide((SPHERE, centre, np.eye(3), np.array([0.08, 0, 0])),
                                       (HULL, np.zeros(3), R, rec))
    assert len(depths) == 1
    np.testing.assert_allclose(normals[0], R[:, 2], atol=1e-14)
    assert depths[0] == pytest.approx(1e-4, abs=1e-14)
    # Beyond a corner, 2e-4 apart: the normal along corner → centre.
    corner = R @ np.array([0.1, 0.2, 0.05])
    out = R @ np.array([1.0, 2.0, 0.5]) / math.sqrt(5.25)
    centre = corner + (0.08 + 2e-4) * out
    points, normals, depths = _collide((HULL, np.zeros(3), R, rec),
                                       (SPHERE, centre, np.eye(3), np.array([0.08, 0, 0])))
    assert len(depths) == 1
    np.testing.assert_allclose(normals[0], -out, atol=1e-12)   # (b to a: sphere to hull)
    assert depths[0] == pytest.approx(-2e-4, abs=1e-12)
    np.testing.assert_allclose(points[0], corner + 1e-4 * out, atol=1e-12)


def test_a_prism_on_a_box_touches_at_the_corners_of_their_overlap():
    # A hexagonal prism 1e-5 deep in a box's top face, half over its edge at x = 0: the
    # overlap is the hexagon cut at x = 0; its corners are the contacts (four kept: the
    # deepest-first reduction), each 1e-5 deep, all with x ≥ 0 and on the hexagon.
    rec = hull_record(_prism())
    box = (BOX, np.array([-0.5, 0.0, -0.5]), np.eye(3), np.array([0.5, 0.5, 0.5]))
    points, normals, depths = _collide((HULL, np.array([0.02, 0.0, 0.08 - 1e-5]),
                                        np.eye(3), rec), box)
    assert len(depths) == 4
    np.testing.assert_allclose(normals, np.tile([0, 0, 1.0], (4, 1)), atol=0)
    np.testing.assert_allclose(depths, 1e-5, atol=1e-15)
    assert np.all(points[:, 0] >= 0.02 - 0.1 - 1e-15) and np.all(points[:, 0] <= 1e-15)
    np.testing.assert_allclose(points[:, 2], -5e-6, atol=1e-15)


# -- dynamics -------------------------------------------------------------------------------

def _cube_body(name, velocity=(0.0, 0.0, 0.0)):
    mass = 2.0
    inertia = mass * (0.2 ** 2 + 0.2 ** 2) / 12
    return RigidBody(name, mass, (inertia,) * 3, position_world=(0, 0, 0.1),
                     linear_velocity_world=velocity)


@pytest.mark.parametrize('velocity', [(0.0, 0.0, 0.0), (1.0, 0.3, 0.0)])
def test_a_box_hull_rests_and_slides_as_the_box(velocity):
    cube = np.array(list(itertools.product([-0.1, 0.1], repeat=3)))
    sims = []
    for shape in (CollisionShape('box', 'b', size=(0.2,) * 3, friction=0.5),
                  CollisionShape('mesh', 'b', mesh=cube, friction=0.5)):
        sims.append(Simulation([_cube_body('b', velocity)], [Gravity()], integrator='rkmk4',
                               dt=1e-3, shapes=[CollisionShape('plane', None, friction=0.5),
                                                shape]))
    for k in range(1000):
        for sim in sims:
            sim.step()
    box, hull = sims
    np.testing.assert_allclose(hull.state.y, box.state.y, rtol=0, atol=1e-12)
    assert hull.contact.counters['compiled_steps'] == 1000
    if velocity[0] == 0.0:   # at rest: still, its weight on four corners
        assert np.max(np.abs(hull.state.pos_com_world[0] - (0, 0, 0.1))) <= 1e-13
    else:   # it slid and stopped (the box's closed form: test_contact_dynamics)
        assert np.linalg.norm(hull.state.vel_com_world[0]) <= 1e-12
        assert np.linalg.norm(hull.state.pos_com_world[0, :2]) > 0.05
    rep = hull.contacts()
    assert len(rep['normal_force']) == 4
    assert np.sum(rep['normal_force']) == pytest.approx(2.0 * G, rel=1e-9)


def test_a_hexagonal_prism_stands_on_the_ground_carrying_its_weight():
    mass, r, hl = 3.0, 0.1, 0.08
    body = RigidBody('p', mass, (0.01, 0.01, 0.015), position_world=(0.3, -0.2, hl))
    sim = Simulation([body], [Gravity()], integrator='rkmk4', dt=1e-3,
                     shapes=[CollisionShape('plane', None, friction=0.8),
                             CollisionShape('mesh', 'p', mesh=_prism(6, r, hl), friction=0.8)])
    p0 = sim.state.pos_com_world.copy()
    sim.step(1000)
    assert np.max(np.abs(sim.state.pos_com_world - p0)) <= 1e-13
    rep = sim.contacts()
    # Four of its six bottom corners (the reduction keeps those spanning the most).
    assert len(rep['normal_force']) == 4
    assert np.sum(rep['normal_force']) == pytest.approx(mass * G, rel=1e-9)
    spread = rep['point'][:, :2] - (0.3, -0.2)
    np.testing.assert_allclose(np.linalg.norm(spread, axis=1), r, atol=1e-15)
    assert sim.contact.counters['lcp_failures'] == 0


STL_URDF = """<robot name="block">
  <link name="block">
    <inertial><mass value="2"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><mesh filename="block.stl" scale="0.5 0.5 0.5"/></geometry>
    </collision>
    <collision><origin xyz="0 0 0.3"/>
      <geometry><mesh filename="package://nowhere/block.dae"/></geometry></collision>
  </link>
</robot>
"""


def test_a_urdf_links_stl_collision_is_its_hull_and_rests_on_the_ground(tmp_path):
    # The link's STL (a 0.4 m cube, scaled by 0.5: 0.2 m) is simulated; the .dae that
    # cannot be found is named in the warning.
    from rigid_body_sim.scene import load_scene
    tri = hull_triangles(hull_record(CORNERS * (2, 1, 4)))   # 0.4 m cube
    binary = bytearray(b'\0' * 80 + struct.pack('<I', len(tri)))
    for t in tri:
        binary += struct.pack('<12fH', 0, 0, 0, *t.ravel(), 0)
    (tmp_path / 'block.stl').write_bytes(bytes(binary))
    (tmp_path / 'block.urdf').write_text(STL_URDF)
    (tmp_path / 'scene.yaml').write_text(
        'dt: 0.001\nintegrator: rkmk4\neffects: {gravity: {}}\nground: {}\n'
        'robots: [{urdf: block.urdf, collisions: true,\n'
        '          base_pose: {xyz: [0, 0, 0.1]}}]\n')
    scene = load_scene(tmp_path / 'scene.yaml')
    assert any("mesh <collision> of link 'block' (package://nowhere/block.dae: file not "
               'found)' in w for w in scene.warnings)
    sim = scene.simulation
    shapes = sim.contact.detector.shapes
    assert [s.kind for s in shapes] == ['plane', 'mesh']
    np.testing.assert_allclose(shapes[1].dimensions(), 0.1, atol=1e-8)   # (float32 file)
    p0 = sim.state.pos_com_world.copy()
    sim.step(500)
    assert np.max(np.abs(sim.state.pos_com_world - p0)) <= 1e-7   # (its float32 corners)
    assert np.sum(sim.contacts()['normal_force']) == pytest.approx(2.0 * G, rel=1e-9)


def test_a_scene_bodys_mesh_shape_from_a_file_beside_the_scene(tmp_path):
    from rigid_body_sim.scene import load_scene
    (tmp_path / 'part.obj').write_text(''.join(f'v {x:.17g} {y:.17g} {z:.17g}\n'
                                               for x, y, z in CORNERS))
    (tmp_path / 'scene.yaml').write_text(
        'dt: 0.001\nintegrator: rkmk4\neffects: {gravity: {}}\nground: {}\n'
        'bodies:\n  - {name: part, mass: 1.0, inertia: [0.01, 0.01, 0.01],\n'
        '     position_world: [0, 0, 0.05], shapes: [{kind: mesh, mesh: part.obj}]}\n')
    sim = load_scene(tmp_path / 'scene.yaml').simulation
    sim.step(200)
    assert sim.pose('part')[0][2] == pytest.approx(0.05, abs=1e-12)
    assert len(sim.contacts()['normal_force']) == 4


def test_thin_plates_crossing_edge_to_edge_touch_where_they_cross():
    # A 1 x 1 x 0.001 plate and a 0.6 x 0.6 x 0.001 one crossing at A's top edge, B's
    # big face 30° from the normal: B's part within the margin of its top is its thin
    # side (a strip), not its big face. 1e-4 deep: the contacts' deepest is 1e-4, all on
    # both surfaces (the points of the strip over A's face); the box primitive agrees.
    s30, c30 = 0.5, math.sqrt(3) / 2
    n = -np.array([c30, 0.0, s30])
    t, y = np.array([-s30, 0.0, c30]), np.array([0.0, 1.0, 0.0])
    m2, m1 = c30 * n + s30 * y, 0.5 * n - c30 * y
    RB = np.c_[-t, m1, m2]
    plate_a = hull_record(np.array(list(itertools.product([-0.5, 0.5], [-0.5, 0.5],
                                                          [-0.0005, 0.0005]))))
    half_b = np.array([0.3, 0.3, 0.0005])
    plate_b = hull_record(np.array(list(itertools.product(*[[-h, h] for h in half_b]))))
    centre = np.array([0.5, 0.0, 0.0005]) + 1e-4 * n - 0.0005 * m2 - 0.3 * m1
    a = (HULL, np.zeros(3), np.eye(3), plate_a)
    for b in ((HULL, centre, RB, plate_b), (BOX, centre, RB, half_b)):
        points, normals, depths = _collide(a, b)
        assert len(depths) >= 2
        assert depths.max() == pytest.approx(1e-4, abs=1e-12)
        np.testing.assert_allclose(normals, np.tile(n, (len(depths), 1)), atol=1e-12)


def test_a_sphere_on_a_plates_edge_touches_at_its_own_point():
    # A sphere 1e-4 deep on the long edge of the 1 x 1 x 0.001 plate, from 60° above it:
    # its one contact lies at the sphere's own point (y = 0), not at a far corner.
    plate = hull_record(np.array(list(itertools.product([-0.5, 0.5], [-0.5, 0.5],
                                                        [-0.0005, 0.0005]))))
    u = np.array([0.5, 0.0, math.sqrt(3) / 2])
    edge = np.array([0.5, 0.0, 0.0005])
    centre = edge + (0.05 - 1e-4) * u
    points, normals, depths = _collide((SPHERE, centre, np.eye(3), np.array([0.05, 0, 0])),
                                       (HULL, np.zeros(3), np.eye(3), plate))
    assert len(depths) == 1
    np.testing.assert_allclose(normals[0], u, atol=1e-12)
    assert depths[0] == pytest.approx(1e-4, abs=1e-12)
    np.testing.assert_allclose(points[0], edge - 0.5e-4 * u, atol=1e-12)   # (midway)


def test_a_sphere_whose_centre_is_inside_a_hull_is_pushed_out_by_its_nearest_face():
    # Its centre 1.4e-4 inside the cube's corner along the diagonal: the depth is r plus
    # the centre's distance to its nearest face (all three equal: 1.4e-4 / √3), as the
    # box primitive has it; EPA on the centre (a point) and the hull (no curved part).
    r = 0.02
    rec = hull_record(np.array(list(itertools.product([-0.1, 0.1], repeat=3))))
    centre = np.full(3, 0.1) - 1.4e-4 / math.sqrt(3)
    sphere = (SPHERE, centre, np.eye(3), np.array([r, 0, 0]))
    want = r + 1.4e-4 / math.sqrt(3)
    box = (BOX, np.zeros(3), np.eye(3), np.full(3, 0.1))
    for b in ((HULL, np.zeros(3), np.eye(3), rec), box):
        _, normals, depths = _collide(sphere, b)
        assert depths.max() == pytest.approx(want, abs=1e-12)
        assert np.max(np.abs(normals[0])) == pytest.approx(1.0, abs=1e-12)   # (a face's)


def test_a_slightly_tilted_cube_hull_touches_a_box_at_the_corners_within_the_margin():
    # Tilted by (0.003, 0.0028, 0) rad, its lowest corner 2e-5 deep: three corners lie
    # within the 1e-3 margin (the fourth 1.14e-3 up), and the hull finds those three, as
    # the box primitive does.
    R = Rotation.from_rotvec([0.003, 0.0028, 0.0]).as_matrix()
    cube = np.array(list(itertools.product([-0.1, 0.1], repeat=3)))
    low = -np.min((cube @ R.T)[:, 2])
    ground = (BOX, np.array([0.0, 0.0, -0.5]), np.eye(3), np.array([1.0, 1.0, 0.5]))
    got = []
    for a in ((HULL, np.array([0, 0, low - 2e-5]), R, hull_record(cube)),
              (BOX, np.array([0, 0, low - 2e-5]), R, np.full(3, 0.1))):
        points, normals, depths = _collide(a, ground)
        got.append(np.sort(depths))
    assert len(got[0]) == 3
    np.testing.assert_allclose(got[0], got[1], atol=1e-12)


def test_a_tilted_hundred_gon_touches_at_its_lowest_vertex_though_its_cap_keeps_64():
    # A 100-sided prism's caps keep 64 of their corners; tilted 0.3 rad towards the
    # vertex at 3.6° (one the bottom cap leaves out), that vertex is the lowest: its
    # contact must still be the deepest, at the set depth, through the side faces at it.
    rec = hull_record(_prism(100, 0.1, 0.05))
    phi = math.radians(3.6)
    R = Rotation.from_rotvec(0.3 * np.array([-math.sin(phi), math.cos(phi), 0.0])).as_matrix()
    low = -np.min((_vertices(rec) @ R.T)[:, 2])
    ground = (BOX, np.array([0.0, 0.0, -0.5]), np.eye(3), np.array([1.0, 1.0, 0.5]))
    points, normals, depths = _collide((HULL, np.array([0, 0, low - 1e-5]), R, rec), ground)
    assert depths.max() == pytest.approx(1e-5, abs=1e-15)
    lowest = (_vertices(rec) @ R.T)[np.argmin((_vertices(rec) @ R.T)[:, 2])]
    np.testing.assert_allclose(points[np.argmax(depths)][:2], lowest[:2], atol=1e-15)


@pytest.mark.parametrize('theta_deg', [60.0, 89.0, 89.25, 89.45])
def test_a_cube_corner_past_a_thin_plates_edge_is_at_its_distance_from_the_edge(theta_deg):
    # A 0.2 x 0.2 x 0.001 plate (a hull of 8 vertices) and a cube hull turned so that its
    # corner P points at the plate's top edge, g beyond it along u, theta from the plate's
    # side face: the closed form is a point's distance to a box, g, with the witness
    # points P and its foot E on the edge, the contact at their middle, the normal u. The
    # plate's side (1 mm, under the 1e-3 m margin) lies within the margin of its top, but
    # its plane is nearly along u: taken as the feature, the gap along the normal to it
    # divided the normal's error by cos(90° − theta) (3.1e-7 m at 89.45°); the feature is
    # the edge at the top (the face most along u, as a box's).
    # Bound: EPA's normal on a corner and an edge (the inflated pair is curved there, of
    # radius eps = margin + 1e-3 of the size = 1.1e-3 m) is within sqrt(2 tol / eps) =
    # 4.3e-6 rad, tol = 1e-13 of the size (measured: 3.9e-6); the gap and the point move
    # by g times it at most (a line's point seen along the normal, or a plane within 45°
    # of it), measured 2.3e-9 m at most over 0-89.9°. 1e-5 rad leaves room for another
    # CPU's last bits: g * 1e-5, 9e-9 m.
    half = np.array([0.1, 0.1, 0.0005])
    plate = hull_record(np.array(list(itertools.product(*[[-h, h] for h in half]))))
    cube = hull_record(np.array(list(itertools.product([-0.05, 0.05], repeat=3))))
    theta = math.radians(theta_deg)
    u = np.array([math.cos(theta), 0.0, math.sin(theta)])
    E = np.array([0.1, 0.013, 0.0005])
    corner = np.full(3, -1.0) / math.sqrt(3)
    R = Rotation.align_vectors([-u], [corner])[0].as_matrix()
    for g in (5e-4, 9e-4):
        P = E + g * u
        a = (HULL, P - R @ (0.05 * math.sqrt(3) * corner), R, cube)
        for swap in (False, True):
            b = (HULL, np.zeros(3), np.eye(3), plate)
            points, normals, depths = _collide(b, a) if swap else _collide(a, b)
            assert len(depths) == 1, (g, swap)
            bound = g * 1e-5
            assert depths[0] == pytest.approx(-g, abs=bound), (g, swap)
            np.testing.assert_allclose(points[0], 0.5 * (P + E), rtol=0, atol=bound)
            np.testing.assert_allclose(normals[0], -u if swap else u, rtol=0, atol=1e-5)


def _capsule_distance(shape, x):
    """Return the signed distance of x to a capsule: to its axis segment, less its radius."""
    _, c, R, size = shape
    t = min(max((np.asarray(x) - c) @ R[:, 2], -size[1]), size[1])
    return float(np.linalg.norm(x - c - t * R[:, 2]) - size[0])


@pytest.mark.parametrize('about', ['normal', 'across'])
def test_a_capsule_nearly_along_a_cube_hulls_edge_touches_on_both_surfaces(about):
    # A capsule (radius 0.05, half length 0.1) along the top edge of a 0.2 m cube hull at
    # x = z = 0.1, the normal n between its two faces, turned by 0 to 3 mrad about n (its
    # line's sight along n crosses the edge's: they meet along n only there) or across it
    # (one end lower), 1e-4 deep or 5e-4 apart at its middle. Within the margin of
    # parallel (5 mrad for these lengths), both ends of the overlap are contacts. Each
    # contact's two surface points (point ∓ depth/2 n) lie on the capsule (its distance
    # to the axis less the radius) and on the cube (a box's signed distance) to rounding
    # of coordinates of 0.2 m, 1e-15 m (measured 3.5e-17; the end's point on the
    # capsule's line put it up to 1.1e-4 m off the cube at 3 mrad), and the deepest is
    # the pair's depth (the capsule's axis and the edge pass closest at the middle or at
    # the lower end: there its point lies on both lines), to the same.
    cube = hull_record(np.array(list(itertools.product([-0.1, 0.1], repeat=3))))
    box = (BOX, np.zeros(3), np.eye(3), np.full(3, 0.1))
    n = np.array([1.0, 0.0, 1.0]) / math.sqrt(2)
    axis = n if about == 'normal' else np.cross(n, [0.0, 1.0, 0.0])
    lying = Rotation.from_euler('x', -90, degrees=True).as_matrix()   # its z axis along +y
    for phi in np.linspace(0.0, 3e-3, 7):
        R = Rotation.from_rotvec(phi * axis).as_matrix() @ lying
        for depth in (1e-4, -5e-4):
            capsule = (CAPSULE, np.array([0.1, 0.02, 0.1]) + (0.05 - depth) * n, R,
                       np.array([0.05, 0.1, 0.0]))
            # The pair's depth: the capsule's radius less its axis' distance to the cube,
            # least (a convex function along the axis) at an end of the stretch of the
            # axis over the edge (an axis end, or its point nearest a corner), or where
            # their sights cross (the middle, turned about n).
            along = [min(max((np.array([0.1, y, 0.1]) - capsule[1]) @ R[:, 2], -0.1), 0.1)
                     for y in (-0.1, 0.1)] + [-0.1, 0.0, 0.1]
            want = 0.05 - min(_signed_distance(box, capsule[1] + t * R[:, 2]) for t in along)
            for a, b in ((capsule, (HULL, np.zeros(3), np.eye(3), cube)),
                         ((HULL, np.zeros(3), np.eye(3), cube), capsule)):
                points, normals, depths = _collide(a, b)
                assert len(depths) >= 2, (phi, depth)
                for p, m, d in zip(points, normals, depths):
                    for shape, x in ((a, p - 0.5 * d * m), (b, p + 0.5 * d * m)):
                        off = _capsule_distance(shape, x) if shape[0] == CAPSULE else \
                            _signed_distance(box, x)
                        assert abs(off) <= 1e-15, (phi, depth, off)
                assert depths.max() == pytest.approx(want, abs=1e-15), (phi, depth)
