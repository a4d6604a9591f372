"""
Wall-clock pacing of fixed physics steps, and the statistics the node reports (no ROS).

Step ``k`` after an anchor is due at ``anchor_wall + k * dt / rtf``. When steps
fall behind (a step costs more than its budget ``dt / rtf``), the loop runs the
due steps back to back to catch up, but never by more than :data:`MAX_LAG`
seconds of wall time: beyond that the backlog is dropped (the schedule is
re-anchored at now), counted as a lag reset, and shows as a real-time factor
below the requested one. ``dt`` never changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

#: s of wall time: the largest backlog of due steps the loop catches up on.
MAX_LAG = 0.1


class Pacer:
    """
    Tell when physics steps are due on the wall clock.

    Parameters
    ----------
    dt : float
        s, simulated time per step.
    real_time_factor : float
        Simulated seconds per wall second; 0: as fast as possible.

    """

    def __init__(self, dt: float, real_time_factor: float) -> None:
        self.dt = dt
        self.real_time_factor = real_time_factor
        self.anchor_wall = 0.0
        self.steps_since_anchor = 0
        self.lag_resets = 0
        self.dropped_wall = 0.0   # s of wall time dropped by lag resets

    @property
    def period(self) -> float:
        """Wall seconds per step (0 when as fast as possible)."""
        return self.dt / self.real_time_factor if self.real_time_factor > 0.0 else 0.0

    def restart(self, now: float) -> None:
        """Anchor the schedule at ``now`` (after a pause, a reset or a rate change)."""
        self.anchor_wall = now
        self.steps_since_anchor = 0

    def next_due(self) -> float:
        """Wall time at which the next step is due."""
        return self.anchor_wall + self.steps_since_anchor * self.period

    def due(self, now: float) -> bool:
        """
        Tell whether a step is due at ``now``; drop a backlog beyond MAX_LAG.

        The caller takes the step and then calls :meth:`stepped`.
        """
        if self.period == 0.0:
            return True
        lag = now - self.next_due()
        if lag > MAX_LAG:
            self.lag_resets += 1
            self.dropped_wall += lag
            self.restart(now)
            return True
        return lag >= 0.0

    def stepped(self) -> None:
        """Record that the due step was taken."""
        self.steps_since_anchor += 1


@dataclass
class WindowStats:
    """Counts over one reporting window (reset each time diagnostics are published)."""

    wall_start: float = 0.0
    sim_start: float = 0.0
    steps: int = 0
    step_cost_sum: float = 0.0
    step_cost_max: float = 0.0
    overruns: int = 0
    publish_cost_sum: float = 0.0
    publishes: int = 0
    lag_resets_before: int = 0   # the pacer's lag resets when the window began
    accuracy_misses_before: int = 0   # steps that missed the tolerance, at the start
    capped_before: int = 0   # steps that hit the work bound (capped sub-steps), at the start
    impacts_before: int = 0   # joint-limit impacts located, at the start

    def record_step(self, cost: float, budget: float) -> None:
        """Record one step that took ``cost`` wall seconds against ``budget``."""
        self.steps += 1
        self.step_cost_sum += cost
        self.step_cost_max = max(self.step_cost_max, cost)
        if budget > 0.0 and cost > budget:
            self.overruns += 1

    def record_publish(self, cost: float) -> None:
        """Record one publish of the state that took ``cost`` wall seconds."""
        self.publishes += 1
        self.publish_cost_sum += cost


@dataclass
class Totals:
    """Rejected inputs by cause, since the node started."""

    rejected: dict = field(default_factory=dict)   # cause -> count

    def reject(self, cause: str) -> None:
        """Count one rejected input."""
        self.rejected[cause] = self.rejected.get(cause, 0) + 1


def output_due(time_before: float, time_after: float, rate: float) -> bool:
    """
    Tell whether an output at ``rate`` Hz falls in the step from one time to another.

    Outputs fall on simulation times that are whole multiples of ``1 / rate``
    (to rounding): one is due when ``floor(t * rate)`` changes over the step, so
    a rate at or above the physics rate means every step. Time-based, so a
    change of the physics rate keeps outputs on the same grid.
    """
    eps = 1e-6
    return math.floor(time_after * rate + eps) != math.floor(time_before * rate + eps)
