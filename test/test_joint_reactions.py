"""Reaction wrenches against Newton–Euler: forces, torques about the centre of mass and anchor."""

import numpy as np
import pytest
from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
from rigid_body_sim.core import rotation as so3

G_WORLD = np.array([0.0, 0.0, -9.81])
ANCHOR = np.array([0.0, 0.0, 0.0])


def compound_pendulum(kind):
    # A box hanging off-centre from the origin, tilted and spinning: the joint carries
    # a force and, for a hinge, a torque.
    tilt = so3.exp_quat(np.array([0.3, -0.5, 0.2]))
    box = RigidBody('box', 2.0, [0.02, 0.05, 0.06], com_body=[0.0, 0.0, -0.3],
                    position_world=ANCHOR, orientation_xyzw=tilt,
                    angular_velocity_body=[1.0, -2.0, 0.5])
    joint = (Constraint('pin', 'ball', 'box', None, anchor_world=ANCHOR) if kind == 'ball'
             else Constraint('pin', 'hinge', 'box', None, anchor_world=ANCHOR,
                             axis_world=[0.0, 1.0, 0.0]))
    return Simulation([box], [Gravity(G_WORLD)], 'rkmk4', 1e-4, [joint])


@pytest.mark.parametrize('kind', ['ball', 'hinge'])
def test_reaction_wrench_is_the_newton_euler_wrench(kind):
    sim = compound_pendulum(kind)
    sim.run(0.2)
    h = sim.dt
    momenta = []
    for _ in range(3):
        d = sim.diagnostics()
        momenta.append((d.linear_momentum_world, d.angular_momentum_com_world))
        if len(momenta) == 2:
            reaction = sim.reactions()['pin']['box']
            com = sim.state.pos_com_world[0].copy()
            violation = d.constraint_violation   # largest |Φ| (m or rad), ~1e-15 here
        sim.step()
    # d p / dt = m g + f and d L_com / dt = τ_com (gravity has no moment about the COM),
    # by central differences: O(h²) relative to the wrench (rounding: eps |p| / h = 1e-12).
    dp = (momenta[2][0] - momenta[0][0]) / (2 * h)
    dl = (momenta[2][1] - momenta[0][1]) / (2 * h)
    scale = np.linalg.norm(reaction.force_world)
    assert scale > 5.0   # the joint holds a 2 kg box
    # bound: h² |f''| / 6 = h² ω² |f| / 6, ω <~ 6 rad/s (spin, swing): 6e-8 |f|; x17
    np.testing.assert_allclose(reaction.force_world, dp - 2.0 * G_WORLD, rtol=0,
                               atol=1e-6 * scale)
    # bound: the same h² ω² / 6 = 6e-8, relative to the torque itself; x17
    np.testing.assert_allclose(reaction.torque_com_world, dl, rtol=0,
                               atol=1e-6 * np.linalg.norm(dl))
    # The anchor is where the joint is, and the torque about it follows from the lever.
    # bound: off the joint by the point rows' |Φ| <= violation, + rounding of x + R r (~5e-16)
    np.testing.assert_allclose(reaction.anchor_world, ANCHOR, rtol=0, atol=violation + 1e-14)
    lever = reaction.anchor_world - com
    # bound: lever = (x + r) - x rounds by eps (|x| + |r|), the cross 2 eps |r||f|: 4e-16 |f|
    np.testing.assert_allclose(reaction.torque_anchor_world,
                               reaction.torque_com_world - np.cross(lever, reaction.force_world),
                               rtol=0, atol=1e-14 * scale)
    if kind == 'ball':
        # A ball joint transmits no moment about its centre.
        # bound: R (r × Rᵀ f) - (R r) × f, ~13 roundings of terms <= |r||f| = 0.3 |f|: 9e-16 |f|
        np.testing.assert_allclose(reaction.torque_anchor_world, 0.0, rtol=0,
                                   atol=1e-14 * scale)
    else:
        # A hinge transmits moments across its axis, none about it.
        # bound: axis tilt <= violation times |τ| < |f| 0.3 m, + rounding as the ball's
        assert abs(reaction.torque_anchor_world[1]) < (violation + 1e-14) * scale
        assert np.linalg.norm(reaction.torque_anchor_world) > 1e-3


def test_reactions_on_both_bodies_are_equal_and_opposite():
    a = RigidBody('a', 1.0, [0.01, 0.02, 0.025], position_world=[0.0, 0.0, 0.0],
                  angular_velocity_body=[0.0, 3.0, 1.0])
    b = RigidBody('b', 3.0, [0.03, 0.03, 0.05], position_world=[0.4, 0.0, 0.0],
                  linear_velocity_world=[0.0, 0.0, 1.0])
    sim = Simulation([a, b], [Gravity(G_WORLD)], 'lie_poisson2', 1e-3,
                     [Constraint('weld', 'fixed', 'a', 'b', anchor_world=[0.2, 0.0, 0.0])])
    sim.run(0.3)
    r = sim.reactions()['weld']
    violation = sim.diagnostics().constraint_violation   # largest |Φ|, <= ~1e-13 (SHAKE)
    scale = np.linalg.norm(r['a'].force_world)
    assert scale > 0.1   # the weld carries the centripetal load of the spin
    # bound: Gᵀλ with the linear blocks ±e_c: equal up to rounding of its sums, 6 eps |f|; x10
    np.testing.assert_allclose(r['a'].force_world, -r['b'].force_world, rtol=0,
                               atol=1e-14 * scale)
    # bound: the point rows' |Φ| <= violation, + rounding of x + R r on each side (~5e-16)
    np.testing.assert_allclose(r['a'].anchor_world, r['b'].anchor_world, rtol=0,
                               atol=violation + 1e-14)
    # bound: the anchors' offset (<= violation) times |f|, + ~13 eps (|r_a| + |r_b|) |f|; x10
    np.testing.assert_allclose(r['a'].torque_anchor_world, -r['b'].torque_anchor_world,
                               rtol=0, atol=(violation + 1e-14) * scale)
