"""
Right-hand side of the Newton–Euler equations for all bodies at once.

For body k (seed eq. 69 without constraints), in the principal frame::

    m ẍ_g = f_world
    J dΩ/dt + Ω × JΩ = τ_principal
    dR/dt = R hat(Ω)

:class:`Dynamics` evaluates only what the scene contains: the effects it was
given, and the gyroscopic term ``Ω × JΩ`` only for anisotropic bodies. It
counts its work in :class:`WorkCounters`. The steps evaluate it in compiled
code, from the arrays of :meth:`Dynamics.kernel_model`; the numpy right-hand
side here (:meth:`Dynamics.accelerations`) serves the references
(:mod:`.reference`), the reactions and the tests.
"""

from __future__ import annotations

from typing import ClassVar, Mapping, Optional, Sequence

import numpy as np

from . import rotation as so3
from .bodies import BodySet
from .effects import Effect, EFFECTS, KernelModel, Kinematics, WrenchAccumulator
from .errors import SpecError
from .kernels.free_step import HAS_POSITION_FORCES
from .kernels.layout import Count, N_COUNTS, W_BODY, W_KIND, W_PARENT, WRENCH_DRIVE

#: Slot of the steps in a work tally; the slots before it are the compiled kernels'
#: count slots (:mod:`.kernels.free_step`, :mod:`.kernels.constrained_step`).
STEPS = N_COUNTS
#: Length of a work tally.
N_TALLY = N_COUNTS + 1


class TalliedCounters:
    """
    Counters kept in slots of one int64 array, the tally, that the compiled steps add to.

    Subclasses name their slots in ``SLOTS``; each name is an int attribute
    (read and assigned as usual). Counter objects built on the same tally share
    it: a step's kernels then count all their work in one array, with no
    per-counter bookkeeping. :meth:`reset` zeros this object's slots in place,
    :meth:`restore` sets them (say, to an :meth:`as_dict` taken earlier).
    """

    SLOTS: ClassVar[dict] = {}

    def __init_subclass__(cls, **kwargs) -> None:
        """Make each slot an int attribute."""
        super().__init_subclass__(**kwargs)
        for name, slot in cls.SLOTS.items():
            setattr(cls, name, property(
                lambda self, slot=slot: int(self.tally[slot]),
                lambda self, value, slot=slot: self.tally.__setitem__(slot, value)))

    def __init__(self, *, tally: Optional[np.ndarray] = None, **values: int) -> None:
        self.tally = tally if tally is not None else np.zeros(N_TALLY, dtype=np.int64)
        self.restore(values)

    def restore(self, saved: Mapping[str, int]) -> None:
        """Set each counter to its value in ``saved`` (0 if missing), in place."""
        unknown = sorted(set(saved) - set(self.SLOTS))
        if unknown:
            raise TypeError(f'{type(self).__name__} has no counter {unknown[0]!r}')
        for name, slot in self.SLOTS.items():
            self.tally[slot] = saved.get(name, 0)

    def reset(self) -> None:
        """Zero the counters in place (the tally's other slots keep their values)."""
        self.restore({})

    def as_dict(self) -> dict:
        """Counters as a plain dict."""
        n = self.tally.tolist()
        return {name: n[slot] for name, slot in self.SLOTS.items()}

    def __eq__(self, other: object) -> bool:
        """Tell whether ``other`` is of this class and counts the same."""
        return type(other) is type(self) and self.as_dict() == other.as_dict()

    __hash__ = None   # type: ignore[assignment]

    def __repr__(self) -> str:
        """Show the counters as a dataclass would."""
        items = ', '.join(f'{k}={v}' for k, v in self.as_dict().items())
        return f'{type(self).__name__}({items})'


class WorkCounters(TalliedCounters):
    """
    Work done so far (reset with the simulation).

    Attributes
    ----------
    steps : int
        Integrator steps taken.
    rhs_evaluations : int
        Full right-hand sides (every effect plus the gyroscopic term).
    kick_evaluations : int
        Position-dependent wrenches only (the kicks of splitting methods).
    gyroscopic_body_evaluations : int
        Bodies for which ``Ω × JΩ`` or a free-rotor sub-flow was computed.
    rotation_updates : int
        Body orientations updated by an exponential map.
    substeps : int
        Sub-steps taken by steps that had to be split (see "Sub-steps" in
        :mod:`.integrators`); 0 when every step was taken whole.
    retries : int
        Steps redone with twice as many sub-steps because the position
        projection (SHAKE) did not converge in them.
    capped_steps : int
        Steps whose bodies turned so fast that the sub-steps their rotation
        called for exceeded ``Integrator.max_substeps``: they were taken in
        ``max_substeps`` sub-steps, each turning by more than ``max_rotation``
        (bounded work, lower accuracy; the node reports them on diagnostics).
    unconverged_projections : int
        (Sub)steps whose position projection (SHAKE, or its last resort) ended
        after ``max_iterations`` with ``|Φ − target|`` above the tolerance (and
        above the coordinates' rounding): the step was kept, less accurate; the
        node reports them on diagnostics.

    """

    SLOTS = {'steps': STEPS, 'rhs_evaluations': Count.RHS, 'kick_evaluations': Count.KICK,
             'gyroscopic_body_evaluations': Count.GYRO, 'rotation_updates': Count.ROT,
             'substeps': Count.SUBSTEPS, 'retries': Count.RETRIES, 'capped_steps': Count.CAPPED,
             'unconverged_projections': Count.UNCONVERGED}


class SolverCounters(TalliedCounters):
    """Work of the constraint solver: factorizations and projection iterations."""

    SLOTS = {'geometry_evaluations': Count.GEOMETRY, 'factorizations': Count.FACTORIZATIONS,
             'rank_deficient_solves': Count.RANK_DEFICIENT,
             'projection_fallbacks': Count.FALLBACKS, 'acceleration_solves': Count.ACC_SOLVES,
             'position_iterations': Count.POS_ITERATIONS,
             'velocity_projections': Count.VEL_PROJECTIONS,
             'inertia_form_fallbacks': Count.INERTIA_FALLBACKS}


class Dynamics:
    """
    Bodies plus effects: forces, torques and accelerations, vectorized over bodies.

    Parameters
    ----------
    bodies : BodySet
    effects : sequence of Effect
        Already bound to ``bodies``.

    """

    def __init__(self, bodies: BodySet, effects: Sequence[Effect]) -> None:
        self.bodies = bodies
        for i, effect in enumerate(effects):
            check_kernel_effect(effect, f'effects[{i}]')
        self.effects = list(effects)
        # The work tally the compiled steps add to: the counters of this object and of
        # its solver (SolverCounters on the same tally) are slots of it.
        self.tally = np.zeros(N_TALLY, dtype=np.int64)
        self.counters = WorkCounters(tally=self.tally)
        # Set by the Simulation: constraint rows and their solver (None: no constraints).
        self.solver = None
        self.last_multipliers = np.zeros(0)
        # Incremented whenever the model changes between steps (a wrench is
        # applied, an effect added): integrators key cached evaluations on it.
        self.version = 0
        self._kernel_model: Optional[tuple] = None
        self._submodels: dict = {}
        # Kernel work of whole-scene steps not yet added to the effects' counters:
        # (the kernel model it was done with, the tally before it); see defer_effect_work.
        self._unsettled: Optional[tuple] = None

    def add_effect(self, effect: Effect) -> None:
        """Add an (already bound) effect between steps."""
        check_kernel_effect(effect, 'effect')
        self.settle_effect_work()
        self.effects.append(effect)
        self.changed()

    def changed(self) -> None:
        """Mark the model as changed, which invalidates cached evaluations."""
        self.settle_effect_work()
        self.version += 1

    def kernel_model(self, time_mid: float) -> tuple:
        """
        Return the effects as :mod:`.kernels.free_step` takes them: (body, gforce, wrench, flags).

        Each effect adds its own encoding (:meth:`.effects.Effect.add_to_kernel_model`).
        Rebuilt only when the model changed (``version``); ``time_mid`` picks the
        active wrenches of an AppliedWrenches table that no Simulation switched
        (:meth:`.effects.AppliedWrenches.begin_step`).
        """
        cached = self._kernel_model
        if cached is not None and cached[0] == self.version and cached[1] in (None, time_mid):
            return cached[2]
        model = KernelModel(self.bodies)
        rows = []   # per effect, the range of its rows in the wrench array
        for effect in self.effects:
            start = model.n_wrench_rows
            effect.add_to_kernel_model(model, time_mid)
            rows.append((start, model.n_wrench_rows))
        arrays = model.arrays()
        # A model that depends on the time (a wrench table no Simulation switches) is not
        # reused at another time.
        self._kernel_model = (self.version, time_mid if model.time_dependent else None, arrays,
                              rows)
        return arrays

    def kernel_submodel(self, time_mid: float, bodies: np.ndarray) -> tuple:
        """
        Return :meth:`kernel_model` for the subset ``bodies`` (indices), renumbered.

        Also returns, per effect, how many bodies (or wrench entries) it acts on
        in the subset, for :meth:`count_effect_work`. Cached until the model changes.
        """
        body, gforce, wrench, flags = self.kernel_model(time_mid)
        cache = self._submodels
        if cache.get('model') is not body:
            cache.clear()
            cache['model'] = body
        hit = cache.get(id(bodies))
        if hit is not None and hit[0] is bodies:
            return hit[1]
        local = np.full(len(self.bodies), -1)
        local[bodies] = np.arange(len(bodies))
        keep = local[wrench[:, W_BODY].astype(int)] >= 0
        sub_wrench = wrench[keep]
        sub_wrench[:, W_BODY] = local[sub_wrench[:, W_BODY].astype(int)]
        drive = sub_wrench[:, W_KIND] == WRENCH_DRIVE
        if np.any(drive):
            # A drive's parent is in the subset too (a joint joins one component), or the
            # world: index n here, len(bodies) there.
            outer = np.append(local, len(bodies))
            sub_wrench[drive, W_PARENT] = outer[sub_wrench[drive, W_PARENT].astype(int)]
        sub_flags = flags
        if not np.any(gforce[bodies]) and not len(sub_wrench):
            sub_flags &= ~HAS_POSITION_FORCES
        acting = [effect.acting_in(local, keep[start:stop])
                  for effect, (start, stop) in zip(self.effects, self._kernel_model[3])]
        model = (np.ascontiguousarray(body[bodies]), np.ascontiguousarray(gforce[bodies]),
                 np.ascontiguousarray(sub_wrench), sub_flags, acting)
        cache[id(bodies)] = (bodies, model)
        return model

    def count_effect_work(self, rhs: int, kicks: int, flows: int,
                          acting: Optional[list] = None) -> None:
        """
        Add compiled-kernel work to each effect's counters, as if evaluated one by one.

        ``acting``: per effect, the bodies (wrench entries) it acts on in the
        step's subset (see :meth:`kernel_submodel`); default all. Each effect
        says what it counts (:meth:`.effects.Effect.count_kernel_work`).
        """
        for i, effect in enumerate(self.effects):
            effect.count_kernel_work(rhs, kicks, flows, None if acting is None else acting[i])

    def defer_effect_work(self) -> Optional[list]:
        """
        Call before a kernel steps every body with :meth:`kernel_model`'s arrays.

        The effects' counters are a linear function of the tallied right-hand
        sides, kicks and flows for as long as the model stays the same, so the
        work of a run of such steps is added to them at once, when the model
        changes or the counters are read (:meth:`settle_effect_work`), instead of
        after every step. Returns None then; for a model that depends on the
        time (a wrench table no Simulation switches), the tally before the call,
        for :meth:`count_effect_work_since` right after it.
        """
        key = self._kernel_model
        pending = self._unsettled
        if key is not None and key[1] is None:
            if pending is None or pending[0] is not key:
                self.settle_effect_work()
                self._unsettled = (key, self.tally.tolist())
            return None
        self.settle_effect_work()
        return self.tally.tolist()

    def settle_effect_work(self) -> None:
        """Add the deferred kernel work (:meth:`defer_effect_work`) to the effects' counters."""
        pending = self._unsettled
        if pending is not None:
            self._unsettled = None
            self.count_effect_work_since(pending[1])

    def discard_effect_work(self) -> None:
        """Drop the deferred kernel work (the tally was reset or restored under it)."""
        self._unsettled = None

    def count_effect_work_since(self, before: list, acting: Optional[list] = None) -> None:
        """
        Do :meth:`count_effect_work` for the kernel work tallied since ``before``.

        ``before``: ``tally.tolist()`` before the kernel calls.
        """
        n = self.tally.tolist()
        rhs, kick, flow, damp = Count.RHS, Count.KICK, Count.FLOW, Count.DAMP_IN_KICK
        self.count_effect_work(n[rhs] - before[rhs], n[kick] - before[kick],
                               n[flow] + n[damp] - before[flow] - before[damp],
                               acting)

    @property
    def constrained(self) -> bool:
        """Tell whether the scene has constraint rows (only then is λ solved for)."""
        return self.solver is not None and self.solver.constraints.n_rows > 0

    def kinematics(self, time: float, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
                   omega: np.ndarray) -> Kinematics:
        """Bundle a state for effect evaluation (computes rotation matrices once)."""
        return Kinematics(time, pos, so3.quat_to_matrix(quat), vel, omega)

    def wrench(self, kin: Kinematics, effects: Sequence[Effect]) -> tuple[np.ndarray, np.ndarray]:
        """Sum of ``effects`` at ``kin``: force (n, 3) world, torque (n, 3) principal."""
        acc = WrenchAccumulator(len(self.bodies))
        for effect in effects:
            effect.accumulate(kin, acc)
        return acc.force_world, acc.total_torque_principal(kin.R_principal_world)

    def gyroscopic(self, omega: np.ndarray) -> np.ndarray:
        """``Ω × JΩ`` for every body (n, 3); zero rows, never computed, for isotropic bodies."""
        out = np.zeros_like(omega)
        a = self.bodies.anisotropic
        if len(a):
            w = omega[a]
            out[a] = so3.cross(w, self.bodies.moments[a] * w)
            self.counters.gyroscopic_body_evaluations += len(a)
        return out

    def accelerations(self, time: float, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
                      omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """
        Free accelerations: linear (n, 3, world) and dΩ/dt (n, 3, principal) of every body.

        Every effect and the gyroscopic term, evaluated in numpy, without the
        constraints' forces (those come from the compiled solve in a step, and from
        :func:`.reference.constrained_accelerations` for references and tests).
        """
        self.counters.rhs_evaluations += 1
        kin = self.kinematics(time, pos, quat, vel, omega)
        force, torque = self.wrench(kin, self.effects)
        torque = torque - self.gyroscopic(omega)
        return force * self.bodies.inv_mass[:, None], torque / self.bodies.moments


def check_kernel_effect(effect: Effect, field_name: str) -> None:
    """Raise SpecError unless ``effect`` is one the compiled step evaluates (has an encoding)."""
    if not (isinstance(effect, Effect)
            and type(effect).add_to_kernel_model is not Effect.add_to_kernel_model):
        raise SpecError(field_name, f'{type(effect).__name__} is not an effect the compiled '
                                    f'step evaluates; known: {list(EFFECTS)}')
