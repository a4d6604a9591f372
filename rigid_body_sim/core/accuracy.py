"""
The accuracy knob: sub-steps chosen by an error estimate to meet a tolerance.

With ``Simulation(..., tolerance=tol)`` the outer step ``dt`` stays fixed (the
rate a node publishes at), and each step is taken as ``k`` equal sub-steps, with
``k`` chosen so that the estimated local error per unit time is at most ``tol``.
Every estimate is the largest over all bodies of the centre-of-mass position
(m), the orientation (rad), the velocity (m/s) and the angular velocity (rad/s)
errors: every component in SI units, as one absolute tolerance.

Two estimators:

``embedded`` (``rkmk4``, the method with an embedded pair)
    Each sub-step also evaluates the slopes at its end (first same as last) and
    compares its fourth-order result with the embedded third-order one,
    ``h/6 (k4 − k5)`` (:func:`.kernels.free_step.rkmk4_embedded_error`); the step's
    estimate is the largest over its sub-steps, divided by ``h``. That is the
    third-order solution's error; the fourth-order result is kept (local
    extrapolation, as in Dormand–Prince), so its error is smaller still, by a
    factor of order ``h``: the tolerance is met with a margin. A sub-step costs
    five stages instead of four (a constrained one: one more acceleration-level
    solve, whose factorization the velocity projection reuses). ``k`` is any
    whole number: a step whose estimate misses is redone with ``k`` scaled by
    ``(estimate / tol)^(1/3)`` (the estimate goes as ``h³``) and a margin.
``doubling`` (every method)
    Step doubling (Richardson): the step is taken in ``k`` and ``2k`` sub-steps
    (``k`` a power of two) and ``max |y(2k) − y(k)| / (2^p − 1) / dt``, ``p`` the
    method's order, estimates the error of the finer result, which is kept.
    Each doubling reuses the finer run as the coarser one; a step starts from
    the previous step's ``k`` and halves it when the estimate allows. A step of
    ``2k`` sub-steps does the work of ``3k``.

The default for ``rkmk4`` uses both, each where it is cheaper (measured with
``bench/knob_estimators.py``): a step that one sub-step may do is taken once
and checked by the embedded pair (5 stages, where doubling's 1 + 2 sub-steps
cost 12); when that estimate misses, the result serves as doubling's coarse run
and the step goes on by doubling, and so do the next ones until doubling says
one sub-step would do again (after a miss, the check waits 1, 2, 4 ... up to 64
steps, so that a scene where the embedded estimate misses by a little does not
pay for a check every other step). The embedded estimate alone over-resolves tight
tolerances: it goes as ``h³`` where the kept error goes as ``h⁴``, so at 1e-9
the pendulum takes 149 sub-steps a step by it and 32 by doubling. The
splittings have no embedded pair and always use doubling.

A step that reaches ``budget`` sub-steps without meeting the tolerance keeps
its finest result and is counted as a miss, never silently:
:class:`AccuracyReport` says how many (``Simulation.accuracy()`` and
``Simulation.diagnostics()``).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Optional

import numpy as np

from .bodies import State
from .errors import SpecError
from .kernels import free_step as kern

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
    Compiled (:func:`.kernels.free_step.state_distance`): step doubling compares two
    states every step.
    """
    return float(kern.state_distance(*a.parts, *b.parts))


def _positive(value: Any, field_name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SpecError(field_name, f'must be a number, got {value!r}') from None
    if not (math.isfinite(x) and x > 0.0):
        raise SpecError(field_name, f'must be finite and > 0, got {value!r}')
    return x


def _settings(tolerance: Any, budget: Any, estimator: Optional[str]) -> tuple:
    """Return the validated settings of :class:`ErrorControl`: (tolerance, budget, estimator)."""
    tolerance = _positive(tolerance, 'tolerance')
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) \
            or budget < 2 or budget & (budget - 1):
        raise SpecError('tolerance_budget', f'must be a power of two >= 2, got {budget!r}')
    if estimator not in (None, 'embedded', 'doubling'):
        raise SpecError('estimator', f"must be 'embedded' or 'doubling', got {estimator!r}")
    return tolerance, int(budget), estimator


class ErrorControl:
    """
    The knob's sub-step control for one simulation (see the module docstring).

    Parameters
    ----------
    tolerance : float
        Local error per unit time, > 0 (SI units: m, rad, m/s, rad/s per s).
    budget : int
        Most sub-steps a step may take, a power of two >= 2.
    estimator : str, optional
        ``'embedded'`` or ``'doubling'`` alone; default (None): the embedded
        pair for steps of one sub-step and doubling beyond, where the integrator
        has a pair, doubling otherwise. An integrator without a pair always
        uses doubling.

    """

    #: The embedded controller aims at this fraction of the tolerance, so that a
    #: slowly growing error does not make every other step miss and be redone.
    SAFETY = 0.8

    def __init__(self, tolerance: Any, budget: Any = DEFAULT_BUDGET,
                 estimator: Optional[str] = None) -> None:
        self.tolerance, self.budget, self.estimator = _settings(tolerance, budget, estimator)
        self.reset()

    def retune(self, tolerance: Any, budget: Any = None, estimator: Optional[str] = None) -> None:
        """
        Change the settings between steps, keeping the sub-step count and the tallies.

        ``budget``, ``estimator``: None keeps the present one. All three are
        validated before any changes.
        """
        self.tolerance, self.budget, self.estimator = _settings(
            tolerance, self.budget if budget is None else budget,
            self.estimator if estimator is None else estimator)

    def reset(self) -> None:
        """Forget the sub-step count and the tallies (a reset simulation)."""
        self.k = 1
        self.estimate = math.nan
        self.last_k = 0
        self.misses = 0
        self.steps = 0
        self.worst = 0.0
        self._try_embedded = True
        self._wait = 0        # steps by doubling before the next embedded check
        self._backoff = 1     # the wait after the next failed check

    def report(self) -> AccuracyReport:
        """Return what the knob did so far."""
        return AccuracyReport(self.tolerance, self.estimate, self.last_k, self.budget,
                              self.misses, self.steps, self.worst)

    def step(self, integrator, state: State, dt: float, t_end: float) -> State:
        """Take one step of ``dt`` from ``state`` to ``t_end`` with the sub-steps it needs."""
        order = integrator.EMBEDDED_ORDER
        if order is None or self.estimator == 'doubling':
            new, estimate, k = self._doubling(integrator, state, dt, t_end)
        elif self.estimator == 'embedded':
            new, estimate, k = self._embedded(integrator, order, state, dt, t_end)
        elif self.k == 1 and self._try_embedded:
            # One sub-step, checked by the embedded pair (5 stages instead of the 12 of
            # doubling's 1 + 2 sub-steps); when that estimate misses, the result is
            # doubling's coarse run, and the miss cost one stage.
            error = np.zeros(1)
            new = _advance(integrator, state, dt, t_end, 1, error)
            estimate, k = float(error[0]), 1
            if estimate > self.tolerance:
                # The embedded estimate is the larger (third order): it can miss where
                # doubling says one sub-step does. Each miss in a row doubles the steps
                # (up to 64) before the next check, so they do not recur every step.
                self._try_embedded = False
                self._wait, self._backoff = self._backoff, min(2 * self._backoff, 64)
                new, estimate, k = self._doubling(integrator, state, dt, t_end, new)
            else:
                self._backoff = 1
        else:
            new, estimate, k = self._doubling(integrator, state, dt, t_end)
            # Back to the embedded check once doubling says one sub-step would do (and the
            # wait after a miss is over).
            if self.k == 1 and estimate * 2.0 ** (integrator.order + 1) < self.tolerance:
                if self._wait > 0:
                    self._wait -= 1
                else:
                    self._try_embedded = True
        self.steps += 1
        if estimate > self.tolerance:
            self.misses += 1
        self.estimate, self.last_k = estimate, k
        self.worst = max(self.worst, estimate)
        return new

    def charge(self, rate: float) -> None:
        """
        Add a one-off error, per unit time of the step just taken, to its estimate.

        What a step's events leave beyond its sub-steps' own error (an event located
        to a tolerance: :meth:`.joint_events.JointEvents.tighten`): the step's estimate
        becomes the larger of the two, and a step it takes past the tolerance is a miss.
        """
        if not rate > self.estimate:
            return
        if rate > self.tolerance and not self.estimate > self.tolerance:
            self.misses += 1
        self.estimate = rate
        self.worst = max(self.worst, rate)

    def _embedded(self, integrator, order: int, state: State, dt: float, t_end: float):
        """Sub-steps by the embedded pair: redo with more while the estimate misses."""
        k = max(1, min(self.k, self.budget))
        error = np.zeros(1)
        while True:
            error[0] = 0.0
            new = _advance(integrator, state, dt, t_end, k, error)
            estimate = float(error[0])
            if estimate <= self.tolerance or k >= self.budget:
                break
            k = min(self.budget, max(k + 1, _needed(k, estimate, self.tolerance * self.SAFETY,
                                                    order)))
        # The next step starts where this estimate says (fewer sub-steps if it allows).
        self.k = max(1, min(self.budget, _needed(k, estimate, self.tolerance * self.SAFETY,
                                                 order)))
        return new, estimate, k

    def _doubling(self, integrator, state: State, dt: float, t_end: float,
                  coarse: Optional[State] = None):
        """Sub-steps by step doubling (powers of two); ``coarse``: the run in one, if taken."""
        p = integrator.order
        factor = 1.0 / ((2.0 ** p - 1.0) * dt)
        if coarse is not None:
            k = 1
        else:
            k = 1 << max(0, (max(1, min(self.k, self.budget // 2))).bit_length() - 1)
            coarse = _advance(integrator, state, dt, t_end, k)
        while True:
            fine = _advance(integrator, state, dt, t_end, 2 * k)
            estimate = state_distance(fine, coarse) * factor
            if estimate <= self.tolerance or 2 * k >= self.budget:
                break
            k, coarse = 2 * k, fine
        # The next step starts from this one's count; halved when the estimate allows
        # (halving the sub-steps multiplies the local error by about 2^p).
        self.k = max(1, k // 2) if estimate * 2.0 ** (p + 1) < self.tolerance else k
        return fine, estimate, 2 * k


def _needed(k: int, estimate: float, target: float, order: int) -> int:
    """Sub-steps for which an estimate going as ``h^order`` falls to ``target``."""
    if not math.isfinite(estimate):
        return 2 * k
    return max(1, math.ceil(k * (estimate / target) ** (1.0 / order) - 1e-9))


def _advance(integrator, state: State, dt: float, t_end: float, k: int,
             error: Optional[np.ndarray] = None) -> State:
    """``k`` equal sub-steps of ``dt / k`` from ``state``, the last ending at ``t_end``."""
    h = dt / k
    s = state
    for i in range(k):
        s = integrator.step(s, h, t_end if i == k - 1 else state.time + (i + 1) * h, error)
    return s
