"""
Force generators ("effects"): gravity, damping, applied wrenches.

A scene lists the effects it needs and only those are evaluated: a scene
without gravity never computes a gravity term. Each effect counts its own
evaluations (``evaluations``: calls that did work; ``body_evaluations``: the
number of bodies those calls touched), so tests and benchmarks can show it.

An effect adds to a :class:`WrenchAccumulator`: forces in the world frame
(acting at the centre of mass), torques about the centre of mass either in the
world frame or in the principal frame, whichever is cheaper for the effect.

The steps evaluate effects in compiled code (:mod:`.kernels.free_step`), from
model arrays rebuilt when the scene changes. Each effect owns its part of them,
as Drake's force elements own their contribution: it adds its encoding to a
:class:`KernelModel` (:meth:`Effect.add_to_kernel_model`) and says what work the
kernels did with it (:meth:`Effect.count_kernel_work`, :meth:`Effect.acting_in`).
A new effect is one subclass here and its arithmetic in the kernels.
"""

from __future__ import annotations

from dataclasses import dataclass
import enum
from typing import Any, ClassVar, Optional, Sequence

import numpy as np

from . import rotation as so3
from .bodies import BodySet
from .errors import SpecError
from .kernels.free_step import HAS_DAMPING, HAS_POSITION_FORCES
from .kernels.layout import (B_ANISOTROPIC, B_C_ANG, B_C_LIN, B_INV_MASS, B_MASS, B_MOMENTS,
                             B_WIDTH, ROTOR_TOP, W_BODY, W_FORCE, W_IN_BODY, W_POINT, W_TORQUE,
                             W_WIDTH)
from .validate import finite_array, finite_scalar, nonnegative_scalar


class Frame(enum.Enum):
    """Frame in which a vector of an applied wrench is expressed."""

    WORLD = 'world'
    BODY = 'body'

    @classmethod
    def parse(cls, value: Any, field_name: str = 'frame') -> 'Frame':
        """Frame from a Frame or its name ('world' or 'body')."""
        if isinstance(value, Frame):
            return value
        try:
            return cls(value)
        except ValueError:
            raise SpecError(field_name, f"must be 'world' or 'body', got {value!r}") from None


@dataclass
class Kinematics:
    """
    Positions and velocities at which effects are evaluated (n bodies).

    Attributes
    ----------
    time : float
    pos_com_world : ndarray, shape (n, 3)
    R_principal_world : ndarray, shape (n, 3, 3)
    vel_com_world : ndarray, shape (n, 3)
    ang_vel_principal : ndarray, shape (n, 3)

    """

    time: float
    pos_com_world: np.ndarray
    R_principal_world: np.ndarray
    vel_com_world: np.ndarray
    ang_vel_principal: np.ndarray


class WrenchAccumulator:
    """Sums of forces (world) and torques (world or principal frame) on n bodies."""

    def __init__(self, n: int) -> None:
        self.force_world = np.zeros((n, 3))
        self.torque_principal = np.zeros((n, 3))
        self._torque_world: Optional[np.ndarray] = None

    @property
    def torque_world(self) -> np.ndarray:
        """World-frame torque accumulator (n, 3), allocated on first use."""
        if self._torque_world is None:
            self._torque_world = np.zeros_like(self.force_world)
        return self._torque_world

    def total_torque_principal(self, R_principal_world: np.ndarray) -> np.ndarray:
        """All torques in the principal frame, shape (n, 3)."""
        if self._torque_world is None:
            return self.torque_principal
        return self.torque_principal + np.einsum('nji,nj->ni', R_principal_world,
                                                 self._torque_world)


class KernelModel:
    """
    The compiled steps' model arrays while the effects add to them.

    The layout is that of :mod:`.kernels.free_step` ("Model arrays"), its
    columns named in :mod:`.kernels.layout` (``BODY``, ``WRENCH``). Built by
    :meth:`.dynamics.Dynamics.kernel_model` when the scene changes: the bodies'
    columns here, then each effect's :meth:`Effect.add_to_kernel_model`.

    Parameters
    ----------
    bodies : BodySet

    Attributes
    ----------
    body : ndarray, shape (n, B_WIDTH)
        ``mass, 1/mass, J1, J2, J3, c_lin, c_ang, anisotropic`` per body
        (``anisotropic``: 0.0 isotropic, 1.0 asymmetric, ``ROTOR_TOP + a`` a
        symmetric top with distinct axis ``a``, see :data:`.kernels.layout.BODY`).
    gforce : ndarray, shape (n, 3)
        N, world: constant forces at the centres of mass (gravity).
    wrench_rows : list of ndarray, shape (k, W_WIDTH)
        Rows of the applied wrenches active in the step, in effect order
        (:meth:`add_wrench_rows`).
    n_wrench_rows : int
        Rows in ``wrench_rows`` so far.
    flags : int
        Bits ``HAS_POSITION_FORCES`` and ``HAS_DAMPING`` of the kernels.
    time_dependent : bool
        Whether the arrays depend on the step's midpoint (then rebuilt every step).

    """

    def __init__(self, bodies: BodySet) -> None:
        n = len(bodies)
        self.body = np.zeros((n, B_WIDTH))
        self.body[:, B_MASS], self.body[:, B_INV_MASS] = bodies.mass, bodies.inv_mass
        self.body[:, B_MOMENTS:B_MOMENTS + 3] = bodies.moments
        self.body[bodies.anisotropic, B_ANISOTROPIC] = 1.0
        top = bodies.top_axes()
        self.body[top >= 0, B_ANISOTROPIC] = ROTOR_TOP + top[top >= 0]
        self.gforce = np.zeros((n, 3))
        self.wrench_rows: list = []
        self.n_wrench_rows = 0
        self.flags = 0
        self.time_dependent = False

    def add_wrench_rows(self, rows: np.ndarray) -> None:
        """Append rows (k, W_WIDTH) to the wrench array."""
        self.wrench_rows.append(rows)
        self.n_wrench_rows += len(rows)

    def arrays(self) -> tuple:
        """Return ``(body, gforce, wrench, flags)`` as the kernels take them."""
        wrench = np.concatenate([np.zeros((0, W_WIDTH))] + self.wrench_rows)
        return self.body, self.gforce, wrench, self.flags


class Effect:
    """
    Base class: a force generator bound to a :class:`BodySet`.

    A subclass evaluates its wrench in numpy (:meth:`accumulate`, for the
    references and the tests) and in the compiled steps (its encoding,
    :meth:`add_to_kernel_model`, and its work, :meth:`count_kernel_work` and
    :meth:`acting_in`).
    """

    #: Name used in scene files and the registry.
    name: ClassVar[str] = ''
    #: True when the wrench depends on velocities (then it is not a potential force).
    velocity_dependent: ClassVar[bool] = False

    def __init__(self) -> None:
        self.evaluations = 0
        self.body_evaluations = 0

    def bind(self, bodies: BodySet) -> None:
        """Resolve body names to indices and precompute arrays."""
        self.bodies = bodies

    def accumulate(self, kin: Kinematics, acc: WrenchAccumulator) -> None:
        """Add this effect's wrench at ``kin`` to ``acc``."""
        raise NotImplementedError

    def add_to_kernel_model(self, model: KernelModel, time_mid: float) -> None:
        """
        Add this effect's encoding to the compiled steps' model arrays.

        ``time_mid``: the midpoint of the step the model is for. An effect that
        does not implement it is not one the compiled steps evaluate.
        """
        raise NotImplementedError

    def count_kernel_work(self, rhs: int, kicks: int, flows: int,
                          acting: Optional[int] = None) -> None:
        """
        Add the compiled steps' work with this effect to its counters.

        Counted as if the effect had been evaluated one call at a time: the
        kernels took ``rhs`` full right-hand sides, ``kicks`` kicks (the
        position-dependent wrenches only) and ``flows`` exact damping flows.
        ``acting``: the bodies (wrench entries) it acted on when the steps took
        a subset of the bodies (:meth:`acting_in`); default: all it acts on.
        """
        raise NotImplementedError

    def acting_in(self, local: np.ndarray, rows_kept: np.ndarray) -> int:
        """
        Return how many of the bodies (wrench entries) it acts on are in a subset.

        Parameters
        ----------
        local : ndarray of int, shape (n,)
            Each body's index in the subset, ``-1`` if not in it.
        rows_kept : ndarray of bool, shape (k,)
            Per row this effect added to the model's wrench array, whether its
            body is in the subset.

        """
        raise NotImplementedError

    def _count(self, calls: int, bodies: int) -> None:
        self.evaluations += calls
        self.body_evaluations += calls * bodies

    def begin_step(self, time_mid: float) -> bool:
        """
        Prepare a step whose midpoint is ``time_mid``; True if the model changed.

        Time-dependent effects switch here, between steps, never inside one.
        """
        return False

    def potential_energy(self, pos_com_world: np.ndarray) -> Optional[np.ndarray]:
        """Potential energy of each body (n,), or None for a non-conservative effect."""
        return None

    def reset_counters(self) -> None:
        """Zero the work counters."""
        self.evaluations = 0
        self.body_evaluations = 0


class Gravity(Effect):
    """
    Uniform gravity: force ``m g`` at each centre of mass.

    Parameters
    ----------
    g_world : array_like, shape (3,)
        m/s², e.g. ``(0, 0, -9.81)`` (REP 103: z up).

    """

    name = 'gravity'

    def __init__(self, g_world: Any = (0.0, 0.0, -9.81)) -> None:
        super().__init__()
        self.g_world = finite_array(g_world, 'g_world', (3,))

    def bind(self, bodies: BodySet) -> None:
        """Precompute the constant gravity forces."""
        super().bind(bodies)
        self._force = bodies.mass[:, None] * self.g_world

    def accumulate(self, kin: Kinematics, acc: WrenchAccumulator) -> None:
        """Add ``m g`` to every body."""
        self.evaluations += 1
        self.body_evaluations += len(self._force)
        acc.force_world += self._force

    def add_to_kernel_model(self, model: KernelModel, time_mid: float) -> None:
        """Add ``m g`` to ``gforce``: the kicks then have a force to add."""
        model.gforce += self._force
        model.flags |= HAS_POSITION_FORCES

    def count_kernel_work(self, rhs: int, kicks: int, flows: int,
                          acting: Optional[int] = None) -> None:
        """Count every right-hand side and kick, on every body."""
        self._count(rhs + kicks, len(self._force) if acting is None else acting)

    def acting_in(self, local: np.ndarray, rows_kept: np.ndarray) -> int:
        """Return the bodies in the subset: gravity acts on every one."""
        return int(np.count_nonzero(local >= 0))

    def potential_energy(self, pos_com_world: np.ndarray) -> np.ndarray:
        """``-m g · x_com`` for each body (zero at the world origin)."""
        return -self.bodies.mass * (pos_com_world @ self.g_world)


class Damping(Effect):
    """
    Linear viscous damping: ``F = -c_lin v_com`` and ``τ = -c_ang ω``.

    Parameters
    ----------
    linear : float
        N s/m, >= 0.
    angular : float
        N m s/rad, >= 0.
    bodies : sequence of str, optional
        Bodies damped; all bodies when omitted.

    """

    name = 'damping'
    velocity_dependent = True

    def __init__(self, linear: float = 0.0, angular: float = 0.0,
                 bodies: Optional[Sequence[str]] = None) -> None:
        super().__init__()
        self.linear = nonnegative_scalar(linear, 'linear')
        self.angular = nonnegative_scalar(angular, 'angular')
        if bodies is not None and (isinstance(bodies, str) or not all(
                isinstance(b, str) for b in bodies)):
            raise SpecError('bodies', f'expected a list of body names, got {bodies!r}')
        self.body_names = None if bodies is None else list(bodies)

    def bind(self, bodies: BodySet) -> None:
        """Resolve the damped bodies."""
        super().bind(bodies)
        if self.body_names is None:
            self.index = np.arange(len(bodies))
        else:
            self.index = np.array([bodies.lookup(b, f'bodies[{i}]')
                                   for i, b in enumerate(self.body_names)], dtype=int)

    def accumulate(self, kin: Kinematics, acc: WrenchAccumulator) -> None:
        """Add the damping force and torque of the damped bodies."""
        idx = self.index
        self.evaluations += 1
        self.body_evaluations += len(idx)
        if self.linear:
            acc.force_world[idx] -= self.linear * kin.vel_com_world[idx]
        if self.angular:
            acc.torque_principal[idx] -= self.angular * kin.ang_vel_principal[idx]

    def add_to_kernel_model(self, model: KernelModel, time_mid: float) -> None:
        """Add the coefficients to the damped bodies' ``c_lin`` and ``c_ang`` columns."""
        np.add.at(model.body[:, B_C_LIN], self.index, self.linear)
        np.add.at(model.body[:, B_C_ANG], self.index, self.angular)
        model.flags |= HAS_DAMPING

    def count_kernel_work(self, rhs: int, kicks: int, flows: int,
                          acting: Optional[int] = None) -> None:
        """Count every right-hand side and exact flow (a kick has no damping), per damped body."""
        self._count(rhs + flows, len(self.index) if acting is None else acting)

    def acting_in(self, local: np.ndarray, rows_kept: np.ndarray) -> int:
        """Return the damped bodies in the subset."""
        return int(np.count_nonzero(local[self.index] >= 0))

    def exact_flow(self, vel_com_world: np.ndarray, ang_mom_principal: np.ndarray,
                   dt: float) -> None:
        """
        Advance ``v`` and the body angular momentum by the exact damping flow, in place.

        With damping alone, ``m dv/dt = -c v`` and ``J_i dΩ_i/dt = -c Ω_i`` in the
        principal frame (``J`` diagonal), so both decay exponentially.
        """
        idx = self.index
        self.evaluations += 1
        self.body_evaluations += len(idx)
        if self.linear:
            vel_com_world[idx] *= np.exp(-self.linear * self.bodies.inv_mass[idx] * dt)[:, None]
        if self.angular:
            ang_mom_principal[idx] *= np.exp(-self.angular * dt / self.bodies.moments[idx])


class AppliedWrenches(Effect):
    """
    A table of applied wrenches, each constant over an interval of time.

    Each entry acts on one body with a force (at a point given in the body
    frame; the centre of mass when omitted) and a torque, expressed in the world
    or the body frame, from ``start`` (s) for ``duration`` (s; forever when
    None). Entries are evaluated together, vectorized over entries.

    Inside a :class:`Simulation`, wrenches switch on and off between steps: an
    entry acts over every step whose midpoint lies in ``[start, start +
    duration)``, so the impulse it delivers is exact when the duration is a
    whole number of steps (and rounded to whole steps otherwise), whatever the
    integrator's stage times. Evaluated outside a simulation (no
    :meth:`begin_step`), an entry is active at times ``start <= t < end``.
    """

    name = 'wrenches'

    def __init__(self, entries: Sequence[dict] = ()) -> None:
        super().__init__()
        self._pending = list(entries)
        self._rows: list[tuple] = []
        self._arrays: Optional[dict] = None
        self._active: Optional[np.ndarray] = None

    def bind(self, bodies: BodySet) -> None:
        """Validate the initial entries now that the bodies are known."""
        super().bind(bodies)
        self._rows = []
        self._arrays = None
        for i, entry in enumerate(self._pending):
            if not isinstance(entry, dict):
                raise SpecError(f'[{i}]', f'expected a mapping, got {entry!r}')
            unknown = sorted(set(entry) - set(self.KEYS), key=str)
            if unknown:
                raise SpecError(f'[{i}].{unknown[0]}',
                                f'unknown key; known keys: {list(self.KEYS)}')
            if 'body' not in entry:
                raise SpecError(f'[{i}].body', 'required: the name of the body it acts on')
            try:
                self.add(**entry)
            except SpecError as exc:
                raise exc.within(f'[{i}]') from None

    #: The keys of an entry: the parameters of :meth:`add`.
    KEYS = ('body', 'force', 'torque', 'frame', 'point_body', 'start', 'duration')

    def add(self, body: str, force: Any = (0.0, 0.0, 0.0), torque: Any = (0.0, 0.0, 0.0),
            frame: Any = 'world', point_body: Any = None, start: float = 0.0,
            duration: Optional[float] = None, key: Optional[str] = None) -> None:
        """
        Add a wrench; every argument is validated and named on error.

        An entry with a ``key`` replaces the entry added earlier with the same
        key (a held input, such as the latest message on a topic); a keyed
        entry whose force and torque are both zero only removes the old one.

        Parameters
        ----------
        body : str
            Name of the body.
        force, torque : array_like, shape (3,)
            N and N m, in ``frame``.
        frame : {'world', 'body'}
            Frame of ``force`` and ``torque``.
        point_body : array_like, shape (3,), optional
            Point of application in the body frame (m); default: centre of mass.
        start : float
            s, simulation time at which it starts.
        duration : float, optional
            s, > 0; None for forever.
        key : str, optional
            Replace the entry with this key, if any.

        """
        b = self.bodies.lookup(body, 'body')
        f = finite_array(force, 'force', (3,))
        tau = finite_array(torque, 'torque', (3,))
        fr = Frame.parse(frame)
        t0 = finite_scalar(start, 'start')
        if duration is None:
            t1 = np.inf
        else:
            d = finite_scalar(duration, 'duration')
            if not d > 0.0:
                raise SpecError('duration', f'must be positive, got {d!r}')
            t1 = t0 + d
        V = self.bodies.R_body_principal[b]
        if point_body is None:
            r_p = np.zeros(3)
        else:
            r_b = finite_array(point_body, 'point_body', (3,))
            r_p = V.T @ (r_b - self.bodies.com_body[b])
        if fr is Frame.BODY:
            f, tau = V.T @ f, V.T @ tau    # stored in the principal frame
        if key is not None:
            self._rows = [row for row in self._rows if row[7] != key]
            if not (np.any(f) or np.any(tau)):
                self._arrays = None
                self._active = None
                return
        self._rows.append((b, fr is Frame.BODY, f, tau, r_p, t0, t1, key))
        self._arrays = None
        self._active = None

    def remove_expired(self, time: float) -> bool:
        """Drop entries that ended at or before ``time``; return whether any was dropped."""
        keep = [row for row in self._rows if row[6] > time]
        if len(keep) == len(self._rows):
            return False
        self._rows = keep
        self._arrays = None
        self._active = None
        return True

    def clear(self, body: Optional[str] = None) -> None:
        """Remove all entries, or those of one body."""
        if body is None:
            self._rows = []
        else:
            b = self.bodies.lookup(body, 'body')
            self._rows = [row for row in self._rows if row[0] != b]
        self._arrays = None
        self._active = None

    def snapshot(self) -> list:
        """Return the entries as they are now, for :meth:`restore`."""
        return list(self._rows)

    def restore(self, rows: list) -> None:
        """Put back the entries of a :meth:`snapshot`; the next step switches them afresh."""
        self._rows = list(rows)
        self._arrays = None
        self._active = None

    def begin_step(self, time_mid: float) -> bool:
        """Fix the entries active during the step whose midpoint is ``time_mid``."""
        tab = self._table()
        active = (tab['start'] <= time_mid) & (time_mid < tab['end'])
        changed = self._active is None or not np.array_equal(active, self._active)
        self._active = active
        return changed

    def __len__(self) -> int:
        """Return the number of entries (active or not)."""
        return len(self._rows)

    def _table(self) -> dict:
        if self._arrays is None:
            rows = self._rows
            self._arrays = {
                'body': np.array([r[0] for r in rows], dtype=int),
                'in_body': np.array([r[1] for r in rows], dtype=bool),
                'force': np.array([r[2] for r in rows]).reshape(-1, 3),
                'torque': np.array([r[3] for r in rows]).reshape(-1, 3),
                'point': np.array([r[4] for r in rows]).reshape(-1, 3),
                'start': np.array([r[5] for r in rows]),
                'end': np.array([r[6] for r in rows]),
            }
        return self._arrays

    def kernel_rows(self, time_mid: float) -> np.ndarray:
        """
        Return the entries active in this step as rows of the kernels' wrench array.

        Returns
        -------
        ndarray, shape (k, W_WIDTH)
            ``body, in_body, force (3), torque (3), point (3)`` (see
            :mod:`.kernels.free_step`); ``time_mid`` decides which entries are active
            when no :meth:`begin_step` did.

        """
        tab = self._table()
        active = self._active
        if active is None:
            active = (tab['start'] <= time_mid) & (time_mid < tab['end'])
        rows = np.zeros((int(np.count_nonzero(active)), W_WIDTH))   # kind WRENCH_APPLIED
        rows[:, W_BODY] = tab['body'][active]
        rows[:, W_IN_BODY] = tab['in_body'][active]
        rows[:, W_FORCE:W_FORCE + 3] = tab['force'][active]
        rows[:, W_TORQUE:W_TORQUE + 3] = tab['torque'][active]
        rows[:, W_POINT:W_POINT + 3] = tab['point'][active]
        self._kernel_active = len(rows)
        return rows

    def active_count(self) -> int:
        """Entries active in the step the compiled kernels last took."""
        return getattr(self, '_kernel_active', 0)

    def add_to_kernel_model(self, model: KernelModel, time_mid: float) -> None:
        """Add the entries active in the step as wrench rows (:meth:`kernel_rows`)."""
        if not len(self):
            self._kernel_active = 0   # an emptied table acts on nothing, and counts no work
            return
        rows = self.kernel_rows(time_mid)
        # Without begin_step (no Simulation switches it) the rows depend on the time.
        model.time_dependent |= self._active is None
        if len(rows):
            model.add_wrench_rows(rows)
            model.flags |= HAS_POSITION_FORCES

    def count_kernel_work(self, rhs: int, kicks: int, flows: int,
                          acting: Optional[int] = None) -> None:
        """Count every right-hand side and kick, per active entry; nothing without one."""
        entries = self.active_count() if acting is None else acting
        self._count(rhs + kicks if entries else 0, entries)

    def acting_in(self, local: np.ndarray, rows_kept: np.ndarray) -> int:
        """Return the active entries on bodies of the subset."""
        return int(np.count_nonzero(rows_kept))

    def accumulate(self, kin: Kinematics, acc: WrenchAccumulator) -> None:
        """Add the wrenches active in this step (or at ``kin.time``, outside a simulation)."""
        if not self._rows:
            return
        tab = self._table()
        active = self._active
        if active is None:
            active = (tab['start'] <= kin.time) & (kin.time < tab['end'])
        if not np.any(active):
            return
        self.evaluations += 1
        body = tab['body'][active]
        self.body_evaluations += len(body)
        in_body = tab['in_body'][active]
        f = tab['force'][active]
        tau = tab['torque'][active]
        r_p = tab['point'][active]
        R = kin.R_principal_world[body]
        # World-frame force on every entry; body-frame entries are rotated.
        f_world = np.where(in_body[:, None], np.einsum('kij,kj->ki', R, f), f)
        np.add.at(acc.force_world, body, f_world)
        # Torque about the centre of mass: body-frame entries in the principal
        # frame, world-frame entries in the world frame.
        tau_p = np.where(in_body[:, None], tau + so3.cross(r_p, f), 0.0)
        np.add.at(acc.torque_principal, body, tau_p)
        wb = ~in_body
        if np.any(wb):
            r_w = np.einsum('kij,kj->ki', R[wb], r_p[wb])
            np.add.at(acc.torque_world, body[wb], tau[wb] + so3.cross(r_w, f[wb]))


EFFECTS: dict[str, type] = {cls.name: cls for cls in (Gravity, Damping, AppliedWrenches)}
