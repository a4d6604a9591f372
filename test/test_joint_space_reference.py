"""
The joint-space reference (joint_space_reference.py) checked on its own.

Closed forms (the textbook 2R arm), invariants (M symmetric positive definite, the
kinetic energy of the link velocities is ½ qdᵀ M qd, energy conservation, the power
identity dE/dt = qdᵀ tau) and the URDF conventions, before any simulator test trusts it.
"""

import functools

import joint_space_reference as ref
from joint_space_reference import JointSpaceModel

import numpy as np

import pytest

from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

import xacro

EPS = np.finfo(float).eps
ROBOTS = ['two_link_arm', 'two_link_arm_rotated', 'arm7', 'xacro_arm']


@functools.lru_cache(maxsize=None)
def robot(name: str, **mappings) -> JointSpaceModel:
    """Return the reference model of a test robot of test/urdf (xacro expanded)."""
    if name == 'xacro_arm':
        path = ref.urdf_path('xacro_arm.urdf.xacro')
        return JointSpaceModel.from_urdf(xacro.process_file(path, mappings=mappings).toxml())
    with open(ref.urdf_path(name + '.urdf'), encoding='utf-8') as f:
        return JointSpaceModel.from_urdf(f.read())


def random_state(model: JointSpaceModel, rng: np.random.Generator) -> tuple:
    """Return a random (q, qd, tau): angles in [-pi, pi], rates ~1 rad/s, tau ~5 N m."""
    n = model.n
    return rng.uniform(-np.pi, np.pi, n), rng.normal(size=n), 5.0 * rng.normal(size=n)


def derivative(f, step: float):
    """Return f'(0) by the five-point central stencil: error step⁴ |f⁽⁵⁾| / 30."""
    return (f(-2.0 * step) - 8.0 * f(-step) + 8.0 * f(step) - f(2.0 * step)) / (12.0 * step)


def max_error(actual, expected) -> float:
    """Return max |actual - expected| relative to max |expected|."""
    expected = np.asarray(expected)
    return np.abs(np.asarray(actual) - expected).max() / np.abs(expected).max()


def urdf(body: str) -> str:
    """Return a URDF document around ``body`` (links and joints)."""
    return f'<?xml version="1.0"?>\n<robot name="test">\n{body}\n</robot>\n'


def box_link(name: str, extra: str = '') -> str:
    """Return a 1 kg link with a diagonal inertia, centred at its origin, or ``extra``."""
    inertial = extra or ('<origin xyz="0 0 0"/><mass value="1"/><inertia ixx="0.01" '
                         'ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.025"/>')
    return f'<link name="{name}"><inertial>{inertial}</inertial></link>'


def joint(name: str, kind: str, parent: str, child: str, inner: str = '') -> str:
    """Return a joint element."""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/>{inner}</joint>')


# ------------------------------------------------------------------------- invariants


@pytest.mark.parametrize('name', ROBOTS)
def test_mass_matrix_is_symmetric_positive_definite(name, rng):
    """M(q) is exactly symmetric (assembled so) and its Cholesky factor exists."""
    model = robot(name)
    for _ in range(5):
        q, _, _ = random_state(model, rng)
        m = model.mass_matrix(q)
        np.testing.assert_array_equal(m, m.T)
        assert np.linalg.eigvalsh(m).min() > 0.0


@pytest.mark.parametrize('name', ROBOTS)
def test_kinetic_energy_of_the_links_is_half_qd_m_qd(name, rng):
    """The links' kinetic energy, from their own velocities, is ½ qdᵀ M qd: M is its Hessian."""
    model = robot(name)
    for _ in range(5):
        q, qd, _ = random_state(model, rng)
        kinetic, _ = model.energy(q, qd)
        # bound: two sums of ~10² rounded products, terms up to ~10 T (the world-origin
        # lever arms of the spatial inertias, <= 1.5 m, at ~1 rad/s): ~2e-13; measured 1e-14
        assert abs(0.5 * qd @ model.mass_matrix(q) @ qd - kinetic) <= 1e-12 * kinetic


@pytest.mark.parametrize('name', ROBOTS)
def test_inverse_dynamics_undoes_forward_dynamics(name, rng):
    """RNEA of the accelerations that CRBA + RNEA + a solve give for tau returns tau."""
    model = robot(name)
    for _ in range(5):
        q, qd, tau = random_state(model, rng)
        qdd = model.forward_dynamics(q, qd, tau)
        back = model.inverse_dynamics(q, qd, qdd)
        scale = np.abs(tau).max() + np.abs(model.bias(q, qd)).max()
        # bound: the residual of a backward-stable solve, <= n eps cond(M) |tau - h| with
        # n <= 9, cond(M) <= 340 (arm7): 7e-13 |tau - h|, + RNEA rounding; measured 2e-14
        assert np.abs(back - tau).max() <= 1e-10 * scale


@pytest.mark.parametrize('name', ROBOTS)
def test_inverse_dynamics_is_m_qdd_plus_bias(name, rng):
    """The RNEA is linear in qdd with the CRBA's M as coefficient and h as offset."""
    model = robot(name)
    q, qd, _ = random_state(model, rng)
    qdd = 3.0 * rng.normal(size=model.n)
    m_qdd, h = model.mass_matrix(q) @ qdd, model.bias(q, qd)
    scale = np.abs(m_qdd).max() + np.abs(h).max()
    # bound: ~10² roundings on each side of terms <= ~10 scale (lever arms): 2e-13;
    # measured 1.4e-14
    assert np.abs(model.inverse_dynamics(q, qd, qdd) - m_qdd - h).max() <= 1e-12 * scale


@pytest.mark.parametrize('name', ROBOTS)
def test_gravity_is_the_gradient_of_the_potential(name, rng):
    """h(q, 0) = dV/dq with V the links' own -m g·c."""
    model = robot(name)
    q, _, _ = random_state(model, rng)
    zero = np.zeros(model.n)
    grad = [derivative(lambda s: model.energy(q + s * e, zero)[1], 1e-3)
            for e in np.eye(model.n)]
    # bound: rounding 1.5 eps |V| / step with |V| <= 110 J: 4e-11 N m, against |g| >= 1 N m;
    # the stencil's step⁴ |V⁽⁵⁾| / 30 <= 1e-12 x 100 J / 30 is below it; measured 2e-12
    assert max_error(grad, model.bias(q, zero)) < 1e-9


@pytest.mark.parametrize('name', ROBOTS)
def test_bias_follows_from_the_lagrangian(name, rng):
    """h(q, qd) = d/dt(dT/dqd) - dL/dq at qdd = 0, with L = T - V of the links' own energy."""
    model = robot(name)
    q, qd, _ = random_state(model, rng)
    qd *= 2.0
    # dT/dqd = M qd (M checked against T above); its rate along q(t) = q + t qd
    rate = derivative(lambda s: model.mass_matrix(q + s * qd) @ qd, 5e-4)

    def lagrangian(x):
        kinetic, potential = model.energy(x, qd)
        return kinetic - potential

    dl_dq = np.array([derivative(lambda s: lagrangian(q + s * e), 5e-4)
                      for e in np.eye(model.n)])
    # bound: the stencil's step⁴ |f⁽⁵⁾| / 30 <~ (step |qd|₁)⁴ |f| / 30 with |qd|₁ <~ 17 /s
    # (arm7): 2e-10 |f|, + rounding 1.5 eps |L| / step <= 8e-11 N m, against |h| >= 1 N m;
    # measured 4e-12 (arm7), 7e-12 (two-link)
    assert max_error(rate - dl_dq, model.bias(q, qd)) < 1e-9


@pytest.mark.parametrize('name', ROBOTS)
def test_link_twists_are_the_rates_of_the_link_frames(name, rng):
    """link_twists (which energy uses) is d/dt of fk along qd: v = dp/dt, [w]x = dR/dt Rᵀ."""
    model = robot(name)
    q, qd, _ = random_state(model, rng)
    twists = model.link_twists(q, qd)
    frames = model.fk(q)
    for link in model.link_names:
        v = derivative(lambda s: model.fk(q + s * qd)[link][0], 1e-3)
        w_hat = derivative(lambda s: model.fk(q + s * qd)[link][1], 1e-3) @ frames[link][1].T
        w = np.array([w_hat[2, 1], w_hat[0, 2], w_hat[1, 0]])
        # bound: step⁴ |p⁽⁵⁾| / 30 with |p⁽⁵⁾| <~ reach |qd|₁⁵ <~ 1.5 m (8.5 /s)⁵: 2e-9 (arm7),
        # + rounding 1.5 eps 1.5 m / step = 5e-13 (m/s, rad/s); measured 2e-11
        np.testing.assert_allclose(v, twists[link][0], rtol=0, atol=1e-8)
        np.testing.assert_allclose(w, twists[link][1], rtol=0, atol=1e-8)


# -------------------------------------------------------------- closed forms, rewrites


def test_two_link_arm_matches_the_closed_form(rng):
    """M and h of two_link_arm.urdf are the textbook planar 2R arm's, written by hand."""
    model = robot('two_link_arm')
    mass_matrix, bias = ref.two_link_closed_form(ref.TWO_LINK_PARAMS)
    for _ in range(5):
        q, qd, _ = random_state(model, rng)
        qd *= 3.0
        # bound: a few dozen roundings of terms <= |M|, |h|: ~1e-14; measured 1e-15
        assert max_error(model.mass_matrix(q), mass_matrix(q)) < 1e-12
        assert max_error(model.bias(q, qd), bias(q, qd)) < 1e-12


def test_xacro_arm_expands_with_its_prefix():
    """The xacro arm's argument prefixes every generated link and joint name."""
    model = robot('xacro_arm', prefix='left_')
    assert model.link_names == ['world', 'left_base_link', 'left_link1', 'left_link2']
    assert model.joint_names == ['left_joint1', 'left_joint2']


def test_xacro_arm_matches_the_closed_form(rng):
    """The xacro arm, expanded with another link length, is the closed-form 2R arm."""
    model = robot('xacro_arm', link_length='0.55')
    mass_matrix, bias = ref.two_link_closed_form(ref.xacro_arm_params(0.55))
    q, qd, _ = random_state(model, rng)
    # bound: as for two_link_arm, + xacro's printing of the inertias (repr: exact)
    assert max_error(model.mass_matrix(q), mass_matrix(q)) < 1e-12
    assert max_error(model.bias(q, qd), bias(q, qd)) < 1e-12


def test_rotated_two_link_arm_has_the_same_dynamics(rng):
    """two_link_arm_rotated.urdf (rotated frames, full tensors) has the plain arm's M and h."""
    plain, rotated = robot('two_link_arm'), robot('two_link_arm_rotated')
    for _ in range(5):
        q, qd, _ = random_state(plain, rng)
        # bound: its 17-digit numbers (1e-17 relative) and a few dozen roundings: 1e-14;
        # measured 4e-15
        assert max_error(rotated.mass_matrix(q), plain.mass_matrix(q)) < 1e-12
        assert max_error(rotated.bias(q, qd), plain.bias(q, qd)) < 1e-12


def test_rotated_two_link_arm_moves_the_links_alike(rng):
    """Corresponding links: equal origins, orientations differing by the stated rotation."""
    plain, rotated = robot('two_link_arm'), robot('two_link_arm_rotated')
    q, _, _ = random_state(plain, rng)
    frames = rotated.fk(q)
    for link, (p, rot) in plain.fk(q).items():
        offset = ref.rpy_matrix(ref.TWO_LINK_ROTATED_FRAME_RPY[link])
        # bound: products of three or four rotations, ~10 eps per entry, |p| <= 2 m
        np.testing.assert_allclose(frames[link][0], p, rtol=0, atol=1e-12)
        np.testing.assert_allclose(frames[link][1], rot @ offset, rtol=0, atol=1e-12)


# ------------------------------------------------------------------------- integration


def conserved_energy_error(model: JointSpaceModel, duration: float, rng) -> float:
    """Integrate qdd = M⁻¹(-h) with DOP853; return max |E - E0| / max kinetic energy."""
    n = model.n
    zero = np.zeros(n)

    def rhs(_, y):
        return np.concatenate([y[n:], model.forward_dynamics(y[:n], y[n:], zero)])

    y0 = np.concatenate([rng.uniform(-1.0, 1.0, n), rng.uniform(-2.0, 2.0, n)])
    sol = solve_ivp(rhs, (0.0, duration), y0, method='DOP853', rtol=1e-12, atol=1e-12)
    assert sol.success
    samples = sol.y[:, np.unique(np.linspace(0, sol.y.shape[1] - 1, 25).astype(int))]
    energies = np.array([model.energy(y[:n], y[n:]) for y in samples.T])
    total = energies.sum(axis=1)
    return np.abs(total - total[0]).max() / energies[:, 0].max()


@pytest.mark.parametrize('name, duration', [('two_link_arm', 2.0), ('arm7', 0.5)])
def test_energy_is_conserved_without_effort(name, duration, rng):
    """Forward dynamics with tau = 0 keeps T + V constant (independently computed E)."""
    # bound: DOP853's local error <= atol + rtol |y| ~ 3e-12 per step, times |dE/dy| <~ 30 J
    # per unit state, over <~ 300 steps, added up in the worst case: 3e-8 J against max
    # T >~ 3 J; measured (two-link 2 s / arm7 0.5 s) 4e-13 / 7e-14 (errors partly cancel)
    assert conserved_energy_error(robot(name), duration, rng) < 1e-8


@pytest.mark.parametrize('name', ROBOTS)
def test_power_is_qd_dot_tau(name, rng):
    """dE/dt = qdᵀ tau along the forward dynamics with tau != 0 (finite differences)."""
    model = robot(name)
    q, qd, tau = random_state(model, rng)
    qdd = model.forward_dynamics(q, qd, tau)
    power = derivative(lambda s: sum(model.energy(q + s * qd, qd + s * qdd)), 1e-4)
    # bound: rounding 1.5 eps |E| / step with |E| <= 110 J: 4e-10 W; the stencil's step⁴
    # |E⁽⁵⁾| / 30 along the line is below it at step 1e-4 s; measured 2e-10 W
    assert abs(power - qd @ tau) < 1e-8 * max(abs(qd @ tau), 1.0)


# ------------------------------------------------------------------- URDF conventions


def test_origin_rpy_is_fixed_axis_roll_pitch_yaw():
    """A joint origin's rpy is R = Rz(yaw) Ry(pitch) Rx(roll): extrinsic x, y, z."""
    rpy = (0.3, -1.1, 2.4)
    model = JointSpaceModel.from_urdf(urdf(
        '<link name="world"/>' + box_link('a')
        + joint('j', 'fixed', 'world', 'a', '<origin xyz="1 2 3" rpy="%g %g %g"/>' % rpy)))
    p, rot = model.fk(np.zeros(0))['a']
    # bound: three elementary rotations multiplied, a few eps per entry
    np.testing.assert_allclose(rot, Rotation.from_euler('xyz', rpy).as_matrix(), atol=1e-15)
    np.testing.assert_array_equal(p, [1.0, 2.0, 3.0])


def test_missing_axis_is_the_joint_frame_x():
    """A revolute joint without <axis> turns about x of its (rotated) joint frame."""
    origin = '<origin xyz="0.1 0 0" rpy="0 0.7 0"/>'
    model = JointSpaceModel.from_urdf(urdf(
        '<link name="world"/>' + box_link('a')
        + joint('j', 'revolute', 'world', 'a', origin
                + '<limit lower="-3" upper="3" effort="1" velocity="1"/>')))
    angle = 0.9
    _, rot = model.fk([angle])['a']
    expected = Rotation.from_euler('y', 0.7) * Rotation.from_rotvec([angle, 0.0, 0.0])
    # bound: a few rotations multiplied, a few eps per entry
    np.testing.assert_allclose(rot, expected.as_matrix(), atol=1e-15)


def test_prismatic_joint_translates_along_its_normalized_axis():
    """A prismatic child frame moves by q times the unit axis, keeping the joint frame."""
    origin = '<origin xyz="0 0 0.5" rpy="0 0 1.5707963267948966"/>'
    model = JointSpaceModel.from_urdf(urdf(
        '<link name="world"/>' + box_link('a')
        + joint('j', 'prismatic', 'world', 'a', origin + '<axis xyz="3 0 4"/>'
                + '<limit lower="-1" upper="1" effort="1" velocity="1"/>')))
    p, rot = model.fk([0.2])['a']
    # bound: the axis (0.6, 0, 0.8) turned by yaw 90 degrees is (0, 0.6, 0.8), a few eps
    np.testing.assert_allclose(p, [0.0, 0.12, 0.5 + 0.16], atol=1e-15)
    np.testing.assert_allclose(rot, Rotation.from_euler('z', np.pi / 2).as_matrix(),
                               atol=1e-15)


def test_inertial_rpy_rotates_the_tensor_into_the_link_frame():
    """The tensor in the link frame is R I Rᵀ with R the inertial origin's rpy."""
    rpy = (0.4, 0.2, -0.9)
    inertial = ('<origin xyz="0.1 0.2 0.3" rpy="%g %g %g"/><mass value="2"/><inertia '
                'ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.025"/>' % rpy)
    model = JointSpaceModel.from_urdf(urdf(
        '<link name="world"/>' + box_link('a', inertial)
        + joint('j', 'fixed', 'world', 'a')))
    mass, com, inertia = model.link_inertia_world(np.zeros(0))['a']
    rot = Rotation.from_euler('xyz', rpy).as_matrix()
    assert mass == 2.0
    np.testing.assert_array_equal(com, [0.1, 0.2, 0.3])
    # bound: two products of 3x3 matrices, a few eps |I|
    np.testing.assert_allclose(inertia, rot @ np.diag([0.01, 0.02, 0.025]) @ rot.T,
                               atol=1e-17)


def test_fixed_joint_child_rides_rigidly(rng):
    """arm7's hand keeps the fixed hand_joint's offset from link7 at every q."""
    model = robot('arm7')
    q, _, _ = random_state(model, rng)
    frames = model.fk(q)
    p7, r7 = frames['link7']
    offset = ref.rpy_matrix([0.0, 0.0, -np.pi / 4])
    # bound: one product of rotations more, a few eps, |p| <= 1.5 m
    np.testing.assert_allclose(frames['hand'][0], p7 + r7 @ [0.0, 0.0, 0.107], atol=1e-15)
    np.testing.assert_allclose(frames['hand'][1], r7 @ offset, atol=1e-15)


def test_coordinates_follow_the_urdf_joint_order():
    """joint_names are the moving joints in file order; fixed joints have no coordinate."""
    model = robot('arm7')
    assert model.joint_names == ['joint%d' % i for i in range(1, 8)] + [
        'finger_joint1', 'finger_joint2']
    assert model.link_names[0] == 'world'
    assert model.root_link == 'world'


def test_dynamics_and_limits_are_read_but_not_applied():
    """<dynamics> and <limit> are exposed per coordinate (the dynamics ignore them)."""
    model = robot('arm7')
    np.testing.assert_array_equal(model.damping, [0.3, 0.3, 0, 0.2, 0, 0.1, 0.1, 0, 0])
    np.testing.assert_array_equal(model.friction, [0.05, 0.05, 0, 0.02, 0, 0, 0.01, 0, 0])
    assert model.limits['joint4'] == ref.JointLimit(-3.07, 0.1, 87.0, 2.2)
    assert model.limits['finger_joint2'] == ref.JointLimit(0.0, 0.04, 20.0, 0.2)


def test_floating_and_planar_joints_are_rejected():
    """The reference supports fixed bases only: it names the joint it cannot model."""
    with open(ref.urdf_path('floating_planar.urdf'), encoding='utf-8') as f:
        text = f.read()
    with pytest.raises(ValueError, match="joint 'puck_joint': type 'planar'"):
        JointSpaceModel.from_urdf(text)


def test_floating_base_is_not_implemented():
    """base_fixed=False asks for a floating base, which the reference does not have."""
    with pytest.raises(NotImplementedError, match='fixed base only'):
        JointSpaceModel.from_urdf(urdf('<link name="a"/>'), base_fixed=False)


def test_wrong_shapes_are_rejected():
    """A q of the wrong length is an error naming the argument and the shape."""
    with pytest.raises(ValueError, match=r'qd must have shape \(9,\)'):
        robot('arm7').bias(np.zeros(9), np.zeros(8))


# ------------------------------------------------------------------------ mimic joints


def mimic_chain() -> JointSpaceModel:
    """Return three revolute joints in a row, j2 mimicking j1 and j3 mimicking j2."""
    limit = '<limit lower="-3" upper="3" effort="1" velocity="1"/><axis xyz="0 1 0"/>'
    origin = '<origin xyz="0 0 -0.3"/>'
    return JointSpaceModel.from_urdf(urdf(
        '<link name="world"/>' + box_link('a') + box_link('b') + box_link('c')
        + joint('j1', 'revolute', 'world', 'a', limit)
        + joint('j2', 'revolute', 'a', 'b', origin + limit
                + '<mimic joint="j1" multiplier="2" offset="0.1"/>')
        + joint('j3', 'continuous', 'b', 'c', origin + '<axis xyz="1 0 0"/>'
                + '<mimic joint="j2" multiplier="-0.5" offset="0.3"/>')))


def test_mimic_map_resolves_chains_to_an_independent_leader():
    """q3 = -0.5 q2 + 0.3 with q2 = 2 q1 + 0.1 gives q3 = -q1 + 0.25."""
    model = mimic_chain()
    assert model.independent_joint_names == ['j1']
    assert model.mimic_map['j2'] == ('j1', 2.0, 0.1)
    leader, multiplier, offset = model.mimic_map['j3']
    assert (leader, multiplier) == ('j1', -1.0)
    assert offset == pytest.approx(0.25, abs=1e-16)   # bound: one rounding of 0.3 - 0.05
    np.testing.assert_allclose(model.expand([0.7]), [0.7, 1.5, -0.45], atol=1e-15)


def test_arm7_finger_mimics_its_twin():
    """finger_joint2 = finger_joint1: one coordinate of the reduced model fewer."""
    model = robot('arm7')
    assert model.mimic_map == {'finger_joint2': ('finger_joint1', 1.0, 0.0)}
    assert model.independent_joint_names == model.joint_names[:-1]


@pytest.mark.parametrize('chain', [False, True], ids=['arm7', 'mimic_chain'])
def test_reduced_mass_matrix_is_the_kinetic_energy_hessian(chain, rng):
    """½ qd_rᵀ M_r qd_r is the links' kinetic energy at the expanded state."""
    model = mimic_chain() if chain else robot('arm7')
    r = len(model.independent_joint_names)
    q_r, qd_r = rng.uniform(-1.0, 1.0, r), rng.normal(size=r)
    m_r, _ = model.reduced_dynamics(q_r, qd_r)
    kinetic, _ = model.energy(model.expand(q_r), model.mimic_matrix @ qd_r)
    # bound: as for the full model's kinetic energy
    assert abs(0.5 * qd_r @ m_r @ qd_r - kinetic) <= 1e-12 * kinetic


@pytest.mark.parametrize('chain', [False, True], ids=['arm7', 'mimic_chain'])
def test_reduced_forward_dynamics_agrees_with_the_full_inverse_dynamics(chain, rng):
    """Tᵀ RNEA(q, T qd_r, T qdd_r) returns the tau_r that produced qdd_r."""
    model = mimic_chain() if chain else robot('arm7')
    t = model.mimic_matrix
    r = t.shape[1]
    q_r, qd_r, tau_r = rng.uniform(-1.0, 1.0, r), rng.normal(size=r), rng.normal(size=r)
    qdd_r = model.reduced_forward_dynamics(q_r, qd_r, tau_r)
    tau = model.inverse_dynamics(model.expand(q_r), t @ qd_r, t @ qdd_r)
    _, h_r = model.reduced_dynamics(q_r, qd_r)
    # bound: as for the full model, n eps cond(M_r) |tau_r - h_r| + rounding
    scale = np.abs(tau_r).max() + np.abs(h_r).max()
    assert np.abs(t.T @ tau - tau_r).max() <= 1e-10 * scale
