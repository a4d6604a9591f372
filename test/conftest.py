"""Shared fixtures and builders for the physics tests (core only, no ROS)."""

import numpy as np
import pytest
from rigid_body_sim.core import RigidBody
from rigid_body_sim.core import rotation as so3


def random_inertia(rng: np.random.Generator) -> np.ndarray:
    """Return a random physical inertia tensor: rotated moments obeying the triangle law."""
    moments = np.sort(0.5 + rng.random(3))
    if moments[0] + moments[1] < moments[2]:
        moments[2] = moments[0] + moments[1]
    R = so3.quat_to_matrix(so3.quat_normalize(rng.normal(size=4)))
    return R @ np.diag(moments) @ R.T


def random_body(rng: np.random.Generator, name: str) -> RigidBody:
    """Return a body with random mass, inertia, COM offset, pose and velocities."""
    return RigidBody(name, 0.5 + rng.random(), random_inertia(rng),
                     com_body=0.2 * rng.normal(size=3), position_world=rng.normal(size=3),
                     orientation_xyzw=so3.quat_normalize(rng.normal(size=4)),
                     linear_velocity_world=rng.normal(size=3),
                     angular_velocity_body=rng.normal(size=3))


@pytest.fixture
def rng():
    """Seeded generator: tests are repeatable."""
    return np.random.default_rng(20261122)


@pytest.fixture
def ros(tmp_path):
    """Nodes in child processes and a client here, on a random DDS domain (ros_harness)."""
    harness = pytest.importorskip('ros_harness', reason='rclpy not installed')
    yield from harness.ros_session(tmp_path)
