"""
ROS-free numerical core of rigid_body_sim (numpy and scipy only; never rclpy).

The public API: :class:`RigidBody` specs, effects (:class:`Gravity`,
:class:`Damping`, :class:`AppliedWrenches`), the :class:`Simulation` facade,
the integrator registry :data:`INTEGRATORS`, :class:`Constraint` joints, and
:class:`SpecError`, raised for every bad input with the offending field named,
and :class:`DivergenceError`, raised by a step that would leave a non-finite state.
Collision shapes (:class:`CollisionShape`) and their contacts (:class:`ContactDetector`):
detection only, so far.
"""

from . import kernel_cache
from .bodies import BodySet, RigidBody, State
from .constraints import Constraint, JointType
from .diagnostics import Diagnostics
from .effects import AppliedWrenches, Damping, EFFECTS, Frame, Gravity
from .errors import DivergenceError, InconsistentConstraintError, SpecError
from .integrators import INTEGRATORS, Invariant
from .kernels import free_step
from .shapes import CollisionShape, ContactDetector
from .simulation import Reaction, Simulation

# Before any kernel runs: drop cached machine code compiled from older kernel sources.
kernel_cache.check(free_step.free_step)

__all__ = [
    'AppliedWrenches', 'BodySet', 'CollisionShape', 'Constraint', 'ContactDetector', 'Damping',
    'Diagnostics', 'DivergenceError', 'EFFECTS', 'Frame', 'InconsistentConstraintError',
    'Gravity', 'INTEGRATORS', 'Invariant', 'JointType', 'Reaction', 'RigidBody', 'Simulation',
    'SpecError', 'State',
]
