"""
Checks of what arrives from ROS, before it reaches the core (no rclpy).

Every rejection names the field and the problem, and carries a cause (an
:class:`Rejection` member) that the node counts on ``/diagnostics``.
"""

from __future__ import annotations

import enum
import math
import re
from typing import Any, Callable, Optional, Sequence

import numpy as np

from ..core import Constraint, JointType, SpecError


class Rejection(enum.Enum):
    """Why an input was refused (the keys of the node's rejection counters)."""

    NON_FINITE = 'non_finite'                  # NaN or inf in a wrench
    TOO_LARGE = 'too_large'                    # beyond max_force / max_torque
    UNKNOWN_FRAME = 'unknown_frame'            # wrench frame_id neither world nor the body
    UNKNOWN_BODY = 'unknown_body'              # a request names no body of the scene
    UNKNOWN_CONSTRAINT = 'unknown_constraint'  # remove_constraint of a name not present
    BAD_CONSTRAINT = 'bad_constraint'          # malformed request (type, sizes, name)
    INCONSISTENT_CONSTRAINT = 'inconsistent_constraint'   # no configuration satisfies it
    NOT_PAUSED = 'not_paused'                  # ~/step while running
    BAD_STEP = 'bad_step'                      # ~/step with too many steps
    DIVERGED = 'diverged'                      # a request the diverged state cannot serve
    INTERNAL_ERROR = 'internal_error'          # a request that raised unexpectedly (a bug)
    # ~/joint_commands (sensor_msgs/JointState) and <group>/commands (Float64MultiArray):
    UNKNOWN_JOINT = 'unknown_joint'            # a name that is no joint of the robots
    NON_FINITE_EFFORT = 'non_finite_effort'    # NaN or inf where an effort is required
    NON_FINITE_TARGET = 'non_finite_target'    # NaN or inf where a position/velocity is
    JOINT_COMMAND_LENGTHS = 'joint_command_lengths'   # an array's length != len(name)
    WRONG_INTERFACE = 'wrong_interface'        # a value for a joint of another interface
    BAD_JOINT_COMMAND = 'bad_joint_command'    # no names, or a joint named twice
    EFFORT_TOO_LARGE = 'effort_too_large'      # beyond max_torque (rotary) / max_force
    GROUP_COMMAND_SIZE = 'group_command_size'  # <group>/commands: len(data) != the group's


class Rejected(ValueError):
    """An input refused, with its cause."""

    def __init__(self, cause: Rejection, message: str) -> None:
        self.cause = cause
        super().__init__(message)


#: The longest fully qualified topic name ROS accepts (rmw's limit: 255 characters less
#: the 8 that DDS topic prefixes and suffixes take).
MAX_TOPIC_LENGTH = 247
#: One token of a ROS name (ASCII letters, digits, underscores, not starting with a digit:
#: the ROS rule), and here also starting with a letter and without a double underscore
#: (ROS reserves ``__`` for its own names). Matched whole (``fullmatch``: a trailing
#: newline is not ignored, as ``$`` would).
_TOKEN = re.compile(r'[A-Za-z][A-Za-z0-9_]*')
NAME_RULE = ('ASCII letters, digits and single underscores, starting with a letter, '
             f'and the longest topic it names at most {MAX_TOPIC_LENGTH} characters')


def shown(value: Any, limit: int = 80) -> str:
    """``repr(value)``, shortened past ``limit`` characters (a reply never echoes 10 kB)."""
    text = repr(value)
    return text if len(text) <= limit else f'{text[:limit - 20]}... ({len(text)} characters)'


def check_name_token(name: Any, what: str, topic: Optional[str] = None) -> None:
    """
    Raise SpecError unless ``name`` can be one token of a ROS name (:data:`NAME_RULE`).

    The one rule for every name that becomes part of a ROS name: bodies,
    constraints (and later joints and robots).

    Parameters
    ----------
    name : str
        The name to check.
    what : str
        The field, for the message.
    topic : str, optional
        The longest fully qualified topic name ``name`` becomes part of; checked
        against :data:`MAX_TOPIC_LENGTH`.

    """
    if not isinstance(name, str) or _TOKEN.fullmatch(name) is None or '__' in name:
        raise SpecError(what, f'{shown(name)} cannot be part of a ROS name: use {NAME_RULE}')
    if topic is not None and len(topic) > MAX_TOPIC_LENGTH:
        raise SpecError(what, f'{len(name)} characters make the topic {topic[:40]}... '
                              f'{len(topic)} characters long; ROS allows '
                              f'{MAX_TOPIC_LENGTH}: at most '
                              f'{len(name) - (len(topic) - MAX_TOPIC_LENGTH)} characters here')


def check_wrench(force: np.ndarray, torque: np.ndarray, frame_id: str, body: str,
                 world_frame: str, max_force: float, max_torque: float) -> str:
    """
    Check a wrench message's values; return the core frame ('world' or 'body').

    Raises
    ------
    Rejected
        Naming the field and the problem.

    """
    for field, v in (('wrench.force', force), ('wrench.torque', torque)):
        if not np.all(np.isfinite(v)):
            raise Rejected(Rejection.NON_FINITE, f'{field}: must be finite, got {v.tolist()}')
    for field, v, limit, param in (('wrench.force', force, max_force, 'max_force'),
                                   ('wrench.torque', torque, max_torque, 'max_torque')):
        size = math.hypot(*v.tolist())   # (no overflow for values near the float limit)
        if size > limit:
            raise Rejected(Rejection.TOO_LARGE, f'{field}: magnitude {size:.3g} exceeds the '
                                                f'parameter {param} = {limit:.3g}')
    if frame_id == world_frame:
        return 'world'
    if frame_id == body:
        return 'body'
    raise Rejected(Rejection.UNKNOWN_FRAME,
                   f'header.frame_id: {frame_id!r} is neither the world frame '
                   f'{world_frame!r} nor the body {body!r}')


#: The ``sensor_msgs/JointState`` array of each interface.
INTERFACE_FIELDS = ('position', 'velocity', 'effort')


def _known_joints(joints: Sequence[str]) -> str:
    known = list(joints)
    return f'{known}' if len(known) <= 20 else f'{known[:20]} and {len(known) - 20} more'


def _check_value(field: str, i: int, name: str, interface: str, value: float,
                 limits: dict) -> None:
    """Raise Rejected unless ``value`` can be joint ``name``'s command on ``interface``."""
    if not math.isfinite(value):
        cause = Rejection.NON_FINITE_EFFORT if interface == 'effort' \
            else Rejection.NON_FINITE_TARGET
        raise Rejected(cause, f'{field}[{i}] ({name}): must be finite, got {value!r}')
    if interface == 'effort' and abs(value) > limits[name]:
        raise Rejected(Rejection.EFFORT_TOO_LARGE,
                       f'{field}[{i}] ({name}): magnitude {abs(value):.3g} exceeds '
                       f'{limits[name]:.3g} (the parameter max_torque for a revolute '
                       f'or continuous joint, max_force for a prismatic one)')


def check_joint_command(names: Sequence[str], positions: np.ndarray, velocities: np.ndarray,
                        efforts: np.ndarray, interfaces: dict, limits: dict) -> dict:
    """
    Check a ``sensor_msgs/JointState`` command's arrays; return ``{joint: command}``.

    Each joint named is commanded through its own interface: its entry in that
    interface's array (``position``, ``velocity`` or ``effort``) is required and
    must be finite. The arrays of the other interfaces must be empty, or hold
    NaN at that joint's index (the "not commanded" marker of mixed messages).
    Every non-empty array has one entry per name.

    Parameters
    ----------
    names : sequence of str
        ``name``: the joints commanded.
    positions, velocities, efforts : ndarray, shape (k,) or (0,)
        ``position`` (rad or m), ``velocity`` (rad/s or m/s), ``effort`` (N m or N).
    interfaces : dict
        ``{joint: 'effort' | 'position' | 'velocity'}`` of every joint that takes
        commands.
    limits : dict
        ``{joint: largest |effort| accepted}`` of every joint that takes
        commands (N m or N: the parameters max_torque, max_force).

    Returns
    -------
    dict
        ``{joint: value}``: the effort, position target or velocity target of
        each joint named, in the order of ``name``.

    Raises
    ------
    Rejected
        Naming the field, the index and the problem; nothing is commanded.

    """
    names = list(names)
    arrays = dict(zip(INTERFACE_FIELDS, (positions, velocities, efforts)))
    if not names:
        raise Rejected(Rejection.BAD_JOINT_COMMAND,
                       'name: empty: name the joints to command, each with its value in '
                       'the array of its interface (position, velocity or effort)')
    for field, values in arrays.items():
        if len(values) and len(values) != len(names):
            raise Rejected(Rejection.JOINT_COMMAND_LENGTHS,
                           f'{field}: {len(values)} values for {len(names)} names: give '
                           f'one {field} per name (NaN for joints not commanded by it), '
                           f'or none')
    seen = set()
    for i, name in enumerate(names):
        if name in seen:
            raise Rejected(Rejection.BAD_JOINT_COMMAND,
                           f'name[{i}]: joint {shown(name)} is named twice')
        seen.add(name)
        if name not in interfaces:
            raise Rejected(Rejection.UNKNOWN_JOINT,
                           f'name[{i}]: unknown joint {shown(name)}; joints: '
                           + _known_joints(interfaces))
    lists = {field: values.tolist() for field, values in arrays.items()}
    out = {}
    for i, name in enumerate(names):
        interface = interfaces[name]
        for field, values in lists.items():
            if field != interface and values and values[i] == values[i]:   # (not NaN)
                raise Rejected(Rejection.WRONG_INTERFACE,
                               f'{field}[{i}] ({name}): {values[i]!r} given, but joint '
                               f'{name!r} has the {interface} interface: give its value in '
                               f'{interface}[{i}], and NaN (or an empty array) in {field}')
        if not lists[interface]:
            raise Rejected(Rejection.JOINT_COMMAND_LENGTHS,
                           f'{interface}: empty, but name[{i}] ({name}) has the {interface} '
                           f'interface: give one {interface} per name (NaN for joints not '
                           f'commanded by it)')
        value = lists[interface][i]
        _check_value(interface, i, name, interface, value, limits)
        out[name] = value
    return out


def check_group_command(group: str, joints: Sequence[str], interface: str,
                        data: np.ndarray, limits: dict) -> dict:
    """
    Check a ``<group>/commands`` message's ``data``; return ``{joint: command}``.

    As ros2_control's forward_command_controller takes it: one value per joint
    of the group, in the group's order, for the group's interface. A NaN entry
    leaves that joint's command as it is (all NaN: an empty dict, nothing to do).

    Parameters
    ----------
    group : str
        The group's name (for the messages).
    joints : sequence of str
        The group's joints, in the order of ``data``.
    interface : {'effort', 'position', 'velocity'}
        The group's interface: what ``data`` holds.
    data : ndarray, shape (len(joints),)
        N m or N, rad or m, rad/s or m/s.
    limits : dict
        ``{joint: largest |effort| accepted}`` (effort groups).

    Raises
    ------
    Rejected
        A wrong size, inf (NaN is "keep"), an effort beyond its limit; nothing
        is commanded.

    """
    if len(data) != len(joints):
        raise Rejected(Rejection.GROUP_COMMAND_SIZE,
                       f'data: {len(data)} values for the {len(joints)} joints of group '
                       f'{group!r} {list(joints)} ({interface}): give one per joint, in that '
                       'order (NaN keeps the command of that joint)')
    out = {}
    for i, (name, value) in enumerate(zip(joints, data.tolist())):
        if value != value:   # NaN: this joint keeps its command
            continue
        _check_value('data', i, name, interface, value, limits)
        out[name] = value
    return out


def _optional_vector(value: Sequence[float], field: str) -> Any:
    values = list(value)
    if not values:
        return None
    if len(values) != 3:
        raise SpecError(field, f'expected [] or 3 values [x, y, z], got {len(values)}: '
                               f'{shown(values)}')
    return np.array(values, dtype=float)


def constraint_from_request(req: Any, body_names: Sequence[str],
                            topic_of: Optional[Callable[[str], str]] = None) -> Constraint:
    """
    Build a core :class:`Constraint` from an ``AddConstraint`` request.

    ``topic_of(name)``: the longest fully qualified topic the constraint's name
    becomes part of (its length is checked too).

    Raises
    ------
    Rejected
        UNKNOWN_BODY or BAD_CONSTRAINT, naming the field and the problem.

    """
    try:
        check_name_token(req.name, 'name',
                         topic_of(req.name) if topic_of and isinstance(req.name, str) else None)
        if not isinstance(req.type, str) or len(req.type) > 40:
            known = [t.value for t in JointType if t is not JointType.DRIVE]
            raise SpecError('type', f'unknown constraint type {shown(req.type)}; known: '
                                    f'{known}')
        kind = JointType.parse(req.type)
        if kind is JointType.GENERIC:
            raise SpecError('type', 'a generic constraint takes a Python function: add it '
                                    'through the core API (Simulation.add_constraint)')
        for field in ('body_a', 'body_b'):
            body = getattr(req, field)
            if field == 'body_b' and body in ('', 'world'):
                continue
            if body not in body_names:
                known = list(body_names)
                raise Rejected(Rejection.UNKNOWN_BODY,
                               f'{field}: unknown body {shown(body)}; known bodies: '
                               + (f'{known}' if len(known) <= 20 else
                                  f'{known[:20]} and {len(known) - 20} more'))
        length = float(req.length)
        if length != length or length < 0.0 or length == float('inf'):
            raise SpecError('length', f'must be 0 (the current distance) or a positive '
                                      f'number of metres, got {req.length!r}')
        if length and kind is not JointType.DISTANCE:
            raise SpecError('length', f'only for distance constraints, not {kind.value}')
        return Constraint(
            name=req.name, type=kind, body_a=req.body_a,
            body_b=None if req.body_b in ('', 'world') else req.body_b,
            anchor_world=_optional_vector(req.anchor_world, 'anchor_world'),
            anchor_a_body=_optional_vector(req.anchor_a_body, 'anchor_a_body'),
            anchor_b_body=_optional_vector(req.anchor_b_body, 'anchor_b_body'),
            axis_world=_optional_vector(req.axis_world, 'axis_world'),
            length=length or None)
    except SpecError as exc:
        raise Rejected(Rejection.BAD_CONSTRAINT, str(exc)) from None
