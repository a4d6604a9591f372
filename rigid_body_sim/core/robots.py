"""
Robots: a tree of links and joints (as URDF describes one) -> bodies, joints, joint space.

The core never sees XML: :mod:`rigid_body_sim.scene` parses URDF and xacro into
the plain specs here (:class:`LinkSpec`, :class:`JointSpec`, :class:`RobotSpec`),
and :func:`build_robot` turns them into the same bodies and constraints a YAML
scene gives, plus the map between the maximal state and joint coordinates
(:class:`JointSpace`).

Conventions (URDF's)
--------------------
* A joint's frame J sits in its parent link's frame P at ``origin`` (xyz, and
  rpy: roll about x, then pitch about y, then yaw about z, fixed axes, so
  ``R = Rz(yaw) Ry(pitch) Rx(roll)``). The child link's frame C is J moved by
  the joint: rotated by q about ``axis`` (revolute, continuous) or translated
  by ``q axis`` (prismatic); ``axis`` is a unit vector in J. At q = 0, C = J.
* A link's ``inertial`` gives its mass, its centre of mass and the axes of its
  inertia tensor in the link frame (``origin``), and the tensor in those axes;
  in the link frame the tensor is ``R I Rᵀ``.

Conversion rules
----------------
* Links joined by a ``fixed`` joint are lumped into one body (masses, centres
  of mass and inertias combined exactly, by the parallel-axis theorem), whose
  frame is the frame of the group's topmost link; a fixed joint listed in
  ``keep_fixed`` is kept instead, as a weld (a ``fixed`` constraint) whose
  reaction wrench is published: a force/torque sensor.
* A link named ``world`` is the world. The root link is welded to the world
  when the robot has a ``world`` link or ``fixed_base`` is set (then it, and
  every link lumped with it, is part of the world: it never moves); else it
  floats. Either way the root (a ``world`` link too) starts at ``base_pose``.
* revolute and continuous joints become hinges, prismatic joints sliders,
  planar joints planar constraints (3 rows), floating joints nothing; a body
  whose links have no mass, on a joint that moves, is an error naming it.
* Joint coordinates are 0 in the URDF's zero configuration, as the URDF's
  frames put it; revolute and continuous angles unwrap (they count turns).
* A ``mimic`` joint (``q_f = k q_l + c``, follower f, leader l) is one more
  constraint row, ``mimic`` (:class:`.constraints.Coupling`), over the
  follower's two bodies and the leader's (a row of up to four bodies): exact,
  as every joint, where MuJoCo and Gazebo make it a soft equality or a
  controller. Its multiplier is the follower's effort (``−λ``) and adds ``kλ``
  to the leader's. The follower's initial position and velocity follow the
  leader's (a different one given is an error). Both joints must be revolute or
  prismatic (not continuous: the row takes each angle within π of a reference,
  the middle of the leader's limits, so a turning joint is refused); mimic
  chains are followed, cycles refused.

Joint efforts act as equal and opposite wrenches on the joint's two bodies:
a torque ``τ k`` about the axis (revolute), a force ``τ k`` along it applied on
the axis line (prismatic), so the pair exerts no net wrench on the robot and
does work ``τ q̇`` exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import enum
from typing import Any, Optional, Sequence

import numpy as np

from . import rotation as so3
from .bodies import RigidBody
from .constraints import Constraint, Coupling, DriveGeometry, JointType, perpendicular_frame
from .effects import Effect, KernelModel, Kinematics, WrenchAccumulator
from .errors import SpecError
from .kernels.free_step import HAS_DRIVE_DAMPING, HAS_DRIVES
from .kernels.joints import joint_coordinates, joint_coordinates_within
from .kernels.layout import (J_WATCH_HIGH, J_WATCH_LOW, JOINT, O_ANG_VEL_WORLD,
                             O_ORIGIN_VEL_WORLD, O_ORIGIN_WORLD, O_QUAT_BODY_WORLD, W_BODY,
                             W_CENTER, W_DAMPING, W_E1_CHILD, W_E1_PARENT, W_E2_PARENT,
                             W_EFFORT_MAX, W_K_CHILD, W_K_PARENT, W_KD, W_KIND, W_KP, W_PARENT,
                             W_Q_TARGET, W_R_CHILD, W_R_PARENT, W_ROTARY, W_V_TARGET, W_WIDTH,
                             WRENCH_DRIVE)
from .validate import finite_array, finite_scalar


class JointKind(enum.Enum):
    """URDF joint types."""

    REVOLUTE = 'revolute'
    CONTINUOUS = 'continuous'
    PRISMATIC = 'prismatic'
    FIXED = 'fixed'
    FLOATING = 'floating'
    PLANAR = 'planar'


#: Joint kinds with one coordinate (the joints of ``sensor_msgs/JointState``).
ONE_DOF = (JointKind.REVOLUTE, JointKind.CONTINUOUS, JointKind.PRISMATIC)
ROTARY = (JointKind.REVOLUTE, JointKind.CONTINUOUS)

#: The name of the link that is the world, as URDF uses it.
WORLD_LINK = 'world'


def rpy_matrix(rpy: Any) -> np.ndarray:
    """Rotation matrix (3, 3) of URDF roll, pitch, yaw (rad): ``Rz(y) Ry(p) Rx(r)``."""
    r, p, y = np.asarray(rpy, dtype=float)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def axis_angle_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) by ``angle`` (rad) about the unit vector ``axis`` (3,)."""
    k = so3.hat(axis)
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


@dataclass(frozen=True)
class LinkSpec:
    """
    One URDF link's inertial properties.

    Parameters
    ----------
    name : str
    mass : float
        kg, >= 0 (0: no ``<inertial>``).
    com_link : array_like, shape (3,)
        m, centre of mass in the link frame.
    inertia_link : array_like, shape (3, 3)
        kg m², about the centre of mass, in the link frame's axes.

    """

    name: str
    mass: float = 0.0
    com_link: Any = (0.0, 0.0, 0.0)
    inertia_link: Any = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SpecError('name', f'must be a non-empty string, got {self.name!r}')
        mass = finite_scalar(self.mass, 'mass')
        if mass < 0.0:
            raise SpecError('mass', f'must be >= 0, got {mass!r}')
        object.__setattr__(self, 'mass', mass)
        object.__setattr__(self, 'com_link', finite_array(self.com_link, 'com_link', (3,)))
        inertia = finite_array(self.inertia_link, 'inertia_link', (3, 3))
        object.__setattr__(self, 'inertia_link', 0.5 * (inertia + inertia.T))


@dataclass(frozen=True)
class JointSpec:
    """
    One URDF joint.

    Parameters
    ----------
    name : str
    kind : JointKind or str
    parent, child : str
        Link names.
    origin_xyz : array_like, shape (3,)
        m, the joint frame's origin in the parent link frame.
    origin_rpy : array_like, shape (3,)
        rad, its orientation (URDF roll, pitch, yaw).
    axis : array_like, shape (3,)
        In the joint frame; normalized here (URDF's default is 1 0 0).
    lower, upper : float, optional
        rad or m: position limits (enforced by :mod:`.limits` unless the robot's
        ``enforce_limits`` is false).
    effort : float, optional
        N m or N: the largest effort; commands beyond it are clamped (counted).
        0 (a common placeholder) means no limit, as for ``velocity``, and is
        noted at load.
    velocity : float, optional
        rad/s or m/s: the largest speed; excursions are counted (0: no limit).
    damping, friction : float
        N m s/rad (N s/m), N m (N): from ``<dynamics>``.
    mimic : tuple, optional
        ``(joint, multiplier, offset)``: this joint follows ``multiplier q + offset``.

    """

    name: str
    kind: Any
    parent: str
    child: str
    origin_xyz: Any = (0.0, 0.0, 0.0)
    origin_rpy: Any = (0.0, 0.0, 0.0)
    axis: Any = (1.0, 0.0, 0.0)
    lower: Optional[float] = None
    upper: Optional[float] = None
    effort: Optional[float] = None
    velocity: Optional[float] = None
    damping: float = 0.0
    friction: float = 0.0
    mimic: Optional[tuple] = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SpecError('name', f'must be a non-empty string, got {self.name!r}')
        try:
            kind = JointKind(self.kind.value if isinstance(self.kind, JointKind) else self.kind)
        except ValueError:
            raise SpecError('type', f'unknown joint type {self.kind!r}; known: '
                                    f'{[k.value for k in JointKind]}') from None
        object.__setattr__(self, 'kind', kind)
        for key in ('parent', 'child'):
            if not isinstance(getattr(self, key), str) or not getattr(self, key):
                raise SpecError(key, f'must name a link, got {getattr(self, key)!r}')
        if self.parent == self.child:
            raise SpecError('child', f'a joint cannot join link {self.child!r} to itself')
        object.__setattr__(self, 'origin_xyz', finite_array(self.origin_xyz, 'origin.xyz', (3,)))
        object.__setattr__(self, 'origin_rpy', finite_array(self.origin_rpy, 'origin.rpy', (3,)))
        axis = finite_array(self.axis, 'axis', (3,))
        norm = float(np.linalg.norm(axis))
        if kind in ONE_DOF + (JointKind.PLANAR,) and not norm > 1e-12:
            raise SpecError('axis', f'zero-length axis {axis.tolist()}')
        object.__setattr__(self, 'axis', axis / norm if norm > 0.0 else axis)
        for key in ('lower', 'upper', 'effort', 'velocity'):
            value = getattr(self, key)
            if value is not None:
                object.__setattr__(self, key, finite_scalar(value, f'limit.{key}'))
        for key in ('effort', 'velocity'):
            value = getattr(self, key)
            if value is not None and value < 0.0:
                raise SpecError(f'limit.{key}', f'must be >= 0, got {value!r}')
        if self.lower is not None and self.upper is not None and self.lower > self.upper:
            raise SpecError('limit', f'lower {self.lower!r} is above upper {self.upper!r}')
        for key in ('damping', 'friction'):
            value = finite_scalar(getattr(self, key), f'dynamics.{key}')
            if value < 0.0:
                raise SpecError(f'dynamics.{key}', f'must be >= 0, got {value!r}')
            object.__setattr__(self, key, value)
        if self.mimic is not None:
            joint, multiplier, offset = self.mimic
            if not isinstance(joint, str) or not joint:
                raise SpecError('mimic.joint', f'must name a joint, got {joint!r}')
            object.__setattr__(self, 'mimic', (joint, finite_scalar(multiplier,
                                                                    'mimic.multiplier'),
                                               finite_scalar(offset, 'mimic.offset')))

    @property
    def origin(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the joint frame in the parent link frame: position (3,), rotation (3, 3)."""
        return np.asarray(self.origin_xyz), rpy_matrix(self.origin_rpy)

    def motion(self, q: float) -> tuple[np.ndarray, np.ndarray]:
        """Return the child frame in the joint frame at coordinate ``q``: (3,), (3, 3)."""
        if self.kind in ROTARY:
            return np.zeros(3), axis_angle_matrix(self.axis, q)
        if self.kind is JointKind.PRISMATIC:
            return q * self.axis, np.eye(3)
        return np.zeros(3), np.eye(3)


@dataclass(frozen=True)
class RobotSpec:
    """
    A robot as parsed: its links and joints, and where and how it starts.

    Parameters
    ----------
    name : str
    links : sequence of LinkSpec
    joints : sequence of JointSpec
        A tree: each link is the child of at most one joint, and one link (the
        root) of none.
    base_xyz : array_like, shape (3,)
        m, the root link's origin in the world (a link named ``world`` included:
        the robot's world frame is placed there).
    base_quat_xyzw : array_like, shape (4,)
        The root link's orientation in the world.
    fixed_base : bool
        Weld the root link to the world (also implied by a link named ``world``).
    initial_positions, initial_velocities : dict
        ``{joint: q}`` and ``{joint: q̇}`` (rad, m; rad/s, m/s); others start at 0.
    keep_fixed : sequence of str
        Fixed joints kept as welds (with a published reaction) instead of lumped.
    prefix : str
        Prepended to every link and joint name in the simulation (several
        robots of the same URDF in one scene).
    source : str
        Where the robot came from (a file), for messages.
    enforce_limits : bool
        Hold the joints within their URDF ``<limit lower upper>`` (:mod:`.limits`).
    limit_restitution : float or dict
        Newton's restitution ``e`` in [0, 1] at the joints' bounds: one for all, or
        ``{joint: e}`` by URDF joint name (others 0).
    enforce_friction : bool
        Simulate the joints' URDF ``<dynamics friction>`` (Coulomb, :mod:`.limits`).
    enforce_efforts : bool
        Bound the exact drives' efforts by the joints' URDF ``<limit effort>``
        (:class:`.limits.DriveEfforts`; servos and effort commands are clamped either way).
    collisions : sequence of tuple
        The links' collision shapes, ``(link, kind, size, xyz, rpy)``: ``kind`` 'box'
        (``size`` its sides), 'cylinder' (radius, length) or 'sphere' (radius,), posed
        in the link's frame as URDF's ``<collision><origin>``; each becomes a
        :class:`.shapes.CollisionShape` on the link's body (:meth:`.Simulation._robot_shapes`).
    self_collide : bool
        Whether the robot's links meet each other (beyond the pairs its joints join,
        which never do); False (Gazebo's default): they meet only other bodies and the
        world.
    collision_options : dict
        Its shapes' ``friction``, ``restitution``, ``group`` and ``mask`` (as
        :class:`.shapes.CollisionShape`'s; absent: its defaults), and ``links: {link:
        {friction, restitution}}`` per URDF link over them.

    """

    name: str
    links: Sequence[LinkSpec]
    joints: Sequence[JointSpec]
    base_xyz: Any = (0.0, 0.0, 0.0)
    base_quat_xyzw: Any = (0.0, 0.0, 0.0, 1.0)
    fixed_base: bool = False
    initial_positions: dict = field(default_factory=dict)
    initial_velocities: dict = field(default_factory=dict)
    keep_fixed: Sequence[str] = ()
    prefix: str = ''
    source: str = ''
    enforce_limits: bool = True
    limit_restitution: Any = 0.0
    enforce_friction: bool = True
    enforce_efforts: bool = True
    collisions: Sequence = ()
    self_collide: bool = False
    collision_options: dict = field(default_factory=dict)


@dataclass
class Joint:
    """
    A robot joint in the simulation (built by :func:`build_robot`).

    Attributes
    ----------
    name : str
        With the robot's prefix.
    spec : JointSpec
    parent_body, child_body : str or None
        Body names; None: the world.
    joint_in_parent : tuple
        The joint frame in the parent body's frame (the world's for None):
        position (3,) and rotation (3, 3).
    axis : ndarray, shape (3,)
        In the joint frame, which is also the child body's frame at q = 0.

    """

    name: str
    spec: JointSpec
    parent_body: Optional[str]
    child_body: Optional[str]
    joint_in_parent: tuple
    axis: np.ndarray


@dataclass
class LinkFrame:
    """Where a link's frame sits: on body ``body`` (None: the world) at ``(p, R)``."""

    body: Optional[str]
    position: np.ndarray
    rotation: np.ndarray


@dataclass
class RobotModel:
    """
    A robot converted: what :class:`.simulation.Simulation` simulates and reads back.

    Attributes
    ----------
    spec : RobotSpec
    bodies : list of RigidBody
        One per lumped group of links that moves; named after its topmost link.
    constraints : list of Constraint
        The joints that constrain (hinge, slider, planar, kept welds).
    joints : list of Joint
        Every joint that moves or is kept, in URDF order.
    links : dict
        ``{link: LinkFrame}``: every link's frame on its body (for tf).
    lumped : list of str
        Fixed joints lumped into their parent body.
    tree_order : list of int
        Indices into ``joints``, parents before children.
    notes : list of str
        Conversion notes a user should read (unenforced limits, for example).

    """

    spec: RobotSpec
    bodies: list
    constraints: list
    joints: list
    links: dict
    lumped: list
    notes: list
    tree_order: list = field(default_factory=list)


class _Tree:
    """The link tree of a :class:`RobotSpec`: parent joint of each link, root, order."""

    def __init__(self, spec: RobotSpec) -> None:
        self.links = {}
        for i, link in enumerate(spec.links):
            if link.name in self.links:
                raise SpecError(f'links[{i}].name', f'duplicate link name {link.name!r}')
            self.links[link.name] = link
        self.joints = {}
        self.parent_joint: dict = {}
        self.children: dict = {name: [] for name in self.links}
        for i, joint in enumerate(spec.joints):
            where = f'joints[{i}] ({joint.name!r})'
            if joint.name in self.joints:
                raise SpecError(f'{where}.name', f'duplicate joint name {joint.name!r}')
            for key in ('parent', 'child'):
                link = getattr(joint, key)
                if link not in self.links:
                    raise SpecError(f'{where}.{key}', f'unknown link {link!r}')
            if joint.child in self.parent_joint:
                raise SpecError(f'{where}.child', f'link {joint.child!r} is already the '
                                                  f'child of joint '
                                                  f'{self.parent_joint[joint.child].name!r}: '
                                                  f'a URDF is a tree')
            self.joints[joint.name] = joint
            self.parent_joint[joint.child] = joint
            self.children[joint.parent].append(joint)
        roots = [name for name in self.links if name not in self.parent_joint]
        if len(roots) != 1:
            raise SpecError('links', f'a robot needs exactly one root link (a link that is no '
                                     f"joint's child), found {roots or 'none (a loop)'}")
        self.root = roots[0]
        # Depth-first order from the root; links not reached sit on a loop.
        self.order = []
        stack = [self.root]
        while stack:
            name = stack.pop()
            self.order.append(name)
            stack.extend(j.child for j in reversed(self.children[name]))
        if len(self.order) != len(self.links):
            missing = sorted(set(self.links) - set(self.order))
            raise SpecError('joints', f'links {missing} are not connected to the root '
                                      f'{self.root!r}')


def _lump(group: list, frames: dict, links: dict) -> tuple:
    """Mass, centre of mass (3,) and inertia (3, 3) of links in the group's frame."""
    mass, first = 0.0, np.zeros(3)
    parts = []
    for name in group:
        p, R = frames[name]
        link = links[name]
        if link.mass > 0.0:
            c = p + R @ link.com_link
            parts.append((link.mass, c, R @ link.inertia_link @ R.T))
            mass += link.mass
            first += link.mass * c
    if mass == 0.0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = first / mass
    inertia = np.zeros((3, 3))
    for m, c, I_c in parts:
        d = c - com
        inertia += I_c + m * (d @ d * np.eye(3) - np.outer(d, d))
    return mass, com, inertia


def mimic_order(joints: Sequence[JointSpec]) -> list:
    """
    Return the mimic joints as ``(follower, (leader, k, c))``, each after its leader's own.

    Raises SpecError (``joints.<name>.mimic``) for a follower or leader that is not
    revolute or prismatic (a continuous one turns past the π the row allows), a
    joint that mimics itself, and a cycle of mimics.
    """
    kind = {j.name: j.kind for j in joints}
    mimics = {j.name: j.mimic for j in joints if j.mimic is not None}
    for name, (leader, _, _) in mimics.items():
        where = f'joints.{name}.mimic'
        for role, joint in (('a follower', name), ('its leader', leader)):
            if kind.get(joint) not in (JointKind.REVOLUTE, JointKind.PRISMATIC):
                what = 'missing' if joint not in kind else kind[joint].value
                raise SpecError(where, f'{role} ({joint!r}, {what}) must be a revolute or '
                                       f'prismatic joint (the row holds angles within π of '
                                       f'a reference: a continuous joint turns past it)')
        if leader == name:
            raise SpecError(where, f'joint {name!r} mimics itself')
    order: list = []
    done: set = set()
    for name in mimics:
        path = []
        while name in mimics and name not in done:
            if name in path:
                raise SpecError(f'joints.{name}.mimic', f'mimic joints form a cycle: '
                                                        f'{path[path.index(name):] + [name]}')
            path.append(name)
            name = mimics[name][0]
        for follower in reversed(path):
            order.append((follower, mimics[follower]))
            done.add(follower)
    return order


def mimic_name(joint: str) -> str:
    """Name of the constraint that makes ``joint`` follow its leader (a mimic joint)."""
    return f'{joint}_mimic'


def build_robot(spec: RobotSpec) -> RobotModel:
    """
    Convert a robot to bodies and constraints at its initial joint positions.

    Raises
    ------
    SpecError
        Naming the link, joint or key at fault.

    """
    tree = _Tree(spec)
    pre = spec.prefix
    keep = set(spec.keep_fixed)
    for name in keep:
        joint = tree.joints.get(name)
        if joint is None or joint.kind is not JointKind.FIXED:
            fixed = [j.name for j in spec.joints if j.kind is JointKind.FIXED]
            raise SpecError('keep_fixed', f'{name!r} is not a fixed joint of the robot; fixed '
                                          f'joints: {fixed}')
    one_dof = [j.name for j in spec.joints if j.kind in ONE_DOF]
    for key in ('initial_positions', 'initial_velocities'):
        values = getattr(spec, key)
        if not isinstance(values, dict):
            raise SpecError(key, f'expected a mapping joint -> value, got {values!r}')
        for name, value in values.items():
            if name not in one_dof:
                raise SpecError(f'{key}.{name}', f'not a revolute, continuous or prismatic '
                                                 f'joint of the robot; those are {one_dof}')
            finite_scalar(value, f'{key}.{name}')
    q0 = {name: float(spec.initial_positions.get(name, 0.0)) for name in one_dof}
    qd0 = {name: float(spec.initial_velocities.get(name, 0.0)) for name in one_dof}
    for name, (leader, k, c) in mimic_order(spec.joints):
        # A follower starts where its leader puts it (a contradicting value is an error).
        for key, values, value in (('initial_positions', q0, k * q0[leader] + c),
                                   ('initial_velocities', qd0, k * qd0[leader])):
            given = getattr(spec, key).get(name)
            if given is not None and abs(float(given) - value) > 1e-9 * max(1.0, abs(value)):
                raise SpecError(f'{key}.{name}', f'joint {name!r} mimics {leader!r} ({name} = '
                                                 f'{k:g} {leader} + {c:g}): {value!r} follows '
                                                 f'from {leader!r}, got {float(given)!r}')
            values[name] = value

    # Forward kinematics at the initial positions: every link frame in the world.
    base_p = finite_array(spec.base_xyz, 'base_pose.xyz', (3,))
    base_q = so3.quat_normalize(finite_array(spec.base_quat_xyzw, 'base_pose.quat_xyzw',
                                             (4,)))
    world_root = tree.root == WORLD_LINK
    welded = world_root or bool(spec.fixed_base)
    # (a robot's own world link sits at base_pose too: robots side by side in one scene)
    poses = {tree.root: (base_p, so3.quat_to_matrix(base_q))}
    twists = {tree.root: (np.zeros(3), np.zeros(3))}
    for name in tree.order[1:]:
        j = tree.parent_joint[name]
        p_par, R_par = poses[j.parent]
        o_p, o_R = j.origin
        m_p, m_R = j.motion(q0.get(j.name, 0.0))
        p_joint, R_joint = p_par + R_par @ o_p, R_par @ o_R
        poses[name] = (p_joint + R_joint @ m_p, R_joint @ m_R)
        v_par, w_par = twists[j.parent]
        v = v_par + so3.cross(w_par, poses[name][0] - p_par)
        w = w_par.copy()
        rate = qd0.get(j.name, 0.0)
        if j.kind in ROTARY:
            w = w + rate * (R_joint @ j.axis)
        elif j.kind is JointKind.PRISMATIC:
            v = v + rate * (R_joint @ j.axis)
        twists[name] = (v, w)

    # Groups: links joined by lumped fixed joints share a body, named after the top link.
    group_of = {}
    for name in tree.order:
        j = tree.parent_joint.get(name)
        lumped = j is not None and j.kind is JointKind.FIXED and j.name not in keep
        group_of[name] = group_of[j.parent] if lumped else name
    lumped = [j.name for j in spec.joints
              if j.kind is JointKind.FIXED and j.name not in keep]
    world_group = tree.root if welded else None
    links_out, bodies, body_of_group = {}, [], {}
    for top in dict.fromkeys(group_of.values()):
        members = [n for n in tree.order if group_of[n] == top]
        p_top, R_top = poses[top]
        local = {n: (R_top.T @ (poses[n][0] - p_top), R_top.T @ poses[n][1]) for n in members}
        if top == world_group:
            for n in members:
                links_out[n] = LinkFrame(None, *poses[n])
            body_of_group[top] = None
            continue
        mass, com, inertia = _lump(members, local, tree.links)
        if mass == 0.0:
            j = tree.parent_joint.get(top)
            how = (f'the child of joint {j.name!r} ({j.kind.value})' if j is not None
                   else 'the root of a floating base')
            raise SpecError(f'links.{top}.inertial',
                            f'link {top!r} (with {members[1:] or "no"} lumped links) has no '
                            f'mass but is {how}: it would move without inertia; give it an '
                            f'<inertial>, or make its joint fixed')
        v_top, w_top = twists[top]
        try:
            bodies.append(RigidBody(name=pre + top, mass=mass, inertia=inertia, com_body=com,
                                    position_world=p_top,
                                    orientation_xyzw=so3.matrix_to_quat(R_top),
                                    linear_velocity_world=v_top,
                                    angular_velocity_body=R_top.T @ w_top))
        except SpecError as exc:
            raise exc.within(f'links.{top}') from None
        body_of_group[top] = pre + top
        for n in members:
            links_out[n] = LinkFrame(pre + top, *local[n])

    # Joints between bodies (or a body and the world) become constraints.
    constraints, joints, notes = [], [], []
    kind_of = {JointKind.REVOLUTE: 'hinge', JointKind.CONTINUOUS: 'hinge',
               JointKind.PRISMATIC: 'slider', JointKind.PLANAR: 'planar',
               JointKind.FIXED: 'fixed'}
    for j in spec.joints:
        if j.name in lumped:
            continue
        parent_link = links_out[j.parent]
        child_body = body_of_group[group_of[j.child]]
        p_par, R_par = poses[j.parent]
        o_p, o_R = j.origin
        p_joint, R_joint = p_par + R_par @ o_p, R_par @ o_R
        parent_body = parent_link.body
        in_parent = (parent_link.position + parent_link.rotation @ o_p,
                     parent_link.rotation @ o_R)
        joints.append(Joint(pre + j.name, j, parent_body, child_body, in_parent, j.axis))
        if j.kind is JointKind.FLOATING:
            continue
        if child_body is None:
            raise SpecError(f'joints.{j.name}', f'joins two links of the world '
                                                f'({j.parent!r}, {j.child!r})')
        axis = R_joint @ (j.axis if j.kind is not JointKind.FIXED else np.array([0, 0, 1.0]))
        constraints.append(Constraint(name=pre + j.name, type=kind_of[j.kind],
                                      body_a=child_body, body_b=parent_body,
                                      anchor_world=p_joint,
                                      axis_world=axis if j.kind is not JointKind.FIXED
                                      else None))
        if j.kind in ONE_DOF and (j.lower is not None or j.upper is not None) \
                and j.kind is not JointKind.CONTINUOUS and not spec.enforce_limits:
            notes.append(f'joint {pre + j.name!r}: position limits [{j.lower}, {j.upper}] are '
                         f'read but not enforced (the robot has limits: false)')
        if j.kind in ONE_DOF and j.effort == 0.0:
            notes.append(f'joint {pre + j.name!r}: <limit effort="0"> is read as no effort '
                         f'limit (commands are not clamped)')
        if j.friction > 0.0 and not spec.enforce_friction:
            notes.append(f'joint {pre + j.name!r}: Coulomb friction {j.friction} is read but '
                         f'not simulated (the robot has friction: false)')
    index = {j.spec.name: i for i, j in enumerate(joints)}
    order = [index[tree.parent_joint[n].name] for n in tree.order[1:]
             if tree.parent_joint[n].name in index]
    return RobotModel(spec, bodies, constraints, joints, links_out, lumped, notes, order)


@dataclass(frozen=True)
class JointState:
    """
    Joint coordinates of the one-coordinate joints, as ``sensor_msgs/JointState`` has them.

    Attributes
    ----------
    names : list of str
    positions : ndarray, shape (k,)
        rad or m.
    velocities : ndarray, shape (k,)
        rad/s or m/s.
    efforts : ndarray, shape (k,)
        N m or N: the generalized force the joint's actuation applied in the
        last step, along its free direction (after clamping to the effort limit).

    """

    names: list
    positions: np.ndarray
    velocities: np.ndarray
    efforts: np.ndarray


class JointSpace:
    """
    The map between the maximal state and the robots' joint coordinates.

    Vectorized over the k one-coordinate joints (revolute, continuous,
    prismatic) of every robot of a simulation. The angle of a rotary joint is
    the rotation of the child body relative to the joint frame on the parent
    about the axis, ``atan2(e2·R e1, e1·R e1)`` in the frame ``(k, e1, e2)``,
    unwrapped after every step (:meth:`track`) so that it counts turns; a slide
    is the child origin's displacement along the axis in the parent's joint
    frame.

    Parameters
    ----------
    names : list of str
        Body names of the simulation, in body order.
    models : list of RobotModel
    extra : list of Joint
        One-coordinate joints of no robot (a scene's hinges and sliders with limits
        or friction: :class:`.limits.SceneJoint`), after the robots' joints.

    """

    def __init__(self, names: list, models: list, extra: Sequence = ()) -> None:
        self.models = list(models)
        self.body_index = index = {name: i for i, name in enumerate(names)}
        n = len(names)
        self.n_bodies = n
        self.joints = [j for m in self.models for j in m.joints if j.spec.kind in ONE_DOF]
        #: How many of the joints are robots' (the scene's follow them).
        self.n_robot = len(self.joints)
        self.joints += list(extra)
        self.names = [j.name for j in self.joints]
        self.index = {name: i for i, name in enumerate(self.names)}
        k = len(self.joints)
        self.parent = np.array([n if j.parent_body is None else index[j.parent_body]
                                for j in self.joints], dtype=int)
        self.child = np.array([index[j.child_body] for j in self.joints], dtype=int)
        self.p_jp = np.array([j.joint_in_parent[0] for j in self.joints]).reshape(k, 3)
        self.R_jp = np.array([j.joint_in_parent[1] for j in self.joints]).reshape(k, 3, 3)
        frames = np.array([perpendicular_frame(j.axis) for j in self.joints]).reshape(k, 3, 3)
        self.axis, self.e1, self.e2 = frames[:, 0], frames[:, 1], frames[:, 2]
        self.rotary = np.array([j.spec.kind in ROTARY for j in self.joints], dtype=bool)
        self.effort_limit = np.array([np.inf if not j.spec.effort else j.spec.effort
                                      for j in self.joints])
        self.velocity_limit = np.array([np.inf if not j.spec.velocity else j.spec.velocity
                                        for j in self.joints])
        self.table = np.array([JOINT.row(parent=self.parent[i], child=self.child[i],
                                         rotary=float(self.rotary[i]), p_jp=self.p_jp[i],
                                         R_jp=self.R_jp[i].ravel(), axis=self.axis[i],
                                         e1=self.e1[i], e2=self.e2[i],
                                         velocity_limit=self.velocity_limit[i],
                                         watch_low=-np.inf, watch_high=np.inf)
                               for i in range(k)]).reshape(k, JOINT.width)
        self._rates = np.zeros(k)
        self._spare = np.zeros(k)   # the next positions of :meth:`advance`
        #: Mimic joints ``(follower, leader, k, c)`` (indices), each after its leader's own.
        self.mimics = [(self.index[m.spec.prefix + f], self.index[m.spec.prefix + leader], km, c)
                       for m in self.models
                       for f, (leader, km, c) in mimic_order(m.spec.joints)]
        self.reset()

    def __len__(self) -> int:
        """Return the number of one-coordinate joints."""
        return len(self.joints)

    def drive_geometry(self, i: int, target: float) -> DriveGeometry:
        """Where joint ``i``'s coordinate lives on its child (a) and parent (b), and a target."""
        R = self.R_jp[i]
        return DriveGeometry(rotary=bool(self.rotary[i]), e1_a=self.e1[i], e1_b=R @ self.e1[i],
                             e2_b=R @ self.e2[i], k_b=R @ self.axis[i], p_a=np.zeros(3),
                             p_b=self.p_jp[i], target=float(target))

    def mimic_constraints(self) -> list:
        """
        Return one ``mimic`` constraint per mimic joint (named :func:`mimic_name`).

        ``Φ = (q_f − c − k r) − k (q_l − r)`` with each angle taken within π of
        its reference: ``r`` the middle of the leader's limits (0 without both),
        ``c + k r`` for the follower (see :class:`.constraints.Coupling`).
        """
        out = []
        for f, leader, k, c in self.mimics:
            spec = self.joints[leader].spec
            ref = (0.5 * (spec.lower + spec.upper)
                   if spec.lower is not None and spec.upper is not None else 0.0)
            jf, jl = self.joints[f], self.joints[leader]
            out.append(Constraint(
                mimic_name(jf.name), JointType.MIMIC, jf.child_body, jf.parent_body,
                anchor_a_body=np.zeros(3), anchor_b_body=self.p_jp[f],
                drive=self.drive_geometry(f, c + k * ref),
                coupling=Coupling(jl.child_body, jl.parent_body,
                                  self.drive_geometry(leader, ref), k)))
        return out

    def reset(self) -> None:
        """Forget the commands, the counted turns and the counters."""
        k = len(self.joints)
        self.positions = np.zeros(k)   # unwrapped at the last track()
        self.tracked = False
        self.efforts = np.zeros(k)     # held commands, clamped
        self.effort_window = np.tile([0.0, np.inf], (k, 1))
        self.counters = {'clamped_efforts': 0, 'velocity_limit_excursions': 0}

    def lookup(self, name: Any, field_name: str) -> int:
        """Index of joint ``name``; SpecError naming ``field_name`` if unknown."""
        try:
            return self.index[name]
        except (KeyError, TypeError):
            raise SpecError(field_name, f'unknown joint {name!r}; joints: {self.names}') from None

    # -- reading ----------------------------------------------------------------------------

    @staticmethod
    def _with_world(out: np.ndarray) -> tuple:
        """Origins, rotations, origin velocities, angular velocities; the world appended."""
        pos = out[:, O_ORIGIN_WORLD:O_ORIGIN_WORLD + 3]
        R = so3.quat_to_matrix(out[:, O_QUAT_BODY_WORLD:O_QUAT_BODY_WORLD + 4])
        vel = out[:, O_ORIGIN_VEL_WORLD:O_ORIGIN_VEL_WORLD + 3]
        omega = out[:, O_ANG_VEL_WORLD:O_ANG_VEL_WORLD + 3]
        return (np.vstack([pos, np.zeros((1, 3))]), np.concatenate([R, np.eye(3)[None]]),
                np.vstack([vel, np.zeros((1, 3))]), np.vstack([omega, np.zeros((1, 3))]))

    def track(self, out: np.ndarray) -> None:
        """
        Update the unwrapped coordinates from the bodies' outputs after a step.

        Parameters
        ----------
        out : ndarray, shape (n, O_WIDTH)
            The outputs of the new state (:attr:`.bodies.BodySet.outputs_cache`).

        """
        over = joint_coordinates(out, self.table, self.tracked, self.positions, self._rates)
        self.tracked = True
        self.counters['velocity_limit_excursions'] += over

    def advance(self, out: np.ndarray) -> bool:
        """
        :meth:`track` the coordinates after a step if all lie in their windows (:meth:`watch`).

        Returns whether they did; when one lies outside, nothing changes (the step is
        the joint events' to take, :meth:`.JointEvents.step`). Only once tracked.
        """
        spare = self._spare
        over = joint_coordinates_within(out, self.table, self.positions, spare, self._rates)
        if over < 0:
            return False
        # The two arrays take turns (no allocation a step): positions is replaced after
        # every step, as :meth:`adopt` replaces it; readers copy it (:meth:`state`).
        self._spare, self.positions = self.positions, spare
        self.counters['velocity_limit_excursions'] += over
        return True

    def watch(self, low: np.ndarray, high: np.ndarray) -> None:
        """Set the windows (k,) :meth:`advance` checks the coordinates against."""
        self.table[:, J_WATCH_LOW] = low
        self.table[:, J_WATCH_HIGH] = high

    def coordinates(self, out: np.ndarray, previous: np.ndarray) -> tuple:
        """
        Coordinates (k,) and rates (k,) at the outputs ``out``, angles unwrapped near ``previous``.

        Reads only: neither the tracked coordinates nor the counters change. Returns
        ``(positions, rates, over)``, ``over`` the rates beyond their limits.
        """
        positions, rates = np.array(previous, dtype=float), np.empty(len(self.joints))
        over = joint_coordinates(out, self.table, True, positions, rates)
        return positions, rates, over

    def adopt(self, positions: np.ndarray, over: int) -> None:
        """Take ``positions`` from :meth:`coordinates` of a step's end as :meth:`track` would."""
        self.positions = positions
        self.tracked = True
        self.counters['velocity_limit_excursions'] += over

    def state(self, out: np.ndarray, time_mid: float, names: Optional[Sequence] = None
              ) -> JointState:
        """
        Joint state of the outputs ``out`` (n, O_WIDTH) (see :class:`JointState`).

        ``time_mid`` is the midpoint of the last step: an effort command counts
        when it acted over that step.
        """
        if names is not None:
            idx = np.array([self.lookup(name, f'names[{i}]') for i, name in enumerate(names)],
                           dtype=int)
        positions, rates = self.positions.copy(), np.empty(len(self.joints))
        joint_coordinates(out, self.table, self.tracked, positions, rates)
        window = self.effort_window
        acting = (window[:, 0] <= time_mid) & (time_mid < window[:, 1])
        efforts = np.where(acting, self.efforts, 0.0)
        if names is None:
            return JointState(list(self.names), positions, rates, efforts)
        return JointState([self.names[i] for i in idx], positions[idx], rates[idx],
                          efforts[idx])

    # -- commands ---------------------------------------------------------------------------

    def effort_wrenches(self, efforts: dict) -> tuple:
        """
        Validate ``{joint: effort}`` and return the clamped efforts and their wrenches.

        Returns
        -------
        idx : ndarray of int
            Joint indices.
        clamped : ndarray
            The efforts after clamping to each joint's limit.
        wrenches : list of dict
            Keyword arguments of :meth:`.simulation.Simulation.apply_wrench` (body
            frame, keyed per joint and body): the pair of equal and opposite
            wrenches each effort is.

        """
        if not isinstance(efforts, dict):
            raise SpecError('efforts', f'expected a mapping joint -> effort, got {efforts!r}')
        idx = np.array([self.lookup(name, f'efforts.{name}') for name in efforts], dtype=int)
        values = np.array([finite_scalar(value, f'efforts.{name}')
                           for name, value in efforts.items()])
        limit = self.effort_limit[idx] if len(idx) else np.zeros(0)
        clamped = np.clip(values, -limit, limit)
        wrenches = [w for i, tau in zip(idx, clamped) for w in self.effort_pair(i, tau)]
        return idx, clamped, wrenches

    def effort_pair(self, i: int, tau: float, what: str = '') -> list:
        """
        Return the equal and opposite wrenches that are the generalized force ``tau`` on ``i``.

        Keyword arguments of :meth:`.simulation.Simulation.apply_wrench` (body frame),
        keyed ``joint <name> [what ]child|parent`` (the world's side is left out): a
        torque ``τ k`` about the axis (rotary), or a force ``τ k`` along it through the
        child's origin and the parent's joint point (prismatic).
        """
        j = self.joints[i]
        k_child, k_parent = self.axis[i], self.R_jp[i] @ self.axis[i]
        if self.rotary[i]:
            pair = ((j.child_body, {'torque': tau * k_child}),
                    (j.parent_body, {'torque': -tau * k_parent}))
        else:
            pair = ((j.child_body, {'force': tau * k_child, 'point_body': np.zeros(3)}),
                    (j.parent_body, {'force': -tau * k_parent, 'point_body': self.p_jp[i]}))
        prefix = f'joint {j.name} ' + (f'{what} ' if what else '')
        return [dict(body=body, frame='body', key=prefix + side, **load)
                for side, (body, load) in zip(('child', 'parent'), pair) if body is not None]

    def commanded(self, idx: np.ndarray, clamped: np.ndarray, values: np.ndarray,
                  start: float, end: float) -> None:
        """Record efforts that were applied from ``start`` to ``end`` (s)."""
        self.counters['clamped_efforts'] += int(np.count_nonzero(clamped != values))
        self.efforts[idx] = clamped
        self.effort_window[idx] = (start, end)

    # -- setting (forward kinematics) -------------------------------------------------------

    def poses_for(self, out: np.ndarray, positions: dict, velocities: dict) -> tuple:
        """
        Body-origin poses and twists with the joints at new coordinates.

        Bodies not driven by a one-coordinate joint (floating bases, the children
        of floating, planar or kept fixed joints) keep their pose relative to
        their parent; every joint not named keeps its coordinate and rate, but a
        mimic joint follows its leader.

        Returns
        -------
        pos, quat_xyzw, vel, omega : ndarray, shapes (n, 3), (n, 4), (n, 3), (n, 3)
            World frame, of body origins.

        """
        now = self.state(out, 0.0)
        q, qd = now.positions, now.velocities
        for key, given in (('positions', positions), ('velocities', velocities)):
            for name in given:
                if self.lookup(name, f'{key}.{name}') >= self.n_robot:
                    raise SpecError(f'{key}.{name}', f'joint {name!r} is a scene constraint '
                                                     f'with limits or friction, not a robot '
                                                     f"joint: set its bodies' state instead")
        for name, value in positions.items():
            q[self.lookup(name, f'positions.{name}')] = finite_scalar(value,
                                                                      f'positions.{name}')
        for name, value in velocities.items():
            qd[self.lookup(name, f'velocities.{name}')] = finite_scalar(value,
                                                                        f'velocities.{name}')
        for f, leader, k, c in self.mimics:
            # A follower goes where its leader puts it (a contradicting value is refused).
            name = self.names[f]
            for key, given, x, want in (('positions', positions, q, k * q[leader] + c),
                                        ('velocities', velocities, qd, k * qd[leader])):
                if name in given and not abs(x[f] - want) <= 1e-9 * max(1.0, abs(want)):
                    raise SpecError(f'{key}.{name}', f'joint {name!r} mimics '
                                                     f'{self.names[leader]!r}: {want!r} follows '
                                                     f'from it, got {x[f]!r}')
                x[f] = want
        p, R, v, w = (x.copy() for x in self._with_world(out))
        p0, R0, v0, w0 = (x.copy() for x in self._with_world(out))
        index = self.index
        body_index = self.body_index
        for model in self.models:
            for ji in model.tree_order:
                j = model.joints[ji]
                if j.child_body is None:
                    continue
                a = body_index[j.child_body]
                b = self.n_bodies if j.parent_body is None else body_index[j.parent_body]
                p_jp, R_jp = j.joint_in_parent
                # The joint frame on the parent, before and after.
                Rj0, pj0 = R0[b] @ R_jp, p0[b] + R0[b] @ p_jp
                Rj, pj = R[b] @ R_jp, p[b] + R[b] @ p_jp
                # Relative twist of the child in the joint frame, before (kept if not set).
                w_rel = Rj0.T @ (w0[a] - w0[b])
                v_rel = Rj0.T @ (v0[a] - v0[b] - so3.cross(w0[b], p0[a] - p0[b]))
                i = index.get(j.name)
                if i is not None:
                    m_p, m_R = j.spec.motion(q[i])
                    axis = self.axis[i]
                    w_rel = qd[i] * axis if self.rotary[i] else np.zeros(3)
                    v_rel = np.zeros(3) if self.rotary[i] else qd[i] * axis
                else:
                    m_R = Rj0.T @ R0[a]
                    m_p = Rj0.T @ (p0[a] - pj0)
                R[a] = Rj @ m_R
                p[a] = pj + Rj @ m_p
                w[a] = w[b] + Rj @ w_rel
                v[a] = v[b] + so3.cross(w[b], p[a] - p[b]) + Rj @ v_rel
        n = self.n_bodies
        return p[:n], so3.matrix_to_quat(R[:n]), v[:n], w[:n]


class Interface(enum.Enum):
    """What a joint's commands set (ros2_control's command interfaces)."""

    EFFORT = 'effort'
    POSITION = 'position'
    VELOCITY = 'velocity'


@dataclass(frozen=True)
class CommandGroup:
    """
    Joints commanded together, with one interface (a forward-command controller's).

    Parameters
    ----------
    name : str
    joints : sequence of str
        In the order of the group's command arrays.
    interface : {'effort', 'position', 'velocity'}
    mode : {'servo', 'exact'}
        ``servo``: a PD drive ``τ = clip(kp (q* − q) + kd (v* − q̇), ±effort)``
        (MuJoCo's position and velocity actuators). ``exact`` (position and
        velocity groups): the driving constraint ``q − c(t) = 0``, one more row of
        the multiplier solve, so the joint follows its target exactly and its
        effort is the row's multiplier: the torque the motion takes, bounded by
        the URDF effort (a motion that needs more lags at the limit:
        :class:`.limits.DriveEfforts`; the robot's ``enforce_efforts``). A position group's target
        is ``c = q*``: a jump is closed along ``exp(−t /
        constraint_time_constant)``, as any violated constraint, and a hinge goes
        the shorter way (within π). A velocity group's target moves, ``c(t) = c₀ +
        v* (t − t₀)`` from where it was when ``v*`` was commanded (no jump), so
        ``q̇ = v*`` exactly; a hinge may turn without end.
    kp : float
        N m/rad or N/m, > 0 for position servos; 0 for velocity ones.
    kd : float
        N m s/rad or N s/m, >= 0 (> 0 for velocity servos).

    """

    name: str
    joints: Sequence[str]
    interface: Any = 'effort'
    mode: str = 'servo'
    kp: float = 0.0
    kd: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SpecError('name', f'must be a non-empty string, got {self.name!r}')
        if isinstance(self.joints, str) or not all(isinstance(j, str) for j in self.joints) \
                or not len(self.joints):
            raise SpecError('joints', f'expected a non-empty list of joint names, '
                                      f'got {self.joints!r}')
        object.__setattr__(self, 'joints', tuple(self.joints))
        try:
            interface = Interface(self.interface.value if isinstance(self.interface, Interface)
                                  else self.interface)
        except ValueError:
            raise SpecError('interface', f"must be 'effort', 'position' or 'velocity', "
                                         f'got {self.interface!r}') from None
        object.__setattr__(self, 'interface', interface)
        if self.mode not in ('servo', 'exact'):
            raise SpecError('mode', f"must be 'servo' or 'exact', got {self.mode!r}")
        kp, kd = finite_scalar(self.kp, 'kp'), finite_scalar(self.kd, 'kd')
        if kp < 0.0 or kd < 0.0:
            raise SpecError('kp' if kp < 0.0 else 'kd', 'gains must be >= 0')
        if self.mode == 'exact':
            if interface is Interface.EFFORT:
                raise SpecError('mode', "'exact' drives exist for the position and velocity "
                                        'interfaces (an effort group: an effort has nothing '
                                        'to hold)')
            if kp or kd:
                raise SpecError('kp' if kp else 'kd', f'an exact drive has no gains (it is a '
                                                      f'constraint), got kp {kp!r}, kd {kd!r}')
            object.__setattr__(self, 'kp', 0.0)
            object.__setattr__(self, 'kd', 0.0)
            return
        if interface is Interface.POSITION and not kp > 0.0:
            raise SpecError('kp', f'a position servo needs kp > 0, got {kp!r}')
        if interface is Interface.VELOCITY and (kp != 0.0 or not kd > 0.0):
            raise SpecError('kd' if kp == 0.0 else 'kp',
                            f'a velocity servo needs kd > 0 and kp = 0, got kp {kp!r}, '
                            f'kd {kd!r}')
        if interface is Interface.EFFORT and (kp or kd):
            raise SpecError('kp', 'an effort group has no gains')
        object.__setattr__(self, 'kp', kp)
        object.__setattr__(self, 'kd', kd)


def drive_name(joint: str) -> str:
    """Name of the driving constraint of an ``exact`` joint (its reaction's topic too)."""
    return f'{joint}_drive'


class JointDrives(Effect):
    """
    The joints' servos and passive damping, in the compiled steps (:mod:`.kernels.drives`).

    Only joints with a servo or a nonzero ``<dynamics damping>`` have a row;
    without any, the effect adds nothing and costs nothing. In the splittings the
    rate terms (``kd``, ``d``) are exact flows, stable for any gain; the servo's
    spring is a force of the positions in the symplectic kicks, stable while
    ``kp c dt² <= 1`` (ω dt <= 1, half the symplectic limit of 2), checked when
    built and when ``dt`` changes, with ``c`` the joint's inverse inertia
    ``j M⁻¹ jᵀ`` over its two bodies alone, which bounds the constrained system's
    (a joint in a chain moves more inertia, never less). ``rkmk4`` evaluates
    everything explicitly, under ``(kp dt² + (kd + d) dt) c <= 1``.
    """

    name = 'joint_drives'
    velocity_dependent = True

    def __init__(self, space: 'JointSpace', groups: Sequence[CommandGroup] = ()) -> None:
        super().__init__()
        self.space = space
        k = len(space)
        self.interface = [Interface.EFFORT] * k
        self.group_of: dict = {}
        self.groups = {}
        self.kp, self.kd = np.zeros(k), np.zeros(k)
        #: Joints held by a driving constraint (``mode: exact``), not by a servo.
        self.exact = np.zeros(k, dtype=bool)
        for g, group in enumerate(groups):
            where = f'command_groups[{g}]'
            if group.name in self.groups:
                raise SpecError(f'{where}.name', f'duplicate group name {group.name!r}')
            self.groups[group.name] = group
            for j, name in enumerate(group.joints):
                i = space.lookup(name, f'{where}.joints[{j}]')
                if name in self.group_of:
                    raise SpecError(f'{where}.joints[{j}]', f'joint {name!r} is already in '
                                                            f'group {self.group_of[name]!r}')
                self.group_of[name] = group.name
                self.interface[i] = group.interface
                self.kp[i], self.kd[i] = group.kp, group.kd
                self.exact[i] = group.mode == 'exact'
                leader = next((space.names[lead] for f, lead, _, _ in space.mimics if f == i),
                              None)
                if self.exact[i] and leader is not None:
                    raise SpecError(f'{where}.joints[{j}]',
                                    f'joint {name!r} mimics {leader!r}: its motion is its '
                                    f"leader's, an exact drive would contradict it (drive "
                                    f'{leader!r} instead)')
        self.damping = np.array([j.spec.damping for j in space.joints]).reshape(k)
        self.servo = self.kp + self.kd > 0.0
        self.rows_of = np.flatnonzero(self.servo | (self.damping > 0.0))
        self.q_target, self.v_target = np.zeros(k), np.zeros(k)
        self.center = np.zeros(k)
        self._geometry: Optional[np.ndarray] = None

    def bind(self, bodies: Any) -> None:
        """Compute each drive row's geometry in the principal frames."""
        super().bind(bodies)
        js = self.space
        V = np.concatenate([bodies.R_body_principal, np.eye(3)[None]])
        com = np.vstack([bodies.com_body, np.zeros((1, 3))])
        rows = np.zeros((len(self.rows_of), W_WIDTH))
        for r, i in enumerate(self.rows_of):
            a, b = js.child[i], js.parent[i]
            Va, Vb = V[a], V[b]
            axis_parent = js.R_jp[i] @ js.axis[i]
            rows[r, W_BODY], rows[r, W_PARENT] = a, b
            rows[r, W_KIND] = WRENCH_DRIVE
            rows[r, W_ROTARY] = float(js.rotary[i])
            rows[r, W_K_CHILD:W_K_CHILD + 3] = Va.T @ js.axis[i]
            rows[r, W_K_PARENT:W_K_PARENT + 3] = Vb.T @ axis_parent
            rows[r, W_E1_CHILD:W_E1_CHILD + 3] = Va.T @ js.e1[i]
            rows[r, W_E1_PARENT:W_E1_PARENT + 3] = Vb.T @ (js.R_jp[i] @ js.e1[i])
            rows[r, W_E2_PARENT:W_E2_PARENT + 3] = Vb.T @ (js.R_jp[i] @ js.e2[i])
            rows[r, W_R_CHILD:W_R_CHILD + 3] = Va.T @ (np.zeros(3) - com[a])
            rows[r, W_R_PARENT:W_R_PARENT + 3] = Vb.T @ (js.p_jp[i] - com[b])
            rows[r, W_KP], rows[r, W_KD] = self.kp[i], self.kd[i]
            rows[r, W_DAMPING] = self.damping[i]
            rows[r, W_EFFORT_MAX] = js.effort_limit[i]
        self._geometry = rows

    def drive_constraints(self, positions: np.ndarray) -> list:
        """
        Return the driving constraints of the ``exact`` joints, holding ``positions`` (k,).

        One ``drive`` :class:`.constraints.Constraint` per joint, named
        :func:`drive_name`, between the joint's child (body a) and parent (b).
        """
        js = self.space
        out = []
        for i in np.flatnonzero(self.exact):
            j = js.joints[i]
            out.append(Constraint(drive_name(j.name), JointType.DRIVE, j.child_body,
                                  j.parent_body, drive=js.drive_geometry(i, positions[i])))
        return out

    def inverse_inertias(self, state: Any) -> np.ndarray:
        """``c = j M⁻¹ jᵀ`` of each joint over its two bodies at ``state`` (k,)."""
        js, bodies = self.space, self.bodies
        n = len(bodies)
        out = np.zeros(len(js))
        R = so3.quat_to_matrix(state.quat_principal_world)
        for i in range(len(js)):
            a, b = js.child[i], js.parent[i]
            ends = [a] if b >= n else [a, b]
            if js.rotary[i]:
                axis_w = R[a] @ (bodies.R_body_principal[a].T @ js.axis[i])
                out[i] = sum(np.sum((R[e].T @ axis_w) ** 2 / bodies.moments[e]) for e in ends)
                continue
            Ra = R[a]
            point = state.pos_com_world[a] + Ra @ (bodies.R_body_principal[a].T
                                                   @ (-bodies.com_body[a]))
            axis_w = Ra @ (bodies.R_body_principal[a].T @ js.axis[i])
            for e in ends:
                lever = np.cross(point - state.pos_com_world[e], axis_w)
                out[i] += bodies.inv_mass[e] + np.sum((R[e].T @ lever) ** 2
                                                      / bodies.moments[e])
        return out

    def check_stability(self, state: Any, dt: float, integrator: str) -> None:
        """Refuse gains the explicit servo (and rkmk4's explicit damping) cannot hold at dt."""
        c = self.inverse_inertias(state)
        kd = self.kd + self.damping if integrator == 'rkmk4' else np.zeros(len(c))
        measure = (self.kp * dt * dt + kd * dt) * c
        bad = np.flatnonzero(measure > 1.0)
        if len(bad):
            i = int(bad[0])
            name = self.space.names[i]
            where = f'command_groups.{self.group_of[name]}' if name in self.group_of \
                else f'joints.{name}.dynamics.damping'
            raise SpecError(where, f'joint {name!r}: kp {self.kp[i]:.6g}, kd {kd[i]:.6g} at dt '
                                   f'{dt:g} s ({integrator}) with the joint inverse inertia '
                                   f'{c[i]:.6g} give (kp dt² + kd dt) c = {measure[i]:.3g} > 1 '
                                   f'(kd counts for rkmk4 only): the explicit drive would be '
                                   f'unstable; lower the gains or dt')

    # -- commands ---------------------------------------------------------------------------

    def set_targets(self, idx: np.ndarray, values: np.ndarray) -> None:
        """Set the targets of joints ``idx`` (positions or velocities, per interface)."""
        for i, value in zip(idx, values):
            if self.interface[i] is Interface.POSITION:
                self.q_target[i] = value
            else:
                self.v_target[i] = value

    def hold(self, positions: np.ndarray) -> None:
        """Position servos hold ``positions`` (k,); velocity servos stop; re-center angles."""
        self.q_target[:] = np.where(self.interface_is(Interface.POSITION), positions, 0.0)
        self.v_target[:] = 0.0
        self.center[:] = positions

    def interface_is(self, interface: Interface) -> np.ndarray:
        """Mask (k,) of the joints with this interface."""
        return np.array([x is interface for x in self.interface], dtype=bool)

    def recenter(self, positions: np.ndarray) -> bool:
        """Move the angle windows of position servos that drifted past π/2; True if any."""
        idx = self.rows_of
        far = np.abs(positions[idx] - self.center[idx]) > 0.5 * np.pi
        if not np.any(far):
            return False
        self.center[idx[far]] = positions[idx[far]]
        return True

    def efforts(self, positions: np.ndarray, rates: np.ndarray) -> np.ndarray:
        """Each joint's drive effort (k,) at coordinates and rates: servo (clamped) + damping."""
        limit = self.space.effort_limit
        servo = np.where(self.servo, np.clip(self.kp * (self.q_target - positions)
                                             + self.kd * (self.v_target - rates),
                                             -limit, limit), 0.0)
        return servo - self.damping * rates

    # -- the effect -------------------------------------------------------------------------

    def add_to_kernel_model(self, model: KernelModel, time_mid: float) -> None:
        """Add one wrench row per driven joint (:data:`.kernels.layout.WRENCH`)."""
        if not len(self.rows_of):
            return
        rows = self._geometry.copy()
        idx = self.rows_of
        rows[:, W_CENTER] = self.center[idx]
        rows[:, W_Q_TARGET] = self.q_target[idx]
        rows[:, W_V_TARGET] = self.v_target[idx]
        model.add_wrench_rows(rows)
        if np.any(self.servo):
            model.flags |= HAS_DRIVES
        if np.any(self.damping > 0.0) or np.any(self.kd > 0.0):
            model.flags |= HAS_DRIVE_DAMPING   # rate terms: exact flows

    def count_kernel_work(self, rhs: int, kicks: int, flows: int,
                          acting: Optional[int] = None) -> None:
        """Count every right-hand side, kick and flow, per driven joint."""
        joints = len(self.rows_of) if acting is None else acting
        self._count(rhs + kicks + flows if joints else 0, joints)

    def acting_in(self, local: np.ndarray, rows_kept: np.ndarray) -> int:
        """Return the driven joints in the subset."""
        return int(np.count_nonzero(rows_kept))

    def accumulate(self, kin: Kinematics, acc: WrenchAccumulator) -> None:
        """Add the drives' wrenches at ``kin`` (numpy, one joint at a time: references)."""
        js, bodies = self.space, self.bodies
        n = len(bodies)
        if not len(self.rows_of):
            return
        self.evaluations += 1
        self.body_evaluations += len(self.rows_of)
        x = np.vstack([kin.pos_com_world, np.zeros((1, 3))])
        R = np.concatenate([kin.R_principal_world, np.eye(3)[None]])
        v = np.vstack([kin.vel_com_world, np.zeros((1, 3))])
        w = np.vstack([np.einsum('nij,nj->ni', kin.R_principal_world, kin.ang_vel_principal),
                       np.zeros((1, 3))])
        rows = self._geometry
        for r, i in enumerate(self.rows_of):
            row = rows[r]
            a, b = int(row[W_BODY]), int(row[W_PARENT])
            k_w = R[b] @ row[W_K_PARENT:W_K_PARENT + 3]
            rho_a = R[a] @ row[W_R_CHILD:W_R_CHILD + 3]
            point = x[a] + rho_a
            if js.rotary[i]:
                e1c = R[a] @ row[W_E1_CHILD:W_E1_CHILD + 3]
                q = np.arctan2((R[b] @ row[W_E2_PARENT:W_E2_PARENT + 3]) @ e1c,
                               (R[b] @ row[W_E1_PARENT:W_E1_PARENT + 3]) @ e1c)
                q += 2.0 * np.pi * np.round((self.center[i] - q) / (2.0 * np.pi))
                rate = k_w @ (w[a] - w[b])
            else:
                q = k_w @ (point - x[b] - R[b] @ row[W_R_PARENT:W_R_PARENT + 3])
                rate = k_w @ (v[a] + np.cross(w[a], rho_a) - v[b] - np.cross(w[b], point - x[b]))
            tau = self.efforts_one(i, q, rate)
            if js.rotary[i]:
                acc.torque_principal[a] += tau * row[W_K_CHILD:W_K_CHILD + 3]
                if b < n:
                    acc.torque_principal[b] -= tau * row[W_K_PARENT:W_K_PARENT + 3]
                continue
            f = tau * k_w
            acc.force_world[a] += f
            acc.torque_world[a] += np.cross(rho_a, f)
            if b < n:
                acc.force_world[b] -= f
                acc.torque_world[b] -= np.cross(point - x[b], f)

    def efforts_one(self, i: int, q: float, rate: float) -> float:
        """Return the drive effort of joint i at one coordinate and rate (:meth:`efforts`)."""
        tau = 0.0
        if self.servo[i]:
            limit = self.space.effort_limit[i]
            tau = min(max(self.kp[i] * (self.q_target[i] - q)
                          + self.kd[i] * (self.v_target[i] - rate), -limit), limit)
        return tau - self.damping[i] * rate
