"""
The messages the node publishes at one instant, built from a Simulation (no publishing).

The node publishes them; the experiment runner writes the same messages into
a bag, so a recorded run and a lockstep run hold the same data. Topics are
private names (``~/...``): the node resolves them under its name, the runner
under the node name it stands for (default ``/rigid_body_sim``).

Frames and points (also in the README): poses are the body frame's origin
and orientation in the world frame; twists the origin's velocity and the
angular velocity, world axes; a constraint's wrench on a body is in that
body's axes about its frame origin (``frame_id`` the body), on the world in
world axes about the world origin.

Robots (URDF): a body is a group of links lumped by fixed joints, and its
frame is the frame of the group's topmost link, named as the body (the link
name with the robot's prefix). So tf has the world frame -> each body (moving,
:meth:`Outputs.transforms`), each body -> its other links, and the world frame
-> the links fixed to the world (both constant, :meth:`Outputs.static_transforms`).
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
from rigid_body_sim_interfaces.msg import Metrics
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from . import conversions as conv
from ..core import rotation as so3
from ..core import Simulation
from ..core.hulls import hull_triangles
from ..core.robots import rpy_matrix

#: m: diameter of the sphere that marks a joint.
JOINT_MARKER_SIZE = 0.04
#: m: size of the points that mark contacts; m per N: length of a contact force's line.
CONTACT_MARKER_SIZE = 0.02
CONTACT_FORCE_SCALE = 0.01
#: m: a plane's collision marker, a square slab this wide and this thick.
PLANE_MARKER_SIDE, PLANE_MARKER_THICKNESS = 20.0, 0.001
#: Body colours (RGBA), cycled.
PALETTE = ((0.12, 0.47, 0.71, 0.9), (1.0, 0.5, 0.05, 0.9), (0.17, 0.63, 0.17, 0.9),
           (0.58, 0.4, 0.74, 0.9), (0.55, 0.34, 0.29, 0.9), (0.89, 0.47, 0.76, 0.9))


def body_topic(body: str, kind: str) -> str:
    """Return ``~/bodies/<body>/<kind>`` (kind: pose, twist or wrench)."""
    return f'~/bodies/{body}/{kind}'


def constraint_topic(name: str) -> str:
    """Return ``~/constraints/<name>/wrench``."""
    return f'~/constraints/{name}/wrench'


def group_topic(group: str) -> str:
    """Return a command group's topic, namespace-relative (forward_command_controller's)."""
    return f'{group}/commands'


STATES_TOPIC = '~/body_states'
CONTACTS_TOPIC = '~/contacts'
METRICS_TOPIC = '~/metrics'
MARKERS_TOPIC = '~/markers'
#: Robots: namespace-relative, as joint_state_broadcaster and robot_state_publisher name them.
JOINT_STATES_TOPIC = 'joint_states'
ROBOT_DESCRIPTION_TOPIC = 'robot_description'
JOINT_COMMANDS_TOPIC = '~/joint_commands'
TF_TOPIC = '/tf'
TF_STATIC_TOPIC = '/tf_static'


class Outputs:
    """
    Build the node's output messages for one Simulation.

    Parameters
    ----------
    sim : Simulation
    shapes : dict
        ``{body: (shape, dims)}`` of the scene (:attr:`rigid_body_sim.scene.Scene.shapes`);
        other bodies are drawn as the box of equal inertia.
    world_frame : str
    robots : sequence of (str, ParsedUrdf)
        :attr:`rigid_body_sim.scene.Scene.robots`, in the order of ``sim.robots``:
        each robot's prefix and URDF (for the links' visuals).

    """

    def __init__(self, sim: Simulation, shapes: dict, world_frame: str,
                 robots: Sequence = ()) -> None:
        self.sim = sim
        self.shapes = dict(shapes)
        self.world_frame = world_frame
        index = {name: i for i, name in enumerate(sim.bodies.names)}
        #: Indices of the robots' bodies (each the frame of its topmost link), body order.
        self.robot_bodies = sorted(index[b.name] for m in sim.robots for b in m.bodies)
        # Each link's frame (frame id with the prefix) on its body (None: the world).
        self._links = [(model.spec.prefix + link, frame)
                       for model in sim.robots for link, frame in model.links.items()]
        # Each visual: (body index or None, its pose in that body's frame, Visual, frame id).
        self._visuals = []
        for (prefix, parsed), model in zip(robots, sim.robots):
            for v in parsed.visuals:
                frame = model.links[v.link]
                R_v = rpy_matrix(v.rpy)
                self._visuals.append((
                    None if frame.body is None else index[frame.body],
                    frame.position + frame.rotation @ np.asarray(v.xyz, dtype=float),
                    frame.rotation @ R_v, v, prefix + v.link))
        #: Draw the collision shapes in ~/markers (the node's ``collision_markers``).
        self.collision_markers = False
        drawn = {i for i, *_ in self._visuals if i is not None}
        #: Bodies drawn as their shape or box: all but the robots' bodies with visuals.
        self._plain = [i for i in range(len(sim.bodies.names)) if i not in drawn]

    def snapshot(self, stamp, bodies: Optional[Sequence[int]] = None,
                 states: bool = True, reactions: Optional[Sequence[str]] = None,
                 metrics: Optional[tuple] = None, markers: bool = True,
                 contacts: bool = False) -> list:
        """
        Return ``[(topic, message), ...]`` of one publish, in publish order.

        Parameters
        ----------
        stamp : builtin_interfaces.msg.Time
            Simulation time of the state.
        bodies : sequence of int, optional
            Indices of bodies whose pose and twist to include (None: all).
        states : bool
            Include ``~/body_states``.
        reactions : sequence of str, optional
            Constraints whose reaction wrenches to include (None: all).
        metrics : (int, float), optional
            ``(step_count, energy at the last reset)``: include ``~/metrics``.
        markers : bool
            Include ``~/markers``.
        contacts : bool
            Include ``~/contacts`` (a scene with collision shapes).

        """
        sim = self.sim
        names = sim.bodies.names
        world = Header(stamp=stamp, frame_id=self.world_frame)
        out = []
        pos, quat = sim.pose()
        vel, omega = sim.twist()
        if states:
            out.append((STATES_TOPIC, conv.body_states(world, names, pos, quat, vel, omega)))
        for i in range(len(names)) if bodies is None else bodies:
            out.append((body_topic(names[i], 'pose'), conv.pose_stamped(world, pos[i], quat[i])))
            out.append((body_topic(names[i], 'twist'),
                        conv.twist_stamped(world, vel[i], omega[i])))
        wanted = sim.constraint_names if reactions is None else reactions
        if wanted:
            out += self._reactions(stamp, pos, quat, set(wanted))
        if metrics is not None:
            out.append((METRICS_TOPIC, self.metrics(world, *metrics)))
        if markers:
            out.append((MARKERS_TOPIC, self.markers(world)))
        if contacts and sim.contact is not None:
            out.append((CONTACTS_TOPIC, conv.contacts(world, sim.contacts())))
        return out

    def _reactions(self, stamp, pos: np.ndarray, quat: np.ndarray, names: set) -> list:
        """
        Each constraint's wrench on each body it acts on, and on the world.

        One WrenchStamped per body, with ``frame_id`` the body's name: force and
        torque in the body's frame, the torque about the body frame's origin (the
        point ``~/bodies/<B>/pose`` reports). For a constraint to the world, one
        more with ``frame_id`` the world frame: the wrench on the world, torque
        about the world origin (equal and opposite). A mimic joint's row acts on the
        bodies of both its joints.
        """
        sim = self.sim
        index = {n: i for i, n in enumerate(sim.bodies.names)}
        com = sim.state.pos_com_world
        out = []
        for name, per_body in sim.reactions().items():
            if name not in names:
                continue
            topic = constraint_topic(name)
            on_world_f = np.zeros(3)
            on_world_t = np.zeros(3)
            for body, r in per_body.items():
                i = index[body]
                R = so3.quat_to_matrix(quat[i])
                torque_origin = r.torque_com_world + so3.cross(com[i] - pos[i], r.force_world)
                out.append((topic, conv.wrench_stamped(Header(stamp=stamp, frame_id=body),
                                                       R.T @ r.force_world,
                                                       R.T @ torque_origin)))
                on_world_f -= r.force_world
                on_world_t -= r.torque_com_world + so3.cross(com[i], r.force_world)
            spec = sim.constraint_spec(name)
            if spec.body_b is None or (spec.coupling is not None
                                       and spec.coupling.body_b is None):
                out.append((topic, conv.wrench_stamped(
                    Header(stamp=stamp, frame_id=self.world_frame), on_world_f, on_world_t)))
        return out

    # -- robots -----------------------------------------------------------------------------

    def joint_states(self, stamp):
        """Return the ``sensor_msgs/JointState`` of every joint now (``sim.joint_state()``)."""
        js = self.sim.joint_state()
        return conv.joint_state(Header(stamp=stamp), js.names, js.positions, js.velocities,
                                js.efforts)

    def transforms(self, stamp) -> list:
        """
        Return the world frame -> each robot body's frame, as TransformStamped (for /tf).

        The child frame is the body's name (its topmost link with the robot's
        prefix); translation and rotation are the body's pose, as
        ``~/bodies/<B>/pose`` has it.
        """
        pos, quat = self.sim.pose()
        world = Header(stamp=stamp, frame_id=self.world_frame)
        names = self.sim.bodies.names
        return [conv.transform_stamped(world, names[i], pos[i], quat[i])
                for i in self.robot_bodies]

    def static_transforms(self, stamp) -> list:
        """
        Return the links' constant transforms, as TransformStamped (for /tf_static).

        Each link lumped into a body relative to that body's frame, and each link
        fixed to the world relative to the world frame (a URDF link that is the
        world frame itself is left out).
        """
        links = [(frame_id, frame, self.world_frame if frame.body is None else frame.body)
                 for frame_id, frame in self._links]
        # (the body's own frame, or the world link as the world frame, left out)
        links = [x for x in links if x[0] != x[2]]
        if not links:
            return []
        quats = so3.matrix_to_quat(np.array([frame.rotation for _, frame, _ in links]))
        return [conv.transform_stamped(Header(stamp=stamp, frame_id=parent), frame_id,
                                       frame.position, q)
                for (frame_id, frame, parent), q in zip(links, quats)]

    def metrics(self, header: Header, step_count: int, energy0: float) -> Metrics:
        """Return the scene's energies, largest violation and momenta now."""
        d = self.sim.diagnostics()
        kinetic = float(np.sum(d.kinetic_energy))
        potential = float(np.sum(d.potential_energy))
        return Metrics(header=header, step_count=int(step_count),
                       total_energy=kinetic + potential, kinetic_energy=kinetic,
                       potential_energy=potential,
                       energy_change=kinetic + potential - energy0,
                       constraint_violation=float(d.constraint_violation),
                       linear_momentum=conv.vector3(d.linear_momentum_world),
                       angular_momentum=conv.vector3(d.angular_momentum_com_world))

    def markers(self, header: Header) -> MarkerArray:
        """
        Return the bodies as their shapes and the joints as small spheres.

        A robot's links are drawn as their URDF visuals (box, cylinder, sphere,
        mesh: a MESH_RESOURCE with the URI as written, ``file://`` for a plain
        path), posed by their bodies, in namespace ``visuals``. A body whose
        scene gives a shape (box, sphere, cylinder) is drawn as that shape about
        its centre of mass in its own axes; any other (also a robot body whose
        links have no visual) as the uniform box of equal mass and principal
        moments, in its principal axes. Each array starts with a DELETEALL, so
        removed constraints disappear.
        """
        sim = self.sim
        bodies = sim.bodies
        state = sim.state
        pos_body, quat_body = sim.pose()
        out = [Marker(header=header, action=Marker.DELETEALL)]
        if self._visuals:
            out += self._visual_markers(header, pos_body, so3.quat_to_matrix(quat_body))
        for i in self._plain:
            name = bodies.names[i]
            kind, dims = self.shapes.get(name, (None, None))
            if kind == 'box':
                shape, scale, q = Marker.CUBE, dims, quat_body[i]
            elif kind == 'sphere':
                shape, scale, q = Marker.SPHERE, [2 * dims[0]] * 3, quat_body[i]
            elif kind == 'cylinder':
                shape, scale, q = Marker.CYLINDER, [2 * dims[0], 2 * dims[0], dims[1]], \
                    quat_body[i]
            else:
                shape, scale = Marker.CUBE, equal_inertia_box(bodies.mass[i], bodies.moments[i])
                q = state.quat_principal_world[i]
            out.append(Marker(
                header=header, ns='bodies', id=i, type=shape, action=Marker.ADD,
                pose=conv.pose(state.pos_com_world[i], q), scale=conv.vector3(scale),
                color=ColorRGBA(**dict(zip('rgba', PALETTE[i % len(PALETTE)]))), text=name))
        for j, (name, point) in enumerate(sim.joint_anchors().items()):
            out.append(Marker(
                header=header, ns='joints', id=j, type=Marker.SPHERE, action=Marker.ADD,
                pose=conv.pose(point, [0.0, 0.0, 0.0, 1.0]),
                scale=conv.vector3([JOINT_MARKER_SIZE] * 3),
                color=ColorRGBA(r=0.84, g=0.15, b=0.16, a=1.0), text=name))
        if sim.contact is not None:
            out += self._contact_markers(header)
            if self.collision_markers:
                out += self._collision_markers(header)
        return MarkerArray(markers=out)

    def _collision_markers(self, header: Header) -> list:
        """
        Return the collision shapes where they are now (namespace ``collisions``, grey).

        Sphere, box and cylinder as themselves; a capsule as its cylinder (id ``k``)
        and its two end spheres (ids ``m + 2k``, ``m + 2k + 1``, ``m`` the shapes'
        count); a mesh as the convex hull that is simulated (a triangle list: each face
        fanned from its first corner); a plane as a 20 m square slab 1 mm thick whose
        top is the plane. Shape ``k`` of the detector's shapes that collide has id ``k``.
        """
        sim = self.sim
        det = sim.contact.detector
        sim.bodies.outputs(sim.state)
        centre, R = det.frames(sim.bodies.outputs_cache.out)
        grey = ColorRGBA(r=0.6, g=0.6, b=0.65, a=0.5)
        m = len(det.live)
        out = []
        for k, s in enumerate(det.live):
            shape = det.shapes[s]
            c, rot = centre[k], R[k]
            quat = so3.matrix_to_quat(rot)
            ends, points = (), []
            if shape.kind == 'sphere':
                kind, scale = Marker.SPHERE, [2 * shape.radius] * 3
            elif shape.kind == 'box':
                kind, scale = Marker.CUBE, list(shape.size)
            elif shape.kind in ('cylinder', 'capsule'):
                kind, scale = Marker.CYLINDER, [2 * shape.radius, 2 * shape.radius,
                                                shape.length]
                if shape.kind == 'capsule':
                    half = 0.5 * shape.length * rot[:, 2]
                    ends = (c + half, c - half)
            elif shape.kind == 'mesh':
                kind, scale = Marker.TRIANGLE_LIST, [1.0, 1.0, 1.0]
                points = [conv.point(p) for p in hull_triangles(shape.centred_hull).reshape(-1, 3)]
            else:   # a plane: its normal is its z axis
                kind, scale = Marker.CUBE, [PLANE_MARKER_SIDE, PLANE_MARKER_SIDE,
                                            PLANE_MARKER_THICKNESS]
                c = c - 0.5 * PLANE_MARKER_THICKNESS * rot[:, 2]
            out.append(Marker(header=header, ns='collisions', id=k, type=kind,
                              action=Marker.ADD, pose=conv.pose(c, quat),
                              scale=conv.vector3(scale), color=grey, text=shape.name,
                              points=points))
            for e, end in enumerate(ends):
                out.append(Marker(header=header, ns='collisions', id=m + 2 * k + e,
                                  type=Marker.SPHERE, action=Marker.ADD,
                                  pose=conv.pose(end, quat),
                                  scale=conv.vector3([2 * shape.radius] * 3), color=grey,
                                  text=shape.name))
        return out

    def _contact_markers(self, header: Header) -> list:
        """
        Return the latest step's contact points and forces (namespace ``contacts``).

        The points (yellow, id 0) and each force on shape a as a line from its point,
        CONTACT_FORCE_SCALE m per N (id 1): a resting body's lines carry its weight.
        """
        rep = self.sim.contacts()
        point = rep['point']
        force = rep['normal_force'][:, None] * rep['normal'] + rep['friction_force']
        yellow = ColorRGBA(r=0.95, g=0.77, b=0.06, a=1.0)
        ends = np.empty((2 * len(point), 3))
        ends[0::2], ends[1::2] = point, point + CONTACT_FORCE_SCALE * force
        identity = conv.pose(np.zeros(3), [0.0, 0.0, 0.0, 1.0])
        return [Marker(header=header, ns='contacts', id=0, type=Marker.POINTS,
                       action=Marker.ADD, pose=identity,
                       scale=conv.vector3([CONTACT_MARKER_SIZE] * 3), color=yellow,
                       points=[conv.point(p) for p in point]),
                Marker(header=header, ns='contacts', id=1, type=Marker.LINE_LIST,
                       action=Marker.ADD, pose=identity,
                       scale=conv.vector3([CONTACT_MARKER_SIZE / 3, 0.0, 0.0]),
                       color=yellow, points=[conv.point(p) for p in ends])]

    def _visual_markers(self, header: Header, pos_body: np.ndarray,
                        R_body: np.ndarray) -> list:
        """Return the URDF visuals, posed by their bodies (pos (n, 3), R (n, 3, 3), world)."""
        out = []
        for k, (i, p_v, R_v, v, frame_id) in enumerate(self._visuals):
            if i is None:
                p, R = p_v, R_v
            else:
                p, R = pos_body[i] + R_body[i] @ p_v, R_body[i] @ R_v
            marker = Marker(header=header, ns='visuals', id=k, action=Marker.ADD,
                            pose=conv.pose(p, so3.matrix_to_quat(R)), text=frame_id)
            if v.shape == 'box':
                marker.type, scale = Marker.CUBE, v.size
            elif v.shape == 'cylinder':
                marker.type, scale = Marker.CYLINDER, (2 * v.size[0], 2 * v.size[0], v.size[1])
            elif v.shape == 'sphere':
                marker.type, scale = Marker.SPHERE, (2 * v.size[0],) * 3
            else:
                marker.type, scale = Marker.MESH_RESOURCE, v.size
                marker.mesh_resource = mesh_resource(v.uri, v.path)
            marker.scale = conv.vector3(scale)
            if v.rgba is not None:
                marker.color = ColorRGBA(**dict(zip('rgba', (float(c) for c in v.rgba))))
            elif v.shape == 'mesh':
                marker.mesh_use_embedded_materials = True   # (colour 0 0 0 0: the mesh's own)
            else:
                body = -1 if i is None else i
                marker.color = ColorRGBA(**dict(zip('rgba', PALETTE[body % len(PALETTE)])))
            out.append(marker)
        return out


def mesh_resource(uri: str, path: str) -> str:
    """Return a URDF mesh's ``mesh_resource``: its URI as written, ``file://`` a plain path."""
    if '://' in uri:
        return uri   # (package:// and file:// as RViz resolves them)
    return 'file://' + (path or uri)


def equal_inertia_box(mass: float, moments: np.ndarray) -> list:
    """
    Return the sides (m) of the uniform box with this mass and principal moments.

    ``I1 = m (b² + c²) / 12`` and so on give ``a² = 6 (I2 + I3 - I1) / m``; a side
    the triangle inequality makes zero (a thin plate or rod) is drawn 1 mm thick.
    """
    i1, i2, i3 = (float(x) for x in moments)
    sq = 6.0 / mass * np.array([i2 + i3 - i1, i1 + i3 - i2, i1 + i2 - i3])
    return np.sqrt(np.maximum(sq, 1e-6)).tolist()
