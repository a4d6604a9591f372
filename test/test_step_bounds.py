"""The bounds a step and a joint keep: the work of one step, the range of a joint's points."""

import numpy as np
import pytest
from rigid_body_sim.core import Constraint, RigidBody, Simulation, SpecError
from rigid_body_sim.core.constraints import MAX_JOINT_DISTANCE
from rigid_body_sim.scene import load_scene
from ros_harness import CONFIG


@pytest.mark.parametrize('far', [1e12, 2e6])
@pytest.mark.parametrize('given', ['anchor_world', 'anchor_a_body'])
def test_a_joint_beyond_the_supported_range_is_refused_naming_the_range(far, given):
    # The pose satisfies the joint (its anchor is the body's own origin); the refusal is
    # for the range, not for inconsistency: at 1e12 m one ulp is 1.2e-4 m, so a residual
    # of that size says nothing about the joint.
    body = RigidBody('b', 1.0, [0.1, 0.1, 0.1], position_world=[far, 0.0, 0.0])
    sim = Simulation([body], [], 'lie_poisson2', 1e-3)
    spec = Constraint('pin', 'ball', 'b', None, **(
        {'anchor_world': [far, 0.0, 0.0]} if given == 'anchor_world'
        else {'anchor_a_body': [0.0, 0.0, 0.0], 'anchor_b_body': [far, 0.0, 0.0]}))
    with pytest.raises(SpecError, match=rf'^{given}: the joint point .* outside the range '
                                        r'of \+-1e\+06 m') as info:
        sim.add_constraint(spec)
    assert 'inconsistent' not in str(info.value)
    assert sim.constraint_names == []
    # Inside the range the same joint holds (rounding at 1e6 m: 1.2e-10 m per coordinate).
    near = RigidBody('b', 1.0, [0.1, 0.1, 0.1], position_world=[MAX_JOINT_DISTANCE, 0, 0])
    sim = Simulation([near], [], 'lie_poisson2', 1e-3)
    sim.add_constraint(Constraint('pin', 'ball', 'b', None,
                                  anchor_world=[MAX_JOINT_DISTANCE, 0.0, 0.0]))
    assert sim.constraint_names == ['pin']


@pytest.mark.parametrize('integrator', ['symplectic_euler', 'lie_poisson2', 'lie_poisson4',
                                        'rkmk4'])
def test_one_hard_push_cannot_make_a_step_take_unbounded_work(integrator):
    # A 1e4 N m torque held on one link of the 5-link chain (0.5 kg rods, transverse
    # inertia 1.7e-3 kg m^2): within 0.1-0.3 s the links spin at 1e4-4e5 rad/s, where
    # 0.25 rad a sub-step would ask for 40-1600 sub-steps a step (before this bound:
    # up to 245 sub-steps in one step, and without limit as the spin grows). Now the
    # rotation's sub-steps are capped at max_substeps (64), and SHAKE's retries double
    # up to it, so a step takes fewer than 3 max_substeps sub-steps (a ladder k, 2k, ...,
    # 64 sums to < 128, plus 64); a capped step is counted.
    sim = load_scene(CONFIG / 'pendulum_chain.yaml').simulation
    sim.set_step(sim.dt, integrator)
    cap = sim.integrator.max_substeps
    sim.apply_wrench('link2', torque=[0.0, 1e4, 0.0], frame='world', key='push')
    most = 0
    for _ in range(2000):
        before = sim.work()['substeps']
        try:
            sim.step()
        except Exception:   # (DivergenceError: the push is beyond what dt resolves)
            break
        most = max(most, sim.work()['substeps'] - before)
    assert 0 < most < 3 * cap, most
    # The spin reached the cap's regime: some step was capped and counted as such
    # (a spin beyond cap * max_rotation / dt = 16,000 rad/s).
    spin = np.abs(sim.state.ang_vel_principal).max()
    assert sim.work()['capped_steps'] > 0 or spin * sim.dt / sim.integrator.max_rotation \
        <= cap, spin


@pytest.mark.parametrize('integrator', ['symplectic_euler', 'lie_poisson2'])
def test_a_projection_left_above_the_tolerance_is_counted(integrator):
    # SHAKE given one Newton iteration (max_iterations = 1) on a pendulum swinging fast at
    # dt = 0.01 s: the first drift misses Φ by ~1e-4 m, one Newton step leaves ~1e-8 (its
    # quadratic convergence), far above the 1e-13 m tolerance: every step ends unconverged,
    # is kept, and is counted. With the default six iterations none is.
    def swing(max_iterations):
        bob = RigidBody('bob', 1.0, [1e-3] * 3, position_world=[0.5, 0.0, 0.0],
                        linear_velocity_world=[0.0, 0.0, -6.0])
        sim = Simulation([bob], [], integrator, 1e-2,
                         [Constraint('rod', 'ball', 'bob', None, anchor_world=[0.0, 0.0, 0.0])])
        sim.dynamics.solver.max_iterations = max_iterations
        sim.step(50)
        return sim.work()['unconverged_projections'], sim.diagnostics().constraint_violation

    count, violation = swing(1)
    assert count > 0 and violation > 1e-12
    count, violation = swing(6)
    assert count == 0 and violation < 1e-12
