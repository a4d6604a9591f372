"""Each integrator keeps its order with constraints: a redundant closed loop (four-bar)."""

import numpy as np
import pytest
from rigid_body_sim.core import INTEGRATORS
from rigid_body_sim.core.mechanisms import four_bar

T_END = 0.6


def crank_state(name: str, dt: float) -> np.ndarray:
    """Crank angle (rad) and every body's centre-of-mass velocity (m/s) at T_END."""
    sim = four_bar(name, dt)
    sim.run(T_END)
    centre = sim.state.pos_com_world[0]
    return np.concatenate([[np.arctan2(centre[2], centre[0])], sim.state.vel_com_world.ravel()])


@pytest.fixture(scope='module')
def reference():
    # lie_poisson4 at dt = 2.5e-4: error 3.5e-10 by its own convergence (measured against
    # dt = 1.25e-4: 3.3e-10, x16/15), rounding of the four-bar's redundant rows included.
    return crank_state('lie_poisson4', 2.5e-4)


@pytest.mark.slow
@pytest.mark.parametrize('name', sorted(INTEGRATORS))
def test_order_with_a_redundant_closed_loop(name, reference):
    # Measured log2 ratios at dt 4e-3 -> 2e-3 (and 2e-3 -> 1e-3): symplectic_euler 1.06
    # (1.03), lie_poisson2 2.00 (2.00), lie_poisson4 4.07 (4.02), rkmk4 3.87 (3.94).
    errors = [np.max(np.abs(crank_state(name, dt) - reference)) for dt in (4e-3, 2e-3)]
    observed = np.log2(errors[0] / errors[1])
    # bound: 30 x the reference's 3.5e-10 shifts the order by < 0.05 (measured: 1.2e-6 and up)
    assert errors[1] > 1e-8, 'too close to the reference error to measure an order'
    # bound: p + pre-asymptotic terms (measured at most 0.13) + the reference's < 0.05
    assert abs(observed - INTEGRATORS[name].order) < 0.2, (errors, observed)
