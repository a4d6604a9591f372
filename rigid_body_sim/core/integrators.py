"""
Fixed-step integrators on (R³ × SO(3) × R³ × R³)ⁿ behind one contract.

Each integrator class is data (name, order, what it conserves, its code in
the compiled kernels); the public :meth:`Integrator.step` calls the kernels,
does the bookkeeping and counts work. Orientation is always updated by the
exponential map ``q <- q ⊗ exp(u)`` (see :mod:`.rotation`), so it stays on
SO(3) by construction; quaternions are renormalized only to remove rounding
error.

Methods
-------
``symplectic_euler``
    Order 1. Semi-implicit Euler as a Lie–Trotter splitting: kick
    ``v += h f/m, L += h τ``, then drift ``x += h v`` and the free rotor by the
    exact flows of ``L_1²/2J_1``, ``L_2²/2J_2``, ``L_3²/2J_3`` in turn.
    Symplectic; conserves linear and angular momentum exactly (to rounding)
    when no force or torque acts; energy error bounded, O(h).
``rkmk4``
    Order 4. Runge–Kutta–Munthe-Kaas with the classical RK4 tableau, the
    inverse ``dexp`` truncated after the second commutator (enough for order
    4; Hairer, Lubich & Wanner, Geometric Numerical Integration, IV.8.2).
    Not symplectic: energy and angular momentum drift, O(h⁴) per unit time.
``lie_poisson2``
    Order 2. Strang splitting kick–drift–kick with the free rotor split into
    exact rotations about the principal axes, 1-2-3-2-1 (Dullweber,
    Leimkuhler & McLachlan, J. Chem. Phys. 107, 5840 (1997); Touma & Wisdom
    1994). Symplectic and Lie–Poisson: |L| and the world angular momentum
    of a free body are conserved to rounding, and the energy error stays
    bounded, O(h²), over arbitrarily long runs.
``lie_poisson4``
    Order 4. The same, composed by Yoshida's triple jump (Phys. Lett. A 150,
    262 (1990)); the same invariants, three times the work of lie_poisson2.

The splittings' drift turns a symmetric top (two principal moments equal to
``ISOTROPY_RTOL``) by the exact flow of its free rotor instead of the split one:
its energy is the sum of ``|L|²/2J_s`` and ``L_a² (1/J_a − 1/J_s)/2``, whose flows
commute (``kernels.free_step.top_flow``), so the drift conserves the energy and
``|L|`` to rounding and costs four sines and cosines instead of twenty.

Damping, where the scene has it, is advanced by its exact exponential flow
inside the splitting methods (first half-step and last half-step), so they keep
their order; other velocity-dependent effects are evaluated in the kick.

Constraints (see :mod:`.solver`)
--------------------------------
``symplectic_euler``, ``lie_poisson2``, ``lie_poisson4``
    RATTLE in every (sub)step: the first kick carries the constraint force of
    the acceleration-level solve as a predictor; the half-step velocities then
    get the impulse along ``G(q_start)ᵀ`` for which the drift from the start
    lands on ``Φ = exp(−h/τ) Φ_start`` (SHAKE, Newton iterations that redo the
    drift), and the end velocities the impulse along ``G(q_end)ᵀ`` onto
    ``Φ̇ = −ωΦ`` (``ω = 1/τ``, at most ``1/(2 dt)``). That projection solves
    for the end velocities whatever impulse along ``M⁻¹ G(q_end)ᵀ`` the last
    kick gave, so the last kick carries no predictor (one solve fewer a
    sub-step) unless a damping flow comes between them. Symmetric and
    symplectic; internal joints conserve linear and angular momentum to
    rounding; the orders stay 1, 2 and 4 (measured).
``rkmk4``
    The constraint force of the Baumgarte-stabilized acceleration-level solve
    at every stage, then the end velocities projected onto ``Φ̇ = −ωΦ`` (an
    internal impulse: momenta conserved). No position projection: it would move
    bodies at fixed momenta; the O(h⁵) drift per step decays through the
    velocity target instead (measured violation ~1e-12 m at dt = 1e-3, 1e-3 m
    at dt = 0.2 s, where the capped ω still halves it every step).

SHAKE's Newton matrix carries how each body's end orientation responds to its
start momentum through the drift (the right Jacobian of exp, that of a
symmetric top's exact flow, or the derivative through the rotor flows), so its
first iteration is Newton's; the later ones reuse that factorization while each
cuts the residual a hundredfold (their matrices differ from it by the size of
the corrections) and refactor otherwise: 1 to 2 iterations a (sub)step up to
0.25 rad a step, 2.4 at 1 rad, and one factorization
(``bench/shake_convergence.py``).

Sub-steps
---------
A step in which a constrained body would turn by more than ``max_rotation``
(0.25 rad) is split into ``ceil(|Ω|max dt / max_rotation)`` equal sub-steps,
counted in ``WorkCounters.substeps``, but never into more than ``max_substeps``
(64): a body spun faster than ``max_substeps · max_rotation / dt`` (16,000 rad/s
at dt = 1e-3 s) gets 64 sub-steps that each turn it by more than
``max_rotation``, so that one step's work stays bounded (a 1 kHz node does not
stall on one hard push); such steps are counted in ``capped_steps`` and are
less accurate (SHAKE falls back to the orthogonal projection there, see
below). A splitting step whose SHAKE iterations
stop converging on joints that hold (a whip that speeds up within the step) is
redone from its start with twice the sub-steps, up to ``max_substeps``
(``WorkCounters.retries``); only there does the position correction fall back
to an orthogonal projection (``projection_fallbacks``). Each connected
component of the constraint graph gets the sub-steps its own motion needs;
bodies no constraint touches, and scenes without constraints, are never
sub-stepped: each gets exactly the step the user asked for, so its motion does
not depend on the other bodies.

Compiled kernels
----------------
A step is one compiled call (numba) per component of the constraint graph
(:mod:`.kernels.constrained_step`) and one for the bodies no constraint couples
(:mod:`.kernels.free_step`): these modules hold the arithmetic of the methods above.
Generic constraint rows (a user's Python function) are evaluated by Python from
inside the compiled step; closed loops by the tree solve of a spanning forest and
the Schur complement of the rows that close them.

"""

from __future__ import annotations

import enum
from typing import ClassVar, Optional

import numpy as np

from .bodies import State
from .dynamics import Dynamics, STEPS
from .errors import SpecError
from .kernels import constrained_step as ckern
from .kernels import free_step as kern
from .kernels import methods
from .kernels.layout import P_T_END, P_T_START
from .kernels.views import Pinned


#: ``error`` argument of the kernels when no estimate is asked for.
_NO_ESTIMATE = np.zeros(0)
#: ``frames, out`` arguments of the free-body kernel when it computes no outputs.
_NO_FRAMES, _NO_OUTPUTS = np.zeros((0, 7)), np.zeros((0, 19))


class Invariant(enum.Enum):
    """Quantities an integrator preserves (to rounding unless stated)."""

    ORIENTATION_ON_SO3 = 'orientation stays on SO(3)'
    LINEAR_MOMENTUM = 'total linear momentum without external force'
    ANGULAR_MOMENTUM = 'angular momentum without external torque'
    SYMPLECTIC = 'the symplectic (Lie-Poisson) structure'
    ENERGY_BOUNDED = 'energy error bounded over long runs, no secular drift'


class Integrator:
    """
    Base class. Subclasses set ``name``, ``order``, ``conserves`` and ``KERNEL``.

    Parameters
    ----------
    dynamics : Dynamics

    """

    name: ClassVar[str] = ''
    order: ClassVar[int] = 0
    conserves: ClassVar[frozenset] = frozenset()
    #: The method's code (:class:`.kernels.methods.Method`).
    KERNEL: ClassVar[int] = -1
    #: Order of the embedded solution whose difference estimates the error (None:
    #: no embedded pair; the accuracy knob then uses step doubling).
    EMBEDDED_ORDER: ClassVar[Optional[int]] = None

    #: Largest rotation (rad) of a constrained body in one (sub)step; a faster one
    #: makes the step split into equal sub-steps (None: never).
    max_rotation: Optional[float] = 0.25
    #: Most sub-steps a step is split into when the position projection of a
    #: constrained step does not converge (see "Sub-steps" above).
    max_substeps: int = 64

    def __init__(self, dynamics: Dynamics) -> None:
        self.dynamics = dynamics
        # The splittings' last kick, reused as the next step's first (first same as
        # last) while the model and the configuration it was evaluated at are current.
        self._kick_buffer = np.zeros((len(dynamics.bodies), 6))
        self._kick_at: Optional[tuple] = None
        self._parameters: Optional[tuple] = None
        # The free-body kernel's workspace, sized for every body of the scene.
        self._ws = np.empty(kern.workspace_size(len(dynamics.bodies)))
        # The arrays of a whole-scene step that persist across steps, as one table.
        self._table: Optional[Pinned] = None
        #: Whether the state the last :meth:`step` returned is finite everywhere
        #: (checked inside the kernels), or None when that step did not check.
        self.finite: Optional[bool] = None

    def step(self, state: State, dt: float, t_end: Optional[float] = None,
             error: Optional[np.ndarray] = None) -> State:
        """
        Advance ``state`` by ``dt`` (s); returns a new State, ``state`` is not modified.

        ``t_end`` is the time of the new state when the caller keeps time as
        ``steps * dt`` (no rounding drift); default ``state.time + dt``. For a
        method with an embedded pair (``EMBEDDED_ORDER``), ``error``, an array of
        one float, is raised to the step's embedded error estimate per unit time
        (the accuracy knob's); the step itself is the same with or without it.
        """
        t_end = state.time + dt if t_end is None else t_end
        err = _NO_ESTIMATE if error is None else error
        if not self.dynamics.constrained:
            return self._free_step(state, dt, t_end, err)
        solver = self.dynamics.solver
        setup = solver.kernel_setup()
        if solver.constraints.moving:
            # Moving drive targets (exact velocity drives): the kernels take them at the
            # start and leave them at the end (t_end: the time the next step starts from).
            solver.targets_at(state.time)
            par = self._kernel_parameters()
            par[P_T_START], par[P_T_END] = state.time, t_end
            solver.kernel_time = None   # until the kernels return: one may raise half-way
            if not len(setup.free) and len(setup.components) == 1:
                new = self._whole_step(state, dt, t_end, setup, err)
            else:
                new = self._constrained_step(state, dt, t_end, setup, err)
            solver.kernel_time = t_end
            return new
        if not len(setup.free) and len(setup.components) == 1:
            return self._whole_step(state, dt, t_end, setup, err)
        return self._constrained_step(state, dt, t_end, setup, err)

    def _kernel_parameters(self) -> np.ndarray:
        """``par`` of the constrained kernels, rebuilt when what it depends on changed."""
        solver = self.dynamics.solver
        # solver.omega is a function of time_constant and dt.
        key = (solver.settings_key(), self.max_rotation, self.max_substeps)
        if self._parameters is None or self._parameters[0] != key:
            self._parameters = (key, solver.kernel_parameters(
                self.max_rotation, self.max_substeps, getattr(self, 'CLOSING', 0.0)))
        return self._parameters[1]

    def _whole_step(self, state: State, dt: float, t_end: float, setup: tuple,
                    err: np.ndarray) -> State:
        """
        Take a step of a scene whose bodies all belong to one component: one compiled call.

        The common case (a mechanism, a chain) of :meth:`_constrained_step`, without
        its bookkeeping of subsets; the arrays that persist across steps go to the
        kernel as one table (:class:`.kernels.views.Pinned`).
        """
        dyn = self.dynamics
        model = dyn.kernel_model(state.time + 0.5 * dt)
        par = self._kernel_parameters()
        table = self._table
        key = table.key if table is not None else None
        if key is None or key[0] is not model or key[1] is not par or key[2] is not setup:
            table = self._component_table(model, par, setup)
        y0 = state.y
        valid = setup.geometry_of[0] is y0
        setup.geometry_of[0] = None   # until the kernel returns: it may raise half-way
        # A new buffer (a copy: the cheapest fresh array), overwritten by the kernel.
        y = y0.copy()
        before = dyn.defer_effect_work() if dyn.effects else None
        with_outputs = dyn.bodies.want_outputs()
        self.finite = ckern.pinned_packed_step(y0, y, dt, valid, with_outputs, err,
                                               table.table)
        dyn.last_multipliers = setup.components[0].multipliers
        if before is not None:
            dyn.count_effect_work_since(before)
        # The component's workspace now holds the geometry of its new configuration.
        setup.geometry_of[0] = y
        dyn.tally[STEPS] += 1
        new = State.of(t_end, y)
        if with_outputs:
            dyn.bodies.outputs_cache.adopt(new)
        return new

    def _component_table(self, model: tuple, par: np.ndarray, setup: tuple):
        """Pin the arrays of :meth:`_whole_step` (kept until one of them changes)."""
        dyn = self.dynamics
        comp = setup.components[0]
        c = dyn.bodies.outputs_cache
        self._table = ckern.component_table(self.KERNEL, model, par, comp.solve, comp.packed,
                                            comp.multipliers, dyn.tally, c.frames, c.out,
                                            (model, par, setup))
        return self._table

    def _free_step(self, state: State, dt: float, t_end: float, err: np.ndarray) -> State:
        """Take a step of bodies no constraint couples: one call of the compiled kernel."""
        dyn = self.dynamics
        model = dyn.kernel_model(state.time + 0.5 * dt)
        table = self._table
        if table is None or table.key is not model:
            c = dyn.bodies.outputs_cache
            table = self._table = kern.free_table(self.KERNEL, model, self._kick_buffer,
                                                  dyn.tally, self._ws, c.frames, c.out)
        y = state.y.copy()
        at = self._kick_at
        valid = at is not None and at[0] == dyn.version and at[1] is state.y
        # The kernel adds its work to the tally that holds the work counters.
        before = dyn.defer_effect_work() if dyn.effects else None
        with_outputs = dyn.bodies.want_outputs()
        code = kern.pinned_free_step(y, dt, valid, with_outputs, err, table.table)
        self._kick_at = (dyn.version, y) if code & kern.KICK_VALID else None
        self.finite = bool(code & kern.FINITE)
        dyn.tally[STEPS] += 1
        if before is not None:
            dyn.count_effect_work_since(before)
        new = State.of(t_end, y)
        if with_outputs:
            dyn.bodies.outputs_cache.adopt(new)
        return new

    def _constrained_step(self, state: State, dt: float, t_end: float, setup: tuple,
                          err: np.ndarray) -> State:
        """
        Take a constrained step in compiled calls: one per component, one for free bodies.

        Each connected component of the constraint graph is sub-stepped (and
        retried) as its own motion needs; bodies no constraint touches take the
        step of an unconstrained scene, whatever the components do.
        """
        dyn = self.dynamics
        solver = dyn.solver
        free, components = setup.free, setup.components
        finite = True
        mid = state.time + 0.5 * dt
        new = State.of(t_end, state.y.copy())
        pos, quat, vel, om = new.parts
        # The kernels add their work to the tally that holds the work counters.
        tally = dyn.tally
        counting = bool(dyn.effects)
        if counting:
            dyn.settle_effect_work()   # counted per subset below
        par = self._kernel_parameters()
        if len(free):
            body, gforce, wrench, flags, acting = dyn.kernel_submodel(mid, free)
            p, q, v, o = pos[free], quat[free], vel[free], om[free]
            before = tally.tolist() if counting else None
            code = kern.free_step(int(self.KERNEL), p, q, v, o, dt, body, gforce, wrench, flags,
                                  np.zeros((len(free), 6)), False, tally, err, self._ws,
                                  _NO_FRAMES, _NO_OUTPUTS)
            finite = bool(code & kern.FINITE)
            pos[free], quat[free], vel[free], om[free] = p, q, v, o
            if counting:
                dyn.count_effect_work_since(before, acting)
        valid = setup.geometry_of[0] is state.y
        setup.geometry_of[0] = None   # until every kernel returns: one may raise half-way
        lam = dyn.last_multipliers
        if len(lam) != solver.constraints.n_rows or lam is components[0].multipliers:
            lam = dyn.last_multipliers = np.zeros(solver.constraints.n_rows)
        for comp in components:
            bodies, lam_c = comp.bodies, comp.multipliers
            body, gforce, wrench, flags, acting = dyn.kernel_submodel(mid, bodies)
            p0, q0, v0, o0 = pos[bodies], quat[bodies], vel[bodies], om[bodies]
            p, q, v, o = (np.empty_like(p0), np.empty_like(q0), np.empty_like(v0),
                          np.empty_like(o0))
            before = tally.tolist() if counting else None
            finite &= ckern.packed_step(int(self.KERNEL), p0, q0, v0, o0, dt, body, gforce, wrench,
                                        flags, par, int(comp.solve), *comp.packed, p, q, v, o,
                                        lam_c, valid,
                                        tally, err, _NO_FRAMES, _NO_OUTPUTS)
            pos[bodies], quat[bodies], vel[bodies], om[bodies] = p, q, v, o
            lam[comp.rows] = lam_c
            if counting:
                dyn.count_effect_work_since(before, acting)
        # Each component's workspace now holds the geometry of its new configuration.
        setup.geometry_of[0] = new.y
        self.finite = finite
        tally[STEPS] += 1
        return new

# ----------------------------------------------------------------------------------------
# The methods (their arithmetic: kernels/free_step.py and kernels/constrained_step.py)


class RKMK4(Integrator):
    """
    Fourth-order Runge–Kutta–Munthe-Kaas (classical RK4 tableau ``A``, ``B``, ``C``).

    Its embedded pair: the third-order weights ``B_HAT`` over the four stages and
    the slopes at the new state (first same as last), for the accuracy knob. The
    tableau is the kernels' (:mod:`.kernels.methods`), the one copy.
    """

    name = 'rkmk4'
    KERNEL = methods.Method.RKMK4
    order = 4
    EMBEDDED_ORDER = 3
    B_HAT = np.array(methods.RK4_B_HAT_NUMERATORS) / methods.RK4_B_DENOMINATOR
    conserves = frozenset({Invariant.ORIENTATION_ON_SO3, Invariant.LINEAR_MOMENTUM})
    A = np.array(methods.RK4_A)
    B = np.array(methods.RK4_B_NUMERATORS) / methods.RK4_B_DENOMINATOR
    C = np.array(methods.RK4_C)


class Splitting(Integrator):
    """
    Kick–drift splitting with the free rotor split about principal axes.

    ``COMPOSITION`` lists the sub-step weights (fractions of ``dt``) of
    symmetric Strang steps composed into one step; ``SYMMETRIC`` False gives the
    first-order Lie–Trotter kick-then-drift (the kernels implement these).
    """

    SYMMETRIC: ClassVar[bool] = True
    COMPOSITION: ClassVar[tuple] = (1.0,)
    #: m or rad: a larger violation at the start of a (sub)step is still closing
    #: (SHAKE then projects instead of redoing the step finer).
    CLOSING: ClassVar[float] = 1e-6


class SymplecticEuler(Splitting):
    """First-order symplectic (semi-implicit) Euler: kick, then drift."""

    name = 'symplectic_euler'
    KERNEL = methods.Method.SYMPLECTIC_EULER
    order = 1
    conserves = frozenset({Invariant.ORIENTATION_ON_SO3, Invariant.LINEAR_MOMENTUM,
                           Invariant.ANGULAR_MOMENTUM, Invariant.SYMPLECTIC,
                           Invariant.ENERGY_BOUNDED})
    SYMMETRIC = False


class LiePoisson2(Splitting):
    """Second-order symplectic Lie–Poisson splitting (Strang, rotor 1-2-3-2-1)."""

    name = 'lie_poisson2'
    KERNEL = methods.Method.LIE_POISSON2
    order = 2
    conserves = SymplecticEuler.conserves


class LiePoisson4(Splitting):
    """Fourth-order symplectic splitting: Yoshida's triple jump of lie_poisson2."""

    name = 'lie_poisson4'
    KERNEL = methods.Method.LIE_POISSON4
    order = 4
    conserves = SymplecticEuler.conserves
    COMPOSITION = methods.TRIPLE_JUMP


INTEGRATORS: dict[str, type] = {
    cls.name: cls for cls in (SymplecticEuler, RKMK4, LiePoisson2, LiePoisson4)}


def integrator_class(name: str, field_name: str = 'integrator') -> type:
    """Integrator class registered under ``name``; SpecError listing the known names."""
    try:
        return INTEGRATORS[name]
    except (KeyError, TypeError):
        raise SpecError(field_name, f'unknown integrator {name!r}; known: '
                                    f'{sorted(INTEGRATORS)}') from None
