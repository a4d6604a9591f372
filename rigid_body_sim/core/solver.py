"""
Constraint forces and drift control: the Schur-complement (KKT) solve and projections.

Acceleration level (every right-hand side evaluation)
-----------------------------------------------------
With the block-diagonal mass matrix ``M = diag(m, m, m, J1, J2, J3)`` per body
(principal frames make it diagonal), unconstrained accelerations
``a_u = M⁻¹ (f − [0, Ω × JΩ])`` and the constraint rows of :mod:`.constraints`,
the multipliers solve::

    G M⁻¹ Gᵀ λ = G a_u + γ + 2 ω Φ̇ + ω² Φ,      a = a_u − M⁻¹ Gᵀ λ,

i.e. ``Φ̈ = −2 ω Φ̇ − ω² Φ`` (critically damped Baumgarte stabilization with
``ω = 1 / time_constant``). Redundant rows (closed loops, a joint added twice)
make ``G M⁻¹ Gᵀ`` singular; a vanishing pivot reveals it, and the
minimum-norm multipliers are then taken (truncated SVD of a dense system or of
a loop's closure block, a 1e-12 relative Tikhonov term in the tree solve). A full-rank system is
solved as it is: no regularization biases the reaction forces, however
ill-conditioned the mass ratios make it (a point mass on a rod: 1e9).

The matrix ``G M⁻¹ Gᵀ`` couples only constraints that share a body: block
tridiagonal for chains, tree-shaped for trees. Chains and trees are eliminated
in tree order by :mod:`.kernels.tree_solve` (Baraff 1996; linear in the number
of links); where every joint of the forest is a built-in fixed, hinge, ball,
slider or distance joint, each tree hanging from the world or floating free,
the systems are eliminated in inertia form instead (:mod:`.kernels.nullspace_solve`,
:mod:`.kernels.nullspace_shake`: each joint's freedoms, not its rows; the same
multipliers, at less work; see
:attr:`ConstraintSolver.inertia_form`); components of at most
:data:`KERNEL_DENSE_ROWS` rows are factorized densely, which is faster at that
size; a closed loop, among bodies or through the world, is solved by the tree
solve of a spanning forest and the Schur complement of the rows that close the
loops (:mod:`.kernels.loop_solve`).

There is one implementation of this solve: the compiled kernels of
:mod:`.kernels.constrained_step`. A step calls it, and so does this class for
the multipliers a user reads (:meth:`ConstraintSolver.reactions`: the λ a kick
at that state uses), the velocity projection when a constraint is added or the
scene reset, and the Gauss–Newton search that decides whether constraints can
hold together. The one other solve is the labelled naive oracle of
:func:`.reference.constrained_accelerations` (a pseudo-inverse), which the
DOP853 reference and the tests use.

Position and velocity level (every step)
----------------------------------------
The integrators (see :mod:`.integrators`) correct positions onto
``Φ = ρ Φ_start`` with ``ρ = exp(−h / time_constant)`` (SHAKE in the splitting
methods, an orthogonal projection as the last resort) and
velocities onto ``Φ̇ = −ω Φ``, ``ω = 1 / time_constant`` (at most ``1 / (2 dt)``)
(:meth:`ConstraintSolver.project_velocities`, the mass-weighted minimum-norm
impulse ``−M⁻¹ Gᵀ (G M⁻¹ Gᵀ)⁻¹ r``). For a satisfied constraint this is
projection onto ``Φ = 0`` and ``Φ̇ = 0`` (drift stays at rounding level); a
constraint that was violated when added (or by a large disturbance) returns to
``Φ = 0`` along ``exp(−t / time_constant)``: smoothly, at a rate that does not
depend on ``dt``, and consistent with the Baumgarte term (``exp(−ω t)`` solves
``Φ̈ + 2 ω Φ̇ + ω² Φ = 0``).

Default ``time_constant = 0.05 s``: five times faster than the slowest motions
robots usually control (~1 Hz) so a violated joint closes well within a second,
yet slow enough that the stabilization force of a 0.1 m violation stays of the
order of the gravity force of the body. Step sizes above
``time_constant / 2`` are stabilized at ``ω = 1 / (2 dt)`` instead.

"""

from __future__ import annotations

import itertools
from typing import NamedTuple, Optional, Sequence, TYPE_CHECKING
import weakref

import numpy as np

from . import rotation as so3
from .bodies import BodySet, State
from .constraints import Constraint, ConstraintSet, JointType
from .dynamics import SolverCounters
from .errors import SpecError
from .graph import closes_loop, component_labels, loop_structure, tree_structure
from .kernels.constrained_step import (component_multipliers, component_project_velocities,
                                       component_reach, CURRENT, dense_storage, GENERIC,
                                       nullspace_storage, pack, tree_storage, workspace)
from .kernels.layout import BODY, COMPONENT, L_OFFSET, L_SHAPE, PAR, PAR_C0, PAR_RATE, \
    PAR_SCALAR, PAR_T0, Solve
from .kernels.nullspace_solve import nullspace_structure
from .validate import positive_scalar

if TYPE_CHECKING:
    from .dynamics import Dynamics


_KEYS = itertools.count()

#: A component whose rows are redundant without a loop of distinct joints (a joint
#: added twice) is solved densely up to this many rows (the truncated SVD: minimum-norm
#: multipliers, unbiased), a larger one by the tree solve with its Tikhonov term.
DENSE_ROWS = 48

#: A component of the compiled step with at most this many rows and no closed loop
#: is solved densely (Cholesky or LU), a larger one by the tree solve. Measured per
#: step at dt 1e-3, ``lie_poisson2``: the dense solve is faster up to 20 rows (a
#: 4-link hinge chain: 13.8 against 14.9 us), the tree solve from 25 (5 links: 16.7
#: against 17.7; 9 links, 45 rows: 24.4 against 43.5).
KERNEL_DENSE_ROWS = 24
#: A component whose joints close a loop (through the world too) and has more rows
#: than this is solved by the tree solve of a spanning forest and the Schur
#: complement of the loop-closing rows (:mod:`.loop_solve`); none is solved densely.
#: A loop has redundant rows as a rule (3 for a planar one), which the dense solve
#: met with the truncated SVD of the whole system: the four-bar (20 rows) took 83 us
#: a step that way and takes 33 us now, a ring of 6 rods (33 rows) 211 and 40 us.
#: The closure block's truncated SVD keeps them unbiased, where the tree solve of
#: the whole loop would add a Tikhonov term (the four-bar then missed the accuracy
#: knob's tolerances of 1e-7 and 1e-9). A joint added twice is redundant without a
#: loop of distinct joints: it stays dense up to ``DENSE_ROWS`` rows.
LOOP_DENSE_ROWS = 0


def _drop_generic(keys: list) -> None:
    for key in keys:
        GENERIC.pop(key, None)


class _GenericRows:
    """
    A component's generic rows, evaluated for the compiled step.

    The constrained kernel calls :meth:`geometry` and :meth:`gamma` (through
    ``kernels.constrained_step.generic_geometry`` and ``generic_gamma``) with the
    component's own state arrays; rows are written after its built-in rows.
    """

    def __init__(self, constraints: ConstraintSet, bodies: np.ndarray, resolved: list,
                 offset: int) -> None:
        self.constraints, self.bodies, self.resolved = constraints, bodies, resolved
        self.offset = offset

    def _frames(self, pos: np.ndarray, quat: np.ndarray) -> tuple:
        n = len(self.constraints.bodies)
        x = np.zeros((n + 1, 3))
        x[self.bodies] = pos
        R = np.tile(np.eye(3), (n + 1, 1, 1))
        R[self.bodies] = so3.quat_to_matrix(quat)
        return x, R

    def geometry(self, pos: np.ndarray, quat: np.ndarray, phi: np.ndarray, Ga: np.ndarray,
                 Gb: np.ndarray) -> None:
        """Fill Φ and the G blocks of the generic rows."""
        x, R = self._frames(pos, quat)
        r0 = self.offset
        for res in self.resolved:
            values, g, _ = self.constraints.generic_rows(res, x, R)
            k = len(values)
            phi[r0:r0 + k] = values
            Ga[r0:r0 + k] = g[:, :6]
            Gb[r0:r0 + k] = g[:, 6:]
            r0 += k

    def gamma(self, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray, om: np.ndarray,
              gamma: np.ndarray) -> None:
        """Fill γ of the generic rows."""
        x, R = self._frames(pos, quat)
        v = np.zeros_like(x)
        w = np.zeros_like(x)
        v[self.bodies] = vel
        w[self.bodies] = np.einsum('nij,nj->ni', R[self.bodies], om)
        r0 = self.offset
        for res in self.resolved:
            values = self.constraints.generic_rows(res, x, R, v, w, True,
                                                   need_jacobian=False)[2]
            gamma[r0:r0 + len(values)] = values
            r0 += len(values)


class ComponentSetup(NamedTuple):
    """What the compiled step of one connected component of the constraint graph works with."""

    #: Indices (k,) of the component's bodies.
    bodies: np.ndarray
    #: Indices (m,) of its rows in the constraint set.
    rows: np.ndarray
    #: ``(key, floats, ints, layout)``: the arguments of
    #: :func:`.kernels.constrained_step.packed_step` (its rows in the component's own
    #: body numbering, workspace and factor storages).
    packed: tuple
    #: The packed arrays by name (:data:`.kernels.layout.COMPONENT`), as views.
    views: dict
    #: How its systems are solved.
    solve: Solve
    #: λ (m,) of its rows, written by the kernels.
    multipliers: np.ndarray
    #: Its bodies' masses and moments as ``body`` columns (:data:`.kernels.layout.BODY`).
    inertia: np.ndarray
    #: Indices (e,) of its coupling parts in the constraint set's ``x_*`` arrays (parts
    #: ``m ..`` of its ``jac``).
    couplings: np.ndarray


#: Setups a component's plan is kept for after the last one that had it (:attr:`plans`).
PLAN_SETUPS = 3


def _repack(packed: tuple) -> tuple:
    """
    Return a copy of a packed component and its views: ``(packed, views)`` as ``pack``'s.

    Its buffers are copied (the copy's workspace is its own), its layout shared (it is
    never written), and its workspace's state set as ``workspace`` sets it: no factor
    held (``factor_state``), every body watched; the rest is work the steps write
    before they read it (:mod:`.kernels.constrained_step`). Generic rows (a key other
    than -1) are not copied: their key names the Python rows of one setup.
    """
    key, floats, ints, layout = packed
    if key != -1:
        raise ValueError('repack: a component with generic rows is packed anew')
    floats, ints = floats.copy(), ints.copy()
    views = {}
    for row, field in zip(layout.tolist(), COMPONENT.fields):
        shape = row[L_SHAPE:L_SHAPE + field.ndim]
        size = 1
        for d in shape:
            size *= d
        buf = floats if field.kind == 'f' else ints
        views[field.name] = buf[row[L_OFFSET]:row[L_OFFSET] + size].reshape(shape)
    views['factor_state'][:] = 0
    views['watch'][:] = 1
    return (key, floats, ints, layout), views


def _content(rows: dict, body: np.ndarray, ja: np.ndarray, jb: np.ndarray, m: int,
             inertia_form: bool) -> bytes:
    """
    Return what a component's plan and packed arrays are made of, as one key.

    Its rows in its own body numbering (kinds, parameters, bodies, couplings), its
    bodies' masses and moments, its joints' pairs (whether they close a loop) and the
    solve's choices: two components with the same key are planned and packed alike.
    """
    parts = [np.array([m, len(body), len(ja), inertia_form], dtype=np.int64), body, ja, jb]
    parts += [rows[k] for k in sorted(rows) if k != 'key']
    return b''.join(np.ascontiguousarray(x).tobytes() + str(x.shape).encode() for x in parts)


class _ReactionPlan(NamedTuple):
    """Per (constraint, side on a body): where :meth:`ConstraintSolver.reactions` reads."""

    owner: tuple             # per component: the constraint index of each of its rows
    row_owner: np.ndarray    # (m,) the constraint index of each row
    constraint: np.ndarray   # (k,) constraint index
    side: np.ndarray         # (k,) 0: its body a, 1: its body b, 2 and 3: its leader's a, b
    body: np.ndarray         # (k,) body index
    lever: np.ndarray        # (k, 3) anchor from the centre of mass, principal frame (m)
    names: list              # (constraint name, body name) per entry


class KernelSetup(NamedTuple):
    """The compiled step's data: the free bodies and the constraint graph's components."""

    #: Indices of the bodies no constraint touches.
    free: np.ndarray
    #: One per connected component.
    components: tuple
    #: ``[y]``: the state buffer whose geometry every component's workspace holds as
    #: its current one (a step ended there), or ``[None]``. Whoever computes in the
    #: workspaces says what they hold now.
    geometry_of: list


class ConstraintSolver:
    """
    Multipliers, reaction forces and projections for a :class:`ConstraintSet`.

    Parameters
    ----------
    bodies : BodySet
    constraints : ConstraintSet
    time_constant : float
        s, > 0: decay time of a violation (see the module docstring).
    regularization : float
        Tikhonov term (relative to the largest diagonal entry of ``G M⁻¹ Gᵀ``)
        for large sparse systems with redundant rows, >= 0.
    rank_rtol : float
        A factorization pivot below this times the largest diagonal entry
        marks the system as rank-deficient (redundant rows).
    position_tolerance : float
        Stop the position projection when ``max |Φ − target|`` is below this.
    max_iterations : int
        Position projection (Newton) iterations at most.
    tally : ndarray of int64, optional
        The work tally to keep :attr:`counters` in (that of the
        :class:`.dynamics.Dynamics` whose steps solve with this solver).

    """

    def __init__(self, bodies: BodySet, constraints: ConstraintSet,
                 time_constant: float = 0.05, regularization: float = 1e-12,
                 rank_rtol: float = 1e-12,
                 position_tolerance: float = 1e-13, max_iterations: int = 6,
                 tally: Optional[np.ndarray] = None) -> None:
        self.bodies = bodies
        self.constraints = constraints
        self.time_constant = positive_scalar(time_constant, 'constraint_time_constant')
        if not (regularization >= 0.0 and np.isfinite(regularization)):
            raise SpecError('regularization', f'must be finite and >= 0, got {regularization!r}')
        self.regularization = float(regularization)
        self.rank_rtol = positive_scalar(rank_rtol, 'rank_rtol')
        self.position_tolerance = positive_scalar(position_tolerance, 'position_tolerance')
        self.max_iterations = int(max_iterations)
        self.counters = SolverCounters(tally=tally)
        self.dt: Optional[float] = None
        self._kernel_cache: Optional[tuple] = None
        #: The last kernel setups' components by their content (:func:`_content`), each
        #: with the number of setups since one had it: the next setup copies a component
        #: of the same content instead of planning and packing it anew (a simulation
        #: rebuilt around a spawn starts with the old one's: only the components a spawn
        #: or a removal changed are planned). Kept for :data:`PLAN_SETUPS` setups (a
        #: rebuild's reset sets up before its drives are added, and again after).
        self.plans: dict = {}
        #: Components planned and packed by :meth:`kernel_setup`, and those copied from
        #: :attr:`plans` (the setups' work, for the tests and benchmarks that show it).
        self.plan_counts = {'planned': 0, 'copied': 0}
        self._plan: Optional[tuple] = None
        self._par: Optional[tuple] = None
        #: The last multipliers read (:meth:`multipliers`) and what they were read of.
        self._read: Optional[tuple] = None
        #: s: the time the kernels' copies of the drives' targets are of (None: unknown,
        #: a step raised half-way). A step moves them from its start to its end.
        self.kernel_time: Optional[float] = None
        # Keys of this solver's generic rows in kernels.constrained_step.GENERIC, dropped
        # when the setup is rebuilt or the solver is collected.
        self._generic_keys: list = []
        weakref.finalize(self, _drop_generic, self._generic_keys)
        self._inertia_form = True

    @property
    def inertia_form(self) -> bool:
        """
        Whether forests of recognized joints solve their systems in inertia form.

        True (the default): a tree-solved component whose joints are all built-in
        ``fixed``, ``hinge``, ``ball`` or ``slider`` joints or ``distance`` rows, each
        tree hanging from the world by one joint or free-floating
        (:func:`.kernels.nullspace_solve.nullspace_structure`
        recognizes them), factorizes ``G M⁻¹ Gᵀ`` and SHAKE's Newton matrix by
        eliminating each joint's freedoms (:mod:`.kernels.nullspace_solve`,
        :mod:`.kernels.nullspace_shake`), and falls back to the
        row-space tree solve at a state where a joint's freedom has next to no
        inertia (a pivot at most ``rank_rtol`` of its scale). Every other
        component (generic or drive rows, redundant rows) always takes the
        row-space tree solve. False: every component does
        (a comparison: the two agree to rounding).
        """
        return self._inertia_form

    @inertia_form.setter
    def inertia_form(self, value: bool) -> None:
        self._inertia_form = bool(value)
        self._kernel_cache = None   # rebuilt with or without the inertia form

    @property
    def omega(self) -> float:
        """Baumgarte rate (1/s): ``1 / time_constant``, at most ``1 / (2 dt)``."""
        w = 1.0 / self.time_constant
        return w if self.dt is None else min(w, 0.5 / abs(self.dt))

    def kernel_setup(self) -> KernelSetup:
        """
        Return what the compiled constrained step works with, per component.

        The constraint graph's connected components (bodies joined through
        constraints) are stepped separately, each with the sub-steps its own
        motion needs, and the bodies no constraint touches as free bodies
        (see "Sub-steps" in :mod:`.integrators`). Generic rows (a user's
        Python function) are evaluated by Python from inside the compiled step
        (:data:`.kernels.constrained_step.GENERIC`). A component of at most
        :data:`KERNEL_DENSE_ROWS` rows without a closed loop is solved densely, a
        larger one by the tree solve, and one whose joints close loops (through the
        world too, :data:`LOOP_DENSE_ROWS`) by the tree solve of a spanning forest
        and the Schur complement of the loop-closing rows (:mod:`.loop_solve`). Returns
        a :class:`KernelSetup`. Rebuilt only when the constraint set changes.
        """
        cs = self.constraints
        c = self._kernel_cache
        if c is not None and c[0] is cs and c[1] == cs.version:
            return c[2]
        self._kernel_cache = (cs, cs.version, None)
        for key in self._generic_keys:   # the previous setup's generic rows
            GENERIC.pop(key, None)
        self._generic_keys.clear()
        n, mb = len(self.bodies), cs.n_builtin_rows
        a, b = cs.all_row_a, cs.all_row_b
        # A coupled (mimic) row joins its leader's bodies to its follower's.
        label = component_labels(np.concatenate([a, cs.x_a, cs.x_a]),
                                 np.concatenate([b, cs.x_b, a[cs.x_row]]), n)
        touched = np.zeros(n, dtype=bool)
        touched[cs.touched] = True
        components = []
        joints_of: dict = {}   # component label -> (a, b) per constraint
        for r in cs.resolved:
            if r.spec.type in (JointType.DRIVE, JointType.MIMIC):
                # A drive adds its joint's missing row to the joint's own pair of
                # bodies: it never closes a loop, nor makes that pair redundant. A
                # mimic row is a closure row (below) whatever the graph.
                continue
            joints_of.setdefault(label[r.a], []).append((r.a, r.b))
        plans, self.plans = self.plans, {}
        for lab in np.unique(label[touched]):
            bodies = np.flatnonzero(label == lab)
            rows_global = np.flatnonzero(label[a] == lab)
            local = np.full(n + 1, -1, dtype=np.int64)
            local[bodies] = np.arange(len(bodies))
            local[n] = len(bodies)   # the world
            ra, rb = local[a[rows_global]], local[b[rows_global]]
            mc = len(rows_global)
            closure = np.zeros(0, dtype=np.int64)
            ja, jb = np.array(joints_of.get(lab, []), dtype=np.int64).reshape(-1, 2).T
            # Coupling parts (mimic rows' leader sides): their rows couple up to four
            # bodies, which the tree solve cannot take: closure rows of the loop solve.
            xs = np.flatnonzero(label[cs.x_a] == lab)
            x_local = np.searchsorted(rows_global, cs.x_row[xs])
            body = np.zeros((len(bodies), BODY.width))
            body[:, BODY.start['inv_mass']] = self.bodies.inv_mass[bodies]
            j = BODY.start['moments']
            body[:, j:j + 3] = self.bodies.moments[bodies]
            # Built-in rows first (compiled), then generic ones (Python, object mode).
            builtin = rows_global[rows_global < mb]
            generic = [res for res in cs.generic if label[res.a] == lab]
            rows = {'kind': cs.row_kind[builtin], 'comp': cs.row_comp[builtin],
                    'row_a': np.concatenate([ra, local[cs.x_a[xs]]]),
                    'row_b': np.concatenate([rb, local[cs.x_b[xs]]]),
                    'row_par': np.ascontiguousarray(cs.row_par[builtin]),
                    'row_owner': np.concatenate([np.arange(mc), x_local]).astype(np.int64),
                    'x_kind': cs.x_kind[xs], 'x_comp': cs.x_comp[xs],
                    'x_par': np.ascontiguousarray(cs.x_par[xs]), 'x_weight': cs.x_weight[xs],
                    'key': -1}
            content = None if generic else _content(
                rows, body, local[ja], local[jb], mc, self._inertia_form)
            old = plans.get(content, (None,))[0]
            if old is not None:   # (the same rows on the same bodies: copied, not planned)
                packed, views = _repack(old.packed)
                for name, table in rows.items():   # (the rows as now: a drive's target moves)
                    if name != 'key':
                        views[name][...] = table
                comp = ComponentSetup(bodies, rows_global, packed, views, old.solve,
                                      np.zeros(mc), body, xs)
                components.append(comp)
                self.plans[content] = (comp, 0)
                self.plan_counts['copied'] += 1
                continue
            closes = closes_loop(local[ja], local[jb], len(bodies))
            # A loop through the world counts: its redundant rows go to the closure
            # (beyond DENSE_ROWS a loop among bodies must: the tree solve needs a tree).
            loops = (loop_structure(ra, rb, len(bodies), through_world=True, forced=x_local)
                     if (closes and mc > min(LOOP_DENSE_ROWS, DENSE_ROWS))
                     or (len(xs) and mc > KERNEL_DENSE_ROWS) else None)
            if loops is not None:
                # Closed loops: the tree solve of a spanning forest and a dense
                # system of the rows that close the loops.
                st, closure = loops
                solve, d = Solve.LOOP, len(closure)
            elif mc <= (DENSE_ROWS if closes else KERNEL_DENSE_ROWS):
                solve, d = Solve.DENSE, mc
                st = tree_structure(ra[:0], rb[:0], len(bodies))
            else:
                st = tree_structure(ra, rb, len(bodies))
                solve, d = Solve.TREE, 0
            # The inertia form, where every joint of the forest is recognized (built-in
            # rows only; a loop solve's closure rows apart).
            joints = None
            if solve != Solve.DENSE and self._inertia_form and np.all(rows_global < mb):
                joints = nullspace_structure(ra, rb, cs.row_kind[rows_global],
                                             cs.row_comp[rows_global], len(bodies),
                                             only=st.group_rows)
            # Two storages each: general, and the symmetric factor kept for the
            # current geometry (see kernels.constrained_step._sym_factor).
            trees = (tree_storage(st, closure, mc, len(bodies)),
                     tree_storage(st, closure, mc, len(bodies)))
            if generic:
                rows['key'] = next(_KEYS)
                GENERIC[rows['key']] = _GenericRows(cs, bodies, generic, len(builtin))
                self._generic_keys.append(rows['key'])
            packed, views = pack(rows, workspace(len(bodies), mc, body, len(xs)),
                                 (dense_storage(d), dense_storage(d)), trees,
                                 nullspace_storage(joints, len(bodies)))
            components.append(ComponentSetup(bodies, rows_global, packed, views, solve,
                                             np.zeros(mc), body, xs))
            self.plan_counts['planned'] += 1
            if content is not None:
                self.plans[content] = (components[-1], 0)
        for content, (comp, age) in plans.items():   # (those not had: kept a while)
            if content not in self.plans and age + 1 < PLAN_SETUPS:
                self.plans[content] = (comp, age + 1)
        setup = KernelSetup(np.flatnonzero(~touched), tuple(components), [None])
        self._kernel_cache = (cs, cs.version, setup)
        self.kernel_time = cs.time   # the copies' targets are the set's
        return setup

    def set_drive_targets(self, names: list, targets: np.ndarray, time: float,
                          rates: Optional[np.ndarray] = None) -> None:
        """
        Set the targets of ``drive`` constraints at ``time`` (s), and their rates.

        In the set and in the kernels' copies (:meth:`.ConstraintSet.set_drive_targets`):
        ``targets`` (k,) rad or m, ``rates`` (k,) rad/s or m/s (default 0). Only the
        rows' ``row_par`` scalars and rates change (not the rows' structure), so the
        kernel setup is kept; its workspaces no longer hold the geometry of the
        current state (Φ changed).
        """
        self.constraints.set_drive_targets(names, targets, time, rates)
        self._copy_targets(True)

    def drive_motions(self, names: list) -> list:
        """Return drives' target motions ``(c₀, ċ, t₀)``: ``c(t) = c₀ + ċ (t − t₀)``."""
        return self.constraints.drive_motions(names)

    def set_drive_motions(self, motions: dict, time: float) -> None:
        """
        Set drives' motions ``{name: (c₀, ċ, t₀)}`` as they are elsewhere, bit for bit.

        (A simulation rebuilt around a spawn takes its drives' targets from the old one;
        :meth:`set_drive_targets` would set ``t₀`` to now.) Targets are then at ``time``.
        """
        for name, (c0, rate, t0) in motions.items():
            self.constraints.set_drive_targets([name], np.array([c0]), t0, np.array([rate]))
        self.constraints.drive_targets_at(time)
        self._copy_targets(True)

    def drive_rate_slot(self, name: str) -> tuple:
        """
        Return where the kernels keep drive ``name``'s target rate: ``(array, index)``.

        For a probe of the velocity projection (:meth:`project_velocities` at a
        state at the targets' time reads it there); the caller puts the value back.
        """
        row = self.constraints.rows_of(name)[0]
        for comp in self.kernel_setup().components:
            local = int(np.searchsorted(comp.rows, row))
            if local < len(comp.rows) and comp.rows[local] == row:
                return comp.views['row_par'], (local, PAR_RATE)
        raise KeyError(name)

    def drive_targets(self, names: list, time: float) -> np.ndarray:
        """Targets (k,) of ``drive`` constraints at ``time`` (s), rad or m."""
        return self.constraints.drive_targets(names, time)

    def targets_at(self, time: float) -> None:
        """
        Put the kernels' copies of moving drive targets at ``time`` (s), if they are not.

        A step leaves them at its end (the kernels advance them by ``ċ dt``): the
        next step from there finds them in place and keeps its geometry. A call
        from another time (a step taken again from the same state, the multipliers
        at a state set by hand) rewrites them from :meth:`.ConstraintSet.drive_targets_at`.
        """
        if not self.constraints.moving or self.kernel_time == time:
            return
        self.constraints.drive_targets_at(time)
        self._copy_targets(False)

    def _copy_targets(self, rates: bool) -> None:
        """Copy the drives' targets (and ``rates``) of the set into the kernels' rows."""
        cs = self.constraints
        rows = cs.drive_rows
        c = self._kernel_cache
        if c is None or c[0] is not cs or c[1] != cs.version or c[2] is None:
            return   # the next setup copies the new targets
        setup = c[2]
        setup.geometry_of[0] = None
        self.kernel_time = cs.time
        columns = [PAR_SCALAR, PAR_RATE, PAR_C0, PAR_T0] if rates else [PAR_SCALAR]
        for comp in setup.components:
            local = np.searchsorted(comp.rows, rows)
            found = comp.rows[np.minimum(local, len(comp.rows) - 1)] == rows
            mine = (local < len(comp.rows)) & found
            if np.any(mine):
                for col in columns:
                    comp.views['row_par'][local[mine], col] = cs.row_par[rows[mine], col]

    def kernel_parameters(self, max_rotation: Optional[float], max_substeps: int,
                          closing: float) -> np.ndarray:
        """Return the ``par`` array of :mod:`.kernels.constrained_step` for the settings now."""
        return PAR.row(tau=self.time_constant, omega=self.omega,
                       pos_tol=self.position_tolerance, max_it=float(self.max_iterations),
                       rank_rtol=self.rank_rtol, reg=self.regularization, closing=closing,
                       max_rot=np.inf if max_rotation is None else float(max_rotation),
                       max_sub=float(max_substeps), t_start=0.0, t_end=0.0)

    # -- the compiled solve outside a step ----------------------------------------------

    def settings_key(self) -> tuple:
        """Everything the solver puts into the kernels' ``par`` (a changed one rebuilds it)."""
        return (self.time_constant, self.dt, self.position_tolerance, self.max_iterations,
                self.rank_rtol, self.regularization)

    def _settings(self) -> np.ndarray:
        """``par`` of the compiled kernels for the solver's own uses (no sub-steps)."""
        key = self.settings_key()
        if self._par is None or self._par[0] != key:
            self._par = (key, self.kernel_parameters(None, 1, 0.0))
        return self._par[1]

    def multipliers(self, dynamics: Dynamics, state: State) -> np.ndarray:
        """
        λ (m,) at ``state``: the multipliers a step's kick there uses, from its own kernels.

        Per component, :func:`.kernels.constrained_step.component_multipliers`:
        the free accelerations of every effect of ``dynamics`` (gravity,
        damping, applied wrenches, gyroscopic terms) and the acceleration-level
        solve ``G M⁻¹ Gᵀ λ = G a_u + γ + 2ωΦ̇ + ω²Φ`` of the step. When the last
        step ended at ``state`` (:attr:`KernelSetup.geometry_of`) its geometry,
        and its factor if it left one, are reused: reading λ after a step costs
        the rates, the free accelerations and one solve. Counts no work.
        Afterwards each component's workspace holds G and Gᵀλ of ``state``. A
        second read at the same state, with nothing changed since (the model, the
        rows, the settings, the workspaces), returns the first one's λ.
        """
        setup = self.kernel_setup()
        self.targets_at(state.time)
        current = setup.geometry_of[0] is state.y
        key = (state.y, dynamics, self.constraints, setup)   # (compared by identity)
        versions = (dynamics.version, self.constraints.version, self.settings_key())
        cached = self._read
        if current and cached is not None and all(a is b for a, b in zip(cached[0], key)) \
                and cached[1] == versions:
            return cached[2].copy()
        setup.geometry_of[0] = None   # until every component is done: one may raise
        par = self._settings()
        lam = np.zeros(self.constraints.n_rows)
        tally = np.zeros_like(self.counters.tally)   # reading is not stepping
        s = state
        for comp in setup.components:
            b = comp.bodies
            body, gforce, wrench, flags, _ = dynamics.kernel_submodel(s.time, b)
            lam_c = np.zeros(len(comp.rows))
            component_multipliers(
                np.ascontiguousarray(s.pos_com_world[b]),
                np.ascontiguousarray(s.quat_principal_world[b]),
                np.ascontiguousarray(s.vel_com_world[b]),
                np.ascontiguousarray(s.ang_vel_principal[b]), body, gforce, wrench, flags, par,
                int(comp.solve), *comp.packed, current, lam_c, tally)
            lam[comp.rows] = lam_c
        setup.geometry_of[0] = state.y   # every workspace now holds the geometry of state
        self._read = (key, versions, lam.copy())
        return lam

    def violation(self, state: State) -> np.ndarray:
        """Φ (m,) at ``state`` (a drive's with its target at the state's time)."""
        if self.constraints.moving:
            self.constraints.drive_targets_at(state.time)
        return self.constraints.geometry(state.pos_com_world, state.quat_principal_world).phi

    def closest_reach(self, pos: np.ndarray, quat: np.ndarray, tolerance: float,
                      max_iterations: int = 50) -> float:
        """
        Smallest ``max |Φ|`` that Gauss–Newton reaches from a configuration.

        Minimum-norm steps ``δ = −M⁻¹ Gᵀ (G M⁻¹ Gᵀ)⁺ Φ`` (the step's own
        factorizations, per connected component:
        :func:`.kernels.constrained_step.component_reach`) converge quadratically to a
        configuration with ``Φ = 0`` when the constraints can hold together; for
        an inconsistent set (say one body point pinned to two world points) they
        stall at the least-squares compromise, whose residual is returned. Stops
        below ``tolerance`` or after three iterations that do not reduce the residual.
        Nothing is modified: this answers "can these constraints all hold?".

        Parameters
        ----------
        pos : ndarray, shape (n, 3)
            m, centres of mass (world frame).
        quat : ndarray, shape (n, 4)
            Principal-frame orientations, xyzw.
        tolerance : float
            m or rad.
        max_iterations : int
            Gauss–Newton iterations at most.

        Returns
        -------
        float
            The smallest ``max |Φ|`` of the iterates.

        """
        setup = self.kernel_setup()
        setup.geometry_of[0] = None   # the workspaces will hold the last iterates
        par = self._settings()
        tally = np.zeros_like(self.counters.tally)   # a question, not work
        worst = 0.0
        for comp in setup.components:
            b = comp.bodies
            worst = max(worst, component_reach(
                np.ascontiguousarray(pos[b]), np.ascontiguousarray(quat[b]), float(tolerance),
                int(max_iterations), par, int(comp.solve), *comp.packed, tally))
        return worst

    # -- consistency -----------------------------------------------------------------------

    #: m or rad: a constraint set is consistent if Gauss–Newton gets ``max |Φ|`` below this.
    CONSISTENCY_TOLERANCE = 1e-8

    def reach(self, state: State) -> float:
        """
        Smallest ``max |Φ|`` Gauss–Newton reaches (see :meth:`closest_reach`).

        From the configuration of ``state`` and, if that stalls, from three random
        re-orientations of growing size (0.3, 1 and 3 rad, the same every call):
        a singular start, such as a straight chain asked to fold, stalls where a
        solution exists, and only a residual left from every start marks the set
        inconsistent. Counts no work.

        Parameters
        ----------
        state : State
            Its positions (n, 3) and orientations (n, 4) are the first start.

        Returns
        -------
        float
            m or rad; at most :attr:`CONSISTENCY_TOLERANCE` when the constraints
            can all hold. 0 when a generic constraint's function fails away from
            the configuration of ``state`` (the search cannot tell: the set is
            taken as consistent).

        """
        tol = self.CONSISTENCY_TOLERANCE
        rng = np.random.default_rng(0)   # the same verdict every time
        best = np.inf
        try:
            for scale in (0.0, 0.3, 1.0, 3.0):
                quat = state.quat_principal_world
                if scale:
                    turn = so3.exp_quat(scale * rng.normal(size=(len(quat), 3)))
                    quat = so3.quat_multiply(quat, turn)
                best = min(best, self.closest_reach(state.pos_com_world, quat, tol))
                if best <= tol:
                    break
        except SpecError:
            return 0.0
        return best

    def consistent(self, state: State) -> bool:
        """Tell whether the constraints can all hold (:meth:`reach` from ``state``)."""
        return self.reach(state) <= self.CONSISTENCY_TOLERANCE

    def first_inconsistent(self, specs: Sequence[Constraint], state: State) -> tuple[int, float]:
        """
        Find the first of ``specs`` that cannot hold together with those before it.

        Bisects on prefixes of ``specs`` (each added at ``state`` to a fresh
        :class:`ConstraintSet`), assuming the whole of ``specs`` is inconsistent
        (:meth:`consistent` is False for it). Replaces :attr:`constraints`: it is
        left holding ``specs[:index + 1]``, the set ``residual`` is of. Counts no
        work.

        Parameters
        ----------
        specs : sequence of Constraint
            In the order they are added; each valid at ``state`` on its own.
        state : State
            The configuration anchors and axes given in the world refer to.

        Returns
        -------
        index : int
            Of the first inconsistent constraint in ``specs``.
        residual : float
            m or rad: :meth:`reach` of ``specs[:index + 1]``.

        """
        specs = list(specs)
        lo, hi = 0, len(specs)   # specs[:lo] hold together, specs[:hi] do not
        while hi - lo > 1:
            mid = (lo + hi) // 2
            self.constraints = self._constraint_set(specs[:mid], state)
            lo, hi = (mid, hi) if self.consistent(state) else (lo, mid)
        self.constraints = self._constraint_set(specs[:hi], state)
        return hi - 1, self.reach(state)

    def _constraint_set(self, specs: Sequence[Constraint], state: State) -> ConstraintSet:
        """Build a new :class:`ConstraintSet` of ``specs``, added in order at ``state``."""
        constraints = ConstraintSet(self.bodies)
        for spec in specs:
            constraints.add(spec, state)
        return constraints

    def project_velocities(self, state: State) -> tuple:
        """
        Project velocities onto ``Φ̇ = −ω Φ`` (mass-orthogonally); returns (vel, omega).

        ``ω`` is :attr:`omega`: ``1 / τ``, capped at ``1 / (2 dt)`` so that a
        method without a position correction (``rkmk4``) still shrinks a
        violation by a factor of about 2 per step however large ``dt / τ`` is.
        The step's own projection, per component
        (:func:`.kernels.constrained_step.component_project_velocities`); the
        work is counted.
        """
        setup = self.kernel_setup()
        self.targets_at(state.time)
        # Of the positions, but never of the new state's buffer.
        setup.geometry_of[0] = None
        par = self._settings()
        s = state
        vel, om = s.vel_com_world.copy(), s.ang_vel_principal.copy()
        for comp in setup.components:
            b = comp.bodies
            v, w = np.ascontiguousarray(vel[b]), np.ascontiguousarray(om[b])
            component_project_velocities(
                np.ascontiguousarray(s.pos_com_world[b]),
                np.ascontiguousarray(s.quat_principal_world[b]), v, w, comp.inertia, par,
                int(comp.solve), *comp.packed, False, self.counters.tally)
            vel[b], om[b] = v, w
        return vel, om

    def project_velocity_sets(self, state: State, vel: np.ndarray, om: np.ndarray) -> None:
        """
        Project ``k`` sets of velocities at ``state``'s positions, in place.

        ``vel``, ``om`` (k, n, 3): each set as :meth:`project_velocities` projects a
        state's (``state``'s own velocities are not read), in order, with the
        kernels' setup, targets and settings fetched once for all of them.
        """
        setup = self.kernel_setup()
        self.targets_at(state.time)
        setup.geometry_of[0] = None
        par = self._settings()
        pos, quat = state.pos_com_world, state.quat_principal_world
        tally = self.counters.tally
        for comp in setup.components:
            b = comp.bodies
            p, q = np.ascontiguousarray(pos[b]), np.ascontiguousarray(quat[b])
            v, w = np.ascontiguousarray(vel[:, b]), np.ascontiguousarray(om[:, b])
            solve, packed = int(comp.solve), comp.packed
            for k in range(len(v)):   # (each set's rows: C-contiguous views)
                component_project_velocities(p, q, v[k], w[k], comp.inertia, par, solve,
                                             *packed, False, tally)
            vel[:, b], om[:, b] = v, w

    # -- reaction wrenches -----------------------------------------------------------------

    def reactions(self, dynamics: Dynamics, state: State) -> dict:
        """
        Wrench each constraint exerts on each of its bodies at ``state`` (world frame).

        λ is :meth:`multipliers` at ``state`` (every effect of ``dynamics``,
        gyroscopic terms, applied wrenches: the multipliers a step's kick there
        uses), so these are the forces the joints carry at this instant. A
        constraint's share is ``−G_cᵀ λ_c`` of its own rows, on each of its two
        bodies (a mimic constraint: on its follower's two and its leader's two). Counts
        no work.

        Parameters
        ----------
        dynamics : Dynamics
            The bodies' effects; its ``solver`` is this one.
        state : State
            Positions (n, 3), orientations (n, 4), velocities (n, 3), angular
            velocities (n, 3, principal frames).

        Returns
        -------
        dict
            ``{name: {body_name: fields}}`` in the order the constraints were
            added (the world is not listed), ``fields`` a dict of ndarrays of
            shape (3,): ``force_world`` (N), ``torque_com_world`` (N m, about the
            body's centre of mass), ``torque_anchor_world`` (N m, about the
            anchor on the body) and ``anchor_world`` (m, where that anchor is).

        """
        lam = self.multipliers(dynamics, state)
        plan = self._reaction_plan()
        # Per constraint: on its a, on its b; a mimic's also on its leader's a and b.
        gen = np.zeros((len(self.constraints), 4, 6))
        cs = self.constraints
        for comp, owner in zip(self.kernel_setup().components, plan.owner):
            m = len(comp.rows)
            jac = comp.views['jac'][CURRENT]   # (2, m + e, 6): G of the state, bodies a and b
            lam_c = lam[comp.rows][:, None]
            np.add.at(gen[:, 0], owner, -jac[0, :m] * lam_c)
            np.add.at(gen[:, 1], owner, -jac[1, :m] * lam_c)
            if len(comp.couplings):
                x_owner = plan.row_owner[cs.x_row[comp.couplings]]
                lam_x = lam[cs.x_row[comp.couplings]][:, None]
                np.add.at(gen[:, 2], x_owner, -jac[0, m:] * lam_x)
                np.add.at(gen[:, 3], x_owner, -jac[1, m:] * lam_x)
        # Every (constraint, side) on a body at once: forces, torques, levers, anchors.
        g = gen[plan.constraint, plan.side]
        R = so3.quat_to_matrix(state.quat_principal_world[plan.body])
        f = g[:, :3]
        tau_com = np.einsum('kij,kj->ki', R, g[:, 3:])
        lever = np.einsum('kij,kj->ki', R, plan.lever)
        tau_anchor = tau_com - so3.cross(lever, f)
        anchor = state.pos_com_world[plan.body] + lever
        out = {name: {} for name in self.constraints.names}
        for k, (name, body) in enumerate(plan.names):
            first = out[name].get(body)
            if first is not None:
                # A mimic whose follower and leader share a body (a gripper's hand): the
                # wrenches of both its parts there, summed, about the first anchor.
                force = first['force_world'] + f[k]
                torque = first['torque_com_world'] + tau_com[k]
                out[name][body] = {
                    'force_world': force, 'torque_com_world': torque,
                    'torque_anchor_world': torque - so3.cross(
                        first['anchor_world'] - state.pos_com_world[plan.body[k]], force),
                    'anchor_world': first['anchor_world']}
                continue
            out[name][body] = {'force_world': f[k], 'torque_com_world': tau_com[k],
                               'torque_anchor_world': tau_anchor[k], 'anchor_world': anchor[k]}
        return out

    def _reaction_plan(self) -> '_ReactionPlan':
        """Return where :meth:`reactions` reads, per constraint set (built once per change)."""
        setup = self.kernel_setup()
        c = self._plan
        if c is not None and c[0] is setup:
            return c[1]
        cs, n = self.constraints, len(self.bodies)
        row_owner = np.empty(cs.n_rows, dtype=np.int64)
        constraint, side, body, lever, names = [], [], [], [], []
        for i, name in enumerate(cs.names):
            row_owner[cs.rows_of(name)] = i
            for s, (b, r_p) in enumerate(cs.anchors(name)):
                if b < n:   # the world is not listed
                    constraint.append(i)
                    side.append(s)
                    body.append(b)
                    lever.append(r_p)
                    names.append((name, self.bodies.names[b]))
        plan = _ReactionPlan(tuple(row_owner[comp.rows] for comp in setup.components),
                             row_owner,
                             np.array(constraint, dtype=np.int64),
                             np.array(side, dtype=np.int64), np.array(body, dtype=np.int64),
                             np.array(lever, dtype=float).reshape(-1, 3), names)
        self._plan = (setup, plan)
        return plan
