"""Diagnostics: energies, momenta (world frame) and orthonormality of rotations."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from . import rotation as so3
from .bodies import BodySet, State
from .effects import Effect


@dataclass(frozen=True)
class Diagnostics:
    """
    Physical invariants of a state.

    Attributes
    ----------
    time : float
        s.
    kinetic_energy : ndarray, shape (n,)
        J, ``(m |v|² + Ωᵀ J Ω) / 2`` per body.
    potential_energy : ndarray, shape (n,)
        J, of the conservative effects (gravity: ``-m g · x_com``).
    linear_momentum_world : ndarray, shape (3,)
        kg m/s, total.
    angular_momentum_world : ndarray, shape (3,)
        kg m²/s, total, about the world origin.
    angular_momentum_com_world : ndarray, shape (3,)
        kg m²/s, total, about the (moving) centre of mass of all bodies, with
        velocities relative to it; unchanged by uniform gravity.
    orthonormality_error : ndarray, shape (n,)
        Largest entry of ``|RᵀR - I|`` for each body's rotation matrix.
    constraint_violation : float
        Largest ``|Φ|`` over all constraint rows (0 without constraints), but for
        the exact drives' rows, whose ``Φ`` is a commanded motion still to go.
    accuracy : AccuracyReport or None
        What the accuracy knob did (see :mod:`.accuracy`); set by the Simulation.

    """

    time: float
    kinetic_energy: np.ndarray
    potential_energy: np.ndarray
    linear_momentum_world: np.ndarray
    angular_momentum_world: np.ndarray
    angular_momentum_com_world: np.ndarray
    orthonormality_error: np.ndarray
    constraint_violation: float = 0.0
    accuracy: Optional[Any] = None

    @property
    def total_energy(self) -> float:
        """Kinetic plus potential energy of all bodies (J)."""
        return float(np.sum(self.kinetic_energy) + np.sum(self.potential_energy))


def kinetic_energy(bodies: BodySet, state: State) -> np.ndarray:
    """Kinetic energy of each body (n,), J."""
    v, w = state.vel_com_world, state.ang_vel_principal
    return 0.5 * (bodies.mass * np.einsum('ni,ni->n', v, v)
                  + np.einsum('ni,ni,ni->n', bodies.moments, w, w))


def potential_energy(effects: Sequence[Effect], state: State, n: int) -> np.ndarray:
    """Potential energy of each body (n,) from the conservative effects, J."""
    total = np.zeros(n)
    for effect in effects:
        pe = effect.potential_energy(state.pos_com_world)
        if pe is not None:
            total += pe
    return total


def linear_momentum_world(bodies: BodySet, state: State) -> np.ndarray:
    """Linear momentum of each body (n, 3), world frame."""
    return bodies.mass[:, None] * state.vel_com_world


def angular_momentum_world(bodies: BodySet, state: State,
                           about: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """
    Angular momentum of each body about the point ``about`` (n, 3), world frame.

    Orbital part ``(x - about) × m v`` plus spin ``R (J Ω)``.
    """
    spin = so3.rotate(state.quat_principal_world, bodies.moments * state.ang_vel_principal)
    r = state.pos_com_world - np.asarray(about, dtype=float)
    return so3.cross(r, linear_momentum_world(bodies, state)) + spin


def angular_momentum_about_com(bodies: BodySet, state: State) -> np.ndarray:
    """Total angular momentum (3,) about the centre of mass of all bodies, world frame."""
    m = bodies.mass[:, None]
    x_c = (m * state.pos_com_world).sum(axis=0) / m.sum()
    v_c = (m * state.vel_com_world).sum(axis=0) / m.sum()
    spin = so3.rotate(state.quat_principal_world, bodies.moments * state.ang_vel_principal)
    return (so3.cross(state.pos_com_world - x_c, m * (state.vel_com_world - v_c))
            + spin).sum(axis=0)


def diagnose(bodies: BodySet, effects: Sequence[Effect], state: State) -> Diagnostics:
    """All diagnostics of ``state``."""
    return Diagnostics(
        time=state.time,
        kinetic_energy=kinetic_energy(bodies, state),
        potential_energy=potential_energy(effects, state, len(bodies)),
        linear_momentum_world=linear_momentum_world(bodies, state).sum(axis=0),
        angular_momentum_world=angular_momentum_world(bodies, state).sum(axis=0),
        angular_momentum_com_world=angular_momentum_about_com(bodies, state),
        orthonormality_error=so3.orthonormality_error(
            so3.quat_to_matrix(state.quat_principal_world)),
    )
