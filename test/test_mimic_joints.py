"""
Mimic joints (URDF ``<mimic>``): ``q_f = k q_l + c`` as one exact constraint row.

The row couples the follower's two bodies and the leader's (up to four bodies), so
the references are the joint-space model with the mimic joints eliminated
(``joint_space_reference``: ``M_r = Tᵀ M T``, ``h_r = Tᵀ h``, its own parser and
RNEA/CRBA), integrated by DOP853 where a trajectory is compared; and the identity
that a joint's effort is the generalized force on its coordinate, ``M q̈ + h``.
"""

from joint_space_reference import JointSpaceModel, urdf_path
import numpy as np
import pytest
from rigid_body_sim.core import SpecError
from rigid_body_sim.core.kernels.layout import Solve
from rigid_body_sim.scene import scene_from_dict, SceneError
from robot_helpers import inertial, joint, joint_accelerations, link, robot
from scipy.integrate import solve_ivp

G = 9.81
INTEGRATORS = ['symplectic_euler', 'lie_poisson2', 'lie_poisson4', 'rkmk4']


def load(text_or_file, tmp_path=None, integrator='lie_poisson2', dt=1e-3, groups=(),
         gravity=True, **entry):
    """Load one robot (a test URDF file name, or URDF text written to ``tmp_path``)."""
    if tmp_path is None:
        path = urdf_path(text_or_file)
    else:
        path = str(tmp_path / 'robot.urdf')
        (tmp_path / 'robot.urdf').write_text(text_or_file)
    data = {'dt': dt, 'integrator': integrator, 'robots': [dict(urdf=path, **entry)],
            'command_groups': list(groups)}
    if gravity:
        data['effects'] = {'gravity': {'g_world': [0.0, 0.0, -G]}}
    return scene_from_dict(data, urdf_path('scene.yaml')).simulation


def two_arms(k=0.5, c=0.1, leader_limits=(-2.0, 2.0), follower='revolute', extra=''):
    """
    Two 2-link arms on the world (hinges about y, gravity along −z); B's elbow mimics A's.

    The mimic row couples four bodies (A1, A2, B1, B2). ``follower='prismatic'`` makes
    B's elbow a slider along x (k in m/rad).
    """
    lo, hi = leader_limits
    lim = f'<limit effort="100" velocity="100" lower="{lo}" upper="{hi}"/>'
    if follower == 'prismatic':
        elbow_b = joint('b_elbow', 'prismatic', 'b1', 'b2', xyz=(0.4, 0, 0), axis=(1, 0, 0),
                        extra=f'<mimic joint="a_elbow" multiplier="{k}" offset="{c}"/>')
    else:
        elbow_b = joint('b_elbow', 'revolute', 'b1', 'b2', xyz=(0.4, 0, 0), axis=(0, 1, 0),
                        extra=f'<mimic joint="a_elbow" multiplier="{k}" offset="{c}"/>')
    return robot(
        'two_arms', link('world'),
        link('a1', inertial(1.0, xyz=(0.2, 0, 0), ixx=0.01, iyy=0.02, izz=0.02)),
        link('a2', inertial(0.7, xyz=(0.15, 0.02, 0), ixx=0.01, iyy=0.015, izz=0.012,
                            ixy=0.001)),
        link('b1', inertial(1.2, xyz=(0.2, 0, 0), ixx=0.01, iyy=0.03, izz=0.03)),
        link('b2', inertial(0.5, xyz=(0.1, 0, 0.03), ixx=0.008, iyy=0.01, izz=0.011,
                            ixz=0.001)),
        joint('a_shoulder', 'revolute', 'world', 'a1', axis=(0, 1, 0)),
        joint('a_elbow', 'revolute', 'a1', 'a2', xyz=(0.4, 0, 0), axis=(0, 1, 0), extra=lim),
        joint('b_shoulder', 'revolute', 'world', 'b1', xyz=(1.0, 0, 0), axis=(0, 1, 0)),
        elbow_b, extra)


def reduced_accelerations(ref, names, q, qd, tau):
    """q̈ (full coordinates, ``names`` order) of the reduced joint-space model."""
    order = [names.index(n) for n in ref.joint_names]
    q, qd, tau = q[order], qd[order], tau[order]
    ind = [ref.joint_names.index(n) for n in ref.independent_joint_names]
    T = ref.mimic_matrix
    M_r, h_r = ref.reduced_dynamics(q[ind], qd[ind])
    qdd = T @ np.linalg.solve(M_r, T.T @ tau - h_r)
    out = np.empty_like(qdd)
    out[order] = qdd
    return out


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_arm7_gripper_follows_its_leader_as_the_reduced_dynamics(seed):
    # arm7's right finger mimics the left (k = 1): a row over the hand and both fingers,
    # a closure row of the loop solve (the arm has 48 rows).
    rng = np.random.default_rng(seed)
    ref = JointSpaceModel.from_urdf(open(urdf_path('arm7.urdf')).read())
    # (limits and friction off: the random states may lie beyond the limits, and the
    # reference has neither)
    sim = load('arm7.urdf', limits=False, friction=False)
    assert [c.solve for c in sim.dynamics.solver.kernel_setup().components] == [Solve.LOOP]
    names = sim.joint_names()
    q = np.concatenate([rng.uniform(-2.5, 2.5, 7), rng.uniform(0.0, 0.04, 1)])
    qd = np.concatenate([rng.normal(size=7), 0.1 * rng.normal(size=1)])
    q, qd = ref.expand(q), ref.mimic_matrix @ qd
    tau = rng.uniform(-5.0, 5.0, 9)   # the follower's effort acts through the row too
    sim.set_joint_state({n: q[i] for i, n in enumerate(names) if n != 'finger_joint2'},
                        {n: qd[i] for i, n in enumerate(names) if n != 'finger_joint2'})
    js = sim.joint_state()
    np.testing.assert_allclose(js.positions, q, atol=1e-12)   # the follower was set too
    np.testing.assert_allclose(js.velocities, qd, atol=1e-12)
    sim.set_joint_efforts(dict(zip(names, tau)))
    sim.step()
    js = sim.joint_state()
    damped = tau - ref.damping * js.velocities
    expected = reduced_accelerations(ref, names, js.positions, js.velocities, damped)
    got = joint_accelerations(sim)
    # bound: two solves of a 9-coordinate system (condition ~1e4 from the 0.1 kg fingers):
    # 1e-16 · 1e4 |q̈|; measured 1.4e-14 |q̈|; 1e-10 leaves room for another CPU's bits.
    scale = np.max(np.abs(expected))
    np.testing.assert_allclose(got, expected, atol=1e-10 * scale)
    # The effort is the generalized force on each coordinate: the command, the damping
    # and the mimic row's multiplier (−λ on the follower, +kλ on the leader), so the
    # joint-space equations hold joint by joint. Same bound.
    M, h = ref.mass_matrix(js.positions), ref.bias(js.positions, js.velocities)
    np.testing.assert_allclose(js.efforts, M @ got + h, atol=1e-10 * np.max(np.abs(M @ got)))
    coupling = js.efforts[8] - damped[8]
    assert abs(coupling) > 1e-3   # the row carries a load here
    np.testing.assert_allclose(js.efforts[7] - damped[7], -coupling, rtol=1e-9)
    # The follower stays on its leader: the row's drift is SHAKE's tolerance (1e-13).
    assert abs(js.positions[8] - js.positions[7]) < 1e-12


def test_four_body_mimic_is_dense_solved_and_exact(tmp_path, rng):
    text = two_arms(k=0.5, c=0.1)
    ref = JointSpaceModel.from_urdf(text)
    sim = load(text, tmp_path, initial_positions={'a_elbow': 0.3})
    assert [c.solve for c in sim.dynamics.solver.kernel_setup().components] == [Solve.DENSE]
    names = sim.joint_names()
    i_f, i_l = names.index('b_elbow'), names.index('a_elbow')
    # The follower started where its leader puts it.
    assert sim.joint_state().positions[i_f] == pytest.approx(0.5 * 0.3 + 0.1, abs=1e-12)
    for _ in range(3):
        q = rng.uniform(-1.5, 1.5, 4)
        qd = rng.normal(size=4)
        state = {n: q[i] for i, n in enumerate(names) if n != 'b_elbow'}
        rates = {n: qd[i] for i, n in enumerate(names) if n != 'b_elbow'}
        sim.set_joint_state(state, rates)
        tau = rng.uniform(-2.0, 2.0, 4)
        sim.set_joint_efforts(dict(zip(names, tau)))
        sim.step()
        js = sim.joint_state()
        assert js.positions[i_f] == pytest.approx(0.5 * js.positions[i_l] + 0.1, abs=1e-12)
        assert js.velocities[i_f] == pytest.approx(0.5 * js.velocities[i_l], abs=1e-11)
        expected = reduced_accelerations(ref, names, js.positions, js.velocities, tau)
        got = joint_accelerations(sim)
        # bound: a 4-coordinate solve, condition ~1e2: 1e-14 |q̈|; 1e-10 for other CPUs.
        np.testing.assert_allclose(got, expected, atol=1e-10 * np.max(np.abs(expected)))
        M, h = ref.mass_matrix(js.positions[[names.index(n) for n in ref.joint_names]]), None
        order = [names.index(n) for n in ref.joint_names]
        h = ref.bias(js.positions[order], js.velocities[order])
        np.testing.assert_allclose(js.efforts[order], M @ got[order] + h,
                                   atol=1e-10 * np.max(np.abs(M @ got[order])))


def assert_on_the_row(sim, integrator):
    """
    Check the mimic row holds as the integrator holds any joint.

    The splittings: SHAKE's tolerance (1e-13) with rounding: 1e-10. rkmk4 has no
    position projection: its rows drift by O(h⁵) a step, damped by the velocity
    projection (1e-10 at dt = 1e-3, 4e-8 at 4e-3 here, the hinges as the mimic):
    the mimic row's |Φ| is at most twice the hinges' largest.
    """
    solver = sim.dynamics.solver
    phi = np.abs(solver.violation(sim.state))
    mimic = solver.constraints.rows_of('b_elbow_mimic')
    others = np.delete(phi, mimic)
    if integrator == 'rkmk4':
        assert phi[mimic].max() <= 2.0 * others.max() + 1e-13
    else:
        assert phi[mimic].max() < 1e-10


def reduced_reference(ref, names, q0, qd0, T_end):
    """Full q at ``T_end`` of the reduced model from (q0, qd0), DOP853 at rtol = atol = 1e-12."""
    order = [names.index(n) for n in ref.joint_names]
    ind = [ref.joint_names.index(n) for n in ref.independent_joint_names]
    r = len(ind)

    def rhs(_, y):
        M_r, h_r = ref.reduced_dynamics(y[:r], y[r:])
        return np.concatenate([y[r:], np.linalg.solve(M_r, -h_r)])

    y0 = np.concatenate([q0[order][ind], qd0[order][ind]])
    sol = solve_ivp(rhs, (0.0, T_end), y0, method='DOP853', rtol=1e-12, atol=1e-12)
    q = ref.expand(sol.y[:r, -1])
    out = np.empty_like(q)
    out[order] = q
    return out


@pytest.mark.parametrize('integrator,order', [('lie_poisson2', 2), ('lie_poisson4', 4),
                                              ('rkmk4', 4)])
def test_mimic_trajectory_converges_at_the_integrators_order(tmp_path, integrator, order):
    # A prismatic follower of a revolute leader (k in m/rad): the two arms swing under
    # gravity for 0.4 s, against the reduced model by DOP853.
    text = two_arms(k=0.05, c=0.02, follower='prismatic')
    ref = JointSpaceModel.from_urdf(text)
    start = {'a_shoulder': 0.4, 'a_elbow': -0.6, 'b_shoulder': -0.3}
    errors = []
    for dt in (4e-3, 2e-3):
        sim = load(text, tmp_path, integrator=integrator, dt=dt, initial_positions=start)
        names = sim.joint_names()
        js0 = sim.joint_state()
        if not errors:
            expected = reduced_reference(ref, names, js0.positions, js0.velocities, 0.4)
        sim.step(int(round(0.4 / dt)))
        js = sim.joint_state()
        assert_on_the_row(sim, integrator)
        errors.append(np.max(np.abs(js.positions - expected)))
    # Halving dt divides the error by 2^order (within 30 %: the asymptotic regime).
    assert errors[0] / errors[1] > 0.7 * 2 ** order, errors


def test_mimic_chain_follows_its_root_leader(tmp_path):
    # c follows b follows a (k 2 then -0.5): the chain is resolved in order.
    text = robot(
        'chain', link('world'),
        link('a', inertial(1.0, xyz=(0.1, 0, 0))), link('b', inertial(1.0, xyz=(0.1, 0, 0))),
        link('c', inertial(1.0, xyz=(0.1, 0, 0))),
        joint('ja', 'revolute', 'world', 'a', axis=(0, 1, 0)),
        joint('jb', 'revolute', 'world', 'b', xyz=(0, 0.5, 0), axis=(0, 1, 0),
              extra='<limit effort="1" velocity="1" lower="-3" upper="3"/>'
                    '<mimic joint="ja" multiplier="2"/>'),
        joint('jc', 'revolute', 'world', 'c', xyz=(0, 1.0, 0), axis=(0, 1, 0),
              extra='<limit effort="1" velocity="1" lower="-3" upper="3"/>'
                    '<mimic joint="jb" multiplier="-0.5" offset="0.2"/>'))
    ref = JointSpaceModel.from_urdf(text)
    sim = load(text, tmp_path, initial_positions={'ja': 0.25})
    names = sim.joint_names()
    np.testing.assert_allclose(sim.joint_state().positions, [0.25, 0.5, -0.05], atol=1e-12)
    sim.step(200)
    js = sim.joint_state()
    q = js.positions
    np.testing.assert_allclose([q[1] - 2 * q[0], q[2] + 0.5 * q[1] - 0.2], 0.0, atol=1e-12)
    expected = reduced_accelerations(ref, names, q, js.velocities, np.zeros(3))
    np.testing.assert_allclose(joint_accelerations(sim), expected,
                               atol=1e-10 * np.max(np.abs(expected)))


def test_mimic_reactions_are_internal_on_each_joint(tmp_path):
    # The row's wrenches: equal and opposite across each joint (it is internal to the
    # robot), on the four bodies, and the follower's torque about its axis is −λ.
    sim = load(two_arms(), tmp_path, initial_positions={'a_shoulder': 0.3, 'a_elbow': 0.5})
    sim.step(5)
    r = sim.reactions()['b_elbow_mimic']
    assert set(r) == {'a1', 'a2', 'b1', 'b2'}
    for child, parent in (('a2', 'a1'), ('b2', 'b1')):
        # bound: Gᵀλ of one row: rounding of a few terms, 10 eps |f|.
        scale = np.linalg.norm(r[child].torque_anchor_world) + 1e-300
        np.testing.assert_allclose(r[child].force_world, -r[parent].force_world,
                                   atol=1e-14 * scale)
        np.testing.assert_allclose(r[child].torque_anchor_world,
                                   -r[parent].torque_anchor_world, atol=1e-14 * scale)
    js = sim.joint_state()
    names = sim.joint_names()
    tau_f = r['b2'].torque_anchor_world @ np.array([0.0, 1.0, 0.0])
    tau_l = r['a2'].torque_anchor_world @ np.array([0.0, 1.0, 0.0])
    # No command or damping here: the efforts are the row's, −λ and kλ (k = 0.5).
    assert abs(tau_f) > 1e-3
    assert js.efforts[names.index('b_elbow')] == pytest.approx(tau_f, rel=1e-9)
    assert js.efforts[names.index('a_elbow')] == pytest.approx(tau_l, rel=1e-9)
    assert tau_l == pytest.approx(-0.5 * tau_f, rel=1e-9)


@pytest.mark.parametrize('integrator', INTEGRATORS)
def test_every_integrator_holds_the_mimic(tmp_path, integrator):
    sim = load(two_arms(), tmp_path, integrator=integrator,
               initial_positions={'a_shoulder': 1.0, 'a_elbow': -1.0},
               initial_velocities={'b_shoulder': 3.0})
    for _ in range(50):
        sim.step(10)
        assert_on_the_row(sim, integrator)


def test_mimic_bad_input_is_refused_naming_it(tmp_path):
    def refused(text, match, **entry):
        with pytest.raises(SceneError, match=match):
            load(text, tmp_path, **entry)

    continuous = two_arms().replace('<joint name="a_elbow" type="revolute"',
                                    '<joint name="a_elbow" type="continuous"')
    refused(continuous, r'a_elbow.*continuous')
    cycle = two_arms().replace(
        '<joint name="a_elbow" type="revolute"><parent link="a1"/>',
        '<joint name="a_elbow" type="revolute"><parent link="a1"/>'
        '<mimic joint="b_elbow"/>')
    refused(cycle, 'cycle')
    refused(two_arms(), r'initial_positions\.b_elbow',
            initial_positions={'a_elbow': 0.2, 'b_elbow': 0.0})
    refused(two_arms(), r'initial_velocities\.b_elbow', initial_velocities={'b_elbow': 1.0})
    with pytest.raises(SceneError, match=r'command_groups\[0\]\.joints\[0\].*mimics'):
        load(two_arms(), tmp_path, groups=[{'name': 'g', 'joints': ['b_elbow'],
                                            'interface': 'position', 'mode': 'exact'}])
    sim = load(two_arms(), tmp_path)
    before = sim.state.y.copy()
    with pytest.raises(SpecError, match=r'positions\.b_elbow.*mimics'):
        sim.set_joint_state({'a_elbow': 0.5, 'b_elbow': 0.0})
    with pytest.raises(SpecError, match=r'follow its leader'):
        sim.remove_constraint('b_elbow_mimic')
    np.testing.assert_array_equal(sim.state.y, before)
    # A consistent value is taken.
    sim.set_joint_state({'a_elbow': 0.5, 'b_elbow': 0.35})
    assert sim.joint_state().positions[sim.joint_names().index('b_elbow')] == \
        pytest.approx(0.35, abs=1e-12)
