"""
The only code that converts between ROS messages and numpy arrays.

Conventions: ROS quaternions are (x, y, z, w), the core's too (Hamilton,
scalar last, body to world), so no reordering happens here; stamps are
simulation time, split into whole seconds and nanoseconds by integer
arithmetic.
"""

from __future__ import annotations

from array import array
from typing import Sequence

from builtin_interfaces.msg import Time
from geometry_msgs.msg import (Accel, Point, Pose, PoseStamped, Quaternion, Transform,
                               TransformStamped, Twist, TwistStamped, Vector3, Wrench,
                               WrenchStamped)
import numpy as np
from rigid_body_sim_interfaces.msg import BodyStates, Contacts
from sensor_msgs.msg import JointState
from simulation_interfaces.msg import EntityState
from std_msgs.msg import Float64MultiArray, Header

NANOSECONDS = 1_000_000_000


def time_msg(seconds: float) -> Time:
    """Return a ``builtin_interfaces/Time`` for a non-negative time in seconds."""
    return time_msg_ns(int(round(seconds * NANOSECONDS)))


def time_msg_ns(ns: int) -> Time:
    """Return a ``builtin_interfaces/Time`` for a non-negative time in nanoseconds."""
    return Time(sec=ns // NANOSECONDS, nanosec=ns % NANOSECONDS)


def time_seconds(stamp: Time) -> float:
    """Return the seconds of a ``builtin_interfaces/Time``."""
    return stamp.sec + stamp.nanosec * 1e-9


def vector3(v: np.ndarray) -> Vector3:
    """Return a Vector3 of a (3,) array."""
    return Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def point(v: np.ndarray) -> Point:
    """Return a Point of a (3,) array."""
    return Point(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def array3(v) -> np.ndarray:
    """Return a (3,) float array of a Vector3 or Point."""
    return np.array([v.x, v.y, v.z], dtype=float)


def pose(position: np.ndarray, quat_xyzw: np.ndarray) -> Pose:
    """Return a Pose of a position (3,) and an (x, y, z, w) quaternion (4,)."""
    p = np.asarray(position, dtype=float).tolist()
    q = np.asarray(quat_xyzw, dtype=float).tolist()
    return Pose(position=Point(x=p[0], y=p[1], z=p[2]),
                orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))


def pose_stamped(header: Header, position: np.ndarray, quat_xyzw: np.ndarray) -> PoseStamped:
    """Return a PoseStamped of a position (3,) and an (x, y, z, w) quaternion (4,)."""
    return PoseStamped(header=header, pose=pose(position, quat_xyzw))


def twist_stamped(header: Header, linear: np.ndarray, angular: np.ndarray) -> TwistStamped:
    """Return a TwistStamped of a linear (3,) and an angular (3,) velocity."""
    return TwistStamped(header=header, twist=Twist(linear=vector3(linear),
                                                   angular=vector3(angular)))


def wrench_stamped(header: Header, force: np.ndarray, torque: np.ndarray) -> WrenchStamped:
    """Return a WrenchStamped of a force (3,) and a torque (3,)."""
    return WrenchStamped(header=header, wrench=Wrench(force=vector3(force),
                                                      torque=vector3(torque)))


def wrench_arrays(msg: WrenchStamped) -> tuple[np.ndarray, np.ndarray]:
    """Return the force (3,) and torque (3,) of a WrenchStamped."""
    return array3(msg.wrench.force), array3(msg.wrench.torque)


def body_states(header: Header, names: Sequence[str], position: np.ndarray,
                quat_xyzw: np.ndarray, linear_velocity: np.ndarray,
                angular_velocity: np.ndarray) -> BodyStates:
    """
    Return a BodyStates message of the arrays of all bodies.

    Parameters
    ----------
    header : Header
        Stamp (simulation time) and world frame.
    names : sequence of str
        Body names, in the order of the arrays' rows.
    position : ndarray, shape (n, 3)
        m, body frame origins, world frame.
    quat_xyzw : ndarray, shape (n, 4)
        Orientations, body to world.
    linear_velocity : ndarray, shape (n, 3)
        m/s, of the body frame origins, world frame.
    angular_velocity : ndarray, shape (n, 3)
        rad/s, world frame.

    """
    msg = BodyStates(header=header, names=list(names))
    msg.position = _doubles(position)
    msg.orientation = _doubles(quat_xyzw)
    msg.linear_velocity = _doubles(linear_velocity)
    msg.angular_velocity = _doubles(angular_velocity)
    return msg


def contacts(header: Header, report: dict) -> Contacts:
    """
    Return a Contacts message of :meth:`.core.simulation.Simulation.contacts`' report.

    The header's stamp is the caller's; ``report['time']`` is where the forces were found.
    """
    def vectors(a: np.ndarray, kind: type) -> list:
        return [kind(x=float(v[0]), y=float(v[1]), z=float(v[2])) for v in a]

    msg = Contacts(header=header, shape_a=list(report['shape_a']),
                   shape_b=list(report['shape_b']), body_a=list(report['body_a']),
                   body_b=list(report['body_b']))
    msg.point = vectors(report['point'], Point)
    msg.normal = vectors(report['normal'], Vector3)
    msg.normal_force = _doubles(report['normal_force'])
    msg.friction_force = vectors(report['friction_force'], Vector3)
    msg.depth = _doubles(report['depth'])
    return msg


def _doubles(a: np.ndarray) -> array:
    # rclpy stores float64[] fields as array('d'); built from the raw bytes it is one copy
    # (about 30x faster than from an ndarray for 100 bodies), and it passes field checks.
    return array('d', np.ascontiguousarray(a, dtype=float).tobytes())


def body_states_arrays(msg: BodyStates) -> dict:
    """Return ``{name: (position (3,), quat (4,), linear (3,), angular (3,))}`` of a BodyStates."""
    pos = np.asarray(msg.position, dtype=float).reshape(-1, 3)
    quat = np.asarray(msg.orientation, dtype=float).reshape(-1, 4)
    lin = np.asarray(msg.linear_velocity, dtype=float).reshape(-1, 3)
    ang = np.asarray(msg.angular_velocity, dtype=float).reshape(-1, 3)
    return {name: (pos[i], quat[i], lin[i], ang[i]) for i, name in enumerate(msg.names)}


def joint_state(header: Header, names: Sequence[str], positions: np.ndarray,
                velocities: np.ndarray, efforts: np.ndarray) -> JointState:
    """
    Return a ``sensor_msgs/JointState`` of the joints' arrays.

    Parameters
    ----------
    header : Header
        Stamp (simulation time); ``frame_id`` empty, as joint_state_broadcaster's.
    names : sequence of str
        The joints, in the order of the arrays.
    positions, velocities, efforts : ndarray, shape (k,)
        rad or m; rad/s or m/s; N m or N.

    """
    msg = JointState(header=header, name=list(names))
    msg.position = _doubles(positions)
    msg.velocity = _doubles(velocities)
    msg.effort = _doubles(efforts)
    return msg


def joint_state_arrays(msg: JointState) -> tuple:
    """Return ``(names, positions, velocities, efforts)`` of a JointState: a list, (k,) x 3."""
    return (list(msg.name), np.asarray(msg.position, dtype=float),
            np.asarray(msg.velocity, dtype=float), np.asarray(msg.effort, dtype=float))


def multi_array_values(msg: Float64MultiArray) -> np.ndarray:
    """Return a Float64MultiArray's ``data`` as a (k,) array (its ``layout`` is not read)."""
    return np.asarray(msg.data, dtype=float)


def transform_stamped(header: Header, child_frame_id: str, translation: np.ndarray,
                      quat_xyzw: np.ndarray) -> TransformStamped:
    """
    Return a TransformStamped: the child frame's origin (3,) and orientation (4,, x y z w).

    Both in the parent frame ``header.frame_id`` (tf's convention: the transform
    takes child-frame coordinates to parent-frame coordinates).
    """
    p = np.asarray(translation, dtype=float).tolist()
    q = np.asarray(quat_xyzw, dtype=float).tolist()
    return TransformStamped(header=header, child_frame_id=child_frame_id,
                            transform=Transform(translation=Vector3(x=p[0], y=p[1], z=p[2]),
                                                rotation=Quaternion(x=q[0], y=q[1], z=q[2],
                                                                    w=q[3])))


def transform_arrays(msg: TransformStamped) -> tuple:
    """Return ``(parent, child, translation (3,), quat_xyzw (4,))`` of a TransformStamped."""
    t, r = msg.transform.translation, msg.transform.rotation
    return (msg.header.frame_id, msg.child_frame_id, np.array([t.x, t.y, t.z]),
            np.array([r.x, r.y, r.z, r.w]))


def entity_state(header: Header, position: np.ndarray, quat_xyzw: np.ndarray,
                 velocity: np.ndarray, omega: np.ndarray, acceleration: np.ndarray,
                 alpha: np.ndarray) -> EntityState:
    """Return a ``simulation_interfaces/EntityState``: a frame's pose, twist, accelerations."""
    return EntityState(header=header, pose=pose(position, quat_xyzw),
                       twist=Twist(linear=vector3(velocity), angular=vector3(omega)),
                       acceleration=Accel(linear=vector3(acceleration), angular=vector3(alpha)))


def pose_arrays(msg: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Return a Pose's position (3,) and (x, y, z, w) quaternion (4,)."""
    q = msg.orientation
    return array3(msg.position), np.array([q.x, q.y, q.z, q.w], dtype=float)


def twist_arrays(msg: Twist) -> tuple[np.ndarray, np.ndarray]:
    """Return a Twist's linear (3,) and angular (3,) parts."""
    return array3(msg.linear), array3(msg.angular)
