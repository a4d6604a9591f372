"""
Collision shapes of bodies and of the world, and the contacts between them (detection).

A :class:`CollisionShape` is a primitive fixed to a body (or to the world): a sphere,
a box, a capsule, a cylinder, a mesh (simulated as its convex hull: :mod:`.hulls`), or,
for the world only, a plane (a half-space: a ground). Sizes follow URDF's
``<collision>`` geometry: a sphere's ``radius``; a box's full ``size`` along its axes; a
capsule's and a cylinder's ``radius`` and ``length`` along the shape's z axis (a
capsule's length is that of its axis, the caps beyond it); a mesh's file (STL or OBJ)
or vertices and its ``scale``. A plane's normal is its z axis; it is solid below.

:class:`ContactDetector` finds, for the bodies' poses after a step, every pair of
shapes within a margin of each other and their contacts (:mod:`.kernels.contact`:
points, normals from shape ``b`` to shape ``a``, depths): a broad phase on the
shapes' boxes (a hashed uniform grid: ``O(m)`` for ``m`` shapes of like sizes at a
bounded density, plus the pairs it finds) and a narrow phase per pair. Pairs never
tested: two shapes of one body, shapes whose filters exclude each other (``group``
and ``mask`` bits: a pair is tested when one's group meets the other's mask,
MuJoCo's ``contype`` and ``conaffinity``), shapes with ``collide: false``, and the
pairs of bodies the caller excludes (bodies joined by a joint). Every pair of kinds
has a narrow phase (a cylinder on a box or on a cylinder, and a hull on anything, by
GJK and EPA: :mod:`.kernels.convex`).

Contact forces are not here yet: this module is detection only (issue 21's rows
build on it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Optional, Sequence

import numpy as np

from .errors import SpecError
from .hulls import centred_hull, hull_record, read_vertices
from .kernels.contact import all_bounds, broad_phase, narrow_phase, plane_pairs, Shape, \
    shape_frames
from .rotation import quat_to_matrix
from .validate import finite_array, finite_scalar, nonnegative_scalar, positive_scalar, \
    unit_quaternion

#: The kinds by name, and the sizes each takes (URDF's attribute names).
KINDS = {'sphere': Shape.SPHERE, 'box': Shape.BOX, 'capsule': Shape.CAPSULE,
         'cylinder': Shape.CYLINDER, 'plane': Shape.PLANE, 'mesh': Shape.HULL}
SIZES = {'sphere': ('radius',), 'box': ('size',), 'capsule': ('radius', 'length'),
         'cylinder': ('radius', 'length'), 'plane': (), 'mesh': ('mesh', 'scale')}
#: Sizes a kind may leave out (a mesh's scale: 1).
OPTIONAL = ('scale',)
#: m: contacts are reported up to this gap by default (a contact about to close).
DEFAULT_MARGIN = 1e-3
#: Every group bit (the default group and mask: everything meets everything).
ALL_BITS = (1 << 31) - 1
#: The columns of :meth:`CollisionShape.row` (the filter bits, < 2³¹, are exact floats).
ROW = {'collide': 0, 'kind': 1, 'size': slice(2, 5), 'position_body': slice(5, 8),
       'orientation_xyzw': slice(8, 12), 'group': 12, 'mask': 13, 'friction': 14,
       'restitution': 15}
ROW_WIDTH = 16


@dataclass(frozen=True)
class CollisionShape:
    """
    A collision shape fixed to a body or to the world (validated on construction).

    Parameters
    ----------
    kind : str
        ``'sphere'``, ``'box'``, ``'capsule'``, ``'cylinder'``, ``'mesh'`` or ``'plane'``.
    body : str or None
        The body it is fixed to; None: the world (a plane must be the world's).
    radius, length : float
        m, > 0: a sphere's radius; a capsule's and a cylinder's radius and length
        (along the shape's z axis).
    size : array_like, shape (3,)
        m, > 0: a box's full size along its x, y, z axes.
    mesh : str or array_like, shape (N, 3)
        A mesh's file (STL or OBJ; its units are taken as m) or its vertices (m, in the
        shape's frame); simulated as their convex hull (:mod:`.hulls`).
    scale : array_like, shape (3,)
        A mesh's scale along its x, y, z axes (URDF's ``<mesh scale>``), non-zero (a
        negative one mirrors it); default 1.
    position_body : array_like, shape (3,)
        m, the shape's centre in the body frame (a plane: a point on it).
    orientation_xyzw : array_like, shape (4,)
        The shape's axes in the body frame (a plane: its normal is the z axis).
    friction : float
        Coulomb's coefficient, ≥ 0.
    restitution : float
        Newton's coefficient, in [0, 1].
    collide : bool
        False: the shape meets nothing (drawn, never tested).
    group, mask : int
        Filter bits in [0, 2³¹): two shapes are tested when ``group`` of one meets
        ``mask`` of the other.
    name : str
        What errors and reports call it (default: ``<body>/<kind>``).

    """

    kind: str
    body: Optional[str] = None
    radius: Any = None
    length: Any = None
    size: Any = None
    mesh: Any = None
    scale: Any = None
    position_body: Any = (0.0, 0.0, 0.0)
    orientation_xyzw: Any = (0.0, 0.0, 0.0, 1.0)
    friction: Any = 1.0
    restitution: Any = 0.0
    collide: bool = True
    group: int = 1
    mask: int = ALL_BITS
    name: str = ''

    def __post_init__(self) -> None:
        if not isinstance(self.kind, str) or self.kind not in KINDS:
            raise SpecError('kind', f'unknown shape {self.kind!r}; known: {sorted(KINDS)}')
        if self.body is not None and (not isinstance(self.body, str) or not self.body):
            raise SpecError('body', f'must be a body name or None (the world), got '
                                    f'{self.body!r}')
        if self.kind == 'plane' and self.body is not None:
            raise SpecError('body', f"a plane is the world's (a ground), not body "
                                    f"{self.body!r}'s: give a box instead")
        want = SIZES[self.kind]
        for key in ('radius', 'length', 'size', 'mesh', 'scale'):
            given = getattr(self, key) is not None
            if given and key not in want:
                raise SpecError(key, f'a {self.kind} takes {list(want) or "no size"}, '
                                     f'not {key}')
            if not given and key in want and key not in OPTIONAL:
                raise SpecError(key, f'a {self.kind} needs its {key} (m)')
        conv = {'position_body': finite_array(self.position_body, 'position_body', (3,)),
                'orientation_xyzw': unit_quaternion(self.orientation_xyzw,
                                                    'orientation_xyzw'),
                'friction': nonnegative_scalar(self.friction, 'friction'),
                'restitution': finite_scalar(self.restitution, 'restitution')}
        if 'radius' in want:
            conv['radius'] = positive_scalar(self.radius, 'radius')
        if 'length' in want:
            conv['length'] = positive_scalar(self.length, 'length')
        if 'size' in want:
            size = finite_array(self.size, 'size', (3,))
            if not np.all(size > 0.0):
                raise SpecError('size', f'must be positive, got {self.size!r}')
            conv['size'] = size
        if self.kind == 'mesh':
            scale = np.ones(3) if self.scale is None else finite_array(self.scale, 'scale',
                                                                       (3,))
            if not np.all(scale != 0.0):   # (negative: mirrored, as URDF allows)
                raise SpecError('scale', f'must be non-zero, got {self.scale!r}')
            conv['scale'] = scale
            if isinstance(self.mesh, str) or hasattr(self.mesh, '__fspath__'):
                verts = read_vertices(self.mesh, 'mesh')
            else:
                try:
                    verts = np.array(self.mesh, dtype=float)
                except (TypeError, ValueError):
                    raise SpecError('mesh', f'expected a file name or vertices (N, 3), got '
                                            f'{self.mesh!r}') from None
            rec = hull_record(verts * scale, 'mesh')
            object.__setattr__(self, '_hull', rec)
            object.__setattr__(self, '_centred', centred_hull(rec))
        if not 0.0 <= conv['restitution'] <= 1.0:
            raise SpecError('restitution', f'must be in [0, 1], got {self.restitution!r}')
        if not isinstance(self.collide, (bool, np.bool_)):
            raise SpecError('collide', f'expected true or false, got {self.collide!r}')
        for key in ('group', 'mask'):
            bits = getattr(self, key)
            if isinstance(bits, bool) or not isinstance(bits, (int, np.integer)) \
                    or not 0 <= bits <= ALL_BITS:
                raise SpecError(key, f'must be an integer in [0, 2^31), got {bits!r}')
        if not isinstance(self.name, str):
            raise SpecError('name', f'must be a string, got {self.name!r}')
        for key, value in conv.items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, key, value)
        if not self.name:
            object.__setattr__(self, 'name', f'{self.body or "world"}/{self.kind}')
        # (a mesh's row is its hull's about that hull's own centre: centred_hull)
        centre = np.asarray(self.position_body) if self.kind != 'mesh' else \
            self.position_body + quat_to_matrix(self.orientation_xyzw) @ self._centred[1]
        object.__setattr__(self, '_row', (
            float(self.collide), float(KINDS[self.kind]), *self.dimensions(),
            *centre, *self.orientation_xyzw, float(self.group), float(self.mask),
            self.friction, self.restitution))

    def row(self) -> tuple:
        """
        Return the detector's numbers of this shape, made once (:data:`ROW` names them).

        A detector's tables are these rows stacked: rebuilding one for a scene with a
        shape more (a spawn) costs a copy of the others' numbers, not their making.
        """
        return self._row

    @property
    def hull(self) -> Optional[np.ndarray]:
        """Return a mesh's convex hull, packed (:func:`.hulls.hull_record`); None: a primitive."""
        return getattr(self, '_hull', None)

    @property
    def centred_hull(self) -> Optional[np.ndarray]:
        """
        Return a mesh's hull about its own centre (:func:`.hulls.centred_hull`).

        The record the detector and the markers use, at :attr:`hull_centre` (None: a
        primitive).
        """
        return self._centred[0] if self.kind == 'mesh' else None

    @property
    def hull_centre(self) -> Optional[np.ndarray]:
        """Return the centre of a mesh's hull's box (3,) m, shape frame (None: a primitive)."""
        return self._centred[1] if self.kind == 'mesh' else None

    def dimensions(self) -> np.ndarray:
        """Return the kernels' size (3,): radius; half extents (a hull's about its centre)..."""
        if self.kind == 'sphere':
            return np.array([self.radius, 0.0, 0.0])
        if self.kind == 'box':
            return 0.5 * np.asarray(self.size)
        if self.kind in ('capsule', 'cylinder'):
            return np.array([self.radius, 0.5 * self.length, 0.0])
        if self.kind == 'mesh':
            return np.array(self.centred_hull[:3])
        return np.zeros(3)


class Contacts(NamedTuple):
    """
    The contacts found at one state (``c`` of them).

    ``shape_a``, ``shape_b`` (c,): indices into the detector's shapes; ``body_a``,
    ``body_b`` (c,): their bodies (the world is the number of bodies); ``point`` (c,
    3) m, midway between the surfaces; ``normal`` (c, 3), unit, from ``b`` to ``a``;
    ``depth`` (c,) m, the overlap along the normal (negative: a gap within the
    margin).
    """

    shape_a: np.ndarray
    shape_b: np.ndarray
    body_a: np.ndarray
    body_b: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    depth: np.ndarray


class ContactDetector:
    """
    The contacts of a set of shapes on bodies, at the bodies' poses.

    Parameters
    ----------
    shapes : sequence of CollisionShape
    body_names : sequence of str
        The bodies, in the order of the poses :meth:`detect` is given; every
        shape's body must be one of them.
    excluded : iterable of (str, str)
        Body pairs whose shapes never meet (bodies joined by a joint; None names
        the world).
    margin : float
        m, ≥ 0: contacts are reported up to this gap.

    Raises
    ------
    SpecError
        A shape on an unknown body, or two shapes of one name.

    """

    def __init__(self, shapes: Sequence[CollisionShape], body_names: Sequence[str],
                 excluded: Any = (), margin: float = DEFAULT_MARGIN) -> None:
        self.shapes = list(shapes)
        self.margin = nonnegative_scalar(margin, 'margin')
        index = {name: i for i, name in enumerate(body_names)}
        n = self.n_bodies = len(body_names)
        names = [s.name for s in self.shapes]
        seen: set = set()
        twice = sorted({x for x in names if x in seen or seen.add(x)})
        if twice:
            raise SpecError('shapes', f'shape names used twice: {twice} (name them)')
        body = np.array([n if s.body is None else index.get(s.body, -1) for s in self.shapes],
                        dtype=np.int64)
        if np.any(body < 0):
            k = int(np.argmax(body < 0))
            raise SpecError(f'shapes[{k}].body', f'unknown body {self.shapes[k].body!r}')
        #: Every shape's numbers (a row each, :data:`ROW`): the friction and restitution
        #: the contact rows read, the rest the kernels' tables below.
        self.table = np.array([s.row() for s in self.shapes], dtype=float).reshape(
            len(self.shapes), ROW_WIDTH)
        live = np.flatnonzero(self.table[:, ROW['collide']] > 0.0)
        m = len(live)
        rows = self.table[live]
        #: Indices of the shapes that collide (the kernels' rows), and per row its data.
        self.live = live.astype(np.int64)
        self.body = body[live]
        self.kind = rows[:, ROW['kind']].astype(np.int64)
        self.size = rows[:, ROW['size']].copy()
        # The hulls' records, one after another (their rows' starts in hull_at).
        records, at, self.hull_at = [], 0, np.full(m, -1, dtype=np.int64)
        for row in np.flatnonzero(self.kind == int(Shape.HULL)):
            rec = self.shapes[live[row]].centred_hull   # (its row's centre: its own)
            self.hull_at[row] = at
            records.append(rec)
            at += len(rec)
        self.hulls = np.concatenate(records) if records else np.zeros(1)
        self.c_body = rows[:, ROW['position_body']].copy()
        self.R_body = quat_to_matrix(rows[:, ROW['orientation_xyzw']].copy())
        self.group = rows[:, ROW['group']].astype(np.int64)
        self.mask = rows[:, ROW['mask']].astype(np.int64)
        self._index = index
        self.excluded = self._codes(excluded)
        plane = self.kind == int(Shape.PLANE)
        self._planes = np.flatnonzero(plane)
        self._solids = np.flatnonzero(~plane)
        self._solid_body = self.body[self._solids]
        self._solid_group = self.group[self._solids]
        self._solid_mask = self.mask[self._solids]
        self._pairs = np.zeros((max(4 * m, 16), 2), dtype=np.int64)
        self._plane_pairs = np.zeros((max(len(self._solids) * len(self._planes), 1), 2),
                                     dtype=np.int64)
        cap = max(8 * m, 16)
        self._points, self._normals = np.zeros((cap, 3)), np.zeros((cap, 3))
        self._depths, self._owner = np.zeros(cap), np.zeros(cap, dtype=np.int64)
        self.counters = {'detections': 0, 'pairs_tested': 0, 'contacts': 0}

    def _codes(self, excluded: Any) -> np.ndarray:
        """Return the sorted codes of the excluded body pairs (names; None: the world)."""
        index, n = self._index, self.n_bodies
        codes = set()
        for k, pair in enumerate(excluded):
            if isinstance(pair, str) or len(pair) != 2 \
                    or any(x is not None and x not in index for x in pair):
                raise SpecError(f'excluded[{k}]', f'expected a pair of body names (None: '
                                                  f'the world), got {pair!r}')
            a, b = (n if x is None else index[x] for x in pair)
            codes.add(min(a, b) * (n + 1) + max(a, b))
        return np.array(sorted(codes), dtype=np.int64)

    def exclude(self, excluded: Any) -> None:
        """Replace the excluded body pairs (a joint added or removed at run time)."""
        self.excluded = self._codes(excluded)

    def _meets(self, i: int, j: int) -> bool:
        """Tell whether rows ``i`` and ``j`` may ever be tested (bodies, filters, exclusions)."""
        bi, bj = self.body[i], self.body[j]
        if bi == bj:
            return False
        if not (self.group[i] & self.mask[j] or self.group[j] & self.mask[i]):
            return False
        code = min(bi, bj) * (self.n_bodies + 1) + max(bi, bj)
        e = np.searchsorted(self.excluded, code)
        return not (e < len(self.excluded) and self.excluded[e] == code)

    def frames(self, out: np.ndarray) -> tuple:
        """Return the shapes' centres (m, 3; a mesh's: its hull's) and rotations at ``out``."""
        m = len(self.live)
        c, R = np.empty((m, 3)), np.empty((m, 3, 3))
        shape_frames(out, self.body, self.c_body, self.R_body, c, R)
        return c, R

    def detect(self, out: np.ndarray) -> Contacts:
        """
        Return the contacts at the bodies' outputs ``out`` (n, O_WIDTH).

        ``out`` holds each body frame's origin and orientation in the world
        (:data:`.kernels.layout.OUTPUT`), as :meth:`.BodySet.outputs` makes them.
        """
        if out.shape[0] != self.n_bodies:
            raise ValueError(f'detect: outputs of {out.shape[0]} bodies, the detector has '
                             f'{self.n_bodies}')
        c, R = self.frames(out)
        solids = self._solids
        ms = len(solids)
        lo, hi = np.empty((ms, 3)), np.empty((ms, 3))
        all_bounds(self.kind, c, R, self.size, solids, self.margin, lo, hi)
        while True:
            k = broad_phase(lo, hi, self._solid_body, self._solid_group, self._solid_mask,
                            self.n_bodies, self.excluded, self._pairs)
            if k <= len(self._pairs):
                break
            self._pairs = np.zeros((2 * k, 2), dtype=np.int64)
        while True:
            kp = plane_pairs(solids, self._planes, self.body, self.group, self.mask,
                             self.n_bodies, self.excluded, self._plane_pairs)
            if kp <= len(self._plane_pairs):
                break
            self._plane_pairs = np.zeros((2 * kp, 2), dtype=np.int64)
        pairs = np.concatenate([solids[self._pairs[:k]].reshape(-1, 2),
                                self._plane_pairs[:kp]])
        while True:
            count = narrow_phase(pairs, self.kind, c, R, self.size, self.hulls, self.hull_at,
                                 self.margin, self._points, self._normals, self._depths,
                                 self._owner)
            if count <= len(self._depths):
                break
            cap = 2 * count
            self._points, self._normals = np.zeros((cap, 3)), np.zeros((cap, 3))
            self._depths, self._owner = np.zeros(cap), np.zeros(cap, dtype=np.int64)
        self.counters['detections'] += 1
        self.counters['pairs_tested'] += len(pairs)
        self.counters['contacts'] += count
        which = pairs[self._owner[:count]] if count else np.zeros((0, 2), dtype=np.int64)
        return Contacts(self.live[which[:, 0]], self.live[which[:, 1]], self.body[which[:, 0]],
                        self.body[which[:, 1]], self._points[:count].copy(),
                        self._normals[:count].copy(), self._depths[:count].copy())
