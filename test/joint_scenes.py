"""Builders of constrained scenes shared by the joint tests."""

import numpy as np
from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
from scipy.special import ellipk

G = 9.81
# A point mass: the inertia only has to be positive; 1e-9 kg m² changes the period of a
# 1 kg, 0.25 m pendulum by 8e-9 relative, far below every tolerance used.
POINT_INERTIA = [1e-9, 1e-9, 1e-9]


def pendulum(name: str, dt: float, theta0: float, length: float = 0.25,
             mass: float = 1.0) -> Simulation:
    """Return a point mass on a ball joint at the origin, released from rest at theta0."""
    pos = [length * np.sin(theta0), 0.0, -length * np.cos(theta0)]
    return Simulation([RigidBody('bob', mass, POINT_INERTIA, position_world=pos)],
                      [Gravity((0.0, 0.0, -G))], name, dt,
                      [Constraint('rod', 'ball', 'bob', None, anchor_world=[0.0, 0.0, 0.0])])


def pendulum_period(theta0: float, length: float = 0.25) -> float:
    """Return the exact period 4 sqrt(L/g) K(sin²(θ0/2)) of a simple pendulum."""
    return 4.0 * np.sqrt(length / G) * ellipk(np.sin(theta0 / 2.0) ** 2)


def upward_crossings(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Return the times where x crosses zero upward, by linear interpolation."""
    i = np.flatnonzero((x[:-1] < 0.0) & (x[1:] >= 0.0))
    return t[i] + (t[i + 1] - t[i]) * (-x[i]) / (x[i + 1] - x[i])
