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
    # ~/joint_commands (sensor_msgs/JointState):
    UNKNOWN_JOINT = 'unknown_joint'            # a name that is no joint of the robots
    NON_FINITE_EFFORT = 'non_finite_effort'    # NaN or inf in effort
    JOINT_COMMAND_LENGTHS = 'joint_command_lengths'   # len(effort) != len(name)
    NOT_EFFORT = 'not_effort'                  # position or velocity values: not yet
    BAD_JOINT_COMMAND = 'bad_joint_command'    # no names, or a joint named twice
    EFFORT_TOO_LARGE = 'effort_too_large'      # beyond max_torque (rotary) / max_force


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


def check_joint_command(names: Sequence[str], positions: np.ndarray, velocities: np.ndarray,
                        efforts: np.ndarray, limits: dict) -> dict:
    """
    Check a ``sensor_msgs/JointState`` command's arrays; return ``{joint: effort}``.

    Parameters
    ----------
    names : sequence of str
        ``name``: the joints commanded.
    positions, velocities, efforts : ndarray, shape (k,) or (0,)
        ``position``, ``velocity``, ``effort``; only efforts exist so far, so
        ``position`` and ``velocity`` must be empty.
    limits : dict
        ``{joint: largest |effort| accepted}`` of every joint that takes
        commands (N m or N: the parameters max_torque, max_force).

    Raises
    ------
    Rejected
        Naming the field and the problem; nothing is commanded.

    """
    names = list(names)
    if not names:
        raise Rejected(Rejection.BAD_JOINT_COMMAND,
                       'name: empty: name the joints to command, with their effort')
    for field, values in (('position', positions), ('velocity', velocities)):
        if len(values):
            raise Rejected(Rejection.NOT_EFFORT,
                           f'{field}: {len(values)} values given, but only effort commands '
                           f'exist so far (no joint has a position or velocity interface '
                           f'yet): send name and effort, with position and velocity empty')
    if len(efforts) != len(names):
        raise Rejected(Rejection.JOINT_COMMAND_LENGTHS,
                       f'effort: {len(efforts)} values for {len(names)} names: give one '
                       f'effort per name')
    seen = set()
    for i, name in enumerate(names):
        if name in seen:
            raise Rejected(Rejection.BAD_JOINT_COMMAND,
                           f'name[{i}]: joint {shown(name)} is named twice')
        seen.add(name)
        if name not in limits:
            known = list(limits)
            raise Rejected(Rejection.UNKNOWN_JOINT,
                           f'name[{i}]: unknown joint {shown(name)}; joints: '
                           + (f'{known}' if len(known) <= 20 else
                              f'{known[:20]} and {len(known) - 20} more'))
    for i, (name, value) in enumerate(zip(names, efforts.tolist())):
        if not math.isfinite(value):
            raise Rejected(Rejection.NON_FINITE_EFFORT,
                           f'effort[{i}] ({name}): must be finite, got {value!r}')
        if abs(value) > limits[name]:
            raise Rejected(Rejection.EFFORT_TOO_LARGE,
                           f'effort[{i}] ({name}): magnitude {abs(value):.3g} exceeds '
                           f'{limits[name]:.3g} (the parameter max_torque for a revolute '
                           f'or continuous joint, max_force for a prismatic one)')
    return dict(zip(names, efforts.tolist()))


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
            raise SpecError('type', f'unknown constraint type {shown(req.type)}; known: '
                                    f'{[t.value for t in JointType]}')
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
