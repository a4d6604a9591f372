"""The facade a user scripts: build a scene, step it, apply wrenches, read state, reset.

Example
-------
>>> from rigid_body_sim.core import RigidBody, Simulation, Gravity
>>> sim = Simulation([RigidBody('ball', mass=1.0, inertia=[0.1, 0.1, 0.1])],
...                  effects=[Gravity((0.0, 0.0, -9.81))], integrator='lie_poisson2', dt=1e-3)
>>> sim.step(1000)
>>> position, orientation_xyzw = sim.pose('ball')
>>> round(float(position[2]), 6)   # -g t² / 2 at t = 1 s
-4.905

Inputs and outputs are in the user's body frame (origin and axes of each body
as given); the core works in principal frames internally (see
:mod:`.bodies`). Changes (wrenches, reset) take effect between steps.
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np

from .bodies import BodySet, RigidBody, State
from .diagnostics import diagnose, Diagnostics
from .dynamics import Dynamics
from .effects import AppliedWrenches, Effect
from .errors import SpecError
from .integrators import integrator_class
from .validate import positive_scalar


class Simulation:
    """Rigid bodies, the effects that act on them, and a fixed-step integrator.

    Parameters
    ----------
    bodies : sequence of RigidBody
    effects : sequence of Effect
        Only these are evaluated (e.g. no gravity term unless Gravity is listed).
    integrator : str
        A name from :data:`rigid_body_sim.core.integrators.INTEGRATORS`.
    dt : float
        Step size (s), > 0.
    """

    def __init__(self, bodies: Sequence[RigidBody], effects: Sequence[Effect] = (),
                 integrator: str = 'lie_poisson2', dt: float = 1e-3) -> None:
        self.dt = positive_scalar(dt, 'dt')
        self._specs = list(bodies)
        self.bodies = BodySet.from_bodies(self._specs)
        effects = list(effects)
        for i, effect in enumerate(effects):
            if not isinstance(effect, Effect):
                raise SpecError(f'effects[{i}]', f'expected an Effect, got {effect!r}')
            try:
                effect.bind(self.bodies)
            except SpecError as exc:
                raise exc.within(f'effects[{i}]') from None
        self.dynamics = Dynamics(self.bodies, effects)
        self.integrator = integrator_class(integrator)(self.dynamics)
        self._initial_wrenches = [self._wrench_rows(e) for e in effects]
        self.reset()

    # -- time stepping --------------------------------------------------------------------

    @property
    def time(self) -> float:
        """Simulation time (s)."""
        return self.state.time

    @property
    def integrator_name(self) -> str:
        """Name of the integrator in use."""
        return self.integrator.name

    def step(self, n: int = 1) -> None:
        """Take ``n`` steps of size ``dt``."""
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise SpecError('n', f'must be a non-negative integer, got {n!r}')
        for _ in range(int(n)):
            # Time as steps * dt, not a running sum: no rounding drift.
            self.state = self.integrator.step(self.state, self.dt, (self._steps + 1) * self.dt)
            self._steps += 1
            if self._wrenches is not None and len(self._wrenches):
                self._wrenches.remove_expired(self.state.time)

    def run(self, duration: float) -> None:
        """Step until ``duration`` (s) more has elapsed (rounded to whole steps)."""
        d = positive_scalar(duration, 'duration')
        self.step(int(round(d / self.dt)))

    def reset(self) -> None:
        """Back to the initial state; applied wrenches return to the scene's own."""
        self.state: State = self.bodies.initial_state(self._specs)
        self._steps = 0
        for effect, rows in zip(self.dynamics.effects, self._initial_wrenches):
            if rows is not None:
                effect._rows = list(rows)
                effect._arrays = None
        # Effects added at run time (a lazily created wrench table) are dropped.
        self.dynamics.effects = self.dynamics.effects[:len(self._initial_wrenches)]
        self.dynamics._refresh()
        self._wrenches = next((e for e in self.dynamics.effects
                               if isinstance(e, AppliedWrenches)), None)
        for effect in self.dynamics.effects:
            effect.reset_counters()
        self.dynamics.counters.__init__()
        self.dynamics.changed()

    @staticmethod
    def _wrench_rows(effect: Effect) -> Optional[list]:
        return list(effect._rows) if isinstance(effect, AppliedWrenches) else None

    # -- inputs ---------------------------------------------------------------------------

    def apply_wrench(self, body: str, force: Any = (0.0, 0.0, 0.0),
                     torque: Any = (0.0, 0.0, 0.0), frame: str = 'world',
                     point_body: Any = None, duration: Optional[float] = None,
                     start: Optional[float] = None) -> None:
        """Apply a force (at ``point_body``, default the centre of mass) and a torque.

        Parameters
        ----------
        body : str
        force, torque : array_like, shape (3,)
            N, N m, in ``frame`` ('world' or 'body').
        point_body : array_like, shape (3,), optional
            m, in the body frame.
        duration : float, optional
            s; None: until cleared or reset.
        start : float, optional
            s, simulation time; default now.
        """
        if self._wrenches is None:
            self._wrenches = AppliedWrenches()
            self._wrenches.bind(self.bodies)
            self.dynamics.add_effect(self._wrenches)
        self._wrenches.add(body, force, torque, frame, point_body,
                           self.time if start is None else start, duration)
        self.dynamics.changed()

    def clear_wrenches(self, body: Optional[str] = None) -> None:
        """Remove applied wrenches (of one body, or all)."""
        if self._wrenches is not None:
            self._wrenches.clear(body)
            self.dynamics.changed()

    # -- outputs --------------------------------------------------------------------------

    def _select(self, arr: np.ndarray, body: Optional[str]) -> np.ndarray:
        return arr if body is None else arr[self.bodies.lookup(body)]

    def pose(self, body: Optional[str] = None) -> tuple[np.ndarray, np.ndarray]:
        """Position of the body origin (3,) and orientation (4,, xyzw), world frame.

        With ``body`` None, arrays of all bodies, (n, 3) and (n, 4).
        """
        pos, quat = self.bodies.pose_world(self.state)
        return self._select(pos, body), self._select(quat, body)

    def twist(self, body: Optional[str] = None,
              frame: str = 'world') -> tuple[np.ndarray, np.ndarray]:
        """Velocity of the body origin and angular velocity, in ``frame`` ('world' or 'body')."""
        if frame == 'world':
            v, w = self.bodies.twist_world(self.state)
        elif frame == 'body':
            v, w = self.bodies.twist_body(self.state)
        else:
            raise SpecError('frame', f"must be 'world' or 'body', got {frame!r}")
        return self._select(v, body), self._select(w, body)

    def diagnostics(self) -> Diagnostics:
        """Energies, world-frame momenta and orthonormality errors now."""
        return diagnose(self.bodies, self.dynamics.effects, self.state)

    def work(self) -> dict:
        """Work counters: integrator totals plus each effect's evaluations."""
        out = self.dynamics.counters.as_dict()
        for effect in self.dynamics.effects:
            out[f'{effect.name}_evaluations'] = out.get(f'{effect.name}_evaluations', 0) \
                + effect.evaluations
            out[f'{effect.name}_body_evaluations'] = \
                out.get(f'{effect.name}_body_evaluations', 0) + effect.body_evaluations
        return out
