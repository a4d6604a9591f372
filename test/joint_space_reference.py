"""
Joint-space reference dynamics of fixed-base URDF trees: an oracle for the robot tests.

The simulator integrates robots in maximal coordinates (one rigid body per link, joints as
Lagrange-multiplier constraints). This module is an independent check of it: it parses the
URDF itself with ``urdf_parser_py`` and computes the joint-space dynamics

    M(q) qdd + h(q, qd) = tau,    h(q, qd) = C(q, qd) qd + g(q),

from the textbook recursions of Featherstone, *Rigid Body Dynamics Algorithms* (2008):
the recursive Newton-Euler algorithm (RNEA, ch. 5) for ``h`` and inverse dynamics, and the
composite-rigid-body algorithm (CRBA, ch. 6) for ``M``. It imports only numpy and
urdf_parser_py, nothing of the simulator.

Conventions
-----------
- URDF, exactly as specified: a joint frame is its parent link frame moved by the joint
  ``origin`` (translation xyz, then rotation ``R = Rz(yaw) Ry(pitch) Rx(roll)``, i.e.
  fixed-axis roll about x, then pitch about y, then yaw about z). The child link frame is
  the joint frame moved by the joint motion: a rotation by q about ``axis`` (revolute,
  continuous) or a translation ``q * axis`` (prismatic); ``axis`` is given in the joint
  frame, normalized here, and a missing ``<axis>`` means (1, 0, 0). Fixed joints have no
  coordinate: the child rides rigidly on its parent. A link's ``<inertial>`` gives its
  centre of mass (origin xyz) and the inertia tensor about it in the inertial frame
  (origin rpy), so the tensor in the link frame is ``R I Rᵀ``. A link without
  ``<inertial>`` is massless.
- The base is fixed: the root link (often named ``world``) is the world frame. Its own
  inertia does not enter the dynamics. Floating and planar joints are not supported.
- Generalized coordinates: one per revolute, continuous or prismatic joint, in the order
  of ``JointSpaceModel.joint_names``, which is the URDF file's joint order restricted to
  those joints. Zero is the URDF zero configuration. Mimic joints keep their own
  coordinate in the full model (which ignores ``<mimic>``); the reduced model
  (``reduced_*`` methods) eliminates them (see ``JointSpaceModel.mimic_map``).
- Spatial vectors (Featherstone's notation, angular part first) are expressed in world
  coordinates about the world origin O: a twist is ``[omega; v_O]`` with v_O the
  velocity of the body point at O, a wrench ``[n_O; f]``. In these coordinates a joint's
  motion subspace S depends on q but no coordinate transforms are needed along the tree.
- ``tau`` is the total generalized force on each coordinate (N m for revolute, N for
  prismatic). ``<dynamics damping friction>`` and ``<limit>`` are read (``damping``,
  ``friction``, ``limits``) but never applied: a test adds them to tau if it wants them.
- SI units; gravity defaults to (0, 0, -9.81) m/s².
"""

import collections
import os

import numpy as np

from urdf_parser_py.urdf import URDF

_EYE3 = np.eye(3)
_EYE4 = np.eye(4)

#: The directory of the test robots (hand-written URDF and xacro files).
URDF_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'urdf')

#: Joint types with one coordinate; 'fixed' has none; others are rejected.
MOVING_TYPES = ('revolute', 'continuous', 'prismatic')
SUPPORTED_TYPES = MOVING_TYPES + ('fixed',)

JointLimit = collections.namedtuple('JointLimit', 'lower upper effort velocity')


def urdf_path(file_name: str) -> str:
    """Return the path of a test robot in ``test/urdf``."""
    return os.path.join(URDF_DIR, file_name)


def rpy_matrix(rpy) -> np.ndarray:
    """
    Return the URDF rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` of ``rpy = (roll, pitch, yaw)``.

    Parameters
    ----------
    rpy : array_like, shape (3,)
        Roll, pitch, yaw in rad (fixed axes x, then y, then z).

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        The rotation matrix, mapping coordinates in the rotated frame to the parent's.

    """
    roll, pitch, yaw = (float(a) for a in rpy)
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the row-wise cross products of a and b, shapes (..., 3) (faster than np.cross)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _matvecs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the products a_l b_l of matrices a (m, i, j) and vectors b (m, j), (m, i)."""
    return (a @ b[..., None])[..., 0]


def _skews(v: np.ndarray) -> np.ndarray:
    """Return the cross-product matrices (shape (m, 3, 3)) of vectors v (shape (m, 3))."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def spatial_inertias(mass, com_world, inertia_com_world) -> np.ndarray:
    """
    Return bodies' spatial inertias about the world origin (Featherstone eq. 2.63).

    Parameters
    ----------
    mass : array_like, shape (m,)
        Masses in kg.
    com_world : array_like, shape (m, 3)
        Centres of mass in world coordinates, m.
    inertia_com_world : array_like, shape (m, 3, 3)
        Rotational inertias about the centres of mass, world axes, kg m².

    Returns
    -------
    numpy.ndarray, shape (m, 6, 6)
        ``[[I_c + m [c]x [c]xᵀ, m [c]x], [m [c]xᵀ, m 1]]`` (angular rows first).

    """
    mass = np.asarray(mass, dtype=float)[:, None, None]
    cx = _skews(np.asarray(com_world, dtype=float))
    out = np.empty((len(mass), 6, 6))
    out[:, :3, :3] = inertia_com_world + mass * cx @ cx.transpose(0, 2, 1)
    out[:, :3, 3:] = mass * cx
    out[:, 3:, :3] = mass * cx.transpose(0, 2, 1)
    out[:, 3:, 3:] = mass * _EYE3
    return out


def _motion_cross_matrices(v: np.ndarray) -> np.ndarray:
    """Return ``v x = [[[w]x, 0], [[v_O]x, [w]x]]`` (shape (m, 6, 6)) of twists v (m, 6)."""
    out = np.zeros(v.shape[:-1] + (6, 6))
    out[..., :3, :3] = out[..., 3:, 3:] = _skews(v[..., :3])
    out[..., 3:, :3] = _skews(v[..., 3:])
    return out


class _Link:
    """One link: its parent joint and its inertial data in the link frame."""

    def __init__(self, name, mass, com_link, inertia_link):
        self.name = name
        self.mass = mass                    # kg; 0 for a massless link
        self.com_link = com_link            # (3,) m, link frame
        self.inertia_link = inertia_link    # (3, 3) kg m², about the COM, link axes
        self.parent = None                  # index of the parent link, None for the root
        self.joint = None                   # the _Joint to the parent, None for the root


class _Joint:
    """One joint: its origin in the parent link frame, its axis and its coordinate."""

    def __init__(self, name, kind, origin_xyz, origin_rot, axis, coordinate):
        self.name = name
        self.kind = kind                    # 'revolute', 'continuous', 'prismatic', 'fixed'
        self.origin_xyz = origin_xyz        # (3,) m, in the parent link frame
        self.origin_rot = origin_rot        # (3, 3) joint frame -> parent link frame
        self.axis = axis                    # (3,) unit, in the joint frame
        self.coordinate = coordinate        # index into q, None for a fixed joint


class _Kinematics:
    """Link frames, joint motion subspaces and spatial inertias at one configuration."""

    def __init__(self, p, rot, subspace, inertia):
        self.p = p                          # (n_links, 3) link frame origins, world
        self.rot = rot                      # (n_links, 3, 3) link frame -> world
        self.subspace = subspace            # (n_links, 6) S of each link's joint (0: fixed)
        self.inertia = inertia              # (n_links, 6, 6) about the world origin


class JointSpaceModel:
    """
    Joint-space dynamics of a fixed-base URDF tree (RNEA and CRBA, world coordinates).

    Build it with :meth:`from_urdf`. Attributes (read only):

    - ``robot_name`` (str), ``root_link`` (str): the root link, fixed at the world origin.
    - ``link_names`` (list of str): every link, parents before children.
    - ``joint_names`` (list of str): the coordinates' joints, in URDF order (length n).
    - ``n`` (int): number of coordinates.
    - ``gravity`` (numpy.ndarray, shape (3,)): m/s², world frame.
    - ``damping``, ``friction`` (numpy.ndarray, shape (n,)): the URDF ``<dynamics>``
      values (0 when absent); never applied.
    - ``limits`` (dict str -> JointLimit or None): the URDF ``<limit>`` of each coordinate,
      as urdf_parser_py reads it (a missing lower or upper reads as 0).
    - ``mimic_map`` (dict str -> (str, float, float)): mimic joint -> (leader, multiplier,
      offset) with ``q_mimic = multiplier * q_leader + offset``; chains are resolved, so
      the leader is always an independent joint.
    - ``independent_joint_names`` (list of str): ``joint_names`` without the mimic joints,
      the coordinates of the reduced model (length r).
    """

    def __init__(self, robot_name, links, joints, gravity, mimic):
        """Assemble a model from parsed links (parents first); use :meth:`from_urdf`."""
        self.robot_name = robot_name
        self._links = links
        self.root_link = links[0].name
        self.link_names = [link.name for link in links]
        moving = sorted((j for j in joints if j.coordinate is not None),
                        key=lambda j: j.coordinate)
        self.joint_names = [j.name for j in moving]
        self.n = len(moving)
        self.gravity = np.array(gravity, dtype=float).reshape(3)
        self.damping = np.zeros(self.n)
        self.friction = np.zeros(self.n)
        self.limits = {}
        self.mimic_map = _resolve_mimic(mimic, self.joint_names)
        self.independent_joint_names = [name for name in self.joint_names
                                        if name not in self.mimic_map]
        column = {name: k for k, name in enumerate(self.independent_joint_names)}
        self._mimic_matrix = np.zeros((self.n, len(column)))
        self._mimic_offset = np.zeros(self.n)
        for i, name in enumerate(self.joint_names):
            if name in column:
                self._mimic_matrix[i, column[name]] = 1.0
            else:
                leader, multiplier, offset = self.mimic_map[name]
                self._mimic_matrix[i, column[leader]] = multiplier
                self._mimic_offset[i] = offset
        self._mimic_matrix.flags.writeable = False
        self._mimic_offset.flags.writeable = False
        self._arrays()

    def _arrays(self):
        """Lay the tree out as arrays over the links (index 0: the root)."""
        links = self._links
        count = len(links)
        self._parent_list = [0] + [link.parent for link in links[1:]]
        self._parent = np.array(self._parent_list)
        # support[i, j] = 1 where link j is link i or one of its ancestors (the root, which
        # does not move, left out): a sum over the path from the root is a product with it.
        self._support = np.zeros((count, count))
        for i in range(1, count):
            j = i
            while j > 0:
                self._support[i, j] = 1.0
                j = links[j].parent
        joints = [None] + [link.joint for link in links[1:]]
        kinds = ['fixed'] + [joint.kind for joint in joints[1:]]
        self._revolute = np.array([kind in ('revolute', 'continuous') for kind in kinds])
        self._prismatic = np.array([kind == 'prismatic' for kind in kinds])
        self._revolute_column = self._revolute[:, None].astype(float)
        self._prismatic_column = self._prismatic[:, None].astype(float)
        # Each link's coordinate, n (a padded zero) for the root and fixed joints.
        self._coordinate = np.array([self.n if joint is None or joint.coordinate is None
                                     else joint.coordinate for joint in joints])
        self._moving_links = np.argsort(self._coordinate, kind='stable')[:self.n]
        self._moving_rows = self._moving_links[:, None]
        self._strict_support = self._support - np.diag(np.diag(self._support))
        self._origin_xyz = np.array([np.zeros(3)] + [j.origin_xyz for j in joints[1:]])
        self._origin_rot = np.array([np.eye(3)] + [j.origin_rot for j in joints[1:]])
        axis = np.array([np.zeros(3)] + [j.axis if j.kind in MOVING_TYPES else np.zeros(3)
                                         for j in joints[1:]])
        self._axis_parent = _matvecs(self._origin_rot, axis)
        self._k = _skews(axis * self._revolute[:, None])
        self._k2 = self._k @ self._k
        self._mass = np.array([0.0] + [link.mass for link in links[1:]])
        self._com_link = np.array([link.com_link for link in links])
        self._inertia_link = np.array([link.inertia_link for link in links])

    # ---------------------------------------------------------------- construction

    @classmethod
    def from_urdf(cls, xml_string, base_fixed: bool = True,
                  gravity=(0.0, 0.0, -9.81)) -> 'JointSpaceModel':
        """
        Parse a URDF document into a joint-space model.

        Parameters
        ----------
        xml_string : str or bytes
            The URDF document (after xacro, if any).
        base_fixed : bool
            Must be True: the root link is fixed at the world origin (a floating base is
            not supported).
        gravity : array_like, shape (3,)
            Gravitational acceleration in the world frame, m/s².

        Returns
        -------
        JointSpaceModel

        Raises
        ------
        NotImplementedError
            If ``base_fixed`` is False.
        ValueError
            If a joint type other than revolute, continuous, prismatic or fixed occurs,
            an axis is zero, the links do not form one tree, or a mimic joint names an
            unknown or non-moving leader.

        """
        if not base_fixed:
            raise NotImplementedError('JointSpaceModel supports a fixed base only')
        if isinstance(xml_string, str):
            xml_string = xml_string.encode('utf-8')   # lxml refuses str with an encoding
        robot = URDF.from_xml_string(xml_string)
        links = {}
        for link in robot.links:
            links[link.name] = _parse_link(link)
        joints = []
        by_child = {}
        mimic = {}
        for joint in robot.joints:
            if joint.type not in SUPPORTED_TYPES:
                raise ValueError(f'joint {joint.name!r}: type {joint.type!r} is not '
                                 f'supported (only {", ".join(SUPPORTED_TYPES)})')
            for end in (joint.parent, joint.child):
                if end not in links:
                    raise ValueError(f'joint {joint.name!r}: unknown link {end!r}')
            if joint.child in by_child:
                raise ValueError(f'link {joint.child!r} is the child of two joints')
            coordinate = None
            if joint.type in MOVING_TYPES:
                coordinate = sum(j.coordinate is not None for j in joints)
            parsed = _parse_joint(joint, coordinate)
            joints.append(parsed)
            by_child[joint.child] = (parsed, joint)
            if joint.mimic is not None:
                if coordinate is None:
                    raise ValueError(f'joint {joint.name!r}: a fixed joint cannot mimic')
                multiplier = 1.0 if joint.mimic.multiplier is None else joint.mimic.multiplier
                offset = 0.0 if joint.mimic.offset is None else joint.mimic.offset
                mimic[joint.name] = (joint.mimic.joint, float(multiplier), float(offset))
        roots = [name for name in links if name not in by_child]
        if len(roots) != 1:
            raise ValueError(f'the links must form one tree; roots: {roots}')
        # Parents before children (breadth first from the root), children in URDF order.
        children = {name: [] for name in links}
        for joint in robot.joints:
            children[joint.parent].append(joint.child)
        order = [roots[0]]
        for name in order:
            order.extend(children[name])
        if len(order) != len(links):
            raise ValueError('the joints contain a cycle')
        position = {name: i for i, name in enumerate(order)}
        ordered = [links[name] for name in order]
        for name in order[1:]:
            parsed, joint = by_child[name]
            links[name].parent = position[joint.parent]
            links[name].joint = parsed
        model = cls(robot.name, ordered, joints, gravity, mimic)
        for parsed, joint in by_child.values():
            if parsed.coordinate is None:
                continue
            dynamics = joint.dynamics
            if dynamics is not None:
                model.damping[parsed.coordinate] = dynamics.damping or 0.0
                model.friction[parsed.coordinate] = dynamics.friction or 0.0
            limit = joint.limit
            model.limits[joint.name] = None if limit is None else JointLimit(
                limit.lower, limit.upper, limit.effort, limit.velocity)
        return model

    # ---------------------------------------------------------------- kinematics

    def _vector(self, x, name: str, size: int = None) -> np.ndarray:
        size = self.n if size is None else size
        out = np.asarray(x, dtype=float)
        if out.shape != (size,):
            raise ValueError(f'{name} must have shape ({size},), got {out.shape}')
        return out

    def _per_link(self, x: np.ndarray) -> np.ndarray:
        """Return each link's joint coordinate of x (shape (n,)): 0 for root and fixed."""
        padded = np.zeros(self.n + 1)
        padded[:self.n] = x
        return padded[self._coordinate]

    def _kinematics(self, q) -> _Kinematics:
        q_link = self._per_link(self._vector(q, 'q'))
        angle = np.where(self._revolute, q_link, 0.0)[:, None, None]
        slide = np.where(self._prismatic, q_link, 0.0)[:, None]
        # Each link frame in its parent's: the joint origin, then the joint motion.
        local_rot = self._origin_rot @ (_EYE3 + np.sin(angle) * self._k
                                        + (1.0 - np.cos(angle)) * self._k2)
        count = len(self._links)
        local = np.zeros((count, 4, 4))
        local[:, :3, :3] = local_rot
        local[:, :3, 3] = self._origin_xyz + slide * self._axis_parent
        local[:, 3, 3] = 1.0
        pose = [_EYE4]              # homogeneous link -> world transforms
        for i, parent in enumerate(self._parent_list[1:], start=1):
            pose.append(pose[parent] @ local[i])
        pose = np.array(pose)
        p = pose[:, :3, 3]
        rot = pose[:, :3, :3]
        parent = self._parent
        rot_parent = rot[parent]
        axis_world = _matvecs(rot_parent, self._axis_parent)
        p_joint = p[parent] + _matvecs(rot_parent, self._origin_xyz)
        # Motion subspaces: [a; p_joint x a] (revolute), [0; a] (prismatic), 0 (fixed).
        subspace = np.zeros((count, 6))
        subspace[:, :3] = axis_world * self._revolute_column
        subspace[:, 3:] = (_cross(p_joint, axis_world) * self._revolute_column
                           + axis_world * self._prismatic_column)
        com_world = p + _matvecs(rot, self._com_link)
        inertia_world = rot @ self._inertia_link @ rot.transpose(0, 2, 1)
        inertia = spatial_inertias(self._mass, com_world, inertia_world)
        return _Kinematics(p, rot, subspace, inertia)

    def fk(self, q) -> dict:
        """
        Return the world pose of every link frame.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint coordinates (rad or m), in the order of ``joint_names``.

        Returns
        -------
        dict
            link name -> ``(p_world, R_world)``: the frame origin, shape (3,), and the
            rotation from link to world coordinates, shape (3, 3).

        """
        kin = self._kinematics(q)
        return {link.name: (kin.p[i], kin.rot[i]) for i, link in enumerate(self._links)}

    def joint_axes_world(self, q) -> dict:
        """
        Return each moving joint's axis in the world frame.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint coordinates.

        Returns
        -------
        dict
            joint name -> ``(point_world, axis_world)``: the joint frame origin, shape (3,),
            and the unit axis, shape (3,), both in world coordinates. For a prismatic joint
            the point is where the child frame is at q = 0 for the current parent pose.

        """
        q = self._vector(q, 'q')
        kin = self._kinematics(q)
        out = {}
        for i in range(1, len(self._links)):
            link = self._links[i]
            joint = link.joint
            if joint.coordinate is None:
                continue
            parent = link.parent
            rot_joint = kin.rot[parent] @ joint.origin_rot
            out[joint.name] = (kin.p[parent] + kin.rot[parent] @ joint.origin_xyz,
                               rot_joint @ joint.axis)
        return out

    def link_twists(self, q, qd) -> dict:
        """
        Return the velocity of every link frame, by classical velocity propagation.

        ``omega_child = omega_parent + qd axis`` (revolute) and ``v_child = v_parent +
        omega_parent x (p_child - p_parent) + qd axis`` (prismatic), independently of
        the spatial-vector recursions used for the dynamics.

        Parameters
        ----------
        q, qd : array_like, shape (n,)
            Joint coordinates and velocities.

        Returns
        -------
        dict
            link name -> ``(v_origin_world, omega_world)``: the velocity of the link frame
            origin, m/s, and the angular velocity, rad/s, both shape (3,), world frame.

        """
        qd = self._vector(qd, 'qd')
        kin = self._kinematics(q)
        count = len(self._links)
        v = np.zeros((count, 3))
        w = np.zeros((count, 3))
        for i in range(1, count):
            link = self._links[i]
            joint = link.joint
            parent = link.parent
            w[i] = w[parent]
            v[i] = v[parent] + _cross(w[parent], kin.p[i] - kin.p[parent])
            if joint.coordinate is None:
                continue
            axis_world = kin.rot[parent] @ joint.origin_rot @ joint.axis
            if joint.kind == 'prismatic':
                v[i] += qd[joint.coordinate] * axis_world
            else:
                w[i] += qd[joint.coordinate] * axis_world
        return {link.name: (v[i], w[i]) for i, link in enumerate(self._links)}

    def link_inertia_world(self, q) -> dict:
        """
        Return every massive link's mass, centre of mass and inertia in the world frame.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint coordinates.

        Returns
        -------
        dict
            link name -> ``(mass, com_world, inertia_world)``: kg, shape (3,) m, and the
            inertia about the centre of mass in world axes, shape (3, 3) kg m². Massless
            links are left out.

        """
        kin = self._kinematics(q)
        out = {}
        for i, link in enumerate(self._links):
            if link.mass > 0.0:
                rot = kin.rot[i]
                out[link.name] = (link.mass, kin.p[i] + rot @ link.com_link,
                                  rot @ link.inertia_link @ rot.T)
        return out

    # ---------------------------------------------------------------- dynamics

    def _rnea(self, kin, qd, qdd, gravity) -> np.ndarray:
        """
        Return tau by Featherstone's RNEA, every quantity in world coordinates.

        The forward pass ``v_i = v_p + S_i qd_i``, ``a_i = a_p + S_i qdd_i + v_i x S_i
        qd_i`` (S_i is fixed in body i, so d/dt S_i = v_i x S_i in world coordinates),
        with ``a_0 = -g`` (gravity as an upward acceleration of the base), sums over each
        link's path from the root; the backward pass ``f_p += f_i`` sums over each link's
        subtree. Both are products with the support matrix.
        """
        support = self._support
        s = kin.subspace
        s_qd = s * self._per_link(qd)[:, None]
        s_qdd = s * self._per_link(qdd)[:, None]
        v = support @ s_qd
        cross = _motion_cross_matrices(v)       # v x; the force cross product is -(v x)ᵀ
        a = support @ (s_qdd + _matvecs(cross, s_qd))
        a[:, 3:] -= gravity
        inertia = kin.inertia
        f = (_matvecs(inertia, a)
             - np.einsum('lji,lj->li', cross, _matvecs(inertia, v)))
        f_subtree = support.T @ f
        return np.einsum('li,li->l', s, f_subtree)[self._moving_links]

    def _crba(self, kin) -> np.ndarray:
        """
        Return M by Featherstone's CRBA, every quantity in world coordinates.

        ``I^c_i`` is the sum of the spatial inertias of link i's subtree, and ``M_ij =
        S_iᵀ I^c_i S_j`` for a joint j on the path from the root to link i (M_ji by
        symmetry; 0 for joints on different branches).
        """
        support = self._support
        s = kin.subspace
        composite = np.einsum('ji,jkl->ikl', support, kin.inertia)
        force = _matvecs(composite, s)
        products = force @ s.T                  # [i, j] = S_jᵀ I^c_i S_i
        full = products * support + (products * self._strict_support).T
        return full[self._moving_rows, self._moving_links]

    def mass_matrix(self, q) -> np.ndarray:
        """
        Return the joint-space mass matrix M(q) by the CRBA.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint coordinates.

        Returns
        -------
        numpy.ndarray, shape (n, n)
            Symmetric positive definite (when every moving subtree has mass).

        """
        return self._crba(self._kinematics(q))

    def bias(self, q, qd) -> np.ndarray:
        """
        Return ``h(q, qd) = C(q, qd) qd + g(q)``: the RNEA with qdd = 0.

        Parameters
        ----------
        q, qd : array_like, shape (n,)
            Joint coordinates and velocities.

        Returns
        -------
        numpy.ndarray, shape (n,)
            The generalized force that keeps qdd = 0 (Coriolis, centrifugal, gravity).

        """
        qd = self._vector(qd, 'qd')
        return self._rnea(self._kinematics(q), qd, np.zeros(self.n), self.gravity)

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """
        Return the generalized force ``tau = M(q) qdd + h(q, qd)`` by the RNEA.

        Parameters
        ----------
        q, qd, qdd : array_like, shape (n,)
            Joint coordinates, velocities and accelerations.

        Returns
        -------
        numpy.ndarray, shape (n,)
            tau, N m or N per coordinate.

        """
        qd = self._vector(qd, 'qd')
        qdd = self._vector(qdd, 'qdd')
        return self._rnea(self._kinematics(q), qd, qdd, self.gravity)

    def forward_dynamics(self, q, qd, tau) -> np.ndarray:
        """
        Return ``qdd = M(q)⁻¹ (tau - h(q, qd))`` (CRBA, RNEA and a linear solve).

        Parameters
        ----------
        q, qd, tau : array_like, shape (n,)
            Joint coordinates, velocities and generalized forces.

        Returns
        -------
        numpy.ndarray, shape (n,)
            The joint accelerations.

        """
        qd = self._vector(qd, 'qd')
        tau = self._vector(tau, 'tau')
        kin = self._kinematics(q)
        h = self._rnea(kin, qd, np.zeros(self.n), self.gravity)
        return np.linalg.solve(self._crba(kin), tau - h)

    def energy(self, q, qd) -> tuple:
        """
        Return the kinetic and potential energy from the links' velocities and poses.

        Computed link by link (``½ m |v_com|² + ½ ωᵀ I_world ω`` and ``-m g·c``) from
        :meth:`link_twists`, not from M: comparing it with ``½ qdᵀ M qd`` checks M.

        Parameters
        ----------
        q, qd : array_like, shape (n,)
            Joint coordinates and velocities.

        Returns
        -------
        tuple of float
            ``(kinetic, potential)`` in J; the potential is zero with every centre of mass
            at the world origin.

        """
        twists = self.link_twists(q, qd)
        frames = self.fk(q)
        kinetic = potential = 0.0
        for name, (mass, com, inertia) in self.link_inertia_world(q).items():
            if name == self.root_link:
                continue        # fixed: no kinetic energy, a constant potential
            v_origin, w = twists[name]
            v_com = v_origin + _cross(w, com - frames[name][0])
            kinetic += 0.5 * mass * (v_com @ v_com) + 0.5 * w @ inertia @ w
            potential -= mass * (self.gravity @ com)
        return kinetic, potential

    # ---------------------------------------------------------------- mimic joints

    @property
    def mimic_matrix(self) -> np.ndarray:
        """Return the map T, shape (n, r), with ``q = T q_r + mimic_offset`` (read only)."""
        return self._mimic_matrix

    @property
    def mimic_offset(self) -> np.ndarray:
        """Return the offsets b, shape (n,), with ``q = T q_r + b`` (read only)."""
        return self._mimic_offset

    def expand(self, q_r) -> np.ndarray:
        """
        Return the full coordinates ``q = T q_r + b`` (shape (n,)) of reduced ones (r,).

        For velocities and accelerations use ``mimic_matrix @ qd_r`` (no offset).
        """
        return self._mimic_matrix @ self._vector(q_r, 'q_r', self._mimic_matrix.shape[1]) \
            + self._mimic_offset

    def reduced_dynamics(self, q_r, qd_r) -> tuple:
        """
        Return the dynamics with the mimic joints eliminated: ``M_r qdd_r + h_r = tau_r``.

        ``M_r = Tᵀ M(q) T`` and ``h_r = Tᵀ h(q, T qd_r)`` at ``q = T q_r + b``; a full
        generalized force tau acts on the reduced coordinates as ``tau_r = Tᵀ tau``.

        Parameters
        ----------
        q_r, qd_r : array_like, shape (r,)
            Coordinates and velocities of ``independent_joint_names``.

        Returns
        -------
        tuple
            ``(M_r, h_r)`` of shapes (r, r) and (r,).

        """
        t = self._mimic_matrix
        q = self.expand(q_r)
        qd = t @ self._vector(qd_r, 'qd_r', t.shape[1])
        kin = self._kinematics(q)
        h = self._rnea(kin, qd, np.zeros(self.n), self.gravity)
        return t.T @ self._crba(kin) @ t, t.T @ h

    def reduced_forward_dynamics(self, q_r, qd_r, tau_r) -> np.ndarray:
        """
        Return ``qdd_r = M_r⁻¹ (tau_r - h_r)`` (shape (r,)) of the reduced model.

        Parameters
        ----------
        q_r, qd_r, tau_r : array_like, shape (r,)
            Reduced coordinates, velocities and generalized forces (``tau_r = Tᵀ tau``).

        Returns
        -------
        numpy.ndarray, shape (r,)
            The accelerations of ``independent_joint_names``.

        """
        m_r, h_r = self.reduced_dynamics(q_r, qd_r)
        tau_r = self._vector(tau_r, 'tau_r', m_r.shape[0])
        return np.linalg.solve(m_r, tau_r - h_r)


def _parse_link(link) -> _Link:
    inertial = link.inertial
    if inertial is None or not inertial.mass:
        return _Link(link.name, 0.0, np.zeros(3), np.zeros((3, 3)))
    xyz, rot = _pose(inertial.origin)
    tensor = np.zeros((3, 3)) if inertial.inertia is None \
        else np.array(inertial.inertia.to_matrix(), dtype=float)
    return _Link(link.name, float(inertial.mass), xyz, rot @ tensor @ rot.T)


def _parse_joint(joint, coordinate) -> _Joint:
    xyz, rot = _pose(joint.origin)
    axis = np.array([1.0, 0.0, 0.0] if joint.axis is None else joint.axis, dtype=float)
    norm = np.linalg.norm(axis)
    if joint.type in MOVING_TYPES and not norm > 0.0:
        raise ValueError(f'joint {joint.name!r}: the axis is zero')
    return _Joint(joint.name, joint.type, xyz, rot, axis / norm if norm > 0.0 else axis,
                  coordinate)


def _pose(origin) -> tuple:
    if origin is None:
        return np.zeros(3), np.eye(3)
    xyz = np.zeros(3) if origin.xyz is None else np.array(origin.xyz, dtype=float)
    return xyz, rpy_matrix([0.0, 0.0, 0.0] if origin.rpy is None else origin.rpy)


def _resolve_mimic(mimic: dict, joint_names: list) -> dict:
    """Map each mimic joint to (independent leader, multiplier, offset), resolving chains."""
    out = {}
    for name in mimic:
        multiplier, offset = 1.0, 0.0
        current, seen = name, []
        while current in mimic:
            if current in seen:
                raise ValueError(f'mimic joints form a cycle: {seen}')
            seen.append(current)
            leader, m, b = mimic[current]
            if leader not in joint_names:
                raise ValueError(f'joint {current!r} mimics {leader!r}, which is not a '
                                 'revolute, continuous or prismatic joint of this robot')
            # q_current = m q_leader + b; composing with what maps current to name.
            multiplier, offset = multiplier * m, multiplier * b + offset
            current = leader
        out[name] = (current, multiplier, offset)
    return out


# -------------------------------------------------------------------- the planar 2R arm

#: Parameters of the textbook planar 2R arm: masses (kg), the first link's length l1,
#: the distances lc1, lc2 of the centres of mass from their joints (m), the inertias
#: i1, i2 about the joint axis through each centre of mass (kg m²) and g (m/s²).
TwoLinkParams = collections.namedtuple('TwoLinkParams', 'm1 m2 l1 lc1 lc2 i1 i2 g')

#: The parameters of ``two_link_arm.urdf`` (and of ``two_link_arm_rotated.urdf``).
TWO_LINK_PARAMS = TwoLinkParams(m1=1.3, m2=0.8, l1=0.5, lc1=0.22, lc2=0.17,
                                i1=0.021, i2=0.011, g=9.81)

#: The constant rotation of each link frame of ``two_link_arm_rotated.urdf`` relative to
#: the same link's frame in ``two_link_arm.urdf`` (rpy): ``R_rotated = R_plain Rpy(off)``.
TWO_LINK_ROTATED_FRAME_RPY = {'world': (0.0, 0.0, 0.0), 'base_link': (0.4, -0.3, 0.7),
                              'upper_arm': (-0.6, 0.25, 1.1), 'forearm': (0.9, 0.5, -0.35)}


def two_link_closed_form(params: TwoLinkParams) -> tuple:
    """
    Return M(q) and h(q, qd) of the planar 2R arm, written from its Lagrangian.

    Both joints turn about the horizontal y axis; at q = 0 the arm hangs straight down
    and q1 is the first link's angle from the downward vertical, q2 the second link's
    angle relative to the first. The centres of mass in the x-z plane are
    ``c1 = -lc1 (sin q1, cos q1)`` and ``c2 = -l1 (sin q1, cos q1) - lc2 (sin(q1 + q2),
    cos(q1 + q2))``, so ``T = ½ qdᵀ M qd`` and ``V = -g (m1 lc1 cos q1 + m2 (l1 cos q1 +
    lc2 cos(q1 + q2)))`` give

        M11 = i1 + i2 + m1 lc1² + m2 (l1² + lc2² + 2 l1 lc2 cos q2)
        M12 = M21 = i2 + m2 (lc2² + l1 lc2 cos q2),    M22 = i2 + m2 lc2²
        h1 = -m2 l1 lc2 sin q2 (2 qd1 qd2 + qd2²) + g1,    h2 = m2 l1 lc2 sin q2 qd1² + g2
        g1 = g (m1 lc1 sin q1 + m2 (l1 sin q1 + lc2 sin(q1 + q2))),  g2 = g m2 lc2 sin(q1 + q2)

    Parameters
    ----------
    params : TwoLinkParams
        Masses, lengths, inertias and g (see ``TwoLinkParams``).

    Returns
    -------
    tuple
        ``(mass_matrix, bias)``: ``mass_matrix(q)`` returns shape (2, 2) and
        ``bias(q, qd)`` returns h, shape (2,), for q, qd of shape (2,).

    """
    m1, m2, l1, lc1, lc2, i1, i2, g = params

    def mass_matrix(q) -> np.ndarray:
        c2 = np.cos(q[1])
        m11 = i1 + i2 + m1 * lc1 ** 2 + m2 * (l1 ** 2 + lc2 ** 2 + 2.0 * l1 * lc2 * c2)
        m12 = i2 + m2 * (lc2 ** 2 + l1 * lc2 * c2)
        return np.array([[m11, m12], [m12, i2 + m2 * lc2 ** 2]])

    def bias(q, qd) -> np.ndarray:
        s2 = np.sin(q[1])
        s1, s12 = np.sin(q[0]), np.sin(q[0] + q[1])
        coupling = m2 * l1 * lc2 * s2
        g1 = g * (m1 * lc1 * s1 + m2 * (l1 * s1 + lc2 * s12))
        g2 = g * m2 * lc2 * s12
        return np.array([-coupling * (2.0 * qd[0] * qd[1] + qd[1] ** 2) + g1,
                         coupling * qd[0] ** 2 + g2])

    return mass_matrix, bias


def xacro_arm_params(link_length: float = 0.4) -> TwoLinkParams:
    """
    Return the 2R-arm parameters of ``xacro_arm.urdf.xacro`` expanded with ``link_length``.

    Its links are uniform rods of 1 kg and radius 0.02 m hanging from their joints, so
    ``lc = L / 2`` and the inertia about the joint axis through the centre of mass is
    ``m (L² / 12 + r² / 4)``.
    """
    mass, radius = 1.0, 0.02
    inertia = mass * (link_length ** 2 / 12.0 + radius ** 2 / 4.0)
    return TwoLinkParams(m1=mass, m2=mass, l1=link_length, lc1=link_length / 2.0,
                         lc2=link_length / 2.0, i1=inertia, i2=inertia, g=9.81)
