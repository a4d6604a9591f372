"""
Fixed-step integrators on (R³ × SO(3) × R³ × R³)ⁿ behind one contract.

Each integrator class is mostly data (name, order, what it conserves, a
tableau) and implements ``_step``; the public :meth:`Integrator.step` does the
bookkeeping and counts work. Orientation is always updated by the exponential
map ``q <- q ⊗ exp(u)`` (see :mod:`.rotation`), so it stays on SO(3) by
construction; quaternions are renormalized only to remove rounding error.

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

Damping, where the scene has it, is advanced by its exact exponential flow
inside the splitting methods (first half-step and last half-step), so they keep
their order; other velocity-dependent effects are evaluated in the kick.

Constraints (see :mod:`.solver`)
--------------------------------
``symplectic_euler``, ``lie_poisson2``, ``lie_poisson4``
    RATTLE in every (sub)step: the kick carries the constraint force of the
    acceleration-level solve as a predictor; the half-step velocities then get
    the impulse along ``G(q_start)ᵀ`` for which the drift from the start lands
    on ``Φ = exp(−h/τ) Φ_start`` (SHAKE, Newton iterations that redo the drift),
    and the end velocities the impulse along ``G(q_end)ᵀ`` onto
    ``Φ̇ = −ωΦ`` (``ω = 1/τ``, at most ``1/(2 dt)``). Symmetric and
    symplectic; internal joints conserve linear and angular momentum to
    rounding; the orders stay 1, 2 and 4 (measured).
``rkmk4``
    The constraint force of the Baumgarte-stabilized acceleration-level solve
    at every stage, then the end velocities projected onto ``Φ̇ = −ωΦ`` (an
    internal impulse: momenta conserved). No position projection: it would move
    bodies at fixed momenta; the O(h⁵) drift per step decays through the
    velocity target instead (measured violation ~1e-12 m at dt = 1e-3, 1e-3 m
    at dt = 0.2 s, where the capped ω still halves it every step).

A step in which a constrained body would turn by more than ``max_rotation``
(0.25 rad) is split into equal sub-steps (see :meth:`Integrator.substeps`):
a fixed step cannot resolve a whip. A splitting step whose SHAKE iterations
still fail is redone with twice the sub-steps (:class:`NotConverged`). Each
connected component of the constraint graph gets the sub-steps its own motion
needs; bodies no constraint touches, and scenes without constraints, are never
sub-stepped.

Compiled kernels
----------------
A step is one compiled call (numba): :mod:`.step_kernels` for bodies no
constraint couples, :mod:`.constrained_kernels` for each component of the
constraint graph (sub-steps and retries included). The Python code below is
the readable description of the same methods and still runs the scenes the
kernels do not take: a constraint set with a generic (user-function) row, or a
closed loop of more than ``DENSE_ROWS`` rows (the sparse LU path).

"""

from __future__ import annotations

import enum
from typing import ClassVar, Optional

import numpy as np

from . import constrained_kernels as ckern
from . import rotation as so3
from . import step_kernels as kern
from .bodies import State
from .dynamics import Dynamics
from .errors import SpecError


class NotConverged(Exception):
    """
    A (sub)step's position projection did not converge: redo the step finer.

    Raised inside a splitting step when SHAKE's Newton iterations stop
    halving the residual on joints that hold (a joint still closing a violation
    is projected instead), which happens when a constrained body turned much
    further within the step than at its start (a whip that accelerates). The
    step is then retried from its start with twice the sub-steps, up to
    ``Integrator.max_substeps``; only there does the projection fall back to an
    orthogonal projection (not momentum-consistent: a last resort).
    """


class Invariant(enum.Enum):
    """Quantities an integrator preserves (to rounding unless stated)."""

    ORIENTATION_ON_SO3 = 'orientation stays on SO(3)'
    LINEAR_MOMENTUM = 'total linear momentum without external force'
    ANGULAR_MOMENTUM = 'angular momentum without external torque'
    SYMPLECTIC = 'the symplectic (Lie-Poisson) structure'
    ENERGY_BOUNDED = 'energy error bounded over long runs, no secular drift'


class Integrator:
    """
    Base class. Subclasses set ``name``, ``order``, ``conserves`` and ``_step``.

    Parameters
    ----------
    dynamics : Dynamics

    """

    name: ClassVar[str] = ''
    order: ClassVar[int] = 0
    conserves: ClassVar[frozenset] = frozenset()
    #: The method's code in :mod:`.step_kernels`.
    KERNEL: ClassVar[int] = -1

    #: Largest rotation (rad) of a constrained body in one (sub)step; a faster one
    #: makes the step split into equal sub-steps (None: never).
    max_rotation: Optional[float] = 0.25
    #: Most sub-steps a step is split into when the position projection of a
    #: constrained step does not converge (see :class:`NotConverged`).
    max_substeps: int = 64
    _last_resort: bool = True

    def __init__(self, dynamics: Dynamics) -> None:
        self.dynamics = dynamics
        # The splittings' last kick, reused as the next step's first (first same as
        # last) while the model and the configuration it was evaluated at are current.
        self._kick_buffer = np.zeros((len(dynamics.bodies), 6))
        self._kick_at: Optional[tuple] = None
        self._geometry_at: Optional[tuple] = None
        self._parameters: Optional[tuple] = None

    def substeps(self, state: State, dt: float) -> int:
        """
        Return the number of equal sub-steps for a step of ``dt`` from ``state``.

        The position projection (SHAKE's Newton iterations) linearizes the
        constraints over one step, which fails when a constrained body turns by
        more than about a quarter radian in it (a whip, a fast spin under a
        joint). Such a step is split into ``ceil(|Ω|max dt / max_rotation)``
        sub-steps, counted in ``WorkCounters.substeps``. Only constrained bodies
        are watched, and a scene without constraints is never sub-stepped:
        each body gets exactly the step the user asked for (the splittings'
        rotor flows are exact at any rate; ``rkmk4``'s accuracy at large
        ``|Ω| dt`` is what the work-precision benchmark shows), so its motion
        does not depend on the other bodies. The compiled step applies the count
        to each connected component of the constraint graph separately (see
        :mod:`.constrained_kernels`); the Python step, to the whole scene.
        """
        if self.max_rotation is None:
            return 1
        dyn = self.dynamics
        if not dyn.constrained:
            return 1
        watch = dyn.solver.constraints.touched
        if not len(watch):
            return 1
        rate = float(np.max(np.abs(state.ang_vel_principal[watch])))
        return max(1, int(np.ceil(rate * abs(dt) / self.max_rotation)))

    def step(self, state: State, dt: float, t_end: Optional[float] = None) -> State:
        """
        Advance ``state`` by ``dt`` (s); returns a new State, ``state`` is not modified.

        ``t_end`` is the time of the new state when the caller keeps time as
        ``steps * dt`` (no rounding drift); default ``state.time + dt``.
        """
        t_end = state.time + dt if t_end is None else t_end
        if not self.dynamics.constrained:
            return self._free_step(state, dt, t_end)
        setup = self.dynamics.solver.kernel_setup()
        if setup is not None:
            return self._constrained_step(state, dt, t_end, setup)
        # Generic rows (a user's Python function) or a large closed loop: in Python.
        k = self.substeps(state, dt)
        while True:
            # At the finest split a step must finish: the projection then falls back.
            self._last_resort = k >= self.max_substeps
            try:
                new = self._substepped(state, dt, t_end, k)
                break
            except NotConverged:
                # A whip sped up within the step: redo it from the start, finer.
                self.dynamics.counters.retries += 1
                k = min(2 * k, self.max_substeps)
        new.time = t_end
        q = new.quat_principal_world
        q /= np.linalg.norm(q, axis=-1, keepdims=True)   # rounding only, in place
        self.dynamics.counters.steps += 1
        return new

    def _free_step(self, state: State, dt: float, t_end: float) -> State:
        """Take a step of bodies no constraint couples: one call of the compiled kernel."""
        dyn = self.dynamics
        body, gforce, wrench, flags = dyn.kernel_model(state.time + 0.5 * dt)
        pos, quat = state.pos_com_world.copy(), state.quat_principal_world.copy()
        vel, om = state.vel_com_world.copy(), state.ang_vel_principal.copy()
        at = self._kick_at
        valid = (at is not None and at[0] == dyn.version and at[1] is state.pos_com_world
                 and at[2] is state.quat_principal_world)
        counts = np.zeros(5, dtype=np.int64)
        valid = kern.free_step(self.KERNEL, pos, quat, vel, om, dt, body, gforce, wrench, flags,
                               self._kick_buffer, valid, counts)
        self._kick_at = (dyn.version, pos, quat) if valid else None
        rhs, kicks, gyro, rot, flows = counts.tolist()
        c = dyn.counters
        c.rhs_evaluations += rhs
        c.kick_evaluations += kicks
        c.gyroscopic_body_evaluations += gyro
        c.rotation_updates += rot
        c.steps += 1
        if dyn.effects:
            dyn.count_effect_work(rhs, kicks, flows)
        return State(t_end, pos, quat, vel, om)

    def _constrained_step(self, state: State, dt: float, t_end: float, setup: tuple) -> State:
        """
        Take a constrained step in compiled calls: one per component, one for free bodies.

        Each connected component of the constraint graph is sub-stepped (and
        retried) as its own motion needs; bodies no constraint touches take the
        step of an unconstrained scene, whatever the components do.
        """
        dyn = self.dynamics
        solver = dyn.solver
        free, components = setup
        mid = state.time + 0.5 * dt
        whole = not len(free) and len(components) == 1   # one component, every body
        pos, quat = state.pos_com_world, state.quat_principal_world
        vel, om = state.vel_com_world, state.ang_vel_principal
        if whole:
            pos, quat, vel, om = (np.empty_like(pos), np.empty_like(quat), np.empty_like(vel),
                                  np.empty_like(om))
        else:
            pos, quat, vel, om = pos.copy(), quat.copy(), vel.copy(), om.copy()
        counts = np.zeros(ckern.N_COUNTS, dtype=np.int64)
        key = (solver.time_constant, solver.omega, self.max_rotation, self.max_substeps)
        if self._parameters is None or self._parameters[0] != key:
            self._parameters = (key, solver.kernel_parameters(
                self.max_rotation, self.max_substeps, getattr(self, 'CLOSING', 0.0)))
        par = self._parameters[1]
        if len(free):
            body, gforce, wrench, flags, acting = dyn.kernel_submodel(mid, free)
            p, q, v, o = pos[free], quat[free], vel[free], om[free]
            part = np.zeros(5, dtype=np.int64)
            kern.free_step(self.KERNEL, p, q, v, o, dt, body, gforce, wrench, flags,
                           np.zeros((len(free), 6)), False, part)
            pos[free], quat[free], vel[free], om[free] = p, q, v, o
            counts[:5] += part
            dyn.count_effect_work(int(part[kern.RHS]), int(part[kern.KICK]),
                                  int(part[kern.FLOW]), acting)
        at = self._geometry_at
        valid = (at is not None and at[0] is setup and at[1] is state.pos_com_world
                 and at[2] is state.quat_principal_world)
        lam = dyn.last_multipliers
        if not whole and (len(lam) != solver.constraints.n_rows or lam is components[0][7]):
            lam = dyn.last_multipliers = np.zeros(solver.constraints.n_rows)
        for bodies, rows_global, rows, use_tree, tree, dense, ws, lam_c in components:
            if whole:
                body, gforce, wrench, flags = dyn.kernel_model(mid)
                acting = None
                p0, q0, v0, o0 = (state.pos_com_world, state.quat_principal_world,
                                  state.vel_com_world, state.ang_vel_principal)
                p, q, v, o = pos, quat, vel, om
            else:
                body, gforce, wrench, flags, acting = dyn.kernel_submodel(mid, bodies)
                p0, q0, v0, o0 = pos[bodies], quat[bodies], vel[bodies], om[bodies]
                p, q, v, o = (np.empty_like(p0), np.empty_like(q0), np.empty_like(v0),
                              np.empty_like(o0))
            part = counts if whole else np.zeros(ckern.N_COUNTS, dtype=np.int64)
            # Only the storage in use is passed (numba compiles each case).
            ckern.constrained_step(self.KERNEL, p0, q0, v0, o0, dt, body, gforce, wrench,
                                   flags, rows, ws[9], par, use_tree,
                                   tree if use_tree else None, None if use_tree else dense, ws,
                                   p, q, v, o, lam_c, valid, part)
            if whole:
                dyn.last_multipliers = lam_c
            else:
                pos[bodies], quat[bodies], vel[bodies], om[bodies] = p, q, v, o
                lam[rows_global] = lam_c
                counts += part
            dyn.count_effect_work(int(part[kern.RHS]), int(part[kern.KICK]),
                                  int(part[kern.FLOW] + part[ckern.DAMP_IN_KICK]), acting)
        # Each component's workspace now holds the geometry of its new configuration.
        self._geometry_at = (setup, pos, quat)
        n = counts.tolist()
        c = dyn.counters
        c.rhs_evaluations += n[kern.RHS]
        c.kick_evaluations += n[kern.KICK]
        c.gyroscopic_body_evaluations += n[kern.GYRO]
        c.rotation_updates += n[kern.ROT]
        c.substeps += n[ckern.SUBSTEPS]
        c.retries += n[ckern.RETRIES]
        c.steps += 1
        sc = solver.counters
        sc.geometry_evaluations += n[ckern.GEOMETRY]
        sc.factorizations += n[ckern.FACTORIZATIONS]
        sc.rank_deficient_solves += n[ckern.RANK_DEFICIENT]
        sc.projection_fallbacks += n[ckern.FALLBACKS]
        sc.acceleration_solves += n[ckern.ACC_SOLVES]
        sc.position_iterations += n[ckern.POS_ITERATIONS]
        sc.velocity_projections += n[ckern.VEL_PROJECTIONS]
        return State(t_end, pos, quat, vel, om)

    def _substepped(self, state: State, dt: float, t_end: float, k: int) -> State:
        """Advance by ``k`` equal sub-steps of ``dt / k``."""
        if k == 1:
            return self._step(state, dt, t_end)
        self.dynamics.counters.substeps += k
        new, h = state, dt / k
        for i in range(k):
            te = t_end if i == k - 1 else state.time + (i + 1) * h
            new = self._step(new, h, te)
            new.time = te
        return new

    def _step(self, state: State, dt: float, t_end: float) -> State:
        raise NotImplementedError

    def _rotate(self, quat: np.ndarray, rotvec_principal: np.ndarray) -> np.ndarray:
        """``q ⊗ exp(u)`` for every body."""
        self.dynamics.counters.rotation_updates += len(quat)
        return so3.quat_multiply(quat, so3.exp_quat(rotvec_principal))


# ----------------------------------------------------------------------------------------
# Runge–Kutta–Munthe-Kaas


def dexpinv_right(u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """
    Inverse right-trivialized derivative of exp on so(3), to second order in ``u``.

    For ``R(t) = R0 exp(hat(u(t)))`` with ``dR/dt = R hat(w)``,
    ``du/dt = w + u × w / 2 + u × (u × w) / 12 + O(|u|⁴)``.

    Parameters
    ----------
    u, w : ndarray, shape (n, 3)
        Rotation vectors of the step so far, and body angular velocities.

    Returns
    -------
    ndarray, shape (n, 3)

    """
    uw = so3.cross(u, w)
    return w + 0.5 * uw + so3.cross(u, uw) / 12.0


class RungeKuttaMuntheKaas(Integrator):
    """Explicit RKMK method from a Butcher tableau (class attributes A, B, C)."""

    A: ClassVar[np.ndarray]
    B: ClassVar[np.ndarray]
    C: ClassVar[np.ndarray]

    def _step(self, state: State, dt: float, t_end: float) -> State:
        dyn = self.dynamics
        if not dyn.constrained:
            return rkmk_step(self, state, dt, self.A, self.B, self.C)
        # Constraint forces at every stage (Baumgarte-stabilized); then the velocities
        # are projected onto Φ̇ = −ωΦ at the end configuration, an internal impulse
        # that conserves momenta and makes the O(dt⁵) position drift decay. A position
        # projection would move bodies at fixed momenta and break angular momentum.
        new = rkmk_step(self, state, dt, self.A, self.B, self.C)
        pos, quat = new.pos_com_world, new.quat_principal_world
        vel, om = dyn.solver.project_velocities(pos, quat, new.vel_com_world,
                                                new.ang_vel_principal)
        return State(new.time, pos, quat, vel, om)


def rkmk_step(integrator: Integrator, s: State, h: float, A: np.ndarray, B: np.ndarray,
              C: np.ndarray) -> State:
    """One RKMK step; positions and velocities by the same tableau as plain RK."""
    dyn = integrator.dynamics
    n_stages = len(B)
    k_pos, k_vel, k_om, k_rot = [], [], [], []
    for i in range(n_stages):
        pos, vel, om = s.pos_com_world.copy(), s.vel_com_world.copy(), s.ang_vel_principal.copy()
        u = np.zeros_like(pos)
        for j in range(i):
            a = A[i, j]
            if a:
                pos += h * a * k_pos[j]
                vel += h * a * k_vel[j]
                om += h * a * k_om[j]
                u += h * a * k_rot[j]
        quat = integrator._rotate(s.quat_principal_world, u) if i else s.quat_principal_world
        acc, om_dot = dyn.accelerations(s.time + C[i] * h, pos, quat, vel, om)
        k_pos.append(vel)
        k_vel.append(acc)
        k_om.append(om_dot)
        k_rot.append(dexpinv_right(u, om) if i else om)
    u = h * sum(b * k for b, k in zip(B, k_rot))
    return State(
        s.time,
        s.pos_com_world + h * sum(b * k for b, k in zip(B, k_pos)),
        integrator._rotate(s.quat_principal_world, u),
        s.vel_com_world + h * sum(b * k for b, k in zip(B, k_vel)),
        s.ang_vel_principal + h * sum(b * k for b, k in zip(B, k_om)),
    )


class RKMK4(RungeKuttaMuntheKaas):
    """Fourth-order Runge–Kutta–Munthe-Kaas (classical RK4 tableau)."""

    name = 'rkmk4'
    KERNEL = kern.RKMK4
    order = 4
    conserves = frozenset({Invariant.ORIENTATION_ON_SO3, Invariant.LINEAR_MOMENTUM})
    A = np.array([[0.0, 0.0, 0.0, 0.0],
                  [0.5, 0.0, 0.0, 0.0],
                  [0.0, 0.5, 0.0, 0.0],
                  [0.0, 0.0, 1.0, 0.0]])
    B = np.array([1.0, 2.0, 2.0, 1.0]) / 6.0
    C = np.array([0.0, 0.5, 0.5, 1.0])


# ----------------------------------------------------------------------------------------
# Splitting methods


def _axis_flow(quat: np.ndarray, mom: np.ndarray, moments: np.ndarray, axis: int,
               dt: float) -> None:
    """
    Exact flow of ``H = L_axis² / (2 J_axis)`` over ``dt``, in place.

    The body rotates by ``φ = dt L_axis / J_axis`` about its principal axis
    ``axis``: ``q <- q ⊗ exp(φ e_axis)`` and ``L <- exp(-φ hat(e_axis)) L``,
    so the world angular momentum ``R L`` is unchanged.
    """
    phi = dt * mom[:, axis] / moments[:, axis]
    c, s = np.cos(phi), np.sin(phi)
    j, k = (axis + 1) % 3, (axis + 2) % 3
    lj, lk = mom[:, j].copy(), mom[:, k]
    mom[:, j] = c * lj + s * lk
    mom[:, k] = c * lk - s * lj
    # q <- q ⊗ (sin(φ/2) e_axis, cos(φ/2)), written out for the one non-zero component.
    half = 0.5 * phi
    c, s = np.cos(half), np.sin(half)
    qi, qj, qk, qw = quat[:, axis].copy(), quat[:, j].copy(), quat[:, k].copy(), quat[:, 3].copy()
    quat[:, axis] = c * qi + s * qw
    quat[:, j] = c * qj + s * qk
    quat[:, k] = c * qk - s * qj
    quat[:, 3] = c * qw - s * qi


class Splitting(Integrator):
    """
    Kick–drift splitting with the free rotor split about principal axes.

    ``COMPOSITION`` lists the sub-step weights (fractions of ``dt``) of
    symmetric Strang steps composed into one step; ``SYMMETRIC`` False gives the
    first-order Lie–Trotter kick-then-drift.
    """

    SYMMETRIC: ClassVar[bool] = True
    COMPOSITION: ClassVar[tuple] = (1.0,)
    #: m or rad: a larger violation at the start of a (sub)step is still closing.
    CLOSING: ClassVar[float] = 1e-6

    def __init__(self, dynamics: Dynamics) -> None:
        super().__init__(dynamics)
        self._cache: Optional[tuple] = None

    def _kick(self, time: float, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
              mom: np.ndarray, tau: float) -> None:
        """``v += tau f/m`` and ``L += tau τ`` in place, reusing the last evaluation if valid."""
        dyn = self.dynamics
        velocity_free = not dyn.velocity_effects and not dyn.constrained
        c = self._cache
        if (velocity_free and c is not None and c[0] == dyn.version and c[1] == time
                and c[2] is pos and c[3] is quat):
            force, torque = c[4], c[5]
        else:
            if not dyn.position_effects and velocity_free:
                return
            force, torque = dyn.kick_wrench(time, pos, quat, vel, mom / dyn.bodies.moments)
            self._cache = (dyn.version, time, pos, quat, force, torque)
        vel += (tau * dyn.bodies.inv_mass)[:, None] * force
        mom += tau * torque

    def _flows(self, vel: np.ndarray, mom: np.ndarray, tau: float) -> None:
        for effect in self.dynamics.flow_effects:
            effect.exact_flow(vel, mom, tau)

    def _drift(self, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray, mom: np.ndarray,
               tau: float) -> tuple[np.ndarray, np.ndarray]:
        """Free flight ``x += tau v`` and the free rotor; returns new (pos, quat)."""
        bodies = self.dynamics.bodies
        pos = pos + tau * vel
        quat = quat.copy()
        a = bodies.anisotropic
        if len(a) == len(bodies):
            quat_a, mom_a, j_a = quat, mom, bodies.moments
        elif len(a):
            quat_a, mom_a, j_a = quat[a], mom[a], bodies.moments[a]
        if len(a):
            counters = self.dynamics.counters
            seq = ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5)) if self.SYMMETRIC \
                else ((0, 1.0), (1, 1.0), (2, 1.0))
            for axis, w in seq:
                _axis_flow(quat_a, mom_a, j_a, axis, w * tau)
                counters.gyroscopic_body_evaluations += len(a)
            counters.rotation_updates += len(a) * len(seq)
            if len(a) < len(bodies):
                quat[a], mom[a] = quat_a, mom_a
        iso = self._isotropic
        if len(iso):
            # Isotropic body: Ω is constant during the drift, exp is exact.
            self.dynamics.counters.rotation_updates += len(iso)
            quat[iso] = so3.quat_multiply(
                quat[iso], so3.exp_quat(tau * mom[iso] / bodies.moments[iso]))
        return pos, quat

    @property
    def _isotropic(self) -> np.ndarray:
        bodies = self.dynamics.bodies
        mask = np.ones(len(bodies), dtype=bool)
        mask[bodies.anisotropic] = False
        return np.flatnonzero(mask)

    def _strang(self, t: float, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
                mom: np.ndarray, h: float, t_next: float) -> tuple:
        """
        One symmetric (or, if not SYMMETRIC, Lie–Trotter) sub-step; RATTLE with constraints.

        With constraints this is RATTLE: the half-step velocities get the
        impulse ``M⁻¹ G_startᵀ κ`` for which the drift *from the start* lands on
        the position constraint (SHAKE, solved by Newton iterations that redo
        the drift), and the final velocities the impulse along ``G_endᵀ`` that
        satisfies the velocity constraint. Both impulses act where their
        Jacobian was taken, so internal constraint forces conserve linear and
        angular momentum exactly, and the sub-step stays symmetric and
        symplectic (a composition of sub-steps keeps its order).
        """
        dyn = self.dynamics
        moments = dyn.bodies.moments
        constrained = dyn.constrained
        if constrained:
            start = dyn.solver.evaluate(pos, quat, vel, mom / moments)
        first = 0.5 * h if self.SYMMETRIC else h
        self._flows(vel, mom, first)
        self._kick(t, pos, quat, vel, mom, first)
        if constrained:
            pos, quat, vel, mom = self._shake(start, pos, quat, vel, mom, h)
        else:
            pos, quat = self._drift(pos, quat, vel, mom, h)
        if self.SYMMETRIC:
            self._kick(t_next, pos, quat, vel, mom, 0.5 * h)
            self._flows(vel, mom, 0.5 * h)
        if constrained:
            vel, om = dyn.solver.project_velocities(pos, quat, vel, mom / moments)
            mom = om * moments
        return pos, quat, vel, mom

    def _shake(self, start, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
               mom: np.ndarray, h: float) -> tuple:
        """Drift with the half-step impulse that puts the end on the position constraint."""
        solver = self.dynamics.solver
        moments = self.dynamics.bodies.moments
        target = np.exp(-h / solver.time_constant) * start.phi
        closing = np.max(np.abs(start.phi), initial=0.0) > self.CLOSING
        previous = np.inf
        for it in range(solver.max_iterations + 1):
            mom_end = mom.copy()
            pos_end, quat_end = self._drift(pos, quat, vel, mom_end, h)
            geo = solver.geometry(pos_end, quat_end)
            r = geo.phi - target
            norm = np.max(np.abs(r), initial=0.0)
            if norm <= solver.position_tolerance:
                break
            if it == solver.max_iterations:
                # Slow (linear) convergence: the residual left is corrected by the next
                # step's projection (its target is relative to where this one ends).
                break
            if norm > 0.5 * previous and not closing and not self._last_resort:
                # Not converging on joints that hold: a body turned too far within the
                # step for the linearization (a whip that speeds up, a fast spin).
                # Redo the step finer.
                raise NotConverged
            if norm > 0.5 * previous:
                # Not converging while a violated joint closes (part of its violation is
                # second order in the motion that closes it, out of reach of a
                # first-order impulse; the closing is not physical motion anyway), or
                # at the finest split: finish with a plain projection of the end.
                solver.counters.projection_fallbacks += 1
                pos_end, quat_end, _, _ = solver.project_positions(
                    start, pos_end, quat_end, vel, mom_end / moments, h, orthogonal=True)
                break
            previous = norm
            solver.counters.position_iterations += 1
            # Φ(end) responds to a start impulse κ like h G_end D M⁻¹ G_startᵀ κ, D the
            # rotor's sensitivity (see constrained_kernels._rotor_jacobians): Newton.
            body = np.zeros((len(moments), 8))
            body[:, 2:5] = moments
            body[self.dynamics.bodies.anisotropic, 7] = 1.0
            jr = np.empty((len(moments), 3, 3))
            ckern._rotor_jacobians(quat, quat_end, mom, body, h, self.SYMMETRIC, jr)
            kappa = solver.solve(geo.jacobian.right_multiplied(jr), start.jacobian, r)
            d = -solver.inv_mass_6 * start.jacobian.rmatvec(kappa) / h
            vel = vel + d[:, :3]
            mom = mom + d[:, 3:] * moments
        return pos_end, quat_end, vel, mom_end

    def _step(self, s: State, dt: float, t_end: float) -> State:
        moments = self.dynamics.bodies.moments
        vel = s.vel_com_world.copy()
        mom = s.ang_vel_principal * moments
        pos, quat = s.pos_com_world, s.quat_principal_world
        t = s.time
        last = len(self.COMPOSITION) - 1
        for i, w in enumerate(self.COMPOSITION):
            # The last sub-step ends exactly at t_end, the time the next step starts
            # from, so its final kick is reused there (first same as last).
            t_next = t_end if i == last else t + w * dt
            pos, quat, vel, mom = self._strang(t, pos, quat, vel, mom, w * dt, t_next)
            t = t_next
        return State(s.time, pos, quat, vel, mom / moments)


class SymplecticEuler(Splitting):
    """First-order symplectic (semi-implicit) Euler: kick, then drift."""

    name = 'symplectic_euler'
    KERNEL = kern.SYMPLECTIC_EULER
    order = 1
    conserves = frozenset({Invariant.ORIENTATION_ON_SO3, Invariant.LINEAR_MOMENTUM,
                           Invariant.ANGULAR_MOMENTUM, Invariant.SYMPLECTIC,
                           Invariant.ENERGY_BOUNDED})
    SYMMETRIC = False


class LiePoisson2(Splitting):
    """Second-order symplectic Lie–Poisson splitting (Strang, rotor 1-2-3-2-1)."""

    name = 'lie_poisson2'
    KERNEL = kern.LIE_POISSON2
    order = 2
    conserves = SymplecticEuler.conserves


_W1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))


class LiePoisson4(Splitting):
    """Fourth-order symplectic splitting: Yoshida's triple jump of lie_poisson2."""

    name = 'lie_poisson4'
    KERNEL = kern.LIE_POISSON4
    order = 4
    conserves = SymplecticEuler.conserves
    COMPOSITION = (_W1, 1.0 - 2.0 * _W1, _W1)


INTEGRATORS: dict[str, type] = {
    cls.name: cls for cls in (SymplecticEuler, RKMK4, LiePoisson2, LiePoisson4)}


def integrator_class(name: str, field_name: str = 'integrator') -> type:
    """Integrator class registered under ``name``; SpecError listing the known names."""
    try:
        return INTEGRATORS[name]
    except (KeyError, TypeError):
        raise SpecError(field_name, f'unknown integrator {name!r}; known: '
                                    f'{sorted(INTEGRATORS)}') from None
