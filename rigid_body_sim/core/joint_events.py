"""
The steps of a simulation whose joints have limits or Coulomb friction: events inside a step.

:mod:`.limits` holds the rows' data and rules (bounds, restitution, friction forces);
this module takes the steps. A step is the integrator's (:meth:`.Simulation._advance`);
after it the joint coordinates are read once, and, while a row with a force bound is
held, the multipliers at its end. When nothing happened the step stands. When a free
joint passed a bound, a slipping joint's rate reached zero, a saturated drive's law
holds again, or a held row's force passed its bound (a bound pulls, a sticking
joint needs more than its friction, a drive more than its effort), the step is taken
again up to the first such moment, found by regula falsi (Illinois) on partial steps
from the step's start; there the event is resolved (an impact with Newton's
restitution, a stop that sticks, a drive that engages, a row that pivots: the
direct method's pivots, each followed by a solve) and the rest of the step is
taken, as often as events come, up to :data:`.limits.MAX_EVENTS`.

The rows that come and go here are ``drive`` constraints of the solve, named
:func:`.limits.limit_name` and :func:`.limits.stick_name`; they count as their joints'
(reactions, violations, efforts) and are not among the simulation's constraint names.
Effort-limited exact drives (:class:`.limits.DriveEfforts`) come and go the same way:
a saturated drive's row (``<joint>_drive``) leaves the solve while a constant effort
acts, and comes back where the drive's law holds again (an event located as a
friction stop is); its name stays among the constraints, its reaction being the effort.
"""

from __future__ import annotations

import copy
from typing import Any, Optional

import numpy as np

from .bodies import State
from .complementarity import FREE, solve
from .constraints import Constraint, JointType
from .kernels.layout import O_ORIGIN_WORLD, O_QUAT_BODY_WORLD
from .limits import (DriveEfforts, ENGAGED, EPS, FORCE_TOLERANCE, Impact, JointFriction,
                     JointLimits, LOCATION_FLOOR, LOCATION_TOLERANCE, MAX_BOUNCES, MAX_EVENTS,
                     MAX_LOCATION_ITERATIONS, OFF, RATE_FLOOR, RATE_TOLERANCE, STICK)
from .rotation import cross, quat_to_matrix

_NONE = np.zeros(0, dtype=int)


class JointEvents:
    """
    Limits and friction of a simulation's robot joints, stepped with their events.

    Parameters
    ----------
    sim : Simulation
        The simulation whose steps these are (its joints, solver, wrenches).
    limits : JointLimits or None
    friction : JointFriction or None
    drives : DriveEfforts or None
        The effort limits of exact drives.

    """

    def __init__(self, sim: Any, limits: Optional[JointLimits],
                 friction: Optional[JointFriction],
                 drives: Optional[DriveEfforts] = None) -> None:
        self.sim = sim
        self.limits = limits
        self.friction = friction
        self.drives = drives
        self._bounds_only = limits is not None and friction is None and drives is None
        #: Since the last reset: steps with a located event; the largest force past its
        #: bound a row had where it pivoted (N m or N: within FORCE_TOLERANCE of the
        #: scale at a located event; more only when MAX_EVENTS cut a step short); the
        #: held rows' LCPs solved, their largest residual, those that failed.
        self.counters: dict = {}
        self.reset_counters()
        #: rad or m, rad/s or m/s: the location's tolerances in use: LOCATION_TOLERANCE and
        #: RATE_TOLERANCE, or tighter under the accuracy knob (:meth:`tighten`).
        self.location, self.rate = LOCATION_TOLERANCE, RATE_TOLERANCE
        self._left = 0.0   # what the step's located events may leave (:meth:`_charge`)
        self._sides: dict = {}   # each limited drive's child side (:meth:`_subtree`)
        # The margins at the end of the step being located, and each held row's margin
        # change over it (the scale of its event function: a fraction of the step).
        self._end_margins = np.zeros(0)
        self._span: Optional[np.ndarray] = None
        self._span_keys: list = []   # the rows (kind, joint) the spans are of

    def reset_counters(self) -> None:
        """Zero the counters (a reset)."""
        self.counters = {'located_steps': 0, 'max_force_excess': 0.0, 'lcp_solves': 0,
                         'lcp_residual_max': 0.0, 'lcp_failures': 0}

    # -- names and readings -----------------------------------------------------------------

    def reserved(self) -> set:
        """Return the constraint names these rows may take (no user constraint may)."""
        out = set()
        if self.limits is not None:
            out |= {self.limits.names[i] for i in self.limits.joints}
        if self.friction is not None:
            out |= {self.friction.names[i] for i in self.friction.joints}
        return out

    def held(self) -> dict:
        """Return the rows present now: ``{row name: joint index}``."""
        out = {}
        if self.limits is not None:
            out.update({self.limits.names[i]: i for i in self.limits.rows})
        if self.friction is not None:
            out.update({self.friction.names[i]: i for i in self.friction.rows})
        return out

    def holds(self) -> bool:
        """Tell whether a bound's or a stick's row is present (:meth:`held` not empty)."""
        lim, fr = self.limits, self.friction
        return bool((lim is not None and lim.rows) or (fr is not None and fr.rows))

    def efforts(self, lam: Optional[np.ndarray]) -> Optional[np.ndarray]:
        """
        Generalized force (k,) of the limits and friction on each joint (None: none).

        A present row ``Φ = q − c`` applies ``−λ`` along its joint (``lam``: the
        multipliers at the state, None when no row is present); a slipping joint's
        friction is ``−F d``.
        """
        fr = self.friction
        if lam is None and (fr is None or not len(fr.slipping())):
            return None
        out = np.zeros(len(self.sim.joints))
        if lam is not None:
            rows_of = self.sim.dynamics.solver.constraints.rows_of
            for name, i in self.held().items():
                out[i] -= lam[rows_of(name)[0]]
        if fr is not None:
            slip = fr.slipping()
            out[slip] -= fr.force[slip] * fr.mode[slip]
        return out

    # -- a step -----------------------------------------------------------------------------

    def quiet(self) -> bool:
        """
        Tell whether only the bounds need watching: no row held, no friction, no drive limit.

        Then a step that ends with every coordinate within its widened bounds (the
        joint table's window, :meth:`.JointLimits._watch`, checked in the kernel that
        reads the coordinates: :meth:`.JointSpace.advance`) has no event and stands;
        :meth:`step` is needed only for one that does not. The tolerances are set
        first (:meth:`tighten`), as :meth:`step` sets them.
        """
        if not self._bounds_only or self.limits.rows:
            return False
        self.tighten()
        return True

    def step(self, start: State, t_end: float, first: Optional[State] = None,
             span: Optional[float] = None) -> tuple:
        """
        Take a step from ``start`` to ``t_end`` with every event inside it resolved.

        Returns the new state and ``(coordinates, rates over their limits)`` there
        (None when the step ended on an event), which the joints' tracking takes
        instead of reading them again. ``first``: the integrator's step from
        ``start`` to ``t_end``, when the caller took it already. ``span``: the
        length of the first integrator step (default ``dt``, as a plain step takes
        it; a part of a step, such as a contact's located impact leaves, gives its own).
        """
        sim, lim, fr = self.sim, self.limits, self.friction
        state, previous = start, sim.joints.positions
        self.tighten()
        events = 0
        while True:
            h = t_end - state.time
            if h <= 4.0 * EPS * abs(t_end):   # an event at the step's end
                self._charge(t_end - start.time)
                return State(t_end, *state.parts), None
            # From the step's start, the step is dt, as the plain step (and the fast path of
            # :meth:`quiet`) takes it: t_end − t may differ from dt in its last bits.
            step = (sim.dt if span is None else span) if state is start else h
            if first is not None:
                new, first = first, None
            else:
                new = sim._advance(state, step, t_end)
            q, rates, over = self.coordinates(new, previous)
            crossed = _NONE if lim is None else lim.crossed(q)
            stopped = _NONE if fr is None else fr.stopped(rates)
            reached = self._reached(q, rates, new.time)
            releasing = self._releasing(new, q)
            returned = _NONE if lim is None else lim.returned(q)
            if not (len(crossed) or len(stopped) or len(reached) or releasing
                    or len(returned)):
                self._note(q, rates, new.time)
                if events:
                    self._charge(t_end - start.time)
                return new, (q, over)
            if events >= MAX_EVENTS:
                # Too many events in one step: the step stands, a bound passed is counted
                # (never silently), stopped joints stick where they are (no slip may go on
                # against its own friction), and rows past their force bounds pivot here.
                if len(crossed):
                    lim.counters.events_capped += 1
                    lim.counters.max_violation = max(lim.counters.max_violation,
                                                     -lim.worst_gap(q, crossed))
                if len(stopped) or len(reached) or releasing or len(returned):
                    new = self._resolve(new, q, rates,
                                        (_NONE, stopped, reached, releasing, returned), events)
                self._note(q, rates, new.time)
                self._charge(t_end - start.time)
                return new, (q, over)
            self.counters['located_steps'] += 1
            if lim is not None:
                lim.counters.located_steps += 1
            which = (crossed, stopped, reached, releasing, returned)
            state, previous, rates = self._locate(state, previous, step, new, q, rates, which)
            state = self._resolve(state, previous, rates, which, events)
            events += 1

    def tighten(self) -> None:
        """
        Set the location's tolerances for the accuracy knob (or their defaults without it).

        An event located to a gap ``δ`` (rad or m) or a rate ``δ`` (rad/s or m/s) leaves
        an error of about ``δ`` in the state, once: within the knob's budget for a step,
        ``tolerance dt``, when ``δ`` is at most that. So under the knob both are
        ``min(default, tolerance dt)``, but not below :data:`.limits.LOCATION_FLOOR`
        and :data:`.limits.RATE_FLOOR` (the coordinates' rounding, with room), where a
        step with an event is charged what its location may leave (:meth:`_charge`).
        """
        control, dt = self.sim._control, self.sim.dt
        if control is None:
            location, rate = LOCATION_TOLERANCE, RATE_TOLERANCE
        else:
            budget = control.tolerance * dt
            location = min(LOCATION_TOLERANCE, max(budget, LOCATION_FLOOR))
            rate = min(RATE_TOLERANCE, max(budget, RATE_FLOOR))
        if (location, rate) == (self.location, self.rate):
            return
        self.location, self.rate = location, rate
        if self.limits is not None:
            self.limits.tighten(location, rate)
        if self.friction is not None:
            self.friction.rate = rate

    def _charge(self, dt: float) -> None:
        """
        Charge the knob's estimate of a step with events what their location may leave.

        A crossing's gap tolerance (the impact applied that far from the bound), a stop's
        or an engagement's rate tolerance; a release's location leaves a force off by a
        fraction FORCE_TOLERANCE of its change over the step, for that fraction of the
        step: nothing measurable.
        """
        control, left = self.sim._control, self._left
        self._left = 0.0
        if control is not None and left > 0.0:
            # Within the budget by construction unless floored (no rounding makes a miss).
            budget = control.tolerance * self.sim.dt
            control.charge(control.tolerance if left <= budget else left / dt)

    def _laws(self, q: np.ndarray, rates: np.ndarray, time: float,
              which: np.ndarray) -> np.ndarray:
        """Return ``r = Φ̇ + ωΦ`` of saturated drives ``which`` (:meth:`.DriveEfforts.law`)."""
        dr, js = self.drives, self.sim.joints
        omega = self.sim.dynamics.solver.omega
        return np.array([dr.law(i, q[i], rates[i], time, omega, js.rotary[i]) for i in which])

    def _reached(self, q: np.ndarray, rates: np.ndarray, time: float) -> np.ndarray:
        """
        Return the saturated drives whose law holds again or was passed.

        ``σ r ≥ −tol`` for a drive that lagged its law since it saturated
        (:attr:`.DriveEfforts.away`), ``σ r > tol`` for any.
        """
        dr = self.drives
        if dr is None or not dr.motion:
            return _NONE
        sat = dr.saturated()
        d = dr.mode[sat] * self._laws(q, rates, time, sat)
        return sat[(dr.away[sat] & (d >= -self.rate)) | (d > self.rate)]

    def _note(self, q: np.ndarray, rates: np.ndarray, time: float) -> None:
        """Note, at an accepted step's end, slips that move and drives that lag their law."""
        fr, dr = self.friction, self.drives
        if fr is not None:
            fr.note(rates)
        if dr is not None and dr.motion:
            sat = dr.saturated()
            d = dr.mode[sat] * self._laws(q, rates, time, sat)
            dr.away[sat[d < -self.rate]] = True

    # -- rows at their force bounds ---------------------------------------------------------

    def _margins(self, lam: np.ndarray, q: np.ndarray) -> tuple:
        """
        Return how far each held row's force is from its bound, at the multipliers ``lam``.

        ``(kinds, joints, margins, forces, scales)``: per row its kind (0 a bound, 1 a
        sticking joint, 2 an engaged effort-limited drive), its joint, the margin (a
        bound's push ``s f``; ``F − |f|``; ``E − |f|``: negative past the bound), its
        force ``f = −λ`` along the joint, and the scale of :data:`FORCE_TOLERANCE` for
        it (N m or N): ``F`` or ``E``, and for the bounds the largest of their forces,
        at least the rounding of the solve (64 ulps of the largest multiplier, over
        FORCE_TOLERANCE: a bound that carries nothing does not pull by rounding). A
        joint that started beyond its bound (:attr:`.JointLimits.beyond`) and has not
        come back within the tolerance is held whatever its row's sign: no margin (its
        return is an event of its own, where the margin counts from). Any other gap is
        an impact's location or the rows' drift, and the row's force counts.
        """
        lim, fr, dr = self.limits, self.friction, self.drives
        kinds, joints, margins, forces, scales = [], [], [], [], []
        if lim is not None:
            for i, row in lim.rows.items():
                side = lim.active[i]
                if lim.beyond[i]:
                    continue
                f = -float(lam[row])
                kinds.append(0), joints.append(i), margins.append(side * f), forces.append(f)
            rounding = 64.0 * EPS * float(np.max(np.abs(lam), initial=0.0)) / FORCE_TOLERANCE
            scales = [max(max((abs(f) for f in forces), default=0.0), rounding)] * len(forces)
        for kind, part, bound in ((1, fr, None if fr is None else fr.force),
                                  (2, dr, None if dr is None else dr.effort)):
            if part is None:
                continue
            for i, row in part.rows.items():
                f = -float(lam[row])
                kinds.append(kind), joints.append(i), forces.append(f)
                margins.append(bound[i] - abs(f))   # (inf: a locked joint, never due)
                scales.append(bound[i] if np.isfinite(bound[i]) else max(abs(f), 1.0))
        return kinds, joints, np.array(margins), forces, np.maximum(np.array(scales), 1e-300)

    def _held(self) -> bool:
        """Tell whether a row with a force bound is held (a bound, a stick, a limited drive)."""
        lim, fr, dr = self.limits, self.friction, self.drives
        return bool((lim is not None and lim.rows) or (fr is not None and fr.rows)
                    or (dr is not None and dr.rows))

    def _releasing(self, state: State, q: np.ndarray) -> bool:
        """
        Tell whether a held row's force at ``state`` is past its bound beyond the tolerance.

        The multipliers at the state (the read solve a ``joint_state`` after the step
        reuses); records the bounds' force scale for :meth:`_event`.
        """
        if not self._held():
            return False
        lam = self.sim.dynamics.solver.multipliers(self.sim.dynamics, state)
        _, _, margins, _, scales = self._margins(lam, q)
        self._end_margins, self._span = margins, None
        return bool(len(margins)) and float(np.min(margins / scales)) < -FORCE_TOLERANCE

    def _release(self, state: State, q: np.ndarray, located: bool = False,
                 accepted: bool = False) -> None:
        """
        Pivot the held rows whose force is past its bound, at ``state``.

        When a row's force is past its bound by more than :data:`FORCE_TOLERANCE` of
        its scale, every held row's force is found at once: the box-constrained LCP
        of the held rows (:mod:`.complementarity`), the equality rows eliminated
        (their Schur complement, :meth:`_schur`), warm-started from the forces with
        every row held. A row whose force lands on the end of its box pivots: a
        bound that pushes nothing leaves (and its joint sticks if it has friction,
        or slides away at ``−F`` when even friction cannot hold it: one row
        ``s f ≥ −F``), a sticking joint slips against its friction, a drive
        saturates towards its force. The pivots are taken together, the
        multipliers solved anew, and the check repeats (a pivot's new row, a stick
        after a bound, has its own bound): exact, the LCP's solution being the
        rows' forces to rounding. ``located``: ``state`` is where a row's margin
        was located to reach zero (within FORCE_TOLERANCE of its change over the
        step): that row's box ends at its force there, so it pivots. ``accepted``:
        ``state`` ends a step that stands (:data:`MAX_EVENTS`): its rows carried
        their forces past their bounds over it.

        Counted in ``max_force_excess``: the force past its bound a row carried over
        an accepted (partial) step: at a located pivot, its margin there (within the
        tolerance), at an accepted step, its excess. A force that jumped past its bound
        at an event (an impact's impulse, a pivot, a command) pivots at once and
        carried nothing.
        """
        solver, dyn = self.sim.dynamics.solver, self.sim.dynamics
        for _ in range(2 * len(self.sim.joints) + 1):
            if not self._held():
                return
            kinds, joints, margins, forces, scales = self._margins(
                solver.multipliers(dyn, state), q)
            if not len(margins):
                return
            span = self._span if located and self._span is not None \
                and self._span_keys == list(zip(kinds, joints)) else None
            if span is not None:
                k = int(np.argmin(margins / span))
                due = margins[k] <= FORCE_TOLERANCE * span[k] and (
                    margins[k] < 0.0 or self._falling(margins)[k])
            else:
                k = int(np.argmin(margins / scales))
                due = margins[k] < -FORCE_TOLERANCE * scales[k]
            if not due:
                return
            carried = 0.0
            if accepted:
                carried = -float(margins[k])
            elif span is not None and margins[k] >= -FORCE_TOLERANCE * span[k]:
                carried = max(0.0, -float(margins[k]))
            self.counters['max_force_excess'] = max(self.counters['max_force_excess'],
                                                    carried)
            # A row located where its margin reached zero pivots there; one whose force
            # was already past its bound (a command, an impact) is one of the LCP's rows.
            at_bound = span is not None and margins[k] >= -FORCE_TOLERANCE * span[k]
            pivots = self._pivots(state, kinds, joints, forces, k if at_bound else None)
            if not pivots:   # (the LCP could not be solved: the row past its bound alone)
                pivots = [self._pivot_of(kinds[k], joints[k], forces[k])]
            located = False   # (the rows change: the spans are of the rows before)
            for what, i, direction in pivots:
                self._apply_pivot(what, i, direction, state, q)

    def _boxes(self, kinds: list, joints: list, forces: list,
               located: Optional[int]) -> tuple:
        """
        Return each held row's box ``(lo, hi)`` of forces along its joint.

        A bound on side ``s`` pushes (``s f ≥ 0``), or, on a joint with friction
        ``F``, holds it by friction too (``s f ≥ −F``: it sticks there); a stick
        ``|f| ≤ F``; a drive ``|f| ≤ E``. The ``located`` row's box ends at its force
        on the side its margin reached.
        """
        lim, fr, dr = self.limits, self.friction, self.drives
        n = len(kinds)
        lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
        for r, (kind, i) in enumerate(zip(kinds, joints)):
            rub = 0.0 if fr is None else float(fr.force[i])
            if kind == 0:
                side = lim.active[i]
                if r == located:
                    rub = -float(side * forces[r])   # (the push there, within tolerance)
                if side > 0:
                    lo[r] = -rub
                else:
                    hi[r] = rub
            else:
                bound = float(fr.force[i] if kind == 1 else dr.effort[i])
                lo[r], hi[r] = -bound, bound
                if r == located:
                    if forces[r] > 0.0:
                        hi[r] = forces[r]
                    else:
                        lo[r] = forces[r]
        return lo, hi

    def _pivots(self, state: State, kinds: list, joints: list, forces: list,
                located: Optional[int]) -> list:
        """
        Return the pivots the held rows' LCP asks for: ``[(what, joint, direction)]``.

        ``what``: 'release' (a bound leaves; its joint sticks if it has friction),
        'slide' (a bound leaves and its joint slips away, ``direction`` its side),
        'slip' (a stick slips towards ``direction``), 'saturate' (a drive, towards
        ``direction``). Empty when the LCP cannot be solved (rows made dependent by
        the others) or stopped at its iteration cap: counted, never silent.
        """
        lim, fr = self.limits, self.friction
        names = [self._row_name(kind, i) for kind, i in zip(kinds, joints)]
        f_star = np.array(forces, dtype=float)
        lo, hi = self._boxes(kinds, joints, forces, located)
        sol = self._solved(None, f_star, lo, hi, names, state)
        if sol is None:
            return []
        pivots = []
        for r, (kind, i) in enumerate(zip(kinds, joints)):
            at, f = int(sol.state[r]), float(sol.f[r])
            if kind == 0:
                side = int(lim.active[i])
                rub = 0.0 if fr is None else float(fr.force[i])
                if at == -side:      # the box's end on the bound's side: it lets go
                    if rub > 0.0 and r != located:
                        pivots.append(('slide', i, side))
                    else:
                        pivots.append(('release', i, 0))
                elif rub > 0.0 and side * f < 0.0:
                    pivots.append(('release', i, 0))   # friction holds it, off the bound
            elif at != FREE:
                pivots.append(('slip' if kind == 1 else 'saturate', i, -at if kind == 1 else at))
        return pivots

    def _pivot_of(self, kind: int, i: int, f: float) -> tuple:
        """Return the pivot of one row past its bound (force ``f``): :meth:`_pivots`' form."""
        if kind == 0:
            return ('release', i, 0)
        if kind == 1:
            return ('slip', i, -1 if f > 0.0 else 1)
        return ('saturate', i, 1 if f > 0.0 else -1)

    def _apply_pivot(self, what: str, i: int, direction: int, state: State,
                     q: np.ndarray) -> None:
        """Take one pivot of :meth:`_pivots` at ``state`` (joint coordinates ``q``)."""
        if what in ('release', 'slide'):
            self._unbound(i)
            self.limits.counters.releases += 1
            if self.friction is not None and self.friction.force[i] > 0.0:
                if what == 'slide':
                    self._slip(i, direction)
                else:
                    self._stick(i, state, float(q[i]))
        elif what == 'slip':
            self._slip(i, direction)
        else:
            self._saturate(i, direction, state.time)

    def _solved(self, S: Optional[np.ndarray], f_star: np.ndarray, lo: np.ndarray,
                hi: np.ndarray, names: Optional[list] = None,
                state: Optional[State] = None):
        """
        Return the rows' box LCP ``w = S (f − f*)`` solved from ``f*``, or None, counted.

        ``S`` given, or the Schur complement of rows ``names`` at ``state``
        (:meth:`_schur`). None when it cannot be solved (dependent rows) or stopped at
        its iteration cap: ``lcp_failures`` counts it and the caller's rule without the
        problem applies; else ``lcp_solves`` and ``lcp_residual_max`` count it.
        """
        try:
            if S is None:
                S = self._schur(names, state)
            sol = solve(S, -(S @ f_star), lo, hi, start=f_star)
        except (np.linalg.LinAlgError, ValueError):
            sol = None
        if sol is None or not sol.converged:
            self.counters['lcp_failures'] += 1
            return None
        self.counters['lcp_solves'] += 1
        self.counters['lcp_residual_max'] = max(self.counters['lcp_residual_max'],
                                                sol.residual)
        return sol

    def _row_name(self, kind: int, i: int) -> str:
        """Return the name of joint ``i``'s held row of ``kind`` (:meth:`_margins`)."""
        part = (self.limits, self.friction, self.drives)[kind]
        return part.names[i]

    def _probes(self, names: list, state: State, vel: np.ndarray, om: np.ndarray) -> list:
        """
        Return, per row of ``names``, the velocity projection's change per unit ``r_k``.

        ``Δν_k = −M⁻¹Gᵀ W e_k`` (``W = (G M⁻¹ Gᵀ)⁻¹``, every row held): the projection
        of ``state`` with the row's target rate one lower, less ``(vel, om)``, the
        projection without.
        """
        solver = self.sim.dynamics.solver
        out = []
        for name in names:
            table, at = solver.drive_rate_slot(name)
            rate = table[at]
            table[at] = rate - 1.0      # r_k one larger
            try:
                vk, wk = solver.project_velocities(state)
            finally:
                table[at] = rate
            out.append((vk - vel, wk - om))
        return out

    def _schur(self, names: list, state: State) -> np.ndarray:
        """
        Return the Schur complement ``S`` of rows ``names`` (every other row held).

        The inverse of the rows' block of ``W = (G M⁻¹ Gᵀ)⁻¹``, which is
        ``W_kl = Δν_kᵀ M Δν_l`` (:meth:`_probes`: ``Δν_kᵀ M Δν_l = e_kᵀ W G M⁻¹ Gᵀ W
        e_l``): one projection per row, through the solve's own factorizations. ``S``
        maps the rows' forces to their accelerations with the equality rows held.
        """
        vel, om = self.sim.dynamics.solver.project_velocities(state)
        return self._compliance(names, state, vel, om)[0]

    def _compliance(self, names: list, state: State, vel: np.ndarray, om: np.ndarray
                    ) -> tuple:
        """
        Return ``(S, dv, dw, dot)`` for rows ``names`` from their probes (:meth:`_probes`).

        ``dv``, ``dw`` (m, 3n) the probes' changes flattened; ``dot(a, b)`` the mass-weighted
        product of a probe block with a velocity change; ``S`` the Schur complement
        (:meth:`_schur`). Raises LinAlgError when the rows' block is singular.
        """
        bodies = self.sim.bodies
        probes = self._probes(names, state, vel, om)
        dv = np.array([p[0] for p in probes]).reshape(len(names), -1)
        dw = np.array([p[1] for p in probes]).reshape(len(names), -1)
        mass = np.repeat(bodies.mass, 3)
        moments = np.asarray(bodies.moments).reshape(-1)

        def dot(a_v: np.ndarray, a_w: np.ndarray, b_v: np.ndarray, b_w: np.ndarray
                ) -> np.ndarray:
            return (a_v * mass) @ b_v + (a_w * moments) @ b_w

        W = dot(dv, dw, dv.T, dw.T)
        S = np.linalg.inv(0.5 * (W + W.T))
        return 0.5 * (S + S.T), dv, dw, dot

    def coordinates(self, state: State, previous: np.ndarray) -> tuple:
        """Joint coordinates, rates and rates over their limits at ``state``, near ``previous``."""
        sim = self.sim
        sim.bodies.outputs(state)
        return sim.joints.coordinates(sim.bodies.outputs_cache.out, previous)

    def _event(self, q: np.ndarray, rates: np.ndarray, state: State, which: tuple) -> tuple:
        """
        Return the event function in its tolerances' units, and whether it is an event.

        ``which``: the joints crossing a bound, stopping, drives reaching their law,
        whether a held row's force passes its bound, and the joints back from a start
        beyond their bounds. The smallest of a crossing's gap or a return's distance
        still beyond over :data:`LOCATION_TOLERANCE`, a stop's ``d q̇`` and a saturated drive's
        ``−σ r`` over :data:`RATE_TOLERANCE`, and the smallest force margin over
        :data:`FORCE_TOLERANCE` times each row's force scale (a read solve at ``state``);
        a gap within the tolerance is an event only when its joint moves into the bound.
        """
        crossed, stopped, reached, releasing, returned = which
        time = state.time
        value, real = np.inf, True
        if len(crossed):
            gap, approaching = self.limits.event(q, rates, crossed)
            value, real = gap / self.location, approaching
        if len(returned):
            past = float(np.min(self.limits.past(q, returned))) / self.location
            if past < value:
                value, real = past, True
        if len(stopped):
            rate = self.friction.event(rates, stopped) / self.rate
            if rate < value:
                value, real = rate, True
        if len(reached):
            law = self.drives.event(self._laws(q, rates, time, reached), reached)
            if law / self.rate < value:
                value, real = law / self.rate, True
        if releasing:
            lam = self.sim.dynamics.solver.multipliers(self.sim.dynamics, state)
            kinds, joints, margins = self._margins(lam, q)[:3]
            keys = list(zip(kinds, joints))
            if self._span is None or self._span_keys != keys:
                # The step's start: each row's margin change over the step scales its
                # event function (a time fraction of the step, located to
                # FORCE_TOLERANCE of it, however small the forces).
                aligned = len(margins) == len(self._end_margins)
                span = np.abs(margins - self._end_margins) if aligned else np.abs(margins)
                self._span, self._span_keys = np.maximum(span, 1e-300), keys
            if len(margins):
                k = int(np.argmin(margins / self._span))
                margin = float(margins[k] / self._span[k]) / FORCE_TOLERANCE
                if margin < value:
                    # An event where the margin is past its bound already (a force that
                    # jumped there: a command, an impact) or falls (towards the end's).
                    value, real = margin, bool(margins[k] < 0.0 or self._falling(margins)[k])
        return value, real

    def _falling(self, margins: np.ndarray) -> np.ndarray:
        """Tell, per held row, whether its margin falls from ``margins`` to the step's end's."""
        if len(margins) != len(self._end_margins):
            return np.ones(len(margins), dtype=bool)
        return self._end_margins < margins

    def _locate(self, state: State, previous: np.ndarray, h: float, end: State,
                q_end: np.ndarray, r_end: np.ndarray, which: tuple) -> tuple:
        """
        Find the first event after ``state``: regula falsi (Illinois) on partial steps.

        The event function (:meth:`_event`) is above its tolerance before the event
        and not at ``h`` (the step that found it). Returns the state there, its
        coordinates and rates; the event function is within its tolerance there,
        or the state is the earlier end of a bracket narrowed to rounding.
        """
        sim = self.sim
        q0, r0, _ = self.coordinates(state, previous)
        a, at = 0.0, (state, q0, r0)
        ga, real = self._event(q0, r0, state, which)
        if ga <= 1.0:
            if real:
                return at             # an event right at the start
            # A joint on its bound that leaves it (or rests there) crosses later, if at
            # all: the event sought is the first one after the start.
            ga = 1.0
        b, gb = h, self._event(q_end, r_end, end, which)[0]
        if gb >= -1.0:
            return end, q_end, r_end   # the event is at the step's end, to the tolerance
        stuck = 0
        for _ in range(MAX_LOCATION_ITERATIONS):
            s = (a * gb - b * ga) / (gb - ga)
            if not a < s < b:
                s = 0.5 * (a + b)
            trial = sim._advance(state, s, state.time + s)
            q, r, _ = self.coordinates(trial, previous)
            g, real = self._event(q, r, trial, which)
            if abs(g) <= 1.0 and real:
                return trial, q, r
            if g > -1.0:   # before the event (or on a bound, leaving it)
                a, ga, at = s, max(g, 1.0), (trial, q, r)
                if stuck == 1:
                    gb *= 0.5
                stuck = 1
            else:
                b, gb = s, g
                if stuck == -1:
                    ga *= 0.5
                stuck = -1
            if b - a <= 4.0 * EPS * max(h, abs(state.time)):
                break
        return at

    def _resolve(self, state: State, q: np.ndarray, rates: np.ndarray, which: tuple,
                 events: int) -> State:
        """
        Resolve the events at ``state``: stops stick, impacts get rows and restitution.

        Joints whose slip stopped here stick (a row each); bounds that joints reach
        here, moving in, become active, and one velocity projection of the solve,
        with each bound's row moving at ``−e`` times its approach rate, is Newton's
        law of restitution for all at once (rows of ``e > 0`` then leave: they
        separate, and a joint with friction slips away).
        """
        state = self._resolve_motion(state, q, rates, which[:3], events)
        if which[3]:
            self._release(state, q, located=True, accepted=events >= MAX_EVENTS)
        if len(which[4]):
            # Joints back from a start beyond their bounds: their rows' forces count from
            # here, and a bound that pulls is released at once (it carried nothing).
            self.limits.beyond[which[4]] = False
            self._release(state, q)
        self._span = None
        return state

    def _resolve_motion(self, state: State, q: np.ndarray, rates: np.ndarray, which: tuple,
                        events: int) -> State:
        """Resolve the crossings, stops and drives' engagements at ``state`` (:meth:`_resolve`)."""
        sim, lim, fr = self.sim, self.limits, self.friction
        crossed, stopped, reached = which
        if len(crossed):
            self._left = max(self._left, self.location)
        if len(stopped) or len(reached):
            self._left = max(self._left, self.rate)
        project = False
        engaged = []
        if len(reached):
            laws = self._laws(q, rates, state.time, reached)
            for i, r in zip(reached, laws):
                if abs(r) <= self.rate or self.drives.mode[i] * r >= 0.0:
                    self._engage(int(i), state)
                    engaged.append(int(i))
                    project = True
        if len(stopped):
            for i in stopped:
                if abs(rates[i]) <= self.rate or fr.mode[i] * rates[i] <= 0.0:
                    self._stick(int(i), state, float(q[i]))
                    fr.counters['sticks'] += 1
                    project = True
        hits = []
        if len(crossed):
            hits = lim.touching(q, rates)
            if not hits:
                gap, side = lim.gaps(q)
                hits = [(int(i), int(sd), 0.0) for i, g, sd in zip(lim.joints, gap, side)
                        if i in crossed and g <= self.location]
        solver = sim.dynamics.solver
        if not hits:
            if project:   # the stops: rates to zero, with every other joint kept
                vel, om = solver.project_velocities(state)
                state = State(state.time, state.pos_com_world, state.quat_principal_world,
                              vel, om)
            if engaged:   # a row that needs more than E at once saturates again
                self._release(state, q)
            return state
        names, bounds, rebound, bouncing = [], [], [], []
        for i, side, approach in hits:
            e = lim.restitution[i] if events < MAX_BOUNCES else 0.0
            self._bound(i, side, state)
            names.append(lim.names[i])
            bounds.append(lim.bound(i, side))
            rebound.append(-side * e * approach)   # approach < 0: away from the bound
            if e * approach != 0.0:
                bouncing.append((i, side))
            lim.impacts.append(Impact(state.time, sim.joints.names[i], side, approach,
                                      -e * approach))
        lim.counters.impacts += len(hits)
        solver.set_drive_targets(names, np.array(bounds), state.time, np.array(rebound))
        vel, om, pivots = self._impact(state)
        state = State(state.time, state.pos_com_world, state.quat_principal_world, vel, om)
        for i, side in bouncing:
            self._unbound(i)
            if fr is not None and fr.force[i] > 0.0:
                self._slip(i, side)   # moving away from the bound
        gone = {i for i, _ in bouncing}
        for what, i, direction in pivots:
            if what == 'slide':
                if i in gone:
                    continue
                gone.add(i)
            self._apply_pivot(what, i, direction, state, q)
        held = [(n, b) for n, b, (i, _, _) in zip(names, bounds, hits) if i not in gone]
        if held:
            solver.set_drive_targets([n for n, _ in held], np.array([b for _, b in held]),
                                     state.time)
        if engaged:   # a row that needs more than E at once saturates again
            self._release(state, q)
        return state

    def _grazing(self, ends: list, q: np.ndarray, rates: np.ndarray, after: State,
                 S: np.ndarray) -> list:
        """
        Return the rows of ``ends`` (``(row, joint, side)``: bounds with no impulse) to hold.

        A bound leaves at an impact only if its joint, moving away at ``v = s q̇``,
        leaves for good: not beyond the bound by more than the location's tolerance
        (it would cross again at once), faster than the rate tolerance and than the
        tolerance's width per step, and not back within the step under the force
        pressing it there (with every row held after the impact, ``f``; free, it
        accelerates back at ``a = S_rr s f``, back after ``2 v / a``). A bound held
        so takes a pulling impulse of at most what its pressing force gives over a
        step (as a bounded row's ``E dt``); the force-level check at the step's end
        releases it if it then pulls. Without this, coupled inelastic impacts chatter
        (each pulls another bound off, which comes straight back).
        """
        sim, lim = self.sim, self.limits
        slow = max(self.rate, self.location / sim.dt)
        lam, held = None, []
        for r, i, side in ends:
            v = side * rates[i]
            if v <= slow or side * (q[i] - lim.bound(i, side)) < -self.location:
                held.append(r)
                continue
            if lam is None:
                lam = sim.dynamics.solver.multipliers(sim.dynamics, after)
            a = S[r, r] * side * -float(lam[lim.rows[i]])
            if a > 0.0 and 2.0 * v < a * sim.dt:
                held.append(r)
        return held

    def _impact_rows(self) -> list:
        """Return the held rows with bounds as ``[(kind, joint)]`` (:meth:`_margins`' kinds)."""
        rows = []
        for kind, part in enumerate((self.limits, self.friction, self.drives)):
            if part is not None:
                rows += [(kind, int(i)) for i in part.rows]
        return rows

    def _impact(self, state: State) -> tuple:
        """
        Return the velocities after the impacts at ``state``, and the pivots they make.

        Newton's law for every row at once, as a box LCP on the rows' impulses ``p``
        (:mod:`.complementarity`; ``S`` the rows' Schur complement, :meth:`_schur`,
        and ``w = S (p − p*)`` each row's rate after the impact less its target: the
        rebound ``−e`` times the approach for a bound hit now, ``−ωΦ`` for one resting
        on its bound): a bound's impulse only pushes (``s p ≥ 0``), complementary to its
        joint leaving faster than its target; a sticking joint's friction and an
        effort-limited drive, forces of bounded size, take at most that force times the
        step (``|p| ≤ F dt``, ``E dt``: the bound a command's impulse has, see
        :meth:`commanded`), beyond which the joint slips, the drive saturates. ``p*``,
        the impulses with every row held, is what one projection gives: where it is
        within every box (one bound hit, resting rows that push) that projection is
        all. Returns ``(vel, om, pivots)`` in :meth:`_pivots`' form: ``'slide'`` for
        a bound that leaves (no impulse, its joint moving away fast enough to leave the
        location's tolerance within a step; a bound with no impulse whose joint would
        not, a graze, is held and the problem solved again with it held), ``'slip'``
        and ``'saturate'`` for the rows at their impulse bounds.
        """
        sim = self.sim
        vel, om = sim.dynamics.solver.project_velocities(state)
        rows = self._impact_rows()
        if len(rows) <= 1:
            return vel, om, []
        names = [self._row_name(kind, i) for kind, i in rows]
        try:
            S, dv, dw, dot = self._compliance(names, state, vel, om)
        except np.linalg.LinAlgError:
            self.counters['lcp_failures'] += 1
            return vel, om, []
        # Every row held: μ_k = Δν_kᵀ M Δν (:meth:`_probe_impulses`), the joint's −μ_k.
        p_star = -dot(dv, dw, (vel - state.vel_com_world).reshape(-1),
                      (om - state.ang_vel_principal).reshape(-1))
        lim, fr, dr = self.limits, self.friction, self.drives
        lo, hi = np.zeros(len(rows)), np.zeros(len(rows))
        for r, (kind, i) in enumerate(rows):
            if kind == 0:
                if lim.beyond[i]:     # (held whatever its sign until it is back)
                    lo[r], hi[r] = -np.inf, np.inf
                elif lim.active[i] > 0:
                    hi[r] = np.inf
                else:
                    lo[r] = -np.inf
            else:
                bound = float(fr.force[i] if kind == 1 else dr.effort[i]) * sim.dt
                lo[r], hi[r] = -bound, bound
        if np.all(np.minimum(p_star - lo, hi - p_star) >= 0.0):
            return vel, om, []      # every row's impulse within its box: the projection
        held = (vel, om)
        for _ in range(len(rows)):
            sol = self._solved(S, p_star, lo, hi)
            if sol is None:
                return held[0], held[1], []
            # Δν_k moves row k's rate by −1 with the others held: the rates ``w`` off
            # their targets are ``−Σ w_k Δν_k`` away from the projection's.
            vel = held[0] - (sol.w @ dv).reshape(held[0].shape)
            om = held[1] - (sol.w @ dw).reshape(held[1].shape)
            after = State(state.time, state.pos_com_world, state.quat_principal_world, vel, om)
            q, rates, _ = self.coordinates(after, sim.joints.positions)
            ends = [(r, i, int(lim.active[i])) for r, (kind, i) in enumerate(rows)
                    if kind == 0 and sol.state[r] != FREE]
            grazing = self._grazing(ends, q, rates, after, S)
            if not grazing:
                pivots = [('slide', i, side) for _, i, side in ends]
                for r, (kind, i) in enumerate(rows):
                    at = int(sol.state[r])
                    if kind and at != FREE:
                        pivots.append(('slip', i, -at) if kind == 1 else ('saturate', i, at))
                return vel, om, pivots
            for r in grazing:
                lo[r], hi[r] = -np.inf, np.inf
        return held[0], held[1], []

    # -- the rows ---------------------------------------------------------------------------

    def _add_row(self, name: str, i: int, target: float, state: State) -> None:
        """Add the ``drive`` row ``name`` holding joint ``i`` at ``target``."""
        sim = self.sim
        js = sim.joints
        j = js.joints[i]
        sim.dynamics.solver.constraints.add(
            Constraint(name, JointType.DRIVE, j.child_body, j.parent_body,
                       drive=js.drive_geometry(i, target)), state)

    def rows_changed(self) -> None:
        """Record each present row's index (rows shift as constraints come and go)."""
        sim = self.sim
        rows_of = sim.dynamics.solver.constraints.rows_of
        if self.limits is not None:
            lim = self.limits
            lim.rows = {int(i): int(rows_of(lim.names[i])[0])
                        for i in np.flatnonzero(lim.active)}
        if self.friction is not None:
            fr = self.friction
            fr.rows = {int(i): int(rows_of(fr.names[i])[0])
                       for i in np.flatnonzero(fr.mode == STICK)}
        if self.drives is not None:
            dr = self.drives
            dr.rows = {int(i): int(rows_of(dr.names[i])[0])
                       for i in dr.joints if dr.mode[i] == ENGAGED}
        sim.dynamics.changed()

    def _bound(self, i: int, side: int, state: State) -> None:
        """Make joint ``i``'s bound ``side`` (+1 lower, −1 upper) active (friction off)."""
        lim = self.limits
        self._friction_off(i)
        self._add_row(lim.names[i], i, lim.bound(i, side), state)
        lim.active[i] = side
        lim.counters.activations += 1
        self.rows_changed()

    def _unbound(self, i: int) -> None:
        """Drop joint ``i``'s active bound."""
        lim = self.limits
        self.sim.dynamics.solver.constraints.remove(lim.names[i])
        lim.active[i] = 0
        lim.beyond[i] = False
        self.rows_changed()

    def _stick(self, i: int, state: State, q: float) -> None:
        """Hold joint ``i`` still at ``q`` (its friction sticks)."""
        fr = self.friction
        self._friction_off(i)
        self._add_row(fr.names[i], i, q, state)
        fr.mode[i] = STICK
        self.rows_changed()

    def _slip(self, i: int, direction: int) -> None:
        """Let joint ``i`` slip towards ``direction`` (±1): friction ``−F direction``."""
        fr = self.friction
        self._friction_off(i)
        fr.mode[i] = direction
        fr.moving[i] = False
        fr.counters['slips'] += 1
        self._friction_wrench(i, -fr.force[i] * direction)

    def _friction_off(self, i: int) -> None:
        """Remove joint ``i``'s sticking row or slipping force, if any."""
        fr = self.friction
        if fr is None or fr.mode[i] == OFF:
            return
        if fr.mode[i] == STICK:
            self.sim.dynamics.solver.constraints.remove(fr.names[i])
            fr.mode[i] = OFF
            self.rows_changed()
        else:
            fr.mode[i] = OFF
            self._friction_wrench(i, 0.0)

    def _saturate(self, i: int, direction: int, time: float) -> None:
        """
        Saturate joint ``i``'s exact drive towards ``direction`` (±1): effort ``±E``, no row.

        An engaged drive's motion ``(c₀, ċ, t₀)`` is kept while its row is away.
        """
        dr = self.drives
        if dr.mode[i] == ENGAGED:
            solver = self.sim.dynamics.solver
            name = dr.names[i]
            target = float(solver.drive_targets([name], time)[0])
            rate = float(solver.constraints.drive_rates([name])[0])
            dr.motion[i] = (target, rate, float(time))
            dr.specs[i] = solver.constraints.remove(name)
        dr.mode[i] = direction
        dr.away[i] = False
        dr.counters['saturations'] += 1
        self._drive_wrench(i, direction * dr.effort[i])
        self.rows_changed()

    def _engage(self, i: int, state: State) -> None:
        """Engage joint ``i``'s saturated drive: its row back, on its target's motion."""
        dr = self.drives
        target, rate = dr.target(i, state.time)
        self._add_row(dr.names[i], i, target, state)
        self.sim.dynamics.solver.set_drive_targets([dr.names[i]], np.array([target]),
                                                   state.time, np.array([rate]))
        del dr.motion[i], dr.specs[i]
        dr.mode[i] = ENGAGED
        dr.counters['engagements'] += 1
        self._drive_wrench(i, 0.0)
        self.rows_changed()

    def engage_all(self) -> None:
        """Engage every saturated drive (a state set by hand: its drives hold it)."""
        dr = self.drives
        if dr is not None:
            for i in dr.saturated():
                self._engage(int(i), self.sim.state)

    def set_targets(self, idx: np.ndarray, targets: np.ndarray, rates: np.ndarray) -> np.ndarray:
        """
        Keep new targets of saturated drives ``idx`` (at the simulation's time).

        Returns the mask of ``idx`` whose drives are engaged (the caller sets those in
        the solve).
        """
        dr, now = self.drives, self.sim.time
        engaged = np.ones(len(idx), dtype=bool)
        if dr is None:
            return engaged
        for k, i in enumerate(idx):
            if dr.mode[i] != ENGAGED:
                dr.motion[i] = (float(targets[k]), float(rates[k]), now)
                engaged[k] = False
        return engaged

    def drive_target(self, i: int, time: float) -> Optional[float]:
        """Return the target of joint ``i``'s saturated drive at ``time`` (None: engaged)."""
        dr = self.drives
        if dr is None or dr.mode[i] == ENGAGED:
            return None
        return dr.target(i, time)[0]

    def commanded(self, idx: np.ndarray) -> None:
        """
        Decide, after new targets, which effort-limited drives of ``idx`` saturate.

        The velocity projection closes a new target's law ``r = Φ̇ + ωΦ`` at the next
        step with the impulse ``μ = W r`` (``W``: the inverse of the drives' rows'
        ``G M⁻¹ Gᵀ`` block, the other rows held): a drive whose impulse exceeds what
        its effort gives over a step, ``E dt``, saturates now towards ``−sign μ``; a
        saturated one turns towards its new target (or engages, if its law holds).
        ``W r`` comes from the projection of the state (:meth:`_impulses`: each child
        side's momentum change about its joint's axis, or ``μ_j = Δν_jᵀ M Δν`` with
        ``Δν_j`` the change per unit ``r_j``, one more projection each). When one passes
        its bound, which drives saturate is the box LCP of their impulses
        (:meth:`_saturations`): a saturated drive's missing impulse falls on the others.
        """
        dr, sim = self.drives, self.sim
        if dr is None:
            return
        mine = [int(i) for i in idx if i in set(dr.joints.tolist())]
        if not mine:
            return
        q, rates, _ = self.coordinates(sim.state, sim.joints.positions)
        now = sim.time
        sat = [i for i in mine if dr.mode[i] != ENGAGED]
        if sat:
            laws = self._laws(q, rates, now, np.array(sat))
            for i, r in zip(sat, laws):
                if abs(r) <= self.rate:
                    self._engage(i, sim.state)
                    self._release(sim.state, q)
                elif dr.mode[i] != (-1 if r > 0.0 else 1):
                    self._saturate(i, -1 if r > 0.0 else 1, now)
        eng = [i for i in mine if dr.mode[i] == ENGAGED and i not in sat]
        if not eng:
            self._note(q, rates, now)
            return
        impulse = self._impulses(eng, sim.state)
        bound = np.array([dr.effort[i] for i in eng]) * sim.dt
        if np.any(np.abs(impulse) > bound * (1.0 + 64.0 * EPS)):
            for i, direction in self._saturations(eng, -impulse, bound):
                self._saturate(i, direction, now)
        self._note(q, rates, now)   # a drive saturated behind its law lags it

    def _saturations(self, idx: list, p_star: np.ndarray, bound: np.ndarray) -> list:
        """
        Return the drives of ``idx`` that saturate at a command: ``[(joint, direction)]``.

        Their impulses ``p`` (along their joints; ``p*`` with every drive engaged) solve
        the box LCP ``|p| ≤ E dt`` with ``S`` the drives' Schur complement
        (:meth:`_schur`): a drive at its bound saturates towards it. (Saturating each
        drive whose own ``p*`` exceeds its bound instead would ignore that a saturated
        drive's missing impulse changes the others'.) If the problem cannot be solved,
        those past their bounds saturate (counted in ``lcp_failures``).
        """
        sol = self._solved(None, p_star, -bound, bound, [self.drives.names[i] for i in idx],
                           self.sim.state)
        if sol is None:
            past = np.abs(p_star) > bound * (1.0 + 64.0 * EPS)
            return [(i, 1 if p > 0.0 else -1) for i, p, out in zip(idx, p_star, past) if out]
        return [(i, int(at)) for i, at in zip(idx, sol.state) if at != FREE]

    def _impulses(self, idx: list, state: State) -> np.ndarray:
        """
        Return the velocity projection's impulse ``μ`` on the drives of joints ``idx``.

        From one projection of the state when each drive's joint is the only tie of its
        child's side to the rest (a tree: :meth:`_subtree`): the momentum the projection
        gives that side about the joint's axis is the drive's impulse ``−μ`` (the joint's
        other rows apply none about it). Otherwise one more projection per drive.
        """
        solver = self.sim.dynamics.solver
        vel, om = solver.project_velocities(state)
        dv, dw = vel - state.vel_com_world, om - state.ang_vel_principal
        sides = [self._subtree(i) for i in idx]
        if all(side is not None for side in sides):
            return self._tree_impulses(idx, sides, state, dv, dw)
        return self._probe_impulses(idx, state, vel, om, dv, dw)

    def _tree_impulses(self, idx: list, sides: list, state: State, dv: np.ndarray,
                       dw: np.ndarray) -> np.ndarray:
        """``μ_j = −k_j · ΔL_j``: each child side's axial momentum change (:meth:`_impulses`)."""
        sim = self.sim
        js, bodies = sim.joints, sim.bodies
        linear = bodies.mass[:, None] * dv
        R = quat_to_matrix(state.quat_principal_world)
        # Each body's angular momentum change about the world origin.
        angular = np.einsum('nij,nj->ni', R, bodies.moments * dw) \
            + cross(state.pos_com_world, linear)
        bodies.outputs(state)
        out_rows = bodies.outputs_cache.out
        children = js.child[idx]
        axes = np.einsum('kij,kj->ki', quat_to_matrix(
            out_rows[children, O_QUAT_BODY_WORLD:O_QUAT_BODY_WORLD + 4]), js.axis[idx])
        anchors = out_rows[children, O_ORIGIN_WORLD:O_ORIGIN_WORLD + 3]
        out = np.empty(len(idx))
        for k, (i, side) in enumerate(zip(idx, sides)):
            force = np.sum(linear[side], axis=0)
            if js.rotary[i]:   # about the joint's point: about the origin less anchor × P
                moment = np.sum(angular[side], axis=0) - cross(anchors[k], force)
                out[k] = -float(axes[k] @ moment)
            else:
                out[k] = -float(axes[k] @ force)
        return out

    def _probe_impulses(self, idx: list, state: State, vel: np.ndarray, om: np.ndarray,
                        dv: np.ndarray, dw: np.ndarray) -> np.ndarray:
        """``μ`` by one projection per drive, ``r_k`` one larger (:meth:`_impulses`)."""
        bodies = self.sim.bodies
        probes = self._probes([self.drives.names[i] for i in idx], state, vel, om)
        # Δν = −M⁻¹Gᵀ W r and Δν_k = −M⁻¹Gᵀ W e_k, so Δν_kᵀ M Δν = e_kᵀ W G M⁻¹ Gᵀ W r = μ_k.
        return np.array([float(np.sum(bodies.mass[:, None] * vk * dv)
                               + np.sum(bodies.moments * wk * dw)) for vk, wk in probes])

    def _subtree(self, i: int) -> Optional[np.ndarray]:
        """
        Return the bodies on joint ``i``'s child side, or None if another row ties them on.

        The bodies the child reaches through every constraint but the joint's own (its
        hinge or slider and its drive): None when they reach the parent or the world
        (a loop, a mimic across, a user's constraint), where the side's momentum would
        take other rows' impulses too.
        """
        sim = self.sim
        cs = sim.dynamics.solver.constraints
        key = (cs, cs.version, i)
        cached = self._sides.get(i)
        if cached is not None and cached[0] is cs and cached[1] == key[1]:
            return cached[2]
        js, bodies = sim.joints, sim.bodies
        own = {js.names[i], self.drives.names[i]}
        n = len(bodies)
        links: dict = {}
        for name in cs.names:
            if name in own:
                continue
            spec = cs.spec(name)
            ends = [spec.body_a, spec.body_b]
            if spec.coupling is not None:
                ends += [spec.coupling.body_a, spec.coupling.body_b]
            nodes = [n if e is None else bodies.lookup(e) for e in ends]
            for a in nodes:
                links.setdefault(a, set()).update(nodes)
        child, parent = int(js.child[i]), int(js.parent[i])
        seen, todo = {child}, [child]
        while todo:
            for b in links.get(todo.pop(), ()):
                if b not in seen:
                    seen.add(b)
                    todo.append(b)
        side = None if parent in seen or n in seen else np.array(sorted(seen), dtype=int)
        self._sides[i] = (cs, key[1], side)
        return side

    def _drive_wrench(self, i: int, tau: float) -> None:
        """Apply (``tau = 0``: remove) joint ``i``'s saturated drive effort (held wrenches)."""
        for wrench in self.sim.joints.effort_pair(i, tau, 'drive'):
            self.sim.apply_wrench(**wrench)

    def _friction_wrench(self, i: int, tau: float) -> None:
        """Apply (``tau = 0``: remove) joint ``i``'s friction as a pair of held wrenches."""
        for wrench in self.sim.joints.effort_pair(i, tau, 'friction'):
            self.sim.apply_wrench(**wrench)

    # -- between steps ----------------------------------------------------------------------

    def from_state(self, only: Optional[np.ndarray] = None) -> None:
        """
        Rebuild the rows at the simulation's current state (after a reset, a state set).

        Every bound the joints exceed becomes active (it then converges back as a
        violated constraint does, and a step releases it if it pulls); a joint that
        only touches its bound gets its row when a step moves it into the bound.
        A joint with friction sticks where it is if it is at rest, else slips.
        ``only``: these joints' rows (indices; a robot spawned), the others' as they are.
        """
        sim, lim, fr, dr = self.sim, self.limits, self.friction, self.drives
        mine = np.ones(len(sim.joints), dtype=bool)
        if only is not None:
            mine[:] = False
            mine[np.asarray(only, dtype=int)] = True
        if dr is not None:
            for i in dr.saturated():
                if mine[i]:
                    self._engage(int(i), sim.state)
        self.rows_changed()   # (the drives' rows: a reset added them anew)
        if lim is not None:
            for i in np.flatnonzero(lim.active):
                if mine[i]:
                    self._unbound(int(i))
        if fr is not None:
            for i in fr.joints:
                if mine[i]:
                    self._friction_off(int(i))
        q, rates, _ = sim.joints.coordinates(sim._outputs_now(), sim.joints.positions)
        beyond = np.zeros(len(sim.joints), dtype=bool)
        if lim is not None:
            gap, side = lim.gaps(q)
            out = (gap < -self.location) & mine[lim.joints]
            for i, sd in zip(lim.joints[out], side[out]):
                self._bound(int(i), int(sd), sim.state)
            beyond[lim.joints[out]] = True
            lim.beyond[mine] = beyond[mine]
        sticks = False
        if fr is not None:
            for i in fr.joints:
                if beyond[i] or not mine[i]:
                    continue
                if abs(rates[i]) <= self.rate:
                    self._stick(int(i), sim.state, float(q[i]))
                    sticks = True
                else:
                    self._slip(int(i), 1 if rates[i] > 0.0 else -1)
                    fr.moving[i] = True
        # (``only``: a spawned robot's joints, whose rows its reset had at this state and
        # reconciled its velocities with; the others' velocities stay bit for bit)
        if (beyond.any() or sticks) and only is None:
            sim._reconcile_velocities()

    def carry(self, old: 'JointEvents', pairs: list) -> None:
        """
        Take the rows and modes of ``old`` (a simulation rebuilt around a spawn or a removal).

        ``pairs``: ``[(joint here, joint in old)]`` of the joints both have. Each keeps
        what it was doing: a bound held, a stick at its point, a slip, a saturated
        drive's effort and motion; the others' (a spawned robot's) come from the state
        (:meth:`from_state`). The counters go on. The simulation's state, joint
        positions and drive targets are carried first.
        """
        sim, lim, fr, dr = self.sim, self.limits, self.friction, self.drives
        state, solver = sim.state, old.sim.dynamics.solver
        # First the rows a reset gave these joints go (a stick would stop a slipping
        # joint in the projection below) and the saturated drives let go; then the
        # spawned joints' rows from the state; then these joints' rows as they were.
        for i, k in pairs:
            if dr is not None and dr.mode[i] != ENGAGED:
                self._engage(i, state)
            if lim is not None and lim.active[i]:
                self._unbound(i)
            if fr is not None:
                self._friction_off(i)
            if dr is not None and old.drives is not None and old.drives.mode[k] != ENGAGED:
                self._saturate(i, int(old.drives.mode[k]), state.time)
                dr.motion[i] = old.drives.motion[k]
                dr.away[i] = old.drives.away[k]
        here = np.array([i for i, _ in pairs], dtype=int)
        self.from_state(np.setdiff1d(np.arange(len(sim.joints)), here))
        state = sim.state
        for i, k in pairs:
            if lim is not None and old.limits is not None and old.limits.active[k]:
                self._bound(i, int(old.limits.active[k]), state)
                lim.beyond[i] = old.limits.beyond[k]
            if fr is not None and old.friction is not None and old.friction.mode[k] != OFF:
                if old.friction.mode[k] == STICK:
                    q = solver.drive_targets([old.friction.names[k]], state.time)[0]
                    self._stick(i, state, float(q))
                else:
                    self._slip(i, int(old.friction.mode[k]))
                fr.moving[i] = old.friction.moving[k]
        for part, was in ((lim, old.limits), (fr, old.friction), (dr, old.drives)):
            if part is not None and was is not None:
                part.counters = copy.deepcopy(was.counters)
        self.counters = dict(old.counters)
        self.rows_changed()

    def restore_friction(self) -> None:
        """Apply the slipping joints' friction again (after the wrenches were cleared)."""
        fr, dr = self.friction, self.drives
        if fr is not None:
            for i in fr.slipping():
                self._friction_wrench(int(i), -fr.force[i] * fr.mode[i])
        if dr is not None:
            for i in dr.saturated():
                self._drive_wrench(int(i), dr.mode[i] * dr.effort[i])

    def saturated_reactions(self, out: np.ndarray) -> dict:
        """
        Return the saturated drives' reactions, ``{name: {body: fields}}``: their efforts.

        ``out``: the bodies' outputs now (:mod:`.kernels.layout`'s ``O_`` columns). A rotary
        drive's effort ``σE`` is a torque about the axis on the child and its opposite
        on the parent; a prismatic one's a force along the axis at the child's origin
        (the anchor) and its opposite at the parent's joint point.
        """
        sim, dr = self.sim, self.drives
        js, bodies, com = sim.joints, sim.bodies, sim.state.pos_com_world
        result = {}
        for i in dr.saturated():
            tau = dr.mode[i] * dr.effort[i]
            j = js.joints[i]
            c = bodies.lookup(j.child_body)
            R_c = quat_to_matrix(out[c, O_QUAT_BODY_WORLD:O_QUAT_BODY_WORLD + 4])
            anchor = out[c, O_ORIGIN_WORLD:O_ORIGIN_WORLD + 3].copy()
            axis = R_c @ js.axis[i]
            per_body = {}
            ends = [(j.child_body, 1.0, anchor)]
            if j.parent_body is not None:
                p = bodies.lookup(j.parent_body)
                point = out[p, O_ORIGIN_WORLD:O_ORIGIN_WORLD + 3] + quat_to_matrix(
                    out[p, O_QUAT_BODY_WORLD:O_QUAT_BODY_WORLD + 4]) @ js.p_jp[i]
                ends.append((j.parent_body, -1.0, point))
            for body, sign, point in ends:
                b = bodies.lookup(body)
                if js.rotary[i]:
                    force, torque = np.zeros(3), sign * tau * axis
                    about_anchor = torque
                else:
                    force = sign * tau * axis
                    torque = cross(point - com[b], force)
                    about_anchor = cross(point - anchor, force)
                per_body[body] = {'force_world': force, 'torque_com_world': torque,
                                  'torque_anchor_world': about_anchor, 'anchor_world': anchor}
            result[dr.names[i]] = per_body
        return result

    def merge_reactions(self, fields: dict, com: np.ndarray, lookup: Any) -> None:
        """Add each present row's reaction into its joint's (about the joint's anchor)."""
        names = self.sim.joints.names
        for row, i in self.held().items():
            extra = fields.pop(row, {})
            own = fields.get(names[i])
            if own is None:
                continue
            for body, f in extra.items():
                mine = own.get(body)
                if mine is None:
                    continue
                force = mine['force_world'] + f['force_world']
                torque = mine['torque_com_world'] + f['torque_com_world']
                lever = mine['anchor_world'] - com[lookup(body)]
                own[body] = {'force_world': force, 'torque_com_world': torque,
                             'torque_anchor_world': torque - cross(lever, force),
                             'anchor_world': mine['anchor_world']}
