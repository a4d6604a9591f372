"""
Contact: non-penetration and Coulomb friction as multipliers held over a step; impacts located.

The shapes' contacts (:mod:`.shapes`: points, normals from shape ``b`` to shape
``a``, depths) become rows at the state a step starts from. Each contact touching
there (its gap within :data:`LOCATION_TOLERANCE`) is three rows on the velocity of
its point on ``a`` relative to its point on ``b``: the normal ``n`` and two tangents
``t₁``, ``t₂`` (``t₁`` along the sliding velocity when the contact slides, else any),
with the forces ``λ = (λ_n, λ₁, λ₂)`` they carry

    λ_n ≥ 0,   v_n ≥ 0,   λ_n v_n = 0          (it pushes, only while it touches)
    |(λ₁, λ₂)| ≤ μ λ_n,   sliding ⇒ friction opposes it at μ λ_n     (Coulomb)

held constant over the step, and the velocities those conditions ask of are the
velocities at the step's end. With the other rows (the joints) held, the end
velocities are affine in the rows' impulses ``p = λ h``: ``v⁺ = ṽ + A p``, ``ṽ``
the step taken without contact forces and ``A = G M̄⁻¹ Gᵀ`` the rows' Delassus
operator (``M̄⁻¹`` the inverse mass with the joints' rows held, by the solve's own
projections; ``M⁻¹`` for a free body). That is a box-constrained LCP in ``p``
(:mod:`.complementarity`, each tangent row's box ``±μ p_n``) whose boxes depend on
its normal forces: solved by a fixed-point iteration on the boxes (each solve exact,
warm-started) until no impulse changes by more than :data:`FRICTION_TOLERANCE` of the
largest, or, where its changes stop shrinking (redundant contacts: the iterates drift
among equal solutions), until the conditions hold at the iterate to
:data:`RESIDUAL_TOLERANCE`. With joints and forces of the velocities (servos,
damping), ``A`` is the step's own response (:meth:`ContactSteps._step_response`).
Coulomb's cone, not the pyramid: a contact sliding at the step's start has one
friction row, along its slip (``t₁``), so its friction opposes the slip at ``μ λ_n``;
a sticking contact has two (the pyramid), and where its friction ends on a bound with
its point slipping, or outside the cone inside the pyramid (up to ``√2 μ λ_n`` along a
diagonal), it is turned to slide, along its slip or against its friction, and the
problem solved again (:meth:`ContactSteps._slipping`); where none turns and the
operator is the step's own (servos), a sliding contact that stopped within the step
(its one row inside its bound) sticks, two rows, solved again. Where the fixed point
drifts (below), Lemke's pivoting on the pyramid
LCP solves the rows (:func:`_pyramid`). A Delassus operator made
singular by redundant contacts (a box flat on the ground: four normals on three
freedoms) is regularized proximally (each solve adds ``ρ (p − p_k)``, ``ρ``
:data:`PROXIMAL` of its diagonal, and the iteration takes it out: the forces solve the
unregularized problem to its tolerance); a row no force moves (a point on an axle
fixed to the world) carries nothing.

The step is then taken again with the contact forces as constant wrenches (each a
world-frame force at the contact point: a world force and torque on each body),
so the integrator's own step carries them: a body resting on the ground has its
weight carried exactly and does not move (to rounding), a sphere rolls with its
contact point still, a block slides with ``μ λ_n`` against its motion. This is
Stewart and Trinkle's time-stepping (1996) with the forces held over the step
instead of an impulse at its end: first order in time while contacts come and go
(a release, a stick inside a step), exact for a contact that persists with a
constant force. A step needing no contact force is the free step, unchanged.

**Impacts** are located. After the step, a contact that was not touching at its
start and now overlaps by more than the tolerance is an impact: the step is taken
again up to the moment its depth crossed zero, found by regula falsi (Illinois) on
partial steps from the step's start to :data:`LOCATION_TOLERANCE`, and there every
touching contact takes an impulse: an LCP of the same form whose normal rows ask
``v_n⁺ ≥ −e v_n⁻`` (Newton's law, ``e`` the pair's restitution) and whose
friction impulses keep within ``μ p_n`` (a sticking impact stops the point's
sliding). Then the rest of the step is taken. After :data:`MAX_BOUNCES` impacts in
one step the next are inelastic (a bouncing ball's impacts accumulate in finite
time); after :data:`MAX_EVENTS` the step stands and its depth is corrected below.
So a dropped ball's bounces reach ``e^{2k} h`` and happen at their times, to the
tolerance, with fixed steps as under the accuracy knob (whose tolerance tightens
the location: :meth:`ContactSteps.tighten`), down to :data:`BOUNCE_SPEED`: an
impact slower than that is inelastic, and with the knob off a contact apart within
the detector's margin closing that slowly at the step's start (and slower than twice
that at its free step's end) is not located but held as a row of the step that asks
it to close at most its gap ``g`` (``h (v_n + v_n⁺) / 2 ≥ −g``, not rebounding;
Stewart and Trinkle's time-stepping; :meth:`ContactSteps._step_rows`): first order in
the closure's time, its depth at the step's end at most ``h v / 2``, projected out
there. So impacts faster than twice the bounce speed keep Newton's law, those slower
than it are inelastic, and those between may be either. A pile makes
dozens of such closures a step, each of which was an event located on its own.

**Penetration** beyond the tolerance left by a step (a contact's curvature over the
step, a spawn inside another body) is projected out at the step's end: the bodies
move by ``M̄⁻¹ Gᵀ μ`` with ``μ ≥ 0`` the smallest pushes that zero every depth
(the same LCP on the normal rows, positions only: velocities are untouched; each
pass linearized, up to :data:`PROJECTION_PASSES`, what they leave counted in
``projection_left``). Its largest value is reported (``max_depth``), as is the
energy it may add (``m g`` times a depth within the tolerance).

In scenes of free bodies with the knob off, the steps run in a compiled kernel
(:mod:`.kernels.contact_step`, :meth:`ContactSteps.compiled_steps`) that follows this
module's methods function for function; this module stays the reference (and takes
every step of scenes with joints).

Pairwise coefficients: ``μ = √(μ_a μ_b)`` (so two like surfaces have their own
``μ``, and a frictionless one makes the pair frictionless) and ``e = max(e_a,
e_b)``, as Box2D combines them.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
import math
from typing import Any, NamedTuple, Optional

import numpy as np
import scipy.linalg

from .bodies import State
from .complementarity import lemke, solve_direct
from .dynamics import STEPS
from .effects import Effect, KernelModel, Kinematics, WrenchAccumulator
from .kernels import contact_step as kern
from .kernels.free_step import HAS_POSITION_FORCES, state_outputs
from .kernels.layout import B_INV_MASS, B_MOMENTS, O_WIDTH, W_BODY, W_FORCE, W_TORQUE, W_WIDTH
from .kernels.views import Pinned
from .rotation import cross, exp_quat, quat_multiply, quat_to_matrix
from .shapes import ContactDetector, Contacts, ROW

#: m: a contact whose gap is within this is touching (a row); an impact is located
#: until the depth is within it.
LOCATION_TOLERANCE = 1e-10
#: m/s: a touching contact approaching faster than this is an impact; a sliding speed
#: below it is sticking (the tangents' direction is then arbitrary).
RATE_TOLERANCE = 1e-9
#: m and m/s: the tightest tolerances under the accuracy knob.
LOCATION_FLOOR = 1e-13
RATE_FLOOR = 1e-13
#: Relative: the friction iteration ends when no impulse changes by more than this
#: fraction of the largest (and every friction is within the cone by as much).
FRICTION_TOLERANCE = 1e-8
#: Relative to the rows' velocities ``w = A p + q`` (``|A| |p| + |q|``, the largest
#: row): where the friction iteration's changes stop shrinking (twice in a row, less
#: than halved), it also ends when the contact conditions hold at its iterate to this,
#: plus what no impulse can take out. Redundant contacts (four feet under a rigid
#: body, a rod's tip on a hinge) leave the forces not unique, and the iterates then
#: drift among the solutions without their changes ever falling below
#: :data:`FRICTION_TOLERANCE`: by ``q``'s part outside ``A``'s range (the joints'
#: velocity error across the redundant rows) over ``ρ`` each iteration; that part, the
#: drift times ``ρ``, is the least residual any impulse leaves (twice it is allowed).
RESIDUAL_TOLERANCE = 1e-12
#: The residual, relative as :data:`RESIDUAL_TOLERANCE`, a pivoted solve (:func:`_pyramid`)
#: must reach: its pivots and its final least-squares solve on a support made singular by
#: redundant contacts lose digits to that support's conditioning (measured: 1e-12 of the
#: scale on the Panda pushing a box), where the fixed point's exact solves lose none.
PIVOT_TOLERANCE = 1e-10
#: The diagonals :func:`_pyramid` adds to the rows' operator, relative to its largest:
#: the first, and the second where the first ends on a ray (both within
#: :data:`PIVOT_TOLERANCE` of ``A p``).
PIVOT_REGULARIZATIONS = (1e-12, 1e-10)
#: Most iterations of the friction boxes (each an exact box LCP, warm-started).
FRICTION_ITERATIONS = 60
#: Iterations in a row contracting by less than half after which the friction boxes'
#: fixed point gives way (where its rows have no equalities) to Newton's method on the
#: rows' natural map (:func:`_newton`, once), then, if that fails and at its last
#: contraction ratio the fixed point would not reach :data:`FRICTION_TOLERANCE` within
#: :data:`FRICTION_ITERATIONS` (or no longer contracts), to pivoting. In a pile's
#: sliding islands of 60 contacts it contracts by about 0.8 an iteration (measured):
#: 90 iterations of 0.5 to 2 ms each, where Newton's method takes 2 to 8 solves of
#: about 0.3 ms and a pivoted solve about 18 ms.
STALL_ITERATIONS = 2
#: The proximal regularization, relative to the Delassus operator's largest diagonal.
PROXIMAL = 1e-6
#: The compiled steps pivot (Lemke's, on the pyramid: :func:`_pyramid`) an island of at most
#: this many contacts whose fixed point and Newton's method fail; a larger one they solve
#: instead by its blocks (:func:`.kernels.contact_step.solve_large_island`, counted in
#: ``lcp_sparse``), its result taken where it meets the bar a pivoted one must
#: (:data:`PIVOT_TOLERANCE`), else pivoted after all up to :data:`PIVOT_LAST_CONTACTS`,
#: and where that fails too the fixed point goes on as after a failed pivoting. A
#: pivoted solve's tableau has about seven columns a contact, and its cost grows as their
#: cube: 0.37 s for an island of 190 contacts of the 100-sphere pour, a hundred times its
#: Newton solve; pivoting every island, ``lemke`` took 31 % of that pour's samples (perf).
#: The pour's first second, compiled, this Xeon (one sample each: a pile is chaotic, and
#: each threshold's run takes its own path): every island pivoted 138-167 s, 48 LCP failures;
#: 128 contacts 125 s, 18; 64: 89-92 s, 19; 32: 103-108 s, 4; 16: 90 s, 8. The Python
#: path pivots every island.
PIVOT_CONTACTS = 32
#: The compiled steps pivot an island of more than :data:`PIVOT_CONTACTS` contacts and at
#: most this many as their last resort, where its blocks fail too (else a failure,
#: counted). Rare, and dear: the 100-sphere pour's first second (``bench/
#: contact_dynamics.py``'s pile: 140,000 to 180,000 solves) failed 4 that way, islands of
#: 15, 34, 87 and 96 contacts; pivoting solved the last three within the bar, in 4, 53 and
#: 75 ms (compiled, this Xeon). Over four jitters of that pour (a pile is chaotic: each
#: run takes its own path) the failures went from 4, 9, 13, 7 to 6, 5, 9, 4 (33 to 24),
#: their wall times within the host's noise (measured).
PIVOT_LAST_CONTACTS = 128
#: Islands of more contacts than this are solved by their Delassus operator's blocks alone
#: (the compiled steps: :func:`.kernels.contact_step.solve_large_island`), where the
#: dense path's factors cost ``O(rows³)`` and its matrix ``O(rows²)`` (a pile of a
#: thousand spheres: one island of some 2,500 contacts, 7,500 rows, 450 MB dense). The
#: Python path solves every island densely.
SPARSE_CONTACTS = 500
#: The large islands' proximal regularization, relative to the largest diagonal: at
#: 1e-5 and below the fixed point diverged on a tall pile of 1000 spheres (the boxes
#: that hold leave directions only ρ bounds), at 1e-3 it stalled on one (measured).
SPARSE_PROXIMAL = 1e-4
#: Relative to the rows' velocity scale (as :data:`RESIDUAL_TOLERANCE`): a large
#: island's solve ends when the contact conditions hold to this.
SPARSE_RESIDUAL = 1e-10
#: Most iterations of a large island's fixed point, and of MPRGP within each.
SPARSE_ITERATIONS = 100
SPARSE_INNER = 20000
#: The iterates Anderson's acceleration of a large island's fixed point fits (0: none):
#: on random redundant contacts of 600 rows it took 29 iterations where the plain fixed
#: point took 162 (measured).
SPARSE_HISTORY = 5
#: Most sweeps of projected Gauss–Seidel where a large island's fixed point fails.
PGS_SWEEPS = 5000
#: Most guesses of Newton's method on the rows' natural map (:func:`_newton`); measured
#: on a pile's sliding islands of 60 contacts: 2 to 8 from the fixed point's first iterate.
NEWTON_ITERATIONS = 10
#: Refinements of each of its proximal solves on the same factors: each takes the part
#: of the step the proximal term held back by ``ρ / (λ + ρ)`` (λ the system's least
#: nonzero eigenvalue in size).
NEWTON_REFINEMENTS = 3
#: Relative to the rows' velocities without contact forces: how far a step's end may
#: leave them from the LCP's model before the model is corrected and solved again.
MODEL_TOLERANCE = 1e-12
#: Most corrections of the model per step.
MODEL_CORRECTIONS = 2
#: Most passes of the end's position projection: each is linearized at the positions it
#: starts from, so a projection of ``d`` leaves ``O(d²/ρ)`` (``ρ`` the contacts' and
#: the bodies' radii of curvature and turn), which the next pass takes out.
PROJECTION_PASSES = 3
#: m/s: a loaded contact's normal velocity at a step's end within this of zero is the
#: LCP's model error (it ended the step at zero), set to zero (:meth:`ContactSteps._accept`).
HOLD_RATE = 1e-6
#: Most regula-falsi iterations to locate one impact.
MAX_LOCATION_ITERATIONS = 60
#: Impacts in one step after which the next are inelastic (Zeno's cut).
MAX_BOUNCES = 8
#: m/s: an impact approaching slower than this is inelastic (``e = 0``), and a contact
#: apart (within the detector's margin) closing slower than this at a step's start (and
#: slower than twice this at the end of its free step) is a row of its step (asking it
#: to close at most the gap), not an event located. Its rebound would rise at most
#: ``(e v)² / (2 g)`` (0.5 µm at ``e`` 0.3 under 9.81 m/s²) and return within ``2 e v /
#: g`` (0.6 ms): in a pile such closures come by the dozen each step.
BOUNCE_SPEED = 1e-2
#: Most events (impacts) in one step: beyond them the step stands.
MAX_EVENTS = 32
EPS = float(np.finfo(float).eps)
#: How many of the latest impacts :attr:`ContactSteps.impacts` keeps.
IMPACT_LOG = 256


class ContactImpact(NamedTuple):
    """One located impact of a contact."""

    time: float          #: s, simulation time
    shape_a: str
    shape_b: str
    approach: float      #: m/s, the normal velocity before (< 0)
    rebound: float       #: m/s, after (``−e`` times it for a lone contact)


def pair_friction(mu_a: np.ndarray, mu_b: np.ndarray) -> np.ndarray:
    """Return the pair's Coulomb coefficient ``√(μ_a μ_b)``."""
    return np.sqrt(np.asarray(mu_a) * np.asarray(mu_b))


def pair_restitution(e_a: np.ndarray, e_b: np.ndarray) -> np.ndarray:
    """Return the pair's Newton coefficient ``max(e_a, e_b)``."""
    return np.maximum(e_a, e_b)


class ContactWrenches(Effect):
    """
    The contact forces of the step being taken, as constant world-frame wrenches.

    Set by :class:`ContactSteps` before a step and cleared after it: each body's
    force (N) at its centre and torque (N m) about it, in the world frame.
    """

    name = 'contact'

    def __init__(self) -> None:
        super().__init__()
        self._rows = np.zeros((0, W_WIDTH))

    def act(self, bodies: np.ndarray, force: np.ndarray, torque: np.ndarray) -> None:
        """Act with ``force`` (k, 3) and ``torque`` (k, 3), world frame, on ``bodies`` (k,)."""
        rows = np.zeros((len(bodies), W_WIDTH))
        rows[:, W_BODY] = bodies
        rows[:, W_FORCE:W_FORCE + 3] = force
        rows[:, W_TORQUE:W_TORQUE + 3] = torque
        self._rows = rows

    def clear(self) -> bool:
        """Remove every wrench; return whether there was any."""
        had = len(self._rows) > 0
        self._rows = np.zeros((0, W_WIDTH))
        return had

    def __len__(self) -> int:
        """Return the number of bodies acted on."""
        return len(self._rows)

    def add_to_kernel_model(self, model: KernelModel, time_mid: float) -> None:
        """Add the wrenches as rows of kind WRENCH_APPLIED (world frame, at the centre)."""
        if len(self._rows):
            model.add_wrench_rows(self._rows)
            model.flags |= HAS_POSITION_FORCES

    def count_kernel_work(self, rhs: int, kicks: int, flows: int,
                          acting: Optional[int] = None) -> None:
        """Count every right-hand side and kick, per body acted on."""
        k = len(self._rows) if acting is None else acting
        self._count(rhs + kicks if k else 0, k)

    def acting_in(self, local: np.ndarray, rows_kept: np.ndarray) -> int:
        """Return the bodies of the subset acted on."""
        return int(np.count_nonzero(rows_kept))

    def accumulate(self, kin: Kinematics, acc: WrenchAccumulator) -> None:
        """Add the wrenches (world frame) to ``acc``."""
        if not len(self._rows):
            return
        self.evaluations += 1
        body = self._rows[:, W_BODY].astype(int)
        np.add.at(acc.force_world, body, self._rows[:, W_FORCE:W_FORCE + 3])
        np.add.at(acc.torque_world, body, self._rows[:, W_TORQUE:W_TORQUE + 3])


@dataclass
class ContactRows:
    """
    The touching contacts at one state and their rows (``c`` contacts, ``3c`` rows).

    Rows ``3k``, ``3k + 1``, ``3k + 2`` are contact ``k``'s normal and tangents.
    ``G`` (3c, 6n) maps the bodies' velocities (per body ``v`` world, ``Ω``
    principal) to the rows' relative velocities.
    """

    state: State               #: where the rows were built
    contacts: Contacts
    frame: np.ndarray          #: (c, 3, 3) rows n, t₁, t₂ (world)
    lever_a: np.ndarray        #: (c, 3) contact point − centre of a (world)
    lever_b: np.ndarray        #: (c, 3) contact point − centre of b (world; 0: the world)
    mu: np.ndarray             #: (c,)
    restitution: np.ndarray    #: (c,)
    G: np.ndarray              #: (3c, 6n)
    #: (c,) bool: sliding faster than the rate tolerance at the rows' state (t₁ along it)
    sliding: np.ndarray
    #: (c,) m/s: the normal relative velocity at the rows' state (> 0: apart)
    vn: np.ndarray

    def subset(self, keep: np.ndarray) -> 'ContactRows':
        """Return the rows of the contacts ``keep`` (bool (c,))."""
        rows3 = np.repeat(keep, 3)
        return ContactRows(self.state, Contacts(*(part[keep] for part in self.contacts)),
                           self.frame[keep], self.lever_a[keep], self.lever_b[keep],
                           self.mu[keep], self.restitution[keep], self.G[rows3],
                           self.sliding[keep], self.vn[keep])

    def __len__(self) -> int:
        """Return the number of contacts."""
        return len(self.mu)


@dataclass
class ContactRecord:
    """The contacts of the latest step and the forces they carried over it."""

    time: float = 0.0
    rows: Optional[ContactRows] = None
    force: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


class ContactSteps:
    """
    A simulation's steps with contact (see the module docstring).

    Parameters
    ----------
    sim : Simulation
    detector : ContactDetector
    wrenches : ContactWrenches
        The effect the step's contact forces are put in (one of the dynamics').

    """

    def __init__(self, sim: Any, detector: ContactDetector, wrenches: ContactWrenches) -> None:
        self.sim = sim
        self.detector = detector
        self.wrenches = wrenches
        table = detector.table
        self._mu = table[:, ROW['friction']].copy()
        # m: how far a contact's point may move on its shape a and stay the same contact:
        # a quarter of the shape's smallest half size (a box's corners are further apart).
        size = table[:, ROW['size']]
        self._radius = 0.25 * np.min(np.where(size > 0.0, size, np.inf), axis=1, initial=np.inf)
        self._e = table[:, ROW['restitution']].copy()
        self.location, self.rate = LOCATION_TOLERANCE, RATE_TOLERANCE
        #: m/s: impacts approaching slower are inelastic (:data:`BOUNCE_SPEED`).
        self.bounce = BOUNCE_SPEED
        #: m/s: contacts apart closing slower than this are rows of the step, not events
        #: (:meth:`_step_rows`): the bounce speed; 0 under the accuracy knob (every
        #: closure located).
        self.unlocated = BOUNCE_SPEED
        #: The compiled steps solve islands of more contacts by their blocks alone
        #: (:data:`SPARSE_CONTACTS`).
        self.sparse_contacts = SPARSE_CONTACTS
        self._seen: Optional[tuple] = None
        self._frames_seen: Optional[tuple] = None
        self._lazy: Optional[tuple] = None
        self._overlaps: Optional[ContactRows] = None
        self.record = ContactRecord()
        #: Take the steps of scenes of free bodies in the compiled kernel
        #: (:meth:`compiled_steps`), and the LCPs of the steps that run in Python (joints,
        #: the knob) by its solve (:meth:`_compiled_island`); False: every step in Python,
        #: solves included (the reference).
        self.compiled = True
        self._kernel_key: Optional[tuple] = None
        self._kernel_args: tuple = ()
        self._island_key: Optional[tuple] = None
        self._island_prm = np.zeros(0)
        self._scratch: Optional[tuple] = None
        #: The kernel's table of the detector's arrays (:meth:`_detector_table`): ``(det,
        #: buffers, Pinned)``, kept while they are the same arrays.
        self._dtab: Optional[tuple] = None
        #: The kernel's impacts, a row each: time, shapes a and b, approach, rebound.
        self._log = np.zeros((IMPACT_LOG, 5))
        self.counters: dict = {}
        #: The latest impacts (at most IMPACT_LOG), oldest first.
        self.impacts: deque = deque(maxlen=IMPACT_LOG)
        self.reset()

    def reset(self) -> None:
        """Forget the contacts and the counters (a reset)."""
        if self.wrenches.clear():
            self.sim.dynamics.changed()
        self.record = ContactRecord(time=self.sim.state.time if hasattr(self.sim, 'state')
                                    else 0.0)
        #: The last step's rows' normal impulses: shapes a and b, points, impulses.
        self._warm: tuple = _NO_WARM
        self._overlaps = None
        self._symmetric = True
        self.impacts.clear()
        self.counters = {'impacts': 0, 'located_steps': 0, 'events_capped': 0,
                         'lcp_solves': 0, 'lcp_iterations_max': 0, 'lcp_failures': 0,
                         'complementarity_max': 0.0, 'max_depth': 0.0,
                         'projections': 0, 'max_projected': 0.0, 'model_corrections': 0,
                         'held_rates': 0, 'immovable_rows': 0, 'compiled_steps': 0,
                         'stepped_responses': 0, 'projection_left': 0.0, 'end_depth': 0.0,
                         'lcp_pivoted': 0, 'lcp_newton': 0, 'lcp_sparse': 0, 'lcp_pgs': 0}

    @property
    def record(self) -> ContactRecord:
        """Return the latest step's contacts and forces (built when read, after compiled steps)."""
        if self._lazy is not None:
            state, con, sel, force = self._lazy
            self._lazy = None
            mask = np.zeros(len(con.depth), dtype=bool)
            mask[sel] = True
            rows = self.rows(state, con, select=mask)
            self._record = ContactRecord(state.time, rows, force)
        return self._record

    @record.setter
    def record(self, value: ContactRecord) -> None:
        self._record, self._lazy = value, None

    def tighten(self) -> None:
        """Set the tolerances for the accuracy knob (``tolerance dt``, floored) or the defaults."""
        control, dt = self.sim._control, self.sim.dt
        self.unlocated = self.bounce if control is None else 0.0
        if control is None:
            self.location, self.rate = LOCATION_TOLERANCE, RATE_TOLERANCE
        else:
            budget = control.tolerance * dt
            self.location = min(LOCATION_TOLERANCE, max(budget, LOCATION_FLOOR))
            self.rate = min(RATE_TOLERANCE, max(budget, RATE_FLOOR))

    def _advance(self, state: State, h: float, t: float, accepted: bool = False) -> State:
        """
        Take the integrator's step of ``h`` from ``state`` to ``t``.

        ``accepted``: the step that stands (with the contact forces found), taken with
        the joints' events (limits, friction, drives' efforts) located inside it; the
        trials (the step without contact forces, the location's partial steps) are the
        integrator's alone, with the joints' rows as they are: the events' bookkeeping
        changes only along the steps that stand.
        """
        events = self.sim.events
        if events is None or not accepted:
            return self.sim._advance(state, h, t)
        return events.step(state, t, span=h)[0]

    # -- the rows -------------------------------------------------------------------------

    def _rotations(self, state: State) -> np.ndarray:
        """Return the principal-to-world rotations (n + 1, 3, 3) at ``state``, the world's last."""
        seen = self._frames_seen
        if seen is not None and seen[0] is state and seen[1] is state.y:
            return seen[2]
        n = len(self.sim.bodies.names)
        R = np.concatenate([quat_to_matrix(state.quat_principal_world).reshape(n, 3, 3),
                            np.eye(3)[None]])
        self._frames_seen = (state, state.y, R)
        return R

    def detect(self, state: State) -> Contacts:
        """Return the detector's contacts at ``state`` (within its margin; kept for the state)."""
        seen = self._seen
        if seen is not None and seen[0] is state and seen[1] is state.y \
                and seen[3] is self.detector.excluded:   # (joints added or removed since)
            return seen[2]
        self.sim.bodies.outputs(state)
        con = self.detector.detect(self.sim.bodies.outputs_cache.out)
        self._seen = (state, state.y, con, self.detector.excluded)
        return con

    def rows(self, state: State, contacts: Optional[Contacts] = None,
             separating: bool = True, select: Optional[np.ndarray] = None) -> ContactRows:
        """
        Return the rows of the contacts touching at ``state`` (gap within the tolerance).

        ``separating`` False: without the contacts whose points move apart faster than
        the rate tolerance (a ball just bounced: it flies, and comes back as an impact).
        ``select``: the contacts of ``contacts`` to take instead of the touching ones.
        """
        if contacts is None:
            contacts = self.detect(state)
        n = len(self.sim.bodies.names)
        R_all = self._rotations(state)
        centre = np.concatenate([state.pos_com_world, np.zeros((1, 3))])
        w_world = np.concatenate([np.einsum('nij,nj->ni', R_all[:n], state.ang_vel_principal),
                                  np.zeros((1, 3))])
        vel = np.concatenate([state.vel_com_world, np.zeros((1, 3))])
        keep = contacts.depth >= -self.location if select is None else select
        con = Contacts(*(part[keep] for part in contacts))
        a, b = con.body_a, con.body_b
        lever_a = con.point - centre[a]
        lever_b = np.where((b < n)[:, None], con.point - centre[b], 0.0)
        v_rel = (vel[a] + cross(w_world[a], lever_a)) \
            - (vel[b] + cross(w_world[b], lever_b))
        nrm = con.normal
        vn = np.sum(v_rel * nrm, axis=1)
        v_t = v_rel - vn[:, None] * nrm
        speed = np.linalg.norm(v_t, axis=1)
        t1 = _any_tangent(nrm)
        slide = speed > self.rate
        t1[slide] = v_t[slide] / speed[slide, None]
        frame = np.stack([nrm, t1, cross(nrm, t1)], axis=1)
        G = _jacobian(frame, a, b, lever_a, lever_b, R_all, n)
        mu = pair_friction(self._mu[con.shape_a], self._mu[con.shape_b])
        e = pair_restitution(self._e[con.shape_a], self._e[con.shape_b])
        out = ContactRows(state, con, frame, lever_a, lever_b, mu, e, G, slide, vn)
        return out if separating else out.subset(vn <= self.rate)

    def rows_at(self, rows: ContactRows, state: State) -> np.ndarray:
        """
        Return the rows' ``G`` at ``state`` (a step's end): each row at its contact there.

        Each contact is found again at ``state`` (the same pair, its point continuing:
        :meth:`_match`; a box's corner, a rolling ball's lowest point), its normal the
        one found there and its tangents the start's turned onto it (with body b); a
        row whose contact is not found keeps its start's ``G``. The rows' velocities
        at a step's end are what the contact conditions ask of: at the start's ``G`` a
        pivot whose lever turns within the step would end moving.
        """
        con = self.detect(state)
        match = self._match(rows, np.ones(len(rows), dtype=bool), con, state)
        G = rows.G.copy()
        found = np.flatnonzero(match >= 0)
        if not len(found):
            return G
        n = len(self.sim.bodies.names)
        R_all, R0 = self._rotations(state), self._rotations(rows.state)
        centre = np.concatenate([state.pos_com_world, np.zeros((1, 3))])
        j = match[found]
        a, b = rows.contacts.body_a[found], rows.contacts.body_b[found]
        nrm = con.normal[j]
        t1 = np.einsum('kij,kjl,kl->ki', R_all[b], np.transpose(R0[b], (0, 2, 1)),
                       rows.frame[found, 1])
        t1 = t1 - np.sum(t1 * nrm, axis=1)[:, None] * nrm
        t1 /= np.linalg.norm(t1, axis=1)[:, None]
        frame = np.stack([nrm, t1, cross(nrm, t1)], axis=1)
        point = con.point[j]
        lever_b = np.where((b < n)[:, None], point - centre[b], 0.0)
        rows3 = (3 * found[:, None] + np.arange(3)[None, :]).reshape(-1)
        G[rows3] = _jacobian(frame, a, b, point - centre[a], lever_b, R_all, n)
        return G

    def response(self, state: State, G: np.ndarray) -> np.ndarray:
        """
        Return ``M̄⁻¹ Gᵀ`` (6n, r): the velocity change per unit impulse on each row.

        ``M⁻¹ Gᵀ`` for free bodies; for bodies held by joints, the change the solve's
        velocity projection leaves of it (the joints' rows held: their reactions take
        their share of each impulse).
        """
        bodies = self.sim.bodies
        n = len(bodies.names)
        inv = np.concatenate([np.repeat(bodies.inv_mass[:, None], 3, axis=1),
                              1.0 / np.asarray(bodies.moments)], axis=1).reshape(-1)
        Y = inv[:, None] * G.T
        solver = self.sim.dynamics.solver
        if not len(solver.constraints):
            return Y
        # The projection is affine: each column's, less that of zero velocities (the
        # first set), all in one pass (:meth:`.Solver.project_velocity_sets`).
        sets = np.zeros((Y.shape[1] + 1, n, 6))
        sets[1:] = Y.T.reshape(Y.shape[1], n, 6)
        vel, om = sets[:, :, :3].copy(), sets[:, :, 3:].copy()
        solver.project_velocity_sets(state, vel, om)
        out = np.concatenate([vel, om], axis=2).reshape(len(sets), 6 * n)
        return (out[1:] - out[0]).T   # (Fortran order, as the free bodies' Y above)

    # -- the LCP of the rows --------------------------------------------------------------

    def solve(self, A: np.ndarray, q: np.ndarray, mu: np.ndarray,
              start: Optional[np.ndarray] = None, normal_only: bool = False,
              equal: Optional[np.ndarray] = None,
              sliding: Optional[np.ndarray] = None, symmetric: bool = True) -> np.ndarray:
        """
        Return the rows' impulses ``p`` (3c,): :meth:`solve_island` on each island.

        The contacts fall into islands, the connected parts of the graph whose edges are
        the non-zero 3 × 3 blocks of ``A`` (contacts moved by one impulse through a body
        they share, or a joint): the LCP is block diagonal over them, and each is solved
        on its own (:func:`islands`; the compiled path alike). Objects resting apart on
        the ground cost each their own small solve, not one of all their rows together.
        """
        groups = islands(A)
        if len(groups) <= 1:
            return self.solve_island(A, q, mu, start, normal_only, equal, sliding, symmetric)
        out = np.zeros(len(q))
        for idx in groups:
            rows = (3 * idx[:, None] + np.arange(3)).ravel()
            out[rows] = self.solve_island(
                A[np.ix_(rows, rows)], q[rows], mu[idx], None if start is None else start[rows],
                normal_only, None if equal is None else equal[idx],
                None if sliding is None else sliding[idx], symmetric)
        return out

    def solve_island(self, A: np.ndarray, q: np.ndarray, mu: np.ndarray,
                     start: Optional[np.ndarray] = None, normal_only: bool = False,
                     equal: Optional[np.ndarray] = None,
                     sliding: Optional[np.ndarray] = None, symmetric: bool = True
                     ) -> np.ndarray:
        """
        Return the rows' impulses ``p`` (3c,): ``w = A p + q`` under the contact conditions.

        Normal rows ``p_n ≥ 0 ⊥ w_n ≥ 0``; tangent rows within the cone ``μ p_n``
        and ``w_t = 0`` inside it, sliding against ``w_t`` on it (see the module
        docstring: the boxes' fixed point, proximal). ``normal_only``: the
        tangent rows are left out (``p_t = 0``); ``sliding`` (c,) bool: those
        contacts' friction is along ``t₁`` alone (the slip's direction: Coulomb's
        friction opposes the slip; a sticking contact's two rows are the pyramid
        ``|λᵢ| ≤ μ λ_n``); ``equal`` (c,) bool: those
        contacts' normal rows are equalities (``w_n = 0``, ``p_n`` of either sign).
        ``symmetric``: ``A`` is ``G M̄⁻¹ Gᵀ`` (symmetric, made so to its rounding);
        False: a stepped response (:meth:`_step_response`), taken as it is.
        Counted. A fixed point that does not converge (redundant contacts whose load
        sharing is not unique, and friction bounds that move with it: the iterate drifts
        along the operator's null space) is solved again as the pyramid LCP by Lemke's
        pivoting (:func:`_pyramid`: exact, no iteration on the boxes; counted in
        ``lcp_pivoted``) when its rows have no equalities; if that fails too, the last
        iterate is kept and counted in ``lcp_failures``. One that stalls (contracting
        by less than half :data:`STALL_ITERATIONS` times in a row) is first solved by
        Newton's method on the rows' natural map (:func:`_newton`, counted in
        ``lcp_newton``), exact where it converges; if that fails and the fixed point
        would not reach its tolerance within :data:`FRICTION_ITERATIONS`, it is pivoted
        at once (and goes on iterating if that fails). An island of one contact (a body
        alone on the ground) is solved by its cases, exactly (:func:`_one_contact`),
        where one meets the contact conditions. With :attr:`compiled` and
        ``symmetric``, the compiled kernel's solve of the same method takes it
        (:meth:`_compiled_island`).
        """
        m = len(q)
        if not m:
            return np.zeros(0)
        if self.compiled and symmetric:
            return self._compiled_island(A, q, mu, start, normal_only, equal, sliding)
        rows = np.arange(m) if not normal_only else np.arange(0, m, 3)
        # A row no impulse moves (a point on an axle fixed to the world) carries none: a
        # contact whose normal row is one is left out, a friction row that is one is
        # held at zero (``pinned``).
        diag = np.diag(A)[rows]
        movable = diag > 1e-12 * float(np.max(diag, initial=0.0))
        pinned = np.zeros(len(rows), dtype=bool)
        if not np.all(movable):
            self.counters['immovable_rows'] += int(np.count_nonzero(~movable))
            keep = movable if normal_only else np.repeat(movable[0::3], 3)
            if not np.any(keep):
                return np.zeros(m)
            if not normal_only:
                pinned = ~movable[keep]
                mu = mu[movable[0::3]]
                sliding = None if sliding is None else sliding[movable[0::3]]
            if equal is not None:
                equal = equal[movable] if normal_only else equal[movable[0::3]]
            rows = rows[keep]
        A_r, q_r = A[np.ix_(rows, rows)], q[rows]
        if symmetric:
            A_r = 0.5 * (A_r + A_r.T)   # (symmetric to rounding: G M̄⁻¹ Gᵀ)
        cnt = self.counters
        if len(rows) == 3 and not normal_only and equal is None and not np.any(pinned):
            # One contact (a body alone on the ground): its cases, exact (_one_contact).
            one = _one_contact(A_r, q_r, float(mu[0]),
                               bool(sliding is not None and sliding[0]))
            if one is not None:
                cnt['lcp_solves'] += 1
                cnt['lcp_iterations_max'] = max(cnt['lcp_iterations_max'], 1)
                cnt['complementarity_max'] = max(cnt['complementarity_max'],
                                                 _residual(A_r, q_r, one, mu, False, sliding))
                out = np.zeros(m)
                out[rows] = one
                return out
        rho = PROXIMAL * float(np.max(np.diag(A_r)))
        # What the impulses' rounding is (of q over A's scale). A target inconsistent
        # across redundant rows (the joints' velocity error) moves them along their null
        # space by far more, its inconsistency over ρ each iteration: the residual exit
        # below (RESIDUAL_TOLERANCE) takes that case.
        floor = 64.0 * EPS * float(np.max(np.abs(q_r))) / float(np.max(np.diag(A_r)))
        A_p = A_r + rho * np.eye(len(rows))
        p = np.zeros(len(rows)) if start is None else np.array(start[rows], dtype=float)
        lo, hi = np.zeros(len(rows)), np.full(len(rows), np.inf)
        if equal is not None:
            lo[::1 if normal_only else 3][equal] = -np.inf
        p[::1 if normal_only else 3] = np.maximum(p[::1 if normal_only else 3],
                                                  lo[::1 if normal_only else 3])
        # Where the rows have no equalities, a fixed point that stalls (STALL_ITERATIONS)
        # is solved by Newton's method on the natural map (once) or, if that fails and
        # the fixed point would not reach its tolerance in time, by pivoting (Lemke's, on
        # the pyramid); if that fails too, the fixed point goes on.
        pivots = not normal_only and equal is None
        converged, it, stalled, last, early, pivot_tried = False, 0, 0, np.inf, pivots, False
        newton_tried = False
        while True:
            exited = False
            while it < FRICTION_ITERATIONS:
                it += 1
                if not normal_only:
                    half = mu * np.maximum(p[0::3], 0.0)
                    lo[1::3], hi[1::3] = -half, half
                    half2 = half if sliding is None else np.where(sliding, 0.0, half)
                    lo[2::3], hi[2::3] = -half2, half2
                    lo[pinned], hi[pinned] = 0.0, 0.0
                    p = np.clip(p, lo, hi)
                # Rows whose box is a point (no friction yet, or none: μ = 0, a sliding
                # contact's t₂) are fixed there, out of the problem.
                free = hi > lo
                shift = A_p[np.ix_(free, ~free)] @ p[~free]
                sol = solve_direct(A_p[np.ix_(free, free)],
                                   q_r[free] - rho * p[free] + shift,
                                   lo[free], hi[free], start=p[free])
                new = p.copy()
                new[free] = sol.f
                change = float(np.max(np.abs(new - p)))
                p = new
                scale = max(float(np.max(np.abs(p))), 1e-300)
                ratio = change / last if last > 0.0 else np.inf
                stalled = stalled + 1 if ratio > 0.5 else 0
                last = change
                target = FRICTION_TOLERANCE * scale + floor
                if sol.converged and (change <= target or (
                        stalled >= 2 and _residual(A_r, q_r, p, mu, normal_only, sliding,
                                                   equal, pinned)
                        <= RESIDUAL_TOLERANCE * float(np.max(np.abs(A_r) @ np.abs(p)
                                                             + np.abs(q_r)))
                        + 2.0 * rho * change)):
                    converged = True
                    break
                if early and sol.converged and stalled >= STALL_ITERATIONS:
                    if not newton_tried:
                        newton_tried = True
                        solved, ok = _newton(A_r, q_r, mu, sliding, pinned, p)
                        if ok:
                            p, converged = solved, True
                            cnt['lcp_newton'] += 1
                            break
                    if ratio >= 1.0 or it + math.log(target / change) / math.log(ratio) \
                            > FRICTION_ITERATIONS:
                        exited = True
                        break
            if converged or not pivots:
                break
            # An iterate within what a pivoted solve must reach stands.
            converged = _residual(A_r, q_r, p, mu, False, sliding, None, pinned) \
                <= PIVOT_TOLERANCE * float(np.max(np.abs(A_r) @ np.abs(p) + np.abs(q_r)))
            if converged or pivot_tried:
                break
            pivot_tried = True
            for regularization in PIVOT_REGULARIZATIONS:
                pivoted, ok = _pyramid(A_r, q_r, mu, sliding, pinned, regularization)
                scale = float(np.max(np.abs(A_r) @ np.abs(pivoted) + np.abs(q_r)))
                if ok and _residual(A_r, q_r, pivoted, mu, False, sliding, None, pinned) \
                        <= PIVOT_TOLERANCE * scale:
                    p, converged = pivoted, True
                    cnt['lcp_pivoted'] += 1
                    break
            if converged or not exited:
                break
            early = False   # (the pivoting failed: the fixed point goes on from its iterate)
        cnt['lcp_solves'] += 1
        cnt['lcp_iterations_max'] = max(cnt['lcp_iterations_max'], it)
        if not converged:
            cnt['lcp_failures'] += 1
        if equal is None:
            cnt['complementarity_max'] = max(cnt['complementarity_max'],
                                             _residual(A_r, q_r, p, mu, normal_only, sliding,
                                                       pinned=pinned))
        out = np.zeros(m)
        out[rows] = p
        return out

    def _compiled_island(self, A: np.ndarray, q: np.ndarray, mu: np.ndarray,
                         start: Optional[np.ndarray], normal_only: bool,
                         equal: Optional[np.ndarray], sliding: Optional[np.ndarray]
                         ) -> np.ndarray:
        """
        Return :meth:`solve_island`'s impulses by the compiled kernel's solve.

        The steps that run in Python (scenes with joints, the knob; ``compiled`` True)
        solve their islands by ``kernels.contact_step.solve_island``: the same method
        (the proximal fixed point, Newton's method, Lemke's pivoting, the blocks of a
        large island) with its active-set solves by an updated Cholesky factor, and
        counted alike. Rows no impulse moves (a joint's axis along a friction row) are
        taken as :meth:`solve_island` takes them: a contact whose normal row is one is
        left out; a friction row that is one carries nothing: the kernel is given it
        apart from the others (its row and column zero but the diagonal, which is the
        largest of the rows', and its velocity zero), so that its impulse solves to zero
        within any bound.
        """
        m = len(q)
        rows = np.arange(0, m, 3) if normal_only else np.arange(m)
        A_r = A[np.ix_(rows, rows)]
        diag = np.diag(A_r)
        dmax = float(np.max(diag, initial=0.0))
        movable = diag > 1e-12 * dmax
        out = np.zeros(m)
        per = 1 if normal_only else 3
        kept = np.flatnonzero(movable[0::per])   # (the contacts whose normal row moves)
        if not np.all(movable):
            self.counters['immovable_rows'] += int(np.count_nonzero(~movable))
            if not len(kept):
                return out
        sub = (per * kept[:, None] + np.arange(per)).ravel()
        A_k = A_r[np.ix_(sub, sub)]
        A_k = 0.5 * (A_k + A_k.T)   # (symmetric to rounding: G M̄⁻¹ Gᵀ)
        q_k = np.array(q[rows][sub], dtype=float)
        p0 = np.zeros(len(sub)) if start is None else np.array(start[rows][sub], dtype=float)
        mu_k = np.array(mu[kept], dtype=float)
        sl = np.zeros(len(kept), dtype=bool) if sliding is None \
            else np.array(sliding[kept], dtype=bool)
        eq = np.zeros(len(kept), dtype=bool) if equal is None \
            else np.array(equal[kept], dtype=bool)
        if not normal_only:
            for r in np.flatnonzero(~movable[sub]):
                A_k[r, :], A_k[:, r] = 0.0, 0.0
                A_k[r, r], q_k[r], p0[r] = dmax, 0.0, 0.0
        cnt = np.zeros(len(kern.COUNTERS))
        p, ok = kern.solve_island(np.ascontiguousarray(A_k), q_k, mu_k, p0, bool(normal_only),
                                  eq, equal is not None, sl, self._island_parameters(), cnt)
        if not ok:   # (none: every row given moves, or is one apart)
            raise RuntimeError('the compiled solve was given a row no impulse moves')
        self._add_counters(cnt)
        out[rows[sub]] = p
        return out

    def _island_parameters(self) -> np.ndarray:
        """Return :meth:`kernel_parameters` (kept while the tolerances are the same)."""
        key = (self.location, self.rate, self.bounce, self.unlocated, self.sparse_contacts)
        if self._island_key != key:
            self._island_prm, self._island_key = self.kernel_parameters(), key
        return self._island_prm

    def _add_counters(self, cnt: np.ndarray) -> None:
        """Add the kernel's counters ``cnt`` (``kern.COUNTERS``' order) to :attr:`counters`."""
        for name, value in zip(kern.COUNTERS, cnt.tolist()):
            if name in kern.MAXIMA:
                self.counters[name] = max(self.counters[name], type(self.counters[name])(value))
            elif value:
                self.counters[name] += int(value)

    # -- a step ---------------------------------------------------------------------------

    def step(self, start: State, t_end: float) -> State:
        """Take a step from ``start`` to ``t_end`` with contact forces and impacts (module doc)."""
        sim = self.sim
        self.tighten()
        state, events, bounces = start, 0, 0
        while True:
            h = sim.dt if state is start else t_end - state.time
            if h <= 4.0 * EPS * abs(t_end):
                return self._accept(State(t_end, *state.parts))
            near = self._in_margin(state)
            touching = near if self.unlocated <= 0.0 else near.subset(
                near.contacts.depth >= -self.location)
            if len(touching) and events < MAX_EVENTS:
                state, hit = self._impact(state, touching, bounces >= MAX_BOUNCES)
                if hit:
                    bounces += 1
                    events += 1
                    near = self._in_margin(state)
            rows = self._step_rows(near)
            self._overlaps = self._overlapping(state, rows)
            trial = self._held_step(state, rows, h, t_end)
            rows = self.record.rows   # (those held: the contacts apart it closes slowly)
            hit = None if events >= MAX_EVENTS else self._new_overlap(rows, trial)
            if events >= MAX_EVENTS:
                self.counters['events_capped'] += 1
            if hit is None:
                return self._accept(self._stands(state, h, t_end, trial))
            located, tau = self._locate(state, rows, h, hit)
            if tau <= 0.0:
                # Overlapping already at the start (a contact deep and moving apart: a
                # spawn inside another body): nothing to locate; the step stands and
                # is projected.
                return self._accept(self._stands(state, h, t_end, trial))
            self.counters['located_steps'] += 1
            state = self._stands(state, tau, state.time + tau, located)
            events += 1

    def _in_margin(self, state: State) -> ContactRows:
        """
        Return the rows of the contacts a (partial) step from ``state`` may hold.

        Those touching under the accuracy knob (:attr:`unlocated` 0, every closure
        located), else every contact within the detector's margin (:meth:`_step_rows`).
        """
        if self.unlocated <= 0.0:
            return self.rows(state)
        con = self.detect(state)
        return self.rows(state, con, select=np.ones(len(con.depth), dtype=bool))

    def _step_rows(self, near: ContactRows) -> ContactRows:
        """
        Return the rows a (partial) step holds, of the contacts ``near`` (:meth:`_in_margin`).

        The touching contacts, moving apart too (their rows let them go: a ball's bounce
        flies on, and one slower than the step takes out ends on the ground), and the
        contacts apart within the detector's margin that close slower than
        :attr:`unlocated` (:data:`BOUNCE_SPEED`) at the step's start and slower than
        twice that at the end of its free step (:meth:`_held_step` drops the others):
        such a row asks the step to close at most the contact's gap (:meth:`_held_step`),
        so that a closure in the step, whether the step's own motion or a neighbour's
        held force makes it, is no event located but the step's own: inelastic and first
        order in its time (the time-stepping of Stewart and Trinkle), its depth at the
        end at most ``h v / 2`` and projected out there. So an impact approaching faster
        than twice the bounce speed is located and keeps Newton's law, one slower than
        the bounce speed is inelastic, and one between may be either (it depends on where
        in its step the closure falls). Under the accuracy knob (``unlocated`` 0) every
        closure is located and the rows are those touching and not moving apart.
        """
        if self.unlocated <= 0.0:
            return near.subset(near.vn <= self.rate)
        return near.subset((near.contacts.depth >= -self.location)
                           | (near.vn >= -self.unlocated))

    def _stands(self, state: State, h: float, t: float, trial: State) -> State:
        """
        Return the step of ``h`` from ``state`` that stands: the trial, or with joint events.

        With joints' events (limits, friction, drives' efforts) the step is taken again
        with them, its contact forces held: their bookkeeping changes only along
        steps that stand.
        """
        if self.sim.events is None:
            return trial
        return self._advance(state, h, t, accepted=True)

    def _held_step(self, state: State, rows: ContactRows, h: float, t_end: float) -> State:
        """
        Return the trial step of ``h`` from ``state`` to ``t_end`` with the rows' forces held.

        The forces stay in the wrench effect (for the location's partial steps and the
        step that stands) until :meth:`_accept` clears them. The LCP's affine model
        ``w = A p + q`` is the step's own response to first order; where the step,
        taken with the forces found, ends with the rows' velocities (at the end's
        geometry, :meth:`rows_at`) off the model's by more than
        :data:`MODEL_TOLERANCE`, the model's offset is corrected by what the step
        showed and the LCP solved again (at most :data:`MODEL_CORRECTIONS` times): a
        contact that should rest does, to rounding, instead of lifting by the model's
        error each step.
        """
        self._set_forces(None)
        free = self._advance(state, h, t_end)
        v_free = _stack(free.vel_com_world, free.ang_vel_principal)
        if len(rows):
            # A contact apart closing faster than twice the bounce speed at the free
            # step's end is an event located (:meth:`_step_rows`).
            drop = (rows.contacts.depth < -self.location) \
                & ((rows.G @ v_free)[0::3] < -2.0 * self.unlocated)
            if np.any(drop):
                rows = rows.subset(~drop)
        if not len(rows):
            self.record = ContactRecord(state.time, rows, np.zeros((0, 3)))
            return free
        A = self._step_response(state, rows, h, t_end, v_free)
        q = rows.G @ v_free
        # A row of a contact apart by its gap g, closing at v_n at the step's start, asks
        # the step to close at most g, h (v_n + v_n⁺) / 2 ≥ −g (the displacement under a
        # force steady over the step), and not to rebound: v_n⁺ ≥ min(0, −2 g / h − v_n).
        # So it carries no force unless the step would close it (by its own motion or a
        # neighbour's held force), and then it ends the step touching, or, closing
        # faster than the step can take out, at v_n⁺ = 0, at most h |v_n| / 2 deep.
        shift = np.zeros(len(q))
        depth = rows.contacts.depth
        shift[0::3] = np.where(depth < -self.location,
                               np.maximum(0.0, -2.0 * depth / h + rows.vn), 0.0)
        p = self.solve(A, q + shift, rows.mu, start=self._warm_start(rows),
                       sliding=rows.sliding, symmetric=self._symmetric)
        turned = self._slipping(rows, p, A @ p + q)
        if turned is not None:
            # Contacts that stuck at the start and slip over the step: their friction
            # along their slip (Coulomb's direction), not the pyramid's corner.
            rows = turned
            A = self._step_response(state, rows, h, t_end, v_free)
            q = rows.G @ v_free
            p = self.solve(A, q + shift, rows.mu, start=p, sliding=rows.sliding,
                           symmetric=self._symmetric)
        new = free
        force = np.zeros((len(rows), 3))
        for correction in range(MODEL_CORRECTIONS + 1):
            force = (p.reshape(-1, 3)[:, :, None] * rows.frame).sum(axis=1) / h   # (c, 3)
            if not np.any(p):
                self._set_forces(None)
                new = free
                break
            self._set_forces(rows, force)
            new = self._advance(state, h, t_end)
            w = self.rows_at(rows, new) @ _stack(new.vel_com_world, new.ang_vel_principal)
            offset = w - (A @ p + q)
            if correction == MODEL_CORRECTIONS or \
                    float(np.max(np.abs(offset))) <= MODEL_TOLERANCE * max(
                        float(np.max(np.abs(q))), self.rate):
                break
            self.counters['model_corrections'] += 1
            q = q + offset
            p = self.solve(A, q + shift, rows.mu, start=p, sliding=rows.sliding,
                           symmetric=self._symmetric)
        self._remember(rows, p)
        self.record = ContactRecord(state.time, rows, force)
        return new

    def _step_response(self, state: State, rows: ContactRows, h: float, t_end: float,
                       v_free: np.ndarray) -> np.ndarray:
        """
        Return the rows' Delassus operator over the step: the end velocities per impulse.

        ``G M̄⁻¹ Gᵀ`` (:meth:`response`) when every force but the contacts' is constant
        over the step, or the scene has no joints (free bodies' damping is weak over a
        step, ``c h / m``, and the model's corrections take it, as the compiled steps
        do). With joints and forces of the velocities or positions (servos, joint
        damping, the bodies' damping) the step answers a held force less than the
        masses alone would (a servo's damping flow takes ``1 − exp(−kd c h)`` of a
        joint's rate change back within the step: half of it at ``kd c h ≈ 1``), and a
        model built on the masses would leave the contacts' end velocities off by that
        fraction every step (the model's corrections shrinking it only by that ratio
        each). There each column is the step itself, taken again with a held impulse
        on that row alone (sized to change the row's velocity by 1 mm/s: the step is
        affine in it but for the rotations' turn, and the model's corrections take the
        rest). It is not symmetric (the splitting's flows act joint by joint, not on
        the mechanism's mass matrix): the solve takes it as it is (``symmetric``), a
        P-matrix near a symmetric one, for which its active-set method has no proof of
        termination but its cap (counted as a failure when reached).
        """
        A = rows.G @ self.response(state, rows.G)
        dyn = self.sim.dynamics
        self._symmetric = not (dyn.constrained
                               and any(e.velocity_dependent for e in dyn.effects))
        if self._symmetric:
            return A
        self.counters['stepped_responses'] += 1
        frame = rows.frame
        out = A.copy()
        # (a row no impulse moves, as the solve tells them, keeps its column: the solve
        # leaves it out)
        movable = np.diag(A) > 1e-12 * float(np.max(np.diag(A), initial=0.0))
        try:
            for r in np.flatnonzero(movable):
                size = 1e-3 / A[r, r]
                force = np.zeros((len(rows), 3))
                force[r // 3] = frame[r // 3, r % 3] * (size / h)
                self._set_forces(rows, force)
                new = self._advance(state, h, t_end)
                out[:, r] = rows.G @ (_stack(new.vel_com_world, new.ang_vel_principal)
                                      - v_free) / size
        finally:
            self._set_forces(None)
        return out

    def _slipping(self, rows: ContactRows, p: np.ndarray, w: np.ndarray
                  ) -> Optional[ContactRows]:
        """
        Return the rows with the contacts that begin to slip turned to their slip, or None.

        A contact sticking at the rows' state (two friction rows, the pyramid) whose
        friction ends on a bound with its point slipping at the step's end faster than
        the rate tolerance slips: its ``t₁`` is turned along that slip and it becomes
        a sliding contact (one friction row, ``|λ₁| ≤ μ λ_n``). So does one whose
        friction left Coulomb's cone inside the pyramid (a push along the pyramid's
        diagonal, up to ``√2 μ λ_n``): it slips against its friction. Where none
        turns and the operator is the step's own (servos), a sliding contact whose one
        row ends inside its bound stopped along its slip within the step, and sticks
        (both rows): with its one row nothing would hold it across its slip, and a foot
        under a servo slipped back and forth. (Free bodies keep its one row for that
        step, as the compiled steps do; it sticks from the next, slower than the rate.)
        """
        c = len(rows)
        if not c:
            return None
        bound = rows.mu * np.maximum(p[0::3], 0.0)
        # (a bound is the previous iterate's μ p_n: within the iteration's tolerance)
        slack = 2.0 * FRICTION_TOLERANCE * float(np.max(np.abs(p)))
        on = (np.abs(p[1::3]) >= bound - slack) | (np.abs(p[2::3]) >= bound - slack)
        slip = w[1::3, None] * rows.frame[:, 1] + w[2::3, None] * rows.frame[:, 2]
        speed = np.linalg.norm(slip, axis=1)
        # A sticking contact whose friction left the cone (the pyramid's corner: up to
        # √2 μ λ_n) cannot stick: it slips against its friction.
        friction = p[1::3, None] * rows.frame[:, 1] + p[2::3, None] * rows.frame[:, 2]
        size = np.linalg.norm(friction, axis=1)
        beyond = size > bound + slack
        slip = np.where((beyond & (speed <= self.rate))[:, None],
                        -friction / np.maximum(size, 1e-300)[:, None] * self.rate * 2.0, slip)
        speed = np.linalg.norm(slip, axis=1)
        turn = ~rows.sliding & (bound > 0.0) & ((on & (speed > self.rate)) | beyond)
        # Under a stepped operator (servos), a sliding contact whose one row ends inside
        # its bound stopped along its slip within the step: it sticks, both rows (else
        # nothing holds it across its slip).
        stop = rows.sliding & (bound > 0.0) & (np.abs(p[1::3]) < bound - slack)
        if not self._symmetric and np.any(stop) and not np.any(turn):
            return ContactRows(rows.state, rows.contacts, rows.frame, rows.lever_a,
                               rows.lever_b, rows.mu, rows.restitution, rows.G,
                               rows.sliding & ~stop, rows.vn)
        if not np.any(turn):
            return None
        frame, sliding = rows.frame.copy(), rows.sliding.copy()
        t1 = slip[turn] / speed[turn, None]
        nrm = frame[turn, 0]
        frame[turn] = np.stack([nrm, t1, cross(nrm, t1)], axis=1)
        sliding[turn] = True
        n = len(self.sim.bodies.names)
        con = rows.contacts
        G = _jacobian(frame, con.body_a, con.body_b, rows.lever_a, rows.lever_b,
                      self._rotations(rows.state), n)
        return ContactRows(rows.state, con, frame, rows.lever_a, rows.lever_b, rows.mu,
                           rows.restitution, G, sliding, rows.vn)

    def _set_forces(self, rows: Optional[ContactRows], force: Optional[np.ndarray] = None
                    ) -> None:
        """Put the rows' forces (c, 3, world, on a; −force on b) in the wrench effect."""
        dyn = self.sim.dynamics
        # The kernel work deferred so far was done with the wrenches as they were.
        dyn.settle_effect_work()
        if rows is None:
            if self.wrenches.clear():
                dyn.changed()
            return
        n = len(self.sim.bodies.names)
        f_body, t_body = np.zeros((n + 1, 3)), np.zeros((n + 1, 3))
        con = rows.contacts
        np.add.at(f_body, con.body_a, force)
        np.add.at(t_body, con.body_a, cross(rows.lever_a, force))
        np.add.at(f_body, con.body_b, -force)
        np.add.at(t_body, con.body_b, -cross(rows.lever_b, force))
        acted = np.flatnonzero(np.any(f_body[:n] != 0.0, axis=1)
                               | np.any(t_body[:n] != 0.0, axis=1))
        self.wrenches.act(acted, f_body[acted], t_body[acted])
        dyn.changed()

    def _warm_start(self, rows: ContactRows) -> Optional[np.ndarray]:
        """
        Return last step's normal impulses of the same contacts, or None.

        The same pair of shapes, the point within :data:`.kernels.contact_step.WARM_RADIUS2`
        (m²) of the last one's; the first such (in the last step's order).
        """
        sa, sb, point, p_n = self._warm
        if not len(p_n):
            return None
        con = rows.contacts
        same = (con.shape_a[:, None] == sa[None, :]) & (con.shape_b[:, None] == sb[None, :]) \
            & (np.sum((con.point[:, None, :] - point[None, :, :]) ** 2, axis=2)
               <= kern.WARM_RADIUS2)
        out = np.zeros(3 * len(rows))
        has = np.any(same, axis=1)
        out[0::3][has] = p_n[np.argmax(same, axis=1)[has]]
        return out

    def _remember(self, rows: ContactRows, p: np.ndarray) -> None:
        con = rows.contacts
        self._warm = (con.shape_a.copy(), con.shape_b.copy(), con.point.copy(),
                      p[0::3].copy())

    # -- compiled steps -------------------------------------------------------------------

    def compiled_steps(self, start: State, n: int, base: float, steps: int) -> tuple:
        """
        Take up to ``n`` steps from ``start`` in the compiled kernel; return ``(taken, state)``.

        Scenes of free bodies with the knob off (:mod:`.kernels.contact_step`): the
        same steps as :meth:`step`, the ``k``-th (from 0) ending at ``base + (steps + k +
        1) dt`` (the simulation's clock), until one meets what the kernel gives back (a
        row no force moves), which :meth:`step` then takes. A step whose impacts the
        kernel's log cannot take ends the call before it (the log read, the next call
        takes it); one whose impacts alone overflow it grows the log.
        Elsewhere (joints, the knob, ``compiled`` False): ``(0, start)``.
        """
        sim = self.sim
        dyn = sim.dynamics
        if not self.compiled or sim.events is not None or sim._control is not None \
                or dyn.constrained or n < 1:
            return 0, start
        self.tighten()
        self._set_forces(None)
        dt = sim.dt
        model = dyn.kernel_model(start.time + 0.5 * dt)
        wbuf, det, out, prm, minv = self._kernel_arguments(model)
        integ = sim.integrator
        cnt = np.zeros(len(kern.COUNTERS))
        before = dyn.defer_effect_work() if dyn.effects else None
        while True:
            taken, code, y, warm, rec, logged = kern.contact_steps(
                n, start.y, start.time, base, steps, dt, int(integ.KERNEL),
                (model[0], model[1], wbuf), len(model[2]), model[3], integ._kick_buffer,
                dyn.tally, STEPS, integ._ws, dyn.bodies.outputs_cache.frames, out,
                self._detector_table(det), self._mu, self._e, self._radius, self._warm, prm,
                cnt, self._log, minv)
            if code not in (kern.GROW, kern.FULL) or taken:
                break
            if code == kern.GROW:
                self._grow()
            else:   # (this step's impacts alone overflow the log)
                self._log = np.zeros((2 * len(self._log), 5))
        if before is not None:
            dyn.count_effect_work_since(before)
        # (Charged now, with the contact effect empty: its compiled wrenches are not counted
        # as its evaluations; the other effects' work is.)
        dyn.settle_effect_work()
        integ._kick_at = None
        if not taken:
            return 0, start
        self._add_counters(cnt)
        self.counters['compiled_steps'] += taken
        shapes = self.detector.shapes
        for time, a, b, approach, rebound in self._log[:logged].tolist():
            self.impacts.append(ContactImpact(time, shapes[int(a)].name, shapes[int(b)].name,
                                              approach, rebound))
        self._warm = warm
        sel, force, con, y_rec, t_rec = rec
        self._lazy = (State.of(t_rec, y_rec), Contacts(*con[1:]), sel, force)
        new = State.of(base + (steps + taken) * dt, y)
        if dyn.bodies.want_outputs():
            c = dyn.bodies.outputs_cache
            state_outputs(y, c.frames, c.out)
            c.adopt(new)
        return taken, new

    def _kernel_arguments(self, model: tuple) -> tuple:
        """Return the kernel's ``wbuf``, ``det``, ``out``, ``prm``, ``minv`` (kept while valid)."""
        d = self.detector
        key = self._kernel_key
        if key is not None and key[0] is model and key[1] is d.excluded \
                and key[2] == (self.location, self.rate, self.bounce, self.unlocated,
                               self.sparse_contacts):
            return self._kernel_args
        n = len(self.sim.bodies.names)
        wrench = model[2]
        wbuf = np.zeros((len(wrench) + n, W_WIDTH))
        wbuf[:len(wrench)] = wrench
        det = (d.kind, d.size, d.c_body, d.R_body, d.body, d.group, d.mask, d._solids,
               d._planes, d._solid_body, d._solid_group, d._solid_mask, d.excluded, d.live,
               float(d.margin), d.hulls, d.hull_at)
        body = model[0]
        minv = np.empty((n, 6))   # (per body: 1/m three times, then 1/J by principal axis)
        minv[:, :3] = body[:, B_INV_MASS:B_INV_MASS + 1]
        minv[:, 3:] = 1.0 / body[:, B_MOMENTS:B_MOMENTS + 3]
        self._kernel_args = (wbuf, det, np.zeros((n, O_WIDTH)), self.kernel_parameters(), minv)
        self._kernel_key = (model, d.excluded,
                            (self.location, self.rate, self.bounce, self.unlocated,
                             self.sparse_contacts))
        return self._kernel_args

    def kernel_parameters(self) -> np.ndarray:
        """Return the tolerances and limits the compiled steps take (``prm``, ``P_*``)."""
        prm = np.zeros(kern.P_WIDTH)
        prm[kern.P_LOCATION], prm[kern.P_RATE] = self.location, self.rate
        prm[kern.P_FRICTION_TOLERANCE] = FRICTION_TOLERANCE
        prm[kern.P_FRICTION_ITERATIONS] = FRICTION_ITERATIONS
        prm[kern.P_STALL_ITERATIONS] = STALL_ITERATIONS
        prm[kern.P_NEWTON_ITERATIONS] = NEWTON_ITERATIONS
        prm[kern.P_NEWTON_REFINEMENTS] = NEWTON_REFINEMENTS
        prm[kern.P_PROXIMAL], prm[kern.P_MODEL_TOLERANCE] = PROXIMAL, MODEL_TOLERANCE
        prm[kern.P_MODEL_CORRECTIONS], prm[kern.P_HOLD_RATE] = MODEL_CORRECTIONS, HOLD_RATE
        prm[kern.P_RATE_FLOOR] = RATE_FLOOR
        prm[kern.P_MAX_EVENTS], prm[kern.P_MAX_BOUNCES] = MAX_EVENTS, MAX_BOUNCES
        prm[kern.P_MAX_LOCATION_ITERATIONS] = MAX_LOCATION_ITERATIONS
        prm[kern.P_RESIDUAL_TOLERANCE] = RESIDUAL_TOLERANCE
        prm[kern.P_PROJECTION_PASSES] = PROJECTION_PASSES
        prm[kern.P_PIVOT_TOLERANCE] = PIVOT_TOLERANCE
        prm[kern.P_PIVOT_REGULARIZATION_1], prm[kern.P_PIVOT_REGULARIZATION_2] = \
            PIVOT_REGULARIZATIONS
        prm[kern.P_BOUNCE], prm[kern.P_UNLOCATED] = self.bounce, self.unlocated
        prm[kern.P_SPARSE_CONTACTS] = self.sparse_contacts
        prm[kern.P_SPARSE_PROXIMAL] = SPARSE_PROXIMAL
        prm[kern.P_SPARSE_RESIDUAL] = SPARSE_RESIDUAL
        prm[kern.P_SPARSE_ITERATIONS] = SPARSE_ITERATIONS
        prm[kern.P_SPARSE_INNER], prm[kern.P_PGS_SWEEPS] = SPARSE_INNER, PGS_SWEEPS
        prm[kern.P_SPARSE_HISTORY] = SPARSE_HISTORY
        prm[kern.P_PIVOT_CONTACTS] = PIVOT_CONTACTS
        prm[kern.P_PIVOT_LAST_CONTACTS] = PIVOT_LAST_CONTACTS
        return prm

    def _buffers(self) -> tuple:
        """Return the detector's buffers and the kernel's scratch for its shapes' frames."""
        d = self.detector
        scratch = self._scratch
        if scratch is None:
            m, ms = len(d.live), len(d._solids)
            scratch = self._scratch = (np.empty((ms, 3)), np.empty((ms, 3)), np.empty((m, 3)),
                                       np.empty((m, 3, 3)))
        return (d._pairs, d._plane_pairs, d._points, d._normals, d._depths, d._owner) + scratch

    def _detector_table(self, det: tuple) -> np.ndarray:
        """
        Return ``det`` and the detector's buffers as the kernel's one table.

        (:data:`.kernels.contact_step.DT_ARRAYS`; made again when any of them is another
        array: the buffers grown, ``det`` made again by :meth:`_kernel_arguments`.)
        """
        buf = self._buffers()
        kept = self._dtab
        if kept is not None and kept[0] is det and all(a is b for a, b in zip(kept[1], buf)):
            return kept[2].table
        arrays = det[:14] + (np.array([det[14]]),) + det[15:] + buf
        dims = []
        for a in arrays:
            dims += list(a.shape) + [0] * (3 - a.ndim)
        table = Pinned(arrays, dims)
        self._dtab = (det, buf, table)
        return table.table

    def _grow(self) -> None:
        """Double the detector's buffers (the kernel found them too small)."""
        d = self.detector
        d._pairs = np.zeros((2 * len(d._pairs), 2), dtype=np.int64)
        d._plane_pairs = np.zeros((2 * len(d._plane_pairs), 2), dtype=np.int64)
        cap = 2 * len(d._depths)
        d._points, d._normals = np.zeros((cap, 3)), np.zeros((cap, 3))
        d._depths, d._owner = np.zeros(cap), np.zeros(cap, dtype=np.int64)

    # -- impacts --------------------------------------------------------------------------

    def _new_overlap(self, rows: ContactRows, new: State) -> Optional[tuple]:
        """
        Return the event of ``new`` when a contact not touching at the step's start overlaps.

        ``(depth, contacts)``: the deepest such contact's depth at ``new`` beyond the
        tolerance, or None. A contact continues one touching at the start when it is of
        the same pair of shapes and its point, in body a's frame, is within
        a quarter of its shape's smallest half size of that one's.
        """
        con = self.detect(new)
        depth = self._unmatched_depth(rows, con, new)
        if depth is None or depth <= self.location:
            return None
        return depth, con

    def _unmatched_depth(self, rows: ContactRows, con: Contacts, state: State
                         ) -> Optional[float]:
        """Return the deepest depth at ``state`` of contacts not continuing a row (None: none)."""
        if not len(con.depth):
            return None
        fresh = ~self._known(rows, con, state)
        if not np.any(fresh):
            return None
        return float(np.max(con.depth[fresh]))

    def _known(self, rows: ContactRows, con: Contacts, state: State) -> np.ndarray:
        """
        Tell per contact of ``con`` at ``state`` whether it is not new in this (partial) step.

        It continues a row, or an overlap the step started from (:meth:`_overlapping`).
        """
        known = self._continuing(rows, np.ones(len(rows), dtype=bool), con, state)
        if self._overlaps is not None:
            known |= self._continuing(self._overlaps, np.ones(len(self._overlaps), dtype=bool),
                                      con, state)
        return known

    def _overlapping(self, state: State, rows: ContactRows) -> Optional[ContactRows]:
        """
        Return the contacts deeper than the tolerance at ``state`` that are not rows, or None.

        A contact moving apart from an overlap (one a step's end left for its projection,
        jammed in a pile): not an impact to locate, and not the new contact whose depth
        the location follows. Counted as new, it would stop every location in the step
        (the step would stand from its start, :meth:`_locate`'s ``τ = 0``).
        """
        con = self.detect(state)
        deep = con.depth > self.location
        if not np.any(deep):
            return None
        deep &= ~self._continuing(rows, np.ones(len(rows), dtype=bool), con, state)
        return self.rows(state, con, select=deep) if np.any(deep) else None

    def _continuing(self, rows: Optional[ContactRows], which: np.ndarray, con: Contacts,
                    state: State) -> np.ndarray:
        """Tell per contact of ``con`` at ``state`` whether it continues any of rows ``which``."""
        if rows is None or not len(rows) or not np.any(which) or not len(con.depth):
            return np.zeros(len(con.depth), dtype=bool)
        return np.any(self._near(rows, which, con, state), axis=0)

    def _near(self, rows: ContactRows, which: np.ndarray, con: Contacts,
              state: State) -> np.ndarray:
        """
        Return (r, c) bool: row ``r`` (of ``which``) and contact ``c`` are the same contact.

        The same pair of shapes, and the contact's point, in body a's frame at
        ``state``, within a quarter of shape a's smallest half size of the row's at the
        rows' state (a sliding contact moves less in a step).
        """
        return self._distances(rows, which, con, state)[0]

    def _distances(self, rows: ContactRows, which: np.ndarray, con: Contacts,
                   state: State) -> tuple:
        """Return :meth:`_near` and the squared distances (r, c) of the points in body a."""
        start = rows.contacts
        count = len(self.detector.shapes) + 1
        key_start = start.shape_a * count + start.shape_b
        key_now = con.shape_a * count + con.shape_b
        local_start = self._in_body(start.point, start.body_a, rows.state)
        local_now = self._in_body(con.point, con.body_a, state)
        d2 = np.sum((local_start[:, None, :] - local_now[None, :, :]) ** 2, axis=2)
        radius = self._radius[con.shape_a]
        near = which[:, None] & (key_start[:, None] == key_now[None, :]) \
            & (d2 <= radius[None, :] ** 2)
        return near, d2

    def _match(self, rows: ContactRows, which: np.ndarray, con: Contacts,
               state: State) -> np.ndarray:
        """Return, per row, the nearest contact of ``con`` continuing it (−1: none)."""
        out = np.full(len(rows), -1, dtype=int)
        if not len(rows) or not len(con.depth):
            return out
        near, d2 = self._distances(rows, which, con, state)
        d2 = np.where(near, d2, np.inf)
        best = np.argmin(d2, axis=1) if d2.shape[1] else np.zeros(len(rows), dtype=int)
        has = np.isfinite(d2[np.arange(len(rows)), best])
        out[has] = best[has]
        return out

    def _in_body(self, points: np.ndarray, body: np.ndarray, state: State) -> np.ndarray:
        """Return world ``points`` (k, 3) in their bodies' principal frames at ``state``."""
        n = len(self.sim.bodies.names)
        out = points.copy()
        real = body < n
        if np.any(real):
            R = self._rotations(state)[body[real]]
            out[real] = np.einsum('kji,kj->ki', R,
                                  points[real] - state.pos_com_world[body[real]])
        return out

    def _locate(self, state: State, touching: ContactRows, h: float, hit: tuple) -> tuple:
        """
        Return ``(state, τ)``: where the first new contact's depth crossed zero, ``τ`` in.

        Regula falsi (Illinois) on the deepest new contact's depth over partial trial
        steps from ``state`` with the same forces held, until the depth is within the
        tolerance and the new contact closes; ``τ = 0`` when it overlaps already at
        ``state`` (nothing to locate).
        """
        t0 = state.time
        start_depth = self._depth_at(touching, state)
        if start_depth > self.location:
            return state, 0.0
        # At the start the new contact is apart, or touching and moving apart (a bounce
        # that returns): its depth there counts as below the tolerance.
        lo_t, lo_g = 0.0, min(start_depth, -self.location)
        hi_t, hi_g = h, hit[0]
        side = 0
        best, best_t = None, 0.0
        for _ in range(MAX_LOCATION_ITERATIONS):
            tau = (lo_t * hi_g - hi_t * lo_g) / (hi_g - lo_g)
            if not lo_t < tau < hi_t:
                tau = 0.5 * (lo_t + hi_t)
            trial = self._advance(state, tau, t0 + tau)
            g = self._depth_at(touching, trial)
            if abs(g) <= self.location:
                if self._approaching(touching, trial):
                    return trial, tau
                g = -self.location   # (leaving still: a bounce's start, before the crossing)
            if g > 0.0:
                hi_t, hi_g = tau, g
                if side == 1:
                    lo_g *= 0.5
                side = 1
            else:
                lo_t, lo_g = tau, g
                if side == -1:
                    hi_g *= 0.5
                side = -1
                best, best_t = trial, tau
        if best is None:   # (never closer than the tolerance: the last state before it)
            return state, 0.0
        return best, best_t

    def _approaching(self, touching: ContactRows, state: State) -> bool:
        """Tell whether a new contact (continuing none of ``touching``) closes at ``state``."""
        con = self.detect(state)
        near = con.depth >= -self.location
        fresh = near & ~self._known(touching, con, state)
        if not np.any(fresh):
            return False
        rows = self.rows(state, con, select=fresh)
        return bool(np.any(rows.vn < -self.rate))

    def _depth_at(self, rows: ContactRows, state: State) -> float:
        """Return the deepest new contact's depth at ``state`` (−margin when none is near)."""
        depth = self._unmatched_depth(rows, self.detect(state), state)
        return -self.detector.margin if depth is None else depth

    def _impact(self, state: State, rows: ContactRows, inelastic: bool) -> tuple:
        """
        Resolve the impacts at ``state``: touching contacts approaching faster than the rate.

        Returns ``(state, hit)``. The impulses' LCP (module docstring): normal rows
        ``v_n⁺ ≥ −e v_n⁻``, friction within ``μ p_n``; ``inelastic``: ``e = 0``.
        """
        v = _stack(state.vel_com_world, state.ang_vel_principal)
        rel = rows.G @ v
        vn = rel[0::3]
        approach = vn < -self.rate
        if not np.any(approach):
            return state, False
        e = np.zeros(len(rows)) if inelastic else np.where(vn < -self.bounce,
                                                           rows.restitution, 0.0)
        target = np.where(approach, e * vn, 0.0)   # w_n = v_n⁺ + e v_n⁻ ≥ 0
        q = rel.copy()
        q[0::3] += target
        Y = self.response(state, rows.G)
        A = rows.G @ Y
        p = self.solve(A, q, rows.mu, sliding=rows.sliding)
        dv = Y @ p
        after = (rel + rows.G @ dv)[0::3]
        n = len(self.sim.bodies.names)
        dv = dv.reshape(n, 6)
        self.counters['impacts'] += int(np.count_nonzero(approach))
        shapes, con = self.detector.shapes, rows.contacts
        for k in np.flatnonzero(approach):
            self.impacts.append(ContactImpact(state.time, shapes[con.shape_a[k]].name,
                                              shapes[con.shape_b[k]].name, float(vn[k]),
                                              float(after[k])))
        return State(state.time, state.pos_com_world, state.quat_principal_world,
                     state.vel_com_world + dv[:, :3], state.ang_vel_principal + dv[:, 3:]), True

    # -- the accepted step ----------------------------------------------------------------

    def _accept(self, new: State) -> State:
        """
        Clear the forces and correct the contacts' positions at the step's end.

        Contacts deeper than the tolerance are pushed out (``depth ≥ 0``: the smallest
        pushes, an LCP), and those continuing a row that pushed over the step and left
        apart from it are brought back (``depth = 0``): a constant force over a step
        holds a contact whose force varies only to first order (a box tipping on its
        edge rises by ``O(h³)`` a step), and a contact that carries a load stays on its
        surface, as a joint's rows are held by the projection. Positions first; then
        the loaded contacts' normal velocities, where they are off zero by less than
        :data:`HOLD_RATE` (the model's error, not the physics: the LCP ended them at
        zero), are set to zero by the same mass-weighted projection. Counted: the
        deepest depth, the projections, the rates held, the deepest depth it ends with.
        """
        self._set_forces(None)
        con = self.detect(new)
        rec = self.record
        try:
            return self._settle(new, con, rec)
        finally:
            # What reads the model between steps (joint reactions, efforts) sees the
            # forces the step's last part held; the next step's trial clears them.
            if rec.rows is not None and len(rec.rows) and np.any(rec.force):
                self._set_forces(rec.rows, rec.force)

    def _settle(self, new: State, con: Contacts, rec: ContactRecord) -> State:
        """Return ``new`` with its contacts' positions and loaded rates corrected."""
        active = None
        if rec.rows is not None and len(rec.rows):
            active = np.sum(rec.force * rec.rows.contacts.normal, axis=1) > 0.0
        held = self._continuing(rec.rows, active, con, new) if active is not None \
            else np.zeros(len(con.depth), dtype=bool)
        for passes in range(PROJECTION_PASSES + 1):
            deep = con.depth > self.location
            lift = held & (con.depth < -self.location)
            if not (np.any(deep) or np.any(lift)):
                break
            left = float(np.max(np.where(deep, con.depth, 0.0)
                                - np.where(lift, con.depth, 0.0)))
            if passes == PROJECTION_PASSES:   # what the passes left (counted)
                self.counters['projection_left'] = max(self.counters['projection_left'], left)
                break
            if passes == 0 and np.any(deep):
                self.counters['max_depth'] = max(self.counters['max_depth'],
                                                 float(np.max(con.depth)))
            # The rows: the contacts touching or overlapping, and those apart by less
            # than the deepest overlap or the widest lift, as rows that may not close (a
            # push that takes one overlap out would otherwise drive a neighbour that
            # nearly touches into another: in a pile of 1000 spheres each pass left new
            # overlaps, and the steps' leftovers grew to 4 mm; and a lifted loaded
            # contact pulled back drove neighbours 1e-7 m apart 8e-5 m deep).
            reach = max(self.location, float(np.max(con.depth)), left)
            select = held | (con.depth >= -reach)
            rows = self.rows(new, con, select=select)
            Y = self.response(new, rows.G)
            A = rows.G @ Y
            q3 = np.zeros(3 * len(rows))
            q3[0::3] = -rows.contacts.depth
            # Lifted loaded contacts are pulled back to their surface (an equality); the
            # others pushed out (``depth ≥ 0``): held at zero too, a jammed pile's
            # contacts could leave no push that takes its depth out.
            p = self.solve(A, q3, rows.mu, normal_only=True, equal=lift[select])
            if not np.any(p):   # no push takes it out (a row no force moves: left, counted)
                self.counters['projection_left'] = max(self.counters['projection_left'], left)
                break
            if passes == 0:
                self.counters['projections'] += 1
            dq = (Y @ p).reshape(-1, 6)
            self.counters['max_projected'] = max(self.counters['max_projected'],
                                                 float(np.max(np.abs(rows.contacts.depth))))
            quat = quat_multiply(new.quat_principal_world, exp_quat(dq[:, 3:]))
            new = State(new.time, new.pos_com_world + dq[:, :3], quat, new.vel_com_world,
                        new.ang_vel_principal)
            con = self.detect(new)
            held = self._continuing(rec.rows, active, con, new)
        # (the deepest overlap a step ends with: what a user sees of penetration)
        self.counters['end_depth'] = max(self.counters['end_depth'],
                                         float(np.max(con.depth, initial=0.0)))
        if not np.any(held):
            return new
        rows = self.rows(new, con, select=held)
        near = np.abs(rows.vn) <= HOLD_RATE
        if not np.any(near & (np.abs(rows.vn) > RATE_FLOOR)):
            return new
        rows = rows.subset(near)   # (every loaded contact near zero held at zero together)
        Y = self.response(new, rows.G)
        A = rows.G @ Y
        q3 = np.zeros(3 * len(rows))
        q3[0::3] = rows.vn
        p = self.solve(A, q3, rows.mu, normal_only=True, equal=np.ones(len(rows), dtype=bool))
        dv = (Y @ p).reshape(-1, 6)
        self.counters['held_rates'] += 1
        return State(new.time, new.pos_com_world, new.quat_principal_world,
                     new.vel_com_world + dv[:, :3], new.ang_vel_principal + dv[:, 3:])


_NO_WARM = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 3)),
            np.zeros(0))


def islands(A: np.ndarray) -> list:
    """
    Return the contacts' islands: index arrays, each ascending, ordered by their first.

    Contacts ``k`` and ``l`` are joined when ``A``'s block (rows ``3k..3k+2``, columns
    ``3l..3l+2``) or its transpose has a non-zero; islands are the connected parts
    (:func:`.kernels.contact_step.islands` finds the same).
    """
    c = len(A) // 3
    if c <= 1:
        return [np.arange(c)]
    block = np.any(A.reshape(c, 3, c, 3) != 0.0, axis=(1, 3))
    block |= block.T
    label = np.full(c, -1)
    count = 0
    for k in range(c):
        if label[k] >= 0:
            continue
        label[k] = count
        todo = [k]
        while todo:
            j = todo.pop()
            for n in np.flatnonzero(block[j] & (label < 0)):
                label[n] = count
                todo.append(int(n))
        count += 1
    return [np.flatnonzero(label == g) for g in range(count)]


def _jacobian(frame: np.ndarray, a: np.ndarray, b: np.ndarray, lever_a: np.ndarray,
              lever_b: np.ndarray, R_all: np.ndarray, n: int) -> np.ndarray:
    """
    Return the rows' ``G`` (3c, 6n): each contact's frame rows on its point of a less b.

    ``R_all`` (n + 1, 3, 3) the principal-to-world rotations and the world's identity;
    a row ``d`` on body ``i`` with lever ``r`` is ``d`` on ``v`` and ``Rᵀ (r × d)`` on
    ``Ω`` (``(r × d) · ω``).
    """
    c = len(a)
    G = np.zeros((3 * c, 6 * (n + 1)))
    rows = np.arange(3 * c)
    d = frame.reshape(3 * c, 3)
    for side, body, lever in ((1.0, a, lever_a), (-1.0, b, lever_b)):
        body3 = np.repeat(body, 3)
        ang = np.einsum('ki,kij->kj', cross(np.repeat(lever, 3, axis=0), d), R_all[body3])
        cols = 6 * body3[:, None] + np.arange(6)[None, :]
        np.add.at(G, (rows[:, None], cols), side * np.concatenate([d, ang], axis=1))
    return G[:, :6 * n]


def _stack(vel: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Return the bodies' velocities as one vector (6n,): per body ``v`` then ``Ω``."""
    return np.hstack([vel, omega]).reshape(-1)


def _any_tangent(nrm: np.ndarray) -> np.ndarray:
    """Return unit vectors (c, 3) perpendicular to the unit normals ``nrm`` (c, 3)."""
    helper = np.eye(3)[np.argmin(np.abs(nrm), axis=1)]
    t = cross(nrm, helper)
    return t / np.linalg.norm(t, axis=1)[:, None]


def _pyramid(A: np.ndarray, q: np.ndarray, mu: np.ndarray, sliding: Optional[np.ndarray],
             pinned: np.ndarray, regularization: float) -> tuple:
    """
    Solve the contact rows ``w = A p + q`` (normal, t₁, t₂ per contact) by Lemke's method.

    The friction box ``|p_t| ≤ μ p_n`` of each row (a sliding contact's ``t₁`` alone,
    pinned rows held at zero) in Stewart and Trinkle's form: ``p_t = p⁺ − p⁻`` with
    ``w_t + β ≥ 0 ⊥ p⁺ ≥ 0``, ``−w_t + β ≥ 0 ⊥ p⁻ ≥ 0`` and ``μ p_n − p⁺ − p⁻ ≥ 0 ⊥ β ≥
    0``: one LCP in ``(p_n, p⁺, p⁻, β)``, its boxes exact in it (no fixed point on
    them). ``A`` takes ``regularization`` of its largest diagonal on its diagonal (a
    compliance that moves ``w`` by that fraction of ``A p``): redundant contacts
    otherwise leave the pivoting degenerate enough to end on a ray. Returns
    ``(p, ok)``.
    """
    A = A + regularization * float(np.max(np.diag(A))) * np.eye(len(q))
    c = len(q) // 3
    normal = np.arange(0, 3 * c, 3)
    one_row = np.zeros(c, dtype=bool) if sliding is None else sliding   # (t₁ alone)
    rows = [3 * k + col for k in range(c) for col in (1, 2)
            if not pinned[3 * k + col] and not (col == 2 and one_row[k])]
    f = np.array(rows, dtype=int)
    r = len(f)
    own = f // 3
    Ann, Anf, Afn, Aff = (A[np.ix_(normal, normal)], A[np.ix_(normal, f)],
                          A[np.ix_(f, normal)], A[np.ix_(f, f)])
    U = np.zeros((r, c))
    U[np.arange(r), own] = mu[own]
    eye, zero = np.eye(r), np.zeros
    M = np.block([[Ann, Anf, -Anf, zero((c, r))],
                  [Afn, Aff, -Aff, eye],
                  [-Afn, -Aff, Aff, eye],
                  [U, -eye, -eye, zero((r, r))]])
    z, ok = lemke(M, np.concatenate([q[normal], q[f], -q[f], np.zeros(r)]))
    p = np.zeros(3 * c)
    p[normal] = z[:c]
    p[f] = z[c:c + r] - z[c + r:c + 2 * r]
    return p, ok


def _newton(A: np.ndarray, q: np.ndarray, mu: np.ndarray, sliding: Optional[np.ndarray],
            pinned: np.ndarray, p: np.ndarray) -> tuple:
    """
    Solve the contact rows ``w = A p + q`` by Newton's method on their natural map.

    The rows' conditions (those :func:`_residual` measures) as the fixed point of the
    natural map: ``p_n = max(0, y_n)``, ``p_t = clip(y_t, ±μ p_n)`` with ``y = p −
    w / diag(A)``. Each iteration guesses from ``y`` which normal rows carry a load,
    which friction rows are on their bound ``p_t = ±μ p_n`` (a linear function of
    their normal row's impulse: the coupling the boxes' fixed point takes one
    iteration at a time) and which are inside it, and solves that guess's linear
    system exactly: ``w = 0`` on the loaded normal rows and the friction rows inside
    their bounds (a semi-smooth Newton step, or a primal–dual active-set step). Where
    the guess holds, the solution does, to rounding. The guesses may cycle (friction
    makes the rows' matrix no P-matrix: measured, a cycle of three guesses in a poured
    pile of 125 spheres): then it fails and the caller pivots. A guess that repeats
    without meeting the bar has no exact solution (redundant rows ask a contact to
    stick where the others forbid its motion: a finger's tangent along the face of a box
    the ground holds): its friction row inside the bound that keeps the most slip is
    put on the bound opposing that slip (Coulomb's sliding, at that slip) and held there
    while the natural map would put it inside; with none left to put, it fails. Redundant
    contacts make the system singular (their load sharing is not
    unique): each solve is proximal, ``(K + ρ I) δ = r`` with ``ρ`` :data:`PROXIMAL` of
    the diagonal, refined :data:`NEWTON_REFINEMENTS` times on the same factors, so the
    step leaves the null space where the start has it. Returns ``(p, ok)``: ``ok`` when
    the result meets :data:`PIVOT_TOLERANCE` (as a pivoted solve must), within
    :data:`NEWTON_ITERATIONS` guesses.
    """
    m = len(q)
    c = m // 3
    d = np.diag(A)
    one_row = np.zeros(c, dtype=bool) if sliding is None else sliding
    present = ~pinned.copy()
    present[2::3] &= ~one_row
    present[1::3] &= mu > 0.0
    present[2::3] &= mu > 0.0
    owner = np.arange(m) // 3
    previous = None
    forced = np.zeros(m, dtype=int)
    for _ in range(NEWTON_ITERATIONS):
        w = A @ p + q
        y = p - w / d
        load = y[0::3] > 0.0
        bound = mu * np.maximum(y[0::3], 0.0)
        # Per row: 1 unknown, ±2 on its bound +μ p_n or −μ p_n, 0 held at zero.
        kind = np.zeros(m, dtype=int)
        kind[0::3] = np.where(load, 1, 0)
        for col in (1, 2):
            yt = y[col::3]
            on = np.where(yt >= bound, 2, np.where(yt <= -bound, -2, 1))
            on = np.where((on == 1) & (forced[col::3] != 0), forced[col::3], on)
            kind[col::3] = np.where(present[col::3] & load, on, 0)
        unknown = np.flatnonzero(kind == 1)
        T = np.zeros((m, len(unknown)))
        T[unknown, np.arange(len(unknown))] = 1.0
        at = np.flatnonzero(np.abs(kind) == 2)
        column = np.full(m, -1)
        column[unknown] = np.arange(len(unknown))
        T[at, column[3 * owner[at]]] = np.sign(kind[at]) * mu[owner[at]]
        K = A[unknown] @ T
        z = p[unknown]
        if len(unknown):
            rho = PROXIMAL * float(np.max(np.abs(np.diag(K))))
            factors = scipy.linalg.lu_factor(K + rho * np.eye(len(unknown)),
                                             check_finite=False)
            if not np.all(np.diag(factors[0])):   # (a zero pivot: as the kernel, none)
                return p, False
            step = np.zeros(len(unknown))
            for _refinement in range(NEWTON_REFINEMENTS + 1):
                step = step + scipy.linalg.lu_solve(factors, -q[unknown] - K @ (z + step))
            z = z + step
        p = T @ z
        if _residual(A, q, p, mu, False, sliding, None, pinned) \
                <= PIVOT_TOLERANCE * float(np.max(np.abs(A) @ np.abs(p) + np.abs(q))):
            return p, True
        if previous is not None and np.array_equal(kind, previous):
            # The guess repeats and its system has no exact solution: redundant rows ask
            # a contact to stick that the others let slip (a finger's tangent along the
            # ground's normal). Its friction row inside the bound that keeps the most
            # slip goes on the bound opposing the slip (Coulomb's sliding), and stays
            # there while the natural map puts it inside.
            w = A @ p + q
            inside = np.flatnonzero((kind == 1) & (np.arange(m) % 3 != 0) & (forced == 0))
            if not len(inside):
                return p, False
            j = inside[np.argmax(np.abs(w[inside]))]
            if w[j] == 0.0:
                return p, False
            forced[j] = -2 if w[j] > 0.0 else 2
            previous = None
            continue
        previous = kind
    return p, False


def _one_contact(A: np.ndarray, q: np.ndarray, mu: float, sliding: bool
                 ) -> Optional[np.ndarray]:
    """
    Return one contact's impulses (3,) solved exactly by their cases, or None.

    As ``kernels.contact_step._one_contact``: apart (``p = 0``), and pressed
    (``w_n = 0``) with each friction row inside its bound (``w_t = 0``) or on it
    (``p_t = ±μ p_n``; ``sliding``: ``t₂`` held at zero); of those whose impulses meet
    the contact conditions to :data:`RESIDUAL_TOLERANCE` of the rows' scale, the one of
    least normal impulse (a large ``μ`` coupled through the lever can admit two). None:
    none does (the fixed point solves it).
    """
    mus, slid = np.array([mu]), np.array([sliding])
    cases = [None] + [(s1, s2) for s1 in (0, 1, -1) for s2 in ((0,) if sliding else (0, 1, -1))]
    best = None
    for case in cases:
        p = np.zeros(3)
        if case is not None:
            v = np.array([1.0, case[0] * mu, 0.0 if sliding else case[1] * mu])
            free = [t for t in (1, 2) if case[t - 1] == 0 and not (t == 2 and sliding)]
            rows = [0] + free
            M = np.column_stack([A[rows] @ v] + [A[rows, t] for t in free])
            try:
                x = np.linalg.solve(M, -q[rows])
            except np.linalg.LinAlgError:
                continue
            p = x[0] * v
            p[free] = x[1:]
            if not p[0] > 0.0 or (best is not None and not p[0] < best[0]):
                continue
        if _residual(A, q, p, mus, False, slid) \
                <= RESIDUAL_TOLERANCE * float(np.max(np.abs(A) @ np.abs(p) + np.abs(q))):
            best = p
            if case is None:
                break   # (apart: no impulse is less)
    return best


def _residual(A: np.ndarray, q: np.ndarray, p: np.ndarray, mu: np.ndarray,
              normal_only: bool, sliding: Optional[np.ndarray] = None,
              equal: Optional[np.ndarray] = None,
              pinned: Optional[np.ndarray] = None) -> float:
    """
    Return the contact conditions' residual at impulses ``p`` (velocity units, m/s).

    Per normal row ``|min(p_n A_nn, w_n)|`` (a natural map), ``|w_n|`` for an
    equality (``equal`` (c,)); per friction row whose impulse is inside its bound
    ``μ p_n``, the slip left along it or, if less, how far its force lies from the
    bound that would oppose that slip, times ``A_ii`` (the natural map of the box: a
    force a hair inside its bound while slipping is off by that hair, not by its
    slip; a sliding contact has its ``t₁`` row alone); a friction row on its bound
    must slip against it, and one beyond its bound counts its excess times ``A_ii``.
    Rows ``pinned`` (held at zero) are not conditions.
    """
    if not len(q):
        return 0.0
    w = A @ p + q
    d = np.diag(A)
    step = 1 if normal_only else 3
    pn, wn = p[0::step], w[0::step]
    natural = np.abs(np.minimum(pn * d[0::step], wn))
    if equal is not None:
        natural = np.where(equal, np.abs(wn), natural)
    out = float(np.max(natural))
    if normal_only:
        return out
    bound = mu * np.maximum(pn, 0.0)
    # (a bound is the previous iterate's μ p_n: within the iteration's tolerance of it)
    slack = 2.0 * (FRICTION_TOLERANCE * float(np.max(np.abs(p)))
                   + 64.0 * EPS * float(np.max(np.abs(q))) / float(np.max(d)))
    for col in (1, 2):
        f, v, dc = p[col::3], w[col::3], d[col::3]
        present = np.ones(len(f), dtype=bool) if col == 1 or sliding is None else ~sliding
        if pinned is not None:
            present &= ~pinned[col::3]
        inside = present & (np.abs(f) < bound - slack)
        if np.any(inside):
            # (the bound opposing the slip: −bound for v > 0, +bound for v < 0)
            gap = np.where(v > 0.0, bound + f, bound - f)
            out = max(out, float(np.max(np.minimum(np.abs(v), gap * dc)[inside])))
        # On its bound the row's force opposes its slip (or there is none).
        on = present & ~inside & (bound > 0.0)
        if np.any(on):
            out = max(out, float(np.max(np.maximum(f[on] * v[on], 0.0) / bound[on])))
        beyond = present & (np.abs(f) > bound + slack)
        if np.any(beyond):
            out = max(out, float(np.max((np.abs(f[beyond]) - bound[beyond]) * dc[beyond])))
    return out
