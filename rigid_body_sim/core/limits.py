"""
Joint limits and joint Coulomb friction: rows with bounds, an active set, located events.

(The steps with their events: :mod:`.joint_events`; friction: :class:`JointFriction`.)

A robot joint with a URDF ``<limit lower upper>`` (revolute, prismatic) may not leave
``[lower, upper]``. Each bound is a unilateral row on the joint coordinate ``q``: with
the gap ``g = s (q − bound)`` (``s = +1`` at the lower bound, ``−1`` at the upper)
and the generalized force ``f`` the row applies along ``q``,

    g ≥ 0,   s f ≥ 0,   g · f = 0

(the row pushes, and only while the joint touches its bound). An *active* bound is an
equality row ``Φ = q − bound`` of the constraint solve (a ``drive`` constraint named
:func:`limit_name`, ``f = −λ``), held by the same projections as every joint, so that
while a joint rests on its bound it drifts from it no more than a joint's drift. The
active set changes only between (partial) steps, by two rules that are the pivots of
a direct method on the complementarity conditions:

* **release**: after each step with a row held, the multipliers at its end are solved
  (the read a ``joint_state`` after the step reuses); when an active bound pulls there
  (``s f < 0``: the joint would accelerate away) beyond :data:`FORCE_TOLERANCE`, the
  step is taken again up to the moment its force reached zero, located by regula falsi
  on partial steps (each a solve at the partial step's end) to FORCE_TOLERANCE of the
  force's change over the step, and there the bound leaves the active set; the
  multipliers are solved anew without it, and any other bound then pulling leaves too
  (the direct method's pivots, each exact); then the rest of the step is taken. So a
  bound lets go at its located time and the integrator keeps its order through it;
  resting on a bound costs one solve a step beyond the step's own. The same rule, and
  the same location, serve a sticking joint whose force reaches its friction
  (:class:`JointFriction`) and an exact drive whose force reaches its effort limit
  (:class:`DriveEfforts`);
* **impact**: a step after which an inactive bound is crossed (``g < −tol``) is taken
  again up to the moment ``t*`` of the crossing, located by regula falsi (Illinois) on
  partial steps from the step's start until ``|g| ≤`` :data:`LOCATION_TOLERANCE`; there
  the bound becomes active and Newton's law of restitution sets the joint's rate to
  ``−e`` times its approach rate, with every other joint's constraint kept (the
  mass-weighted velocity projection of the solve: momentum and the joints' reactions
  are those of an impulsive contact), then the rest of the step is taken. ``e = 0``
  leaves the bound active, ``e > 0`` releases it. After :data:`MAX_BOUNCES` impacts in
  one step the next ones are inelastic (a bouncing joint's impacts accumulate in finite
  time, Zeno's series; this cuts it).

So the bound is exceeded by at most :data:`LOCATION_TOLERANCE` at an impact, and an
impact happens at its located time, with fixed steps as with the accuracy knob (the
step after an impact restarts the method). Under the knob every location tolerance
is ``tolerance dt`` instead (not below :data:`LOCATION_FLOOR` and
:data:`RATE_FLOOR`), and a step with events is charged what they may leave, so the
knob's promise holds across them (:meth:`.joint_events.JointEvents.tighten`). A
crossing that begins and ends inside one step (a joint that overshoots its bound and
comes back within ``dt``) is not seen.
Kinetic energy is never gained at an impact for ``e ≤ 1``.

Joints held by an exact drive (the drive is the motion: a target beyond a limit is the
commander's to avoid) and followers of mimic joints (their leader's limits hold them)
have no limit rows.
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, NamedTuple, Optional

import numpy as np

from .errors import SpecError
from .kernels.joints import any_beyond
from .validate import finite_scalar

#: rad or m: how far past its bound a joint may be where an impact is located (the
#: stated bound of the violation at impacts; while a bound is active the joint's
#: drift is that of every constraint).
LOCATION_TOLERANCE = 1e-10
#: rad/s or m/s: a joint on its bound moving into it more slowly than this is at rest
#: there, not hitting it (rounding leaves rates of 1e-16 after an inelastic impact).
RATE_TOLERANCE = 1e-9
#: rad or m, rad/s or m/s: the tightest location tolerances under the accuracy knob
#: (the coordinates' and rates' rounding, 1e-16 of some radians or radians a second,
#: with room).
LOCATION_FLOOR = 1e-13
RATE_FLOOR = 1e-13
#: Relative: where a held row's force reaches its bound (a bound's force zero, a
#: sticking joint's ``F``, a drive's ``E``), the moment is located until the force is
#: within this fraction of its scale of it (``F``, ``E``; for bounds, the largest force
#: of the active bounds).
FORCE_TOLERANCE = 1e-9
#: Most regula-falsi iterations to locate one impact (each a partial step).
MAX_LOCATION_ITERATIONS = 40
#: Impacts in one step after which the next ones are inelastic (Zeno's cut).
MAX_BOUNCES = 8
EPS = float(np.finfo(float).eps)
_NONE = np.zeros(0, dtype=int)
#: Most impacts in one step: beyond them the step is accepted as it is and the
#: excess counted in ``limit_residual`` (never silently).
MAX_EVENTS = 32


#: How many of the latest impacts :attr:`JointLimits.impacts` keeps.
IMPACT_LOG = 256


class Impact(NamedTuple):
    """One located impact of a joint on a bound."""

    time: float          #: s, simulation time
    joint: str
    side: int            #: +1 the lower bound, −1 the upper
    approach: float      #: rad/s or m/s, the joint's rate into the bound (< 0)
    rebound: float       #: rad/s or m/s, its rate away from it after (−e approach)


def limit_name(joint: str) -> str:
    """Name of the constraint that holds ``joint`` on its bound while the bound is active."""
    return f'{joint}_limit'


@dataclass
class LimitCounters:
    """What the limits did since the last reset."""

    impacts: int = 0
    #: Steps in which an event (an impact, a friction stop) was located.
    located_steps: int = 0
    releases: int = 0
    activations: int = 0
    #: Largest complementarity residual seen after a step: a bound exceeded (rad or m)
    #: beyond LOCATION_TOLERANCE, or 0.
    max_violation: float = 0.0
    events_capped: int = 0

    def as_dict(self) -> dict:
        """Return the counters as a dict."""
        return asdict(self)


class JointLimits:
    """
    The position limits of the robots' one-coordinate joints, and their active set.

    Parameters
    ----------
    space : JointSpace
    limited : ndarray of bool, shape (k,)
        Joints whose limits are enforced (the robot asks for it, the joint has a
        bound, no exact drive holds it, it follows no mimic leader).
    restitution : ndarray, shape (k,)
        Newton's coefficient ``e`` in [0, 1] of each joint's bounds.

    """

    def __init__(self, space: Any, limited: np.ndarray, restitution: np.ndarray) -> None:
        self.space = space
        k = len(space)
        self.lower = np.array([-np.inf if j.spec.lower is None else j.spec.lower
                               for j in space.joints]).reshape(k)
        self.upper = np.array([np.inf if j.spec.upper is None else j.spec.upper
                               for j in space.joints]).reshape(k)
        limited = np.asarray(limited, dtype=bool) & (np.isfinite(self.lower)
                                                     | np.isfinite(self.upper))
        #: Indices of the joints with enforced limits.
        self.joints = np.flatnonzero(limited)
        #: rad or m, rad/s or m/s: the location's tolerances in use (:meth:`tighten`).
        self.location, self.rate = LOCATION_TOLERANCE, RATE_TOLERANCE
        # The bounds of the limited joints, each widened by the tolerance: what a step's
        # end is checked against (one comparison each, nothing else, while all are free).
        self._low = self.lower[self.joints] - self.location
        self._high = self.upper[self.joints] + self.location
        # The same per joint in the joints' table (±inf for a joint without enforced
        # limits): checked in the kernel that reads the coordinates while no bound is
        # active (:meth:`.JointSpace.advance`).
        self._watch()
        self.restitution = np.asarray(restitution, dtype=float).reshape(k)
        self.names = [limit_name(space.names[i]) for i in range(k)]
        #: Per joint: 0 free, +1 on its lower bound, −1 on its upper bound.
        self.active = np.zeros(k, dtype=int)
        #: Per joint: its bound became active at a start beyond it (a reset, a state set)
        #: and the joint has not yet come back within the tolerance: held whatever its
        #: row's sign (it converges back as a violated constraint does).
        self.beyond = np.zeros(k, dtype=bool)
        #: The row in Φ and λ of each active bound (joint -> row), kept by the caller.
        self.rows: dict = {}
        self.counters = LimitCounters()
        #: The latest impacts (at most IMPACT_LOG), oldest first.
        self.impacts: deque = deque(maxlen=IMPACT_LOG)

    def __len__(self) -> int:
        """Return the number of joints with enforced limits."""
        return len(self.joints)

    def tighten(self, location: float, rate: float) -> None:
        """Use these tolerances (rad or m, rad/s or m/s) for the crossings and their rates."""
        self.location, self.rate = location, rate
        self._low = self.lower[self.joints] - location
        self._high = self.upper[self.joints] + location
        self._watch()

    def _watch(self) -> None:
        """Watch the widened bounds of the limited joints in the joints' table (±inf: others)."""
        k = len(self.lower)
        low, high = np.full(k, -np.inf), np.full(k, np.inf)
        low[self.joints], high[self.joints] = self._low, self._high
        self.space.watch(low, high)

    def reset(self) -> None:
        """Forget the active set and the counters."""
        self.active[:] = 0
        self.beyond[:] = False
        self.rows = {}
        self.counters = LimitCounters()
        self.impacts.clear()

    def bound(self, i: int, side: int) -> float:
        """Return the bound of joint ``i`` on ``side`` (+1 lower, −1 upper)."""
        return float(self.lower[i] if side > 0 else self.upper[i])

    def gaps(self, q: np.ndarray) -> tuple:
        """
        Signed gaps of the limited joints at coordinates ``q`` (k,).

        Returns ``(gap, side)`` over :attr:`joints`: the smaller of ``q − lower`` and
        ``upper − q`` (negative: beyond a bound) and the side it is on (+1 lower, −1
        upper).
        """
        q = q[self.joints]
        lo, hi = q - self.lower[self.joints], self.upper[self.joints] - q
        side = np.where(lo <= hi, 1, -1)
        return np.minimum(lo, hi), side

    def crossed(self, q: np.ndarray) -> np.ndarray:
        """Return the free joints beyond a bound by more than the tolerance (indices)."""
        if not any_beyond(q, self.joints, self._low, self._high):
            return self.joints[:0]
        gap, _ = self.gaps(q)
        free = self.active[self.joints] == 0
        return self.joints[free & (gap < -self.location)]

    def returned(self, q: np.ndarray) -> np.ndarray:
        """Return the joints held since a start beyond their bound, back within the tolerance."""
        if not self.rows:
            return _NONE   # (a joint beyond its bound is held by a row)
        idx = np.flatnonzero(self.beyond)
        return idx[self.past(q, idx) <= self.location]

    def past(self, q: np.ndarray, which: np.ndarray) -> np.ndarray:
        """Return how far joints ``which`` are beyond their active bounds (negative: within)."""
        side = self.active[which]
        bound = np.where(side > 0, self.lower[which], self.upper[which])
        return side * (bound - q[which])

    def worst_gap(self, q: np.ndarray, which: np.ndarray) -> float:
        """Return the smallest gap of joints ``which`` at ``q`` (the event function)."""
        lo, hi = q[which] - self.lower[which], self.upper[which] - q[which]
        return float(np.min(np.minimum(lo, hi)))

    def event(self, q: np.ndarray, rates: np.ndarray, which: np.ndarray) -> tuple:
        """
        Return the event function of joints ``which``: (smallest gap, whether moving in).

        The second is whether the joint of the smallest gap moves into its bound
        faster than :data:`RATE_TOLERANCE` (an impact, when the gap is within the
        tolerance; a joint on its bound and leaving it, or at rest there, is none).
        """
        lo, hi = q[which] - self.lower[which], self.upper[which] - q[which]
        gaps = np.minimum(lo, hi)
        k = int(np.argmin(gaps))
        side = 1.0 if lo[k] <= hi[k] else -1.0
        return float(gaps[k]), side * rates[which[k]] < -self.rate

    def touching(self, q: np.ndarray, rates: np.ndarray) -> list:
        """
        Free joints at a bound (within the tolerance) moving into it: ``(i, side, rate)``.

        ``rate`` is the approach rate ``s q̇ < 0`` (rad/s or m/s).
        """
        out = []
        for i in self.joints:
            if self.active[i]:
                continue
            for side, b in ((1, self.lower[i]), (-1, self.upper[i])):
                gap = side * (q[i] - b)
                if gap <= self.location and side * rates[i] < -self.rate:
                    out.append((int(i), side, float(side * rates[i])))
        return out


#: Friction modes of a joint (:attr:`JointFriction.mode`); ±1: slipping towards ±q.
OFF, STICK = 0, 2


def stick_name(joint: str) -> str:
    """Name of the constraint that holds ``joint`` still while its friction sticks."""
    return f'{joint}_stick'


class JointFriction:
    """
    Coulomb friction of the robots' one-coordinate joints (URDF ``<dynamics friction>``).

    A joint's friction force ``F`` bounds a row on its rate: while it **sticks**, an
    equality row (a ``drive`` constraint :func:`stick_name` holding the coordinate
    where it stopped) carries whatever force ``f`` keeps it still, as long as ``|f| ≤
    F``; while it **slips** towards ``d = ±1``, a constant generalized force ``−F d``
    acts along it (a pair of equal and opposite wrenches on its two bodies). Static
    and kinetic friction are the same ``F`` (Coulomb). Transitions, with the limits'
    machinery (:mod:`.limits`): a step at whose end the row needs ``|f| > F`` is
    taken again up to the moment ``|f|`` reached ``F`` (located as a bound's release
    is), where the joint begins to slip towards ``−sign f``; a slipping joint whose
    rate reaches zero inside a step (once it has moved: :attr:`moving`) is stopped
    there, the moment located by regula falsi on partial steps to
    :data:`RATE_TOLERANCE`, and sticks (then slips again, the other way, if its row
    needs more than ``F``). A joint on an active bound has neither: the bound holds
    it; it sticks when the bound lets go.

    Parameters
    ----------
    space : JointSpace
    force : ndarray, shape (k,)
        N m or N: ``F`` per joint (0: frictionless, no rows).

    """

    def __init__(self, space: Any, force: np.ndarray) -> None:
        k = len(space)
        self.force = np.asarray(force, dtype=float).reshape(k)
        #: Indices of the joints with friction.
        self.joints = np.flatnonzero(self.force > 0.0)
        self.names = [stick_name(space.names[i]) for i in range(k)]
        #: Per joint: OFF, STICK, or ±1 (slipping towards ±q).
        self.mode = np.zeros(k, dtype=int)
        #: The row in Φ and λ of each sticking joint (joint -> row), kept by the caller.
        self.rows: dict = {}
        #: Per joint: whether it has slipped faster than RATE_TOLERANCE since it began
        #: to slip (a slip that begins where the force just reached F starts at rest).
        self.moving = np.zeros(k, dtype=bool)
        #: rad/s or m/s: the stops' tolerance in use (the events' ``tighten``).
        self.rate = RATE_TOLERANCE
        self.counters = {'sticks': 0, 'slips': 0}

    def __len__(self) -> int:
        """Return the number of joints with friction."""
        return len(self.joints)

    def reset(self) -> None:
        """Forget the modes and the counters."""
        self.mode[:] = OFF
        self.rows = {}
        self.moving[:] = False
        self.counters = {'sticks': 0, 'slips': 0}

    def slipping(self) -> np.ndarray:
        """Return the slipping joints (indices)."""
        return self.joints[np.abs(self.mode[self.joints]) == 1]

    def stopped(self, rates: np.ndarray) -> np.ndarray:
        """
        Return the slipping joints whose rate has reached zero or turned (indices).

        A joint that began to slip at rest counts once it has moved (:attr:`moving`),
        or when it turns back.
        """
        slip = self.slipping()
        d = self.mode[slip] * rates[slip]
        return slip[(self.moving[slip] & (d <= self.rate)) | (d < -self.rate)]

    def note(self, rates: np.ndarray) -> None:
        """Mark the slipping joints moving faster than RATE_TOLERANCE at an accepted state."""
        slip = self.slipping()
        self.moving[slip[self.mode[slip] * rates[slip] > self.rate]] = True

    def event(self, rates: np.ndarray, which: np.ndarray) -> float:
        """Return the event function of slipping joints ``which``: the smallest ``d q̇``."""
        return float(np.min(self.mode[which] * rates[which]))


#: Modes of an effort-limited exact drive (:attr:`DriveEfforts.mode`): engaged (its row
#: holds the motion), or ±1: saturated, pushing with ``±E``.
ENGAGED = 0


class DriveEfforts:
    """
    The effort limits of exact drives (:class:`.robots.CommandGroup` of mode ``exact``).

    An exact drive is the row ``Φ = q − c(t)`` of the solve, held on the law ``Φ̇ =
    −ωΦ`` by the step's velocity projection (``ω``: the solver's rate); its effort is
    ``f = −λ``. With a finite URDF effort ``E`` the row is bounded, ``|f| ≤ E``, and
    complementary to the law: the drive is **engaged** (the row holds the motion,
    ``r = Φ̇ + ωΦ = 0``) while ``|f| ≤ E``, else **saturated** towards ``σ = ±1``:
    no row, a constant generalized force ``σ E`` along the joint (a pair of
    wrenches), while ``σ r < 0`` (the joint lags behind the law). Transitions, with
    the limits' machinery:

    * **saturation**: a step at whose end the row needs ``|f| > E`` is taken again up
      to the moment ``|f|`` reached ``E`` (located as a bound's release is), where the
      drive saturates towards ``sign f``; a command whose velocity projection would
      need an impulse larger than ``E dt`` (a target jump, a new velocity) saturates
      it at once, towards the target (the impulse over a step: first order in time);
    * **engagement**: a saturated drive whose ``r`` reaches zero inside a step is
      engaged there, the moment located by regula falsi on partial steps to
      :data:`RATE_TOLERANCE` (no impulse: the law already holds there); if its row
      then needs more than ``E`` it saturates again at once, towards ``sign f``.

    So the effort never exceeds ``E`` (beyond FORCE_TOLERANCE of it), a motion
    that needs more lags with the effort at ``E``, and the drive catches up along the
    row's law when it can.

    Parameters
    ----------
    names : list of str
        The drives' constraint names, one per joint of the space (``<joint>_drive``).
    limited : ndarray of int
        The joints whose exact drives are effort-limited.
    effort : ndarray, shape (k,)
        N m or N: each joint's effort limit ``E``.

    """

    def __init__(self, names: list, limited: np.ndarray, effort: np.ndarray) -> None:
        self.names = list(names)
        self.joints = np.asarray(limited, dtype=int)
        self.effort = np.asarray(effort, dtype=float)
        #: Per joint: ENGAGED or ±1 (saturated, pushing with ±E).
        self.mode = np.zeros(len(self.names), dtype=int)
        #: The row in Φ and λ of each engaged limited drive (joint -> row), kept by the caller.
        self.rows: dict = {}
        #: Each saturated drive's motion ``(c₀, ċ, t₀)``, kept while its row is away.
        self.motion: dict = {}
        #: Each saturated drive's constraint (its description), kept while it is away.
        self.specs: dict = {}
        #: Per joint: whether its saturated drive has lagged its law beyond
        #: RATE_TOLERANCE since it saturated (a saturation where the force just reached
        #: E starts on the law).
        self.away = np.zeros(len(self.names), dtype=bool)
        self.counters = {'saturations': 0, 'engagements': 0}

    def __len__(self) -> int:
        """Return the number of effort-limited drives."""
        return len(self.joints)

    def reset(self) -> None:
        """Engage every drive; forget the counters."""
        self.mode[:] = ENGAGED
        self.rows, self.motion, self.specs = {}, {}, {}
        self.away[:] = False
        self.counters = {'saturations': 0, 'engagements': 0}

    def saturated(self) -> np.ndarray:
        """Return the saturated drives' joints (indices)."""
        return self.joints[self.mode[self.joints] != ENGAGED]

    def target(self, i: int, time: float) -> tuple:
        """Return a saturated drive's target and its rate at ``time``: ``(c, ċ)``."""
        c0, rate, t0 = self.motion[i]
        return c0 + rate * (time - t0), rate

    def error(self, i: int, q: float, time: float, rotary: bool) -> float:
        """
        Return a saturated drive's ``Φ = q − c(t)`` (its tracking error, rad or m).

        An angle is taken within π (the drive's row goes the shorter way).
        """
        phi = q - self.target(i, time)[0]
        return (phi + np.pi) % (2.0 * np.pi) - np.pi if rotary else phi

    def law(self, i: int, q: float, rate: float, time: float, omega: float,
            rotary: bool) -> float:
        """Return ``r = Φ̇ + ωΦ`` of a saturated drive (0: the row's law holds)."""
        return rate - self.target(i, time)[1] + omega * self.error(i, q, time, rotary)

    def event(self, laws: np.ndarray, which: np.ndarray) -> float:
        """Return the event function of saturated drives ``which``: the smallest ``−σ r``."""
        return float(np.min(-self.mode[which] * laws))


@dataclass(frozen=True)
class SceneJoint:
    """
    Limits and Coulomb friction on a scene's hinge or slider constraint (not a robot's).

    The constraint becomes a joint of the simulation's joint space, named as the
    constraint, whose coordinate counts from the configuration the scene starts in
    (the child ``body_a`` relative to ``body_b`` or the world; rad about the axis, or
    m along it): it has a joint state, takes effort commands, and its limits and
    friction are those of :mod:`.limits`, as a URDF joint's.

    Parameters
    ----------
    constraint : str
        The name of a ``hinge`` or ``slider`` constraint of the scene.
    lower, upper : float, optional
        rad or m, each finite or absent (no bound on that side); ``lower <= upper``.
    restitution : float
        Newton's ``e`` in [0, 1] at the bounds.
    friction : float
        N m or N, >= 0: Coulomb friction ``F`` (0: none; ``inf``: the joint is locked,
        its sticking row never lets go).

    """

    constraint: str
    lower: Optional[float] = None
    upper: Optional[float] = None
    restitution: float = 0.0
    friction: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.constraint, str) or not self.constraint:
            raise SpecError('name', f'must be a non-empty string, got {self.constraint!r}')
        for key in ('lower', 'upper'):
            value = getattr(self, key)
            if value is not None:
                object.__setattr__(self, key, finite_scalar(value, key))
        if self.lower is not None and self.upper is not None and self.lower > self.upper:
            raise SpecError('lower', f'lower {self.lower!r} is above upper {self.upper!r}: '
                                     f'no position satisfies both')
        object.__setattr__(self, 'restitution', _coefficient(self.restitution, 'restitution'))
        try:
            friction = float(self.friction)
        except (TypeError, ValueError):
            friction = float('nan')
        if not friction >= 0.0 or isinstance(self.friction, bool):
            raise SpecError('friction', f'must be a number >= 0 (a Coulomb force bound; '
                                        f'.inf locks the joint), got {self.friction!r}')
        object.__setattr__(self, 'friction', friction)


def restitution_of(value: Any, names: list, field_name: str) -> np.ndarray:
    """
    Validate a restitution (a number, or ``{joint: number}``) into an array over ``names``.

    Each value must be in [0, 1] (more than 1 would gain energy at an impact).
    """
    out = np.zeros(len(names))
    if isinstance(value, dict):
        index = {name: i for i, name in enumerate(names)}
        for joint, e in value.items():
            if joint not in index:
                raise SpecError(f'{field_name}.{joint}', f'unknown joint {joint!r}; joints: '
                                                         f'{names}')
            out[index[joint]] = _coefficient(e, f'{field_name}.{joint}')
        return out
    out[:] = _coefficient(value, field_name)
    return out


def _coefficient(value: Any, field_name: str) -> float:
    e = finite_scalar(value, field_name)
    if not 0.0 <= e <= 1.0:
        raise SpecError(field_name, f'must be in [0, 1] (Newton restitution; above 1 an '
                                    f'impact would gain energy), got {value!r}')
    return e
