"""The hard cases: long runs that must stay finite, conservative and on the constraints."""

from joint_scenes import G
import numpy as np
import pytest
from rigid_body_sim.core import Constraint, DivergenceError, Gravity, RigidBody, Simulation
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.core.mechanisms import chain, four_bar, rod
from rigid_body_sim.core.reference import intermediate_axis_period


def run_and_watch(sim, seconds, every=50):
    """Step, recording the worst energy error, violation and kinetic energy; no NaN."""
    e0 = sim.diagnostics().total_energy
    worst_de = worst_violation = max_ke = 0.0
    for _ in range(int(round(seconds / sim.dt / every))):
        sim.step(every)
        d = sim.diagnostics()
        assert np.isfinite(d.total_energy) and np.all(np.isfinite(sim.state.pos_com_world))
        worst_de = max(worst_de, abs(d.total_energy - e0))
        worst_violation = max(worst_violation, d.constraint_violation)
        max_ke = max(max_ke, float(np.sum(d.kinetic_energy)))
    return worst_de, worst_violation, max_ke


@pytest.mark.slow
def test_chain_of_50_links_released_horizontal_for_20s():
    # 5 m, 5 kg of rods on ball joints falls 2.5 m and whips: the tip links turn at up to
    # 360 rad/s. The motion is chaotic, so the worst energy error is one sample of a
    # spread: at dt = 1e-3 (whips sub-stepped) runs that differ by rounding gave 1.3 %,
    # 3.0 % and 5.4 % of the largest kinetic energy (121 J). At dt = 5e-4 the whips are
    # resolved without sub-steps and the error is 0.23 to 0.31 J, 0.19 % to 0.26 % (runs
    # that differ by rounding): a truncation error that falls tenfold when dt halves, not a
    # drift. Violation at most 2e-12.
    # A splitting's violation: SHAKE leaves at most its tolerance, 1e-13 m (or its rounding
    # floor 16 sqrt(rows) eps max|x| where larger), a (sub)step h, and the target
    # exp(-h/τ) Φ decays it, so it stays below 1e-13 τ / h (the bounds below).
    sim = chain(50, 'lie_poisson2', 5e-4)
    worst_de, worst_violation, max_ke = run_and_watch(sim, 20.0, every=200)
    assert max_ke > 100.0   # it really fell and whipped (2.5 m x 5 kg x g = 123 J)
    assert worst_de < 1.5e-2 * max_ke   # bound: O(dt²) truncation, at most 2.6e-3 measured, x6
    assert worst_violation < 5e-9   # bound: floor 2.2e-13 x τ/dt = 2.2e-11, x64 if sub-stepped


def test_four_bar_linkage_redundant_closed_loop():
    # Four parallel hinges in a plane: 20 rows for 1 degree of freedom, 3 of them
    # redundant. Measured at dt = 2e-3: worst |dE| 4.9e-4 of the largest kinetic energy
    # over 3 s, 7.3e-4 over 9 s (bounded; 1.2e-4 at dt = 1e-3: order 2), violation 6e-13.
    sim = four_bar('lie_poisson2', 2e-3)
    worst_de, worst_violation, max_ke = run_and_watch(sim, 3.0)
    assert sim.dynamics.solver.counters.rank_deficient_solves > 0
    assert max_ke > 0.01   # it moves
    assert worst_de < 2e-3 * max_ke   # bound: O(dt²) truncation, 4.9e-4 measured, x4
    assert worst_violation < 1e-10   # bound: 1e-13 τ / dt = 2.5e-12, x40


def test_same_joint_added_twice_moves_like_once():
    def pendulum(joints):
        return Simulation([RigidBody('bob', 1.0, [1e-3] * 3, position_world=[0.3, 0.0, -0.2])],
                          [Gravity()], 'lie_poisson2', 1e-3, joints)

    once = pendulum([Constraint('a', 'ball', 'bob', None, anchor_world=[0.0, 0.0, 0.0])])
    twice = pendulum([Constraint('a', 'ball', 'bob', None, anchor_world=[0.0, 0.0, 0.0]),
                      Constraint('b', 'ball', 'bob', None, anchor_world=[0.0, 0.0, 0.0])])
    once.run(2.0)
    twice.run(2.0)
    assert twice.dynamics.solver.counters.rank_deficient_solves > 0
    # bound: the two solves differ by at most SHAKE's 1e-13 m a step: 2000 steps, 2e-10, x5
    np.testing.assert_allclose(twice.pose('bob')[0], once.pose('bob')[0], atol=1e-9)
    # The load is shared, not doubled: the two reactions add up to the single one.
    r1 = once.reactions()['a']['bob'].force_world
    r2 = twice.reactions()
    # bound: poses within 1e-9 m of a 0.36 m rod and Tikhonov's 1e-12: ~1e-8; a doubled load
    # is off by 100 %
    np.testing.assert_allclose(r2['a']['bob'].force_world + r2['b']['bob'].force_world, r1,
                               rtol=1e-6, atol=1e-12)


def test_mass_ratio_1e4_between_neighbouring_links():
    # Alternate 1 kg and 0.1 g rods in a 10-link chain. Measured at dt = 1e-3 over 5 s:
    # worst |dE| 3.6e-3 of the largest kinetic energy, violation 1e-13.
    bodies, joints = [], []
    for i in range(10):
        start = np.array([0.2 * i, 0.0, 0.0])
        bodies.append(rod(f'l{i}', start, np.array([1.0, 0.0, 0.0]), 0.2,
                          1.0 if i % 2 == 0 else 1e-4))
        joints.append(Constraint(f'j{i}', 'ball', f'l{i}', None if i == 0 else f'l{i - 1}',
                                 anchor_world=start))
    sim = Simulation(bodies, [Gravity()], 'lie_poisson2', 1e-3, joints)
    worst_de, worst_violation, max_ke = run_and_watch(sim, 5.0)
    assert worst_de < 1e-2 * max_ke   # bound: O(dt²) truncation, 3.7e-3 measured, x2.7
    assert worst_violation < 1e-10   # bound: 1e-13 τ / dt = 5e-12, x20


def test_top_spinning_at_100_rad_s_on_a_ball_joint():
    # A tilted top spinning at 100 rad/s about its axis, released without precession:
    # it nutates. Measured over 3 s at dt = 1e-3 with lie_poisson2: worst |dE| 3.6e-7 of
    # the kinetic energy (15 J), violation 1e-12.
    m, l, i1, i3 = 0.5, 0.1, 2e-3, 3e-3
    tilt = so3.exp_quat(np.array([0.0, np.radians(20.0), 0.0]))
    axis = so3.rotate(tilt, np.array([0.0, 0.0, 1.0]))
    top = RigidBody('top', m, [i1, i1, i3], position_world=l * axis, orientation_xyzw=tilt,
                    angular_velocity_body=[0.0, 0.0, 100.0])
    sim = Simulation([top], [Gravity((0.0, 0.0, -G))], 'lie_poisson2', 1e-3,
                     [Constraint('tip', 'ball', 'top', None, anchor_world=[0.0, 0.0, 0.0])])
    worst_de, worst_violation, max_ke = run_and_watch(sim, 3.0)
    assert worst_de < 2e-6 * max_ke   # bound: O(dt²) truncation, 3.6e-7 measured, x5.5
    assert worst_violation < 1e-10   # bound: 1e-13 τ / dt = 5e-12, x20


def test_constraint_added_mid_run_while_violated_by_10cm():
    bodies = [RigidBody('a', 1.0, [0.01, 0.02, 0.03], position_world=[0.0, 0.0, 0.0]),
              RigidBody('b', 2.0, [0.02, 0.02, 0.04], position_world=[0.5, 0.0, 0.0],
                        linear_velocity_world=[0.0, 0.3, 0.0])]
    sim = Simulation(bodies, [], 'lie_poisson2', 1e-3)
    sim.run(0.2)
    p0 = sim.diagnostics().linear_momentum_world
    # The anchors are 0.4 m and 0.1 m from the centres: 0.1 m apart when added.
    sim.add_constraint(Constraint('snap', 'ball', 'a', 'b', anchor_a_body=[0.4, 0.16, 0.0],
                                  anchor_b_body=[-0.1, 0.0, 0.0]))
    tau = sim.dynamics.solver.time_constant
    v0 = sim.constraint_violation()['snap']
    assert 0.05 < v0 < 0.15   # 0.1 m by construction
    times, violation = [], []
    for _ in range(200):
        sim.step(3)
        times.append(sim.time)
        violation.append(sim.constraint_violation()['snap'])
    violation = np.array(violation)
    # Smooth: monotonic decay (each 3 steps take >= 6 % of Φ >= 6e-7 m, far above rounding) ...
    assert np.all(np.diff(violation) <= 1e-15)
    # ... along exp(-t / tau) while it is far above rounding.
    t = np.array(times) - times[0]
    big = violation > 1e-9
    rate = -np.polyfit(t[big], np.log(violation[big]), 1)[0]
    # bound: exact to SHAKE's 1e-13 m on Φ > 1e-9 (1e-4; measured 6e-12); τ vs 2τ gives 0.5
    assert abs(rate * tau - 1.0) < 0.05
    assert violation[-1] < 1e-4 * v0   # bound: exp(-0.6 / 0.05) = 6e-6, x16
    # No external force: the snap is internal, so linear momentum holds throughout.
    # Angular momentum does not while the joint is open (measured: 3.6 % change): the
    # closing forces ±λ act at two anchors Φ apart, a couple Φ × λ. Once closed, both
    # momenta and energy hold.
    # bound: 10,600 steps x 2 bodies x eps x |m v| < 2 kg m/s = 1e-11 of rounding, x10
    # (measured 2e-15); an unbalanced closing impulse would be ~0.1 kg m/s
    d = sim.diagnostics()
    np.testing.assert_allclose(d.linear_momentum_world, p0, rtol=0.0, atol=1e-10)
    l_closed = d.angular_momentum_world
    worst_de, worst_violation, max_ke = run_and_watch(sim, 10.0)
    d = sim.diagnostics()
    np.testing.assert_allclose(d.linear_momentum_world, p0, rtol=0.0, atol=1e-10)
    # 7.4e-9 measured: the last 6e-7 m of violation still closes in this window.
    # bound: Φ λ τ = 6e-7 m x 0.07 N x 0.05 s = 2e-9 of |L| = 0.31, 7e-9; x2.7 (+ rounding)
    np.testing.assert_allclose(d.angular_momentum_world, l_closed, rtol=2e-8, atol=1e-11)
    assert max_ke > 0.01
    assert worst_de < 1e-6 * max_ke   # measured 3.3e-7 (lie_poisson2's O(dt²) error), x3
    assert worst_violation <= violation[-1]   # still decaying ...
    assert sim.constraint_violation()['snap'] < 5e-11   # ... to 1e-13 τ / dt = 5e-12, x10


def test_intermediate_axis_body_held_at_its_centre_of_mass():
    # A ball joint at the centre of mass leaves the rotation free: the flip still happens
    # with the torque-free period, energy and |L| are conserved.
    moments, omega0 = (1.0, 2.0, 3.0), (0.1, 2.0, 0.1)
    period = intermediate_axis_period(moments, omega0)
    sim = Simulation([RigidBody('racket', 1.0, moments, position_world=[0.0, 0.0, 1.0],
                                angular_velocity_body=omega0)], [Gravity()], 'lie_poisson2',
                     2e-3, [Constraint('pin', 'ball', 'racket', None,
                                       anchor_world=[0.0, 0.0, 1.0])])
    d0 = sim.diagnostics()
    n = int(2.2 * period / sim.dt)
    w2 = np.empty(n)
    for k in range(n):
        sim.step()
        w2[k] = sim.state.ang_vel_principal[0, 1]
    t = sim.dt * np.arange(1, n + 1)
    i = np.flatnonzero((w2[:-1] < 0.0) & (w2[1:] >= 0.0))
    crossings = t[i] + sim.dt * (-w2[i]) / (w2[i + 1] - w2[i])
    assert len(crossings) >= 2
    # bound: lie_poisson2's O(dt²) phase error, 6.4e-7 measured, x30 (O(dt) would be ~1e-3)
    np.testing.assert_allclose(np.diff(crossings), period, rtol=2e-5)
    d = sim.diagnostics()
    # bound: bounded O(dt²) energy error, ~1e-7 at most (test_long_run scaled), x100
    assert abs(d.total_energy - d0.total_energy) < 1e-5 * d0.total_energy
    l0 = np.linalg.norm(d0.angular_momentum_world)
    # bound: 15,348 steps x ~10 roundings x eps = 3.4e-11 (worst case, linear), x10
    assert abs(np.linalg.norm(d.angular_momentum_world) - l0) < 4e-10 * l0
    assert d.constraint_violation < 3e-11   # bound: 1e-13 τ / dt = 2.5e-12, x10


@pytest.mark.parametrize('name', ['symplectic_euler', 'lie_poisson2', 'rkmk4', 'lie_poisson4'])
@pytest.mark.parametrize('dt', [1e-2, 0.2])
def test_violation_decays_at_any_step_size(name, dt):
    # A ball joint added 0.1 m violated, stepped with dt below and far above the time
    # constant (0.05 s). The splittings put every step's end on Φ = exp(-dt/τ) Φ_start:
    # monotonic decay to rounding. rkmk4 has no position correction; its velocity target
    # Φ̇ = -ω Φ (ω capped at 1/(2 dt)) pulls the violation down to the level of its own
    # per-step drift: measured at most 2e-4 (dt 1e-2) and 1.1e-3 (dt 0.2) after step 30,
    # where an uncapped target made it grow without bound for dt > 3τ.
    bob = RigidBody('bob', 1.0, [0.01, 0.02, 0.025], position_world=[0.3, 0.0, -0.2])
    sim = Simulation([bob], [Gravity()], name, dt)
    sim.add_constraint(Constraint('rod', 'ball', 'bob', None, anchor_a_body=[0.1, 0.0, 0.0],
                                  anchor_b_body=[0.5, 0.0, -0.2]))
    violation = [sim.constraint_violation()['rod']]
    assert 0.09 < violation[0] < 0.11   # 0.1 m by construction
    for _ in range(100):
        sim.step()
        violation.append(sim.constraint_violation()['rod'])
    violation = np.array(violation)
    assert np.all(np.isfinite(sim.state.vel_com_world))
    if name == 'rkmk4':
        # bound: its per-step drift, 1.1e-2 Φ0 at dt 0.2 (2e-3 at 1e-2), x1.7; uncapped: grows
        assert np.max(violation[31:]) < 2e-2 * violation[0]
    else:
        big = violation > 1e-9   # 1e4 x SHAKE's 1e-13 m: the decay is far above rounding
        assert np.all(np.diff(violation[big]) < 0.0)
        # bound: exp(-100 dt / τ) = 2.1e-9 (dt 1e-2), 1e-13 m / Φ0 = 1e-12 (dt 0.2), x5
        assert violation[-1] < 1e-8 * violation[0]


def spinning_top(dt):
    m, l, i1, i3 = 0.5, 0.1, 2e-3, 3e-3
    tilt = so3.exp_quat(np.array([0.0, np.radians(20.0), 0.0]))
    axis = so3.rotate(tilt, np.array([0.0, 0.0, 1.0]))
    top = RigidBody('top', m, [i1, i1, i3], position_world=l * axis, orientation_xyzw=tilt,
                    angular_velocity_body=[0.0, 0.0, 100.0])
    return Simulation([top], [Gravity((0.0, 0.0, -G))], 'lie_poisson2', dt,
                      [Constraint('tip', 'ball', 'top', None, anchor_world=[0.0, 0.0, 0.0])])


def test_step_is_redone_finer_when_the_projection_cannot_converge():
    # 100 rad/s at dt = 3e-2 turns the top 3 rad per step, too far for SHAKE's Newton
    # iterations in some steps (they converge in 2 iterations up to about 2 rad a
    # step). With the up-front sub-steps switched off, such steps are redone with
    # twice the sub-steps instead of ending in the last-resort projection. Measured
    # over 1 s: 32 retries, no fallback, energy error 9.7e-3 of the kinetic energy
    # (the steps taken whole at 3 rad are inaccurate, not unstable), violation 6e-14;
    # without retries: 3 fallbacks and 0.68 (at dt = 4e-2 a blow-up).
    sim = spinning_top(3e-2)
    sim.integrator.max_rotation = None
    worst_de, worst_violation, max_ke = run_and_watch(sim, 1.0, every=1)
    assert sim.work()['retries'] > 20
    assert sim.dynamics.solver.counters.projection_fallbacks == 0
    assert worst_de < 2e-2 * max_ke   # bound: the 3-rad steps' truncation, 9.7e-3 measured, x2
    assert worst_violation < 1e-10   # bound: 1e-13 τ / h with h down to dt / 64: 1e-11, x10
    coarse = spinning_top(3e-2)
    coarse.integrator.max_rotation = None
    coarse.integrator.max_substeps = 1
    with np.errstate(all='ignore'):
        coarse_de, _, coarse_ke = run_and_watch(coarse, 1.0, every=1)
    assert coarse.dynamics.solver.counters.projection_fallbacks > 0
    assert coarse_de > 0.2 * coarse_ke   # measured 0.68, 70 x the retried run's error


def test_a_step_that_diverges_raises_and_keeps_the_last_finite_state():
    # The top at dt = 0.2 s (20 rad a step) with neither sub-steps nor retries
    # overflows within seconds: measured at 1.8 s, and at 1.35 to 4.4 s for every dt
    # from 0.15 to 0.4 s (at 5e-2 to 0.1 s it now stays finite: SHAKE's fallback
    # projects from the last iterate that cut the residual).
    sim = spinning_top(0.2)
    sim.integrator.max_rotation = None
    sim.integrator.max_substeps = 1
    message = r"^the step from t = .* gave a non-finite state \(bodies \['top'\]\)"
    with np.errstate(all='ignore'), pytest.raises(DivergenceError, match=message):
        sim.step(50)
    assert 0.0 < sim.time < 10.0
    pos, quat = sim.pose('top')
    assert np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))
    # The defaults (sub-steps up front, retries) take the same steps without trouble.
    ok = spinning_top(4e-2)
    ok.step(25)
    assert ok.work()['substeps'] > 0
    assert np.all(np.isfinite(ok.pose('top')[0]))


def _work(sim):
    w = dict(sim.work())
    w.update(sim.dynamics.solver.counters.as_dict())
    return w


@pytest.mark.parametrize('name', ['lie_poisson2', 'lie_poisson4'])
def test_pendulum_far_from_the_origin_moves_as_at_the_origin(name):
    # At 10 km from the origin a coordinate's ulp is 1.8e-12 m, above SHAKE's 1e-13 m
    # tolerance. The iteration used to stall there and redo steps in up to 64 sub-steps
    # (2,000 steps took 205,572 sub-steps; at 1 km 5,006): it must stop at the rounding
    # floor instead, without sub-steps, and move as the same pendulum at the origin.
    runs = {}
    for offset in (0.0, 1e3, 1e4):
        o = np.array([offset, -2.0 * offset, 0.5 * offset])
        body = rod('rod', o, np.array([1.0, 0.0, 0.0]), 1.0, 1.0)
        sim = Simulation([body], [Gravity((0, 0, -G))], name, 1e-3,
                         [Constraint('pivot', 'ball', 'rod', None, anchor_world=o)])
        e0 = sim.diagnostics().total_energy
        sim.step(2000)
        w = _work(sim)
        assert w['substeps'] == w['retries'] == w['projection_fallbacks'] == 0, (offset, w)
        # Newton converges quadratically: 1 iteration a projection at the origin, 2.1 at most far
        assert w['position_iterations'] <= 2000 * (3 if name == 'lie_poisson4' else 1) * 3
        d = sim.diagnostics()
        # The joint holds to the coordinates' rounding, and the energy (relative to the
        # pivot's height) is conserved as at the origin.
        # bound: SHAKE stops within max(1e-13 m, floor 16 sqrt(3) eps max|x| < 64 eps offset)
        # a step, kept over τ / dt = 50 steps, x10 (measured at most 1.3 eps max(1, 2.5 offset))
        stop = max(1e-13, 64 * np.finfo(float).eps * offset)
        assert d.constraint_violation < 10 * 50 * stop
        # bound: 2.6e-8 J O(dt²) (lie_poisson2) + 2000 steps x m g x ulp(2e4 m) = 7e-8 J, x10
        assert abs(d.total_energy - e0) < 1e-6   # J
        pos, _ = sim.pose('rod')
        runs[offset] = pos - o
    for offset in (1e3, 1e4):
        # The same motion: apart by the rounding of the far coordinates as it accumulates
        # over 2,000 steps of a pendulum swinging from horizontal (measured 4.5e-11 m at
        # 10 km, 3.2e-12 m at 1 km).
        # bound: 2000 steps x eps x |o| (2.3 offset) = 1e-12 offset (worst case, linear), x10
        assert np.max(np.abs(runs[offset] - runs[0.0])) < 1e-11 * offset


def test_ring_of_1000_rods_steps_without_stalling():
    # 5,003 rows, 16 m across: SHAKE's residuals bottom out at 15 to 60 ulps of the
    # coordinates. It used to take them for a stalled iteration and redo steps in up
    # to 64 sub-steps (from the seventh step on).
    from rigid_body_sim.core.mechanisms import ring
    sim = ring(1000, 'lie_poisson2')
    sim.step(25)
    w = _work(sim)
    assert w['retries'] == w['substeps'] == 0, w
    assert w['position_iterations'] <= 3 * 25
    # bound: SHAKE's floor 16 sqrt(5003) eps x 16 m = 4e-12 a step, 25 steps: 1e-10, x10
    assert sim.diagnostics().constraint_violation < 1e-9   # measured 8e-13
