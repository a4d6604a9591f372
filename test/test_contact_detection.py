"""
Collision shapes and the contact detector (issue 21, detection): specs, filters, pairs.

The detector's contacts are compared with the narrow phase run on every pair by
brute force (the broad phase may only drop pairs that have no contact), and its
refusals name the field and the problem.
"""

import numpy as np
import pytest
from rigid_body_sim.core.bodies import BodySet, RigidBody
from rigid_body_sim.core.errors import SpecError
from rigid_body_sim.core.kernels.contact import collide
from rigid_body_sim.core.rotation import exp_quat
from rigid_body_sim.core.shapes import CollisionShape, ContactDetector

TOL = 1e-12


def outputs(bodies):
    """Return the bodies' outputs, shape (n, O_WIDTH), at their initial state."""
    bs = BodySet.from_bodies(bodies)
    state = bs.initial_state(bodies)
    bs.outputs(state)
    return bs.outputs_cache.out


def brute(det, out):
    """Return every pair the detector may test, by the narrow phase alone: {(a, b): depths}."""
    c, R = det.frames(out)
    found = {}
    m = len(det.live)
    for i in range(m):
        for j in range(i + 1, m):
            if not det._meets(i, j):
                continue
            # The detector puts a plane second; the broad phase keeps i < j.
            a, b = (j, i) if det.kind[i] == 4 else (i, j)
            pts, nrm, dep = np.zeros((8, 3)), np.zeros((8, 3)), np.zeros(8)
            k = collide(int(det.kind[a]), c[a], R[a], det.size[a], int(det.kind[b]), c[b],
                        R[b], det.size[b], det.margin, pts, nrm, dep, 0)
            if k > 0:
                found[(int(det.live[a]), int(det.live[b]))] = np.sort(dep[:k])
    return found


def grouped(contacts):
    """Return the detector's contacts as {(shape a, shape b): sorted depths}."""
    out = {}
    for a, b, d in zip(contacts.shape_a, contacts.shape_b, contacts.depth):
        out.setdefault((int(a), int(b)), []).append(d)
    return {key: np.sort(v) for key, v in out.items()}


def test_the_detector_finds_what_every_pair_by_brute_force_finds():
    rng = np.random.default_rng(21)
    bodies, shapes = [], []
    for i in range(60):
        q = exp_quat(rng.normal(size=3))
        bodies.append(RigidBody(f'b{i}', 1.0, (0.1, 0.1, 0.1),
                                position_world=rng.uniform(0.0, 1.5, size=3),
                                orientation_xyzw=q))
        kind = ['sphere', 'box', 'capsule', 'cylinder'][i % 4]
        size = {'sphere': {'radius': rng.uniform(0.05, 0.2)},
                'box': {'size': rng.uniform(0.1, 0.4, size=3)},
                'capsule': {'radius': 0.05, 'length': rng.uniform(0.1, 0.4)},
                'cylinder': {'radius': 0.08, 'length': 0.2}}[kind]
        # Cylinders (group 2) meet only spheres and capsules (group 1) here: boxes (group
        # 4) and cylinders leave each other out of their masks.
        group, mask = {'cylinder': (2, 1), 'box': (4, 5)}.get(kind, (1, 7))
        shapes.append(CollisionShape(kind, f'b{i}', **size,
                                     position_body=rng.uniform(-0.05, 0.05, 3),
                                     group=group, mask=mask))
    shapes.append(CollisionShape('plane', None, position_body=(0, 0, 0.3)))
    det = ContactDetector(shapes, [b.name for b in bodies], excluded=[('b0', 'b4')],
                          margin=0.01)
    out = outputs(bodies)
    got = grouped(det.detect(out))
    want = brute(det, out)
    assert len(want) > 20 and set(got) == set(want)
    for key in want:
        np.testing.assert_allclose(got[key], want[key], atol=TOL)
    assert (0, 4) not in got and (4, 0) not in got


def test_shapes_of_one_body_and_of_joined_bodies_never_meet():
    bodies = [RigidBody('a', 1.0, (1, 1, 1)), RigidBody('b', 1.0, (1, 1, 1))]
    shapes = [CollisionShape('sphere', 'a', radius=0.5, name='a1'),
              CollisionShape('box', 'a', size=(1, 1, 1), name='a2'),
              CollisionShape('sphere', 'b', radius=0.5, name='b1')]
    out = outputs(bodies)
    assert len(ContactDetector(shapes, ['a', 'b']).detect(out).depth) == 2   # a1-b1, a2-b1
    assert len(ContactDetector(shapes, ['a', 'b'], excluded=[('a', 'b')])
               .detect(out).depth) == 0
    off = [CollisionShape('sphere', 'a', radius=0.5, collide=False, name='a1')] + shapes[1:]
    assert len(ContactDetector(off, ['a', 'b']).detect(out).depth) == 1


def test_a_shape_moves_with_its_body():
    q = exp_quat(np.array([0.0, 0.0, np.pi / 2]))
    bodies = [RigidBody('a', 1.0, (1, 1, 1), position_world=(0.0, 0.0, 0.5),
                        orientation_xyzw=q)]
    # 0.2 m along the body's x: along the world's y after the quarter turn.
    shapes = [CollisionShape('sphere', 'a', radius=0.5 + 1e-3, position_body=(0.2, 0.0, 0.0)),
              CollisionShape('plane', None, name='ground')]
    contacts = ContactDetector(shapes, ['a']).detect(outputs(bodies))
    np.testing.assert_allclose(contacts.point, [[0.0, 0.2, -5e-4]], atol=TOL)
    np.testing.assert_allclose(contacts.normal, [[0.0, 0.0, 1.0]], atol=TOL)
    np.testing.assert_allclose(contacts.depth, [1e-3], atol=TOL)
    assert contacts.body_a.tolist() == [0] and contacts.body_b.tolist() == [1]


def test_the_buffers_grow_when_a_crowd_overlaps():
    rng = np.random.default_rng(2)
    bodies = [RigidBody(f's{i}', 1.0, (1, 1, 1), position_world=rng.uniform(0, 0.5, 3))
              for i in range(200)]
    shapes = [CollisionShape('sphere', b.name, radius=0.2) for b in bodies]
    det = ContactDetector(shapes, [b.name for b in bodies])
    contacts = det.detect(outputs(bodies))
    # Spheres of radius 0.2 in a 0.5 m cube: most pairs overlap, far beyond 8 per shape.
    assert len(contacts.depth) > 8 * len(shapes)
    assert len(contacts.depth) == len(brute(det, outputs(bodies)))


@pytest.mark.parametrize('spec, field, message', [
    ({'kind': 'cone', 'radius': 1.0}, 'kind', "unknown shape 'cone'"),
    ({'kind': 'sphere'}, 'radius', 'a sphere needs its radius'),
    ({'kind': 'sphere', 'radius': 0.0}, 'radius', 'must be positive'),
    ({'kind': 'sphere', 'radius': float('nan')}, 'radius', 'must be finite'),
    ({'kind': 'sphere', 'radius': 1.0, 'size': (1, 1, 1)}, 'size', 'a sphere takes'),
    ({'kind': 'box', 'size': (1, 0, 1)}, 'size', 'must be positive'),
    ({'kind': 'box', 'size': (1, 1)}, 'size', 'expected shape'),
    ({'kind': 'capsule', 'radius': 0.1}, 'length', 'needs its length'),
    ({'kind': 'plane', 'body': 'a'}, 'body', "a plane is the world's"),
    ({'kind': ['sphere'], 'radius': 1.0}, 'kind', 'unknown shape'),
    ({'kind': 'sphere', 'radius': 1.0, 'friction': -0.1}, 'friction', 'non-negative'),
    ({'kind': 'sphere', 'radius': 1.0, 'restitution': 1.5}, 'restitution', r'in \[0, 1\]'),
    ({'kind': 'sphere', 'radius': 1.0, 'collide': 'yes'}, 'collide', 'true or false'),
    ({'kind': 'sphere', 'radius': 1.0, 'group': -1}, 'group', 'integer in'),
    ({'kind': 'sphere', 'radius': 1.0, 'mask': 2.5}, 'mask', 'integer in'),
    ({'kind': 'sphere', 'radius': 1.0, 'orientation_xyzw': (0, 0, 0, 2)}, 'orientation_xyzw', ''),
])
def test_a_bad_shape_is_refused_naming_the_field(spec, field, message):
    with pytest.raises(SpecError, match=f'^{field}: .*{message}'):
        CollisionShape(**spec)


def test_a_detector_refuses_unknown_bodies_twice_named_shapes_and_pairs_it_cannot_test():
    with pytest.raises(SpecError, match=r"shapes\[0\]\.body: unknown body 'x'"):
        ContactDetector([CollisionShape('sphere', 'x', radius=1.0)], ['a'])
    with pytest.raises(SpecError, match=r'excluded\[0\]: expected a pair of body names'):
        ContactDetector([CollisionShape('sphere', 'a', radius=1.0)], ['a'],
                        excluded=[('a', 'x')])
    with pytest.raises(SpecError, match=r"shape names used twice: \['a/sphere'\]"):
        ContactDetector([CollisionShape('sphere', 'a', radius=1.0)] * 2, ['a'])
    # A cylinder overlapping a box: contacts (GJK and EPA); kept apart by their filters
    # (neither's group in the other's mask), or joined, none.
    cyl = CollisionShape('cylinder', 'a', radius=0.1, length=0.2)
    box = CollisionShape('box', 'b', size=(1, 1, 1))
    cyl_1 = CollisionShape('cylinder', 'a', radius=0.1, length=0.2, group=1, mask=1)
    box_2 = CollisionShape('box', 'b', size=(1, 1, 1), group=2, mask=2)
    out = outputs([RigidBody('a', 1.0, (1, 1, 1)), RigidBody('b', 1.0, (1, 1, 1))])
    assert len(ContactDetector([cyl, box], ['a', 'b']).detect(out).depth) > 0
    assert len(ContactDetector([cyl_1, box_2], ['a', 'b']).detect(out).depth) == 0
    assert len(ContactDetector([cyl, box], ['a', 'b'], excluded=[('a', 'b')])
               .detect(out).depth) == 0
