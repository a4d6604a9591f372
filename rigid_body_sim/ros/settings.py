"""
The node's parameters: names, defaults, documentation and validation (no ROS).

Each parameter is validated the same way at start-up (a bad value stops the
node with an error naming it) and when set at run time (the set is refused
with the same message and the node runs on). Numbers may be given as integers
or floats (``physics_rate: 1000`` in a YAML file is fine); booleans are not
numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from ..core import INTEGRATORS, SpecError


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SpecError(name, f'expected a number, got {value!r}')
    x = float(value)
    if x != x or x in (float('inf'), float('-inf')):
        raise SpecError(name, f'must be finite, got {value!r}')
    return x


def _positive(limit: float) -> Callable:
    def check(name: str, value: Any) -> float:
        x = _number(name, value)
        if not 0.0 < x <= limit:
            raise SpecError(name, f'must be in (0, {limit:g}], got {value!r}')
        return x
    return check


#: Hz: the slowest rate (a step or an output period of 11.6 days); a subnormal rate's
#: period would be infinite.
SLOWEST_RATE = 1e-6


def _rate(limit: float) -> Callable:
    def check(name: str, value: Any) -> float:
        x = _number(name, value)
        if not SLOWEST_RATE <= x <= limit:
            raise SpecError(name, f'must be in [{SLOWEST_RATE:g}, {limit:g}] Hz, got {value!r}')
        return x
    return check


def _rate_or_zero(limit: float) -> Callable:
    rate = _rate(limit)

    def check(name: str, value: Any) -> float:
        if _number(name, value) == 0.0:
            return 0.0
        try:
            return rate(name, value)
        except SpecError:
            raise SpecError(name, f'must be 0 (as publish_rate) or in [{SLOWEST_RATE:g}, '
                                  f'{limit:g}] Hz, got {value!r}') from None
    return check


def _non_negative(name: str, value: Any) -> float:
    x = _number(name, value)
    if x < 0.0:
        raise SpecError(name, f'must be >= 0, got {value!r}')
    return x


def _boolean(name: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise SpecError(name, f'expected true or false, got {value!r}')
    return value


def _string(name: str, value: Any) -> str:
    if not isinstance(value, str):
        raise SpecError(name, f'expected a string, got {value!r}')
    return value


def _integrator(name: str, value: Any) -> str:
    value = _string(name, value)
    if value and value not in INTEGRATORS:
        raise SpecError(name, f'unknown integrator {value!r}; known: {sorted(INTEGRATORS)} '
                              "('' for the scene's)")
    return value


#: The longest frame name accepted (tf2 itself sets none; a frame_id is repeated in
#: every message header).
MAX_FRAME_LENGTH = 256


def _frame(name: str, value: Any) -> str:
    value = _string(name, value)
    if not value or value.startswith('/') or len(value) > MAX_FRAME_LENGTH \
            or not (value.isascii() and value.isprintable()) \
            or any(c.isspace() for c in value):
        shown = repr(value) if len(value) <= 80 else f'{value[:40]!r}... ({len(value)} ' \
                                                     f'characters)'
        raise SpecError(name, f'must be a frame name of 1 to {MAX_FRAME_LENGTH} printable '
                              f"ASCII characters without spaces or a leading '/', got {shown}")
    return value


#: Values of the parameter ``tf``: what the node publishes on /tf and /tf_static.
TF_MODES = ('links', 'off')


def _tf_mode(name: str, value: Any) -> str:
    if value is False:   # (YAML 1.1, as ROS parameters and -p name:=value read it: off)
        return 'off'
    value = _string(name, value)
    if value not in TF_MODES:
        raise SpecError(name, f'expected one of {list(TF_MODES)}, got {value!r}')
    return value


@dataclass(frozen=True)
class Parameter:
    """One node parameter."""

    name: str
    default: Any
    check: Callable
    description: str
    read_only: bool = False


PARAMETERS = (
    Parameter('scene', '', _string,
              "scene YAML file; '' for the installed default scene", read_only=True),
    Parameter('physics_rate', 1000.0, _rate(1e6),
              'Hz: physics steps per simulated second (dt = 1 / physics_rate; overrides the '
              "scene's dt)"),
    Parameter('publish_rate', 100.0, _rate(1e6),
              'Hz of simulated time: poses, twists, body states, reactions (every step if '
              '>= physics_rate)'),
    Parameter('clock_rate', 1000.0, _rate(1e6),
              'Hz of simulated time: /clock (every step if >= physics_rate)'),
    Parameter('integrator', '', _integrator,
              f"{', '.join(sorted(INTEGRATORS))}; '' for the scene's"),
    Parameter('tolerance', 0.0, _non_negative,
              "the accuracy knob: local error per unit time each step's sub-steps keep "
              "below (SI units, see rigid_body_sim.core.accuracy); 0: the scene's (off "
              'unless the scene sets one)'),
    Parameter('real_time_factor', 1.0, _non_negative,
              'simulated seconds per wall second; 0: as fast as possible'),
    Parameter('start_paused', False, _boolean,
              'start paused (then step with ~/step or resume with ~/pause false)',
              read_only=True),
    Parameter('world_frame', 'world', _frame,
              'frame_id of world-frame outputs, and the world frame of wrench inputs'),
    Parameter('wrench_timeout', 0.0, _non_negative,
              's of simulated time a wrench message holds; 0: until the next message on '
              'its topic'),
    Parameter('max_force', 1e8, _positive(1.7976931348623157e308),
              'N: wrench messages with a larger force are rejected'),
    Parameter('max_torque', 1e8, _positive(1.7976931348623157e308),
              'N m: wrench messages with a larger torque are rejected'),
    Parameter('reset_time', False, _boolean,
              '~/reset also sets the simulation time back to 0 (default: time runs on, so '
              'nodes on /clock see no jump back)'),
    Parameter('per_body_topics', True, _boolean,
              'pose, twist and wrench topics per body (off: ~/body_states only, for large '
              'scenes)', read_only=True),
    Parameter('joint_state_rate', 0.0, _rate_or_zero(1e6),
              'Hz of simulated time: joint_states (robots); 0: as publish_rate'),
    Parameter('tf_rate', 0.0, _rate_or_zero(1e6),
              "Hz of simulated time: /tf of the robots' moving links; 0: as publish_rate"),
    Parameter('collision_markers', False, _boolean,
              "~/markers draws the collision shapes too (namespace collisions: the robots' "
              "URDF <collision> geometry, the bodies' shapes, the ground)"),
    Parameter('tf', 'links', _tf_mode,
              "links: the robots' link frames on /tf and /tf_static; off: none (e.g. when "
              'robot_state_publisher publishes them from joint_states)', read_only=True),
)

BY_NAME = {p.name: p for p in PARAMETERS}


@dataclass
class Settings:
    """Validated parameter values."""

    scene: str = ''
    physics_rate: float = 1000.0
    publish_rate: float = 100.0
    clock_rate: float = 1000.0
    integrator: str = ''
    tolerance: float = 0.0
    real_time_factor: float = 1.0
    start_paused: bool = False
    world_frame: str = 'world'
    wrench_timeout: float = 0.0
    max_force: float = 1e8
    max_torque: float = 1e8
    reset_time: bool = False
    per_body_topics: bool = True
    joint_state_rate: float = 0.0
    tf_rate: float = 0.0
    collision_markers: bool = False
    tf: str = 'links'

    @property
    def joint_state_rate_hz(self) -> float:
        """Hz: the rate of joint_states (``joint_state_rate``, or publish_rate for 0)."""
        return self.joint_state_rate or self.publish_rate

    @property
    def tf_rate_hz(self) -> float:
        """Hz: the rate of /tf (``tf_rate``, or publish_rate for 0)."""
        return self.tf_rate or self.publish_rate

    @classmethod
    def from_values(cls, values: dict) -> 'Settings':
        """Validate ``{name: value}`` (names missing take their defaults)."""
        out = cls()
        out.update(values)
        return out

    def update(self, values: dict) -> None:
        """Validate every value first, then assign them all (or none)."""
        checked = {}
        for name, value in values.items():
            if name not in BY_NAME:
                raise SpecError(name, f'unknown parameter; known: {sorted(BY_NAME)}')
            checked[name] = BY_NAME[name].check(name, value)
        for name, value in checked.items():
            setattr(self, name, value)
