"""
The accuracy knob: sub-steps chosen by an error estimate to meet a tolerance.

With ``Simulation(..., tolerance=tol)`` the outer step ``dt`` stays fixed (the
rate a node publishes at), and each step is taken as ``k`` equal sub-steps, with
``k`` the smallest power of two for which the estimated local error per unit
time is at most ``tol``::

    estimate = max |y(2k) − y(k)| / (2^p − 1) / dt  <=  tol

where ``y(k)`` is the state after the step taken in ``k`` sub-steps, ``p`` the
integrator's order, and the difference is the largest over all bodies of the
centre-of-mass position (m), the orientation (rad), the velocity (m/s) and the
angular velocity (rad/s) differences: every component in SI units, as one
absolute tolerance (step doubling, Richardson's estimate of the error of the
finer result, which is the one kept). A step starts from the previous step's
``k`` and halves it when the estimate allows; each doubling reuses the finer
run as the coarser one. A step that reaches ``budget`` sub-steps without
meeting the tolerance keeps its finest result and is counted as a miss, never
silently: :class:`AccuracyReport` says how many (``Simulation.accuracy()`` and
``Simulation.diagnostics()``).

The estimate costs a coarser run beside the kept one: a step of ``k`` sub-steps
does the work of ``1.5 k`` or more.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Optional

import numpy as np

from . import rotation as so3
from .bodies import State
from .errors import SpecError

#: Default most sub-steps a step may take under the knob.
DEFAULT_BUDGET = 1024


@dataclass(frozen=True)
class AccuracyReport:
    """
    What the accuracy knob did.

    Attributes
    ----------
    tolerance : float or None
        Requested local error per unit time (SI units, see the module docstring);
        None when the knob is off.
    error_estimate : float
        The last step's estimated local error per unit time (NaN before a step).
    substeps : int
        Sub-steps the last step was taken in.
    budget : int
        Most sub-steps a step may take.
    misses : int
        Steps that reached the budget without meeting the tolerance.
    steps : int
        Steps taken under the knob.
    worst_estimate : float
        Largest estimate of all those steps.

    """

    tolerance: Optional[float]
    error_estimate: float
    substeps: int
    budget: int
    misses: int
    steps: int
    worst_estimate: float


def state_distance(a: State, b: State) -> float:
    """
    Largest difference between two states of the same bodies, SI units.

    Over all bodies: centre-of-mass position (m), orientation (rad, the angle of
    the relative rotation), velocity (m/s) and angular velocity (rad/s).
    """
    d = max(float(np.max(np.abs(a.pos_com_world - b.pos_com_world))),
            float(np.max(np.abs(a.vel_com_world - b.vel_com_world))),
            float(np.max(np.abs(a.ang_vel_principal - b.ang_vel_principal))))
    # The angle of q_a⁻¹ ⊗ q_b from atan2 (arccos of the dot product would floor at
    # about 3e-8 rad: it is ill-conditioned near 1).
    rel = so3.quat_multiply(so3.quat_conjugate(a.quat_principal_world), b.quat_principal_world)
    theta = 2.0 * np.arctan2(np.linalg.norm(rel[:, :3], axis=1), np.abs(rel[:, 3]))
    return max(d, float(np.max(theta)))


def _positive(value: Any, field_name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SpecError(field_name, f'must be a number, got {value!r}') from None
    if not (math.isfinite(x) and x > 0.0):
        raise SpecError(field_name, f'must be finite and > 0, got {value!r}')
    return x


class ErrorControl:
    """
    Step doubling for one simulation (see the module docstring).

    Parameters
    ----------
    tolerance : float
        Local error per unit time, > 0 (SI units: m, rad, m/s, rad/s per s).
    budget : int
        Most sub-steps a step may take, a power of two >= 2.

    """

    def __init__(self, tolerance: Any, budget: Any = DEFAULT_BUDGET) -> None:
        self.tolerance = _positive(tolerance, 'tolerance')
        if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) \
                or budget < 2 or budget & (budget - 1):
            raise SpecError('tolerance_budget', f'must be a power of two >= 2, got {budget!r}')
        self.budget = int(budget)
        self.reset()

    def reset(self) -> None:
        """Forget the sub-step count and the tallies (a reset simulation)."""
        self.k = 1
        self.estimate = math.nan
        self.last_k = 0
        self.misses = 0
        self.steps = 0
        self.worst = 0.0

    def report(self) -> AccuracyReport:
        """Return what the knob did so far."""
        return AccuracyReport(self.tolerance, self.estimate, self.last_k, self.budget,
                              self.misses, self.steps, self.worst)

    def step(self, integrator, state: State, dt: float, t_end: float) -> State:
        """Take one step of ``dt`` from ``state`` to ``t_end`` with the sub-steps it needs."""
        p = integrator.order
        factor = 1.0 / ((2.0 ** p - 1.0) * dt)
        k = max(1, min(self.k, self.budget // 2))
        coarse = _advance(integrator, state, dt, t_end, k)
        while True:
            fine = _advance(integrator, state, dt, t_end, 2 * k)
            estimate = state_distance(fine, coarse) * factor
            if estimate <= self.tolerance or 2 * k >= self.budget:
                break
            k, coarse = 2 * k, fine
        self.steps += 1
        if estimate > self.tolerance:
            self.misses += 1
        self.estimate, self.last_k = estimate, 2 * k
        self.worst = max(self.worst, estimate)
        # The next step starts from this one's count; halved when the estimate allows
        # (halving the sub-steps multiplies the local error by about 2^p).
        self.k = max(1, k // 2) if estimate * 2.0 ** (p + 1) < self.tolerance else k
        return fine


def _advance(integrator, state: State, dt: float, t_end: float, k: int) -> State:
    """``k`` equal sub-steps of ``dt / k`` from ``state``, the last ending at ``t_end``."""
    h = dt / k
    s = state
    for i in range(k):
        s = integrator.step(s, h, t_end if i == k - 1 else state.time + (i + 1) * h)
    return s
