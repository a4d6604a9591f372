"""Keyed (held) wrenches and step-size changes between steps: the core API the node uses."""

import numpy as np
import pytest
from rigid_body_sim.core import AppliedWrenches, Gravity, RigidBody, Simulation, SpecError


def _sim(integrator='lie_poisson2', dt=1e-3):
    return Simulation([RigidBody('b', 2.0, [0.1, 0.2, 0.3])], integrator=integrator, dt=dt)


def test_a_keyed_wrench_replaces_the_previous_one():
    held, once = _sim(), _sim()
    held.apply_wrench('b', force=[1.0, 0, 0], key='topic')
    held.step(10)
    held.apply_wrench('b', force=[0, 3.0, 0], key='topic')
    held.step(10)
    once.apply_wrench('b', force=[1.0, 0, 0], duration=10e-3)
    once.step(10)
    once.apply_wrench('b', force=[0, 3.0, 0])
    once.step(10)
    np.testing.assert_array_equal(held.state.vel_com_world, once.state.vel_com_world)
    # Impulse: 1 N for 10 ms along x, 3 N for 10 ms along y, on 2 kg.
    # bound: 40 half kicks, each rounding by eps/2 of |v|: 4.4e-15 relative; z an exact 0
    np.testing.assert_allclose(held.state.vel_com_world[0], [0.005, 0.015, 0.0], rtol=1e-12)


def test_a_zero_keyed_wrench_removes_it_and_unkeyed_ones_add_up():
    sim = _sim()
    sim.apply_wrench('b', force=[1.0, 0, 0], key='topic')
    sim.apply_wrench('b', force=[1.0, 0, 0])
    sim.step(10)
    sim.apply_wrench('b', key='topic')   # zero: removes the held one, keeps the other
    assert len(sim._wrenches) == 1
    sim.step(10)
    # 2 N for 10 ms, then 1 N for 10 ms, on 2 kg.
    # bound: 40 half kicks, each rounding by eps/2 of |v|: 4.4e-15 relative; y, z exact 0s
    np.testing.assert_allclose(sim.state.vel_com_world[0], [0.015, 0.0, 0.0], rtol=1e-12)


def test_an_invalid_keyed_wrench_keeps_the_held_one():
    sim = _sim()
    sim.apply_wrench('b', force=[1.0, 0, 0], key='topic')
    with pytest.raises(SpecError, match='force: must be finite'):
        sim.apply_wrench('b', force=[np.nan, 0, 0], key='topic')
    sim.step(10)
    # bound: 20 half kicks, each rounding by eps/2 of |v|: 2.2e-15 relative; y, z exact 0s
    np.testing.assert_allclose(sim.state.vel_com_world[0], [0.005, 0.0, 0.0], rtol=1e-12)


@pytest.mark.parametrize('integrator', ['symplectic_euler', 'lie_poisson2', 'lie_poisson4',
                                        'rkmk4'])
def test_changing_dt_keeps_time_continuous(integrator):
    sim = Simulation([RigidBody('b', 1.0, [1.0, 1.0, 1.0])], [Gravity((0, 0, -9.81))],
                     integrator, 1e-3)
    sim.step(10)
    sim.set_step(dt=2.5e-3, integrator='rkmk4')
    sim.step(4)
    # bound: base + k dt, 3 roundings of <= 0.02 s: 7e-18 s; x100
    assert sim.time == pytest.approx(0.02, abs=1e-15)
    assert sim.integrator_name == 'rkmk4'
    # Constant gravity: every method but the first-order one integrates it exactly.
    z = sim.pose('b')[0][2]
    if integrator != 'symplectic_euler':
        # bound: 14 steps, N u (|z| + t |v|) = 14 x 1.1e-16 x (2e-3 + 4e-3) m = 9e-18; x100
        assert z == pytest.approx(-9.81 * 0.02 ** 2 / 2, abs=1e-15)
    with pytest.raises(SpecError, match='dt: must be positive'):
        sim.set_step(dt=-1.0, integrator='lie_poisson2')
    assert sim.dt == 2.5e-3 and sim.integrator_name == 'rkmk4'


def test_a_wrench_table_puts_back_a_snapshot():
    sim = _sim()
    table = AppliedWrenches([{'body': 'b', 'force': [1.0, 0.0, 0.0]}])
    table.bind(sim.bodies)
    saved = table.snapshot()
    table.add('b', torque=[0.0, 0.0, 2.0])
    table.clear()
    assert len(table) == 0
    table.restore(saved)
    assert len(table) == 1
    np.testing.assert_array_equal(table.kernel_rows(0.0)[0, 2:8], [1.0, 0, 0, 0, 0, 0])
