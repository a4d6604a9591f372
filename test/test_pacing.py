"""The node's wall-clock pacing and output grid (pure Python: no ROS needed)."""

import pytest
from rigid_body_sim.ros.pacing import MAX_LAG, output_due, Pacer, WindowStats


def test_steps_fall_due_on_the_real_time_schedule():
    pacer = Pacer(dt=1e-3, real_time_factor=0.5)   # 2 ms of wall time a step
    pacer.restart(10.0)
    assert pacer.due(10.0)
    pacer.stepped()
    # (Due at 10.0 + 0.002, equal to 10.002 only to rounding: checked 1 ns either side.)
    assert not pacer.due(10.0019)
    assert not pacer.due(10.002 - 1e-9)
    assert pacer.due(10.002 + 1e-9)
    # bound: one product and one sum of <= 10 s: 2 x eps/2 x 10 s = 2e-15 s; x10
    assert pacer.next_due() == pytest.approx(10.002, rel=0, abs=2e-14)


def test_a_backlog_is_caught_up_within_the_bound_then_dropped():
    pacer = Pacer(dt=1e-3, real_time_factor=1.0)
    pacer.restart(0.0)
    # 50.5 ms late (between the steps due at 50 and 51 ms, not on one to rounding): every
    # due step runs back to back, none dropped.
    now = 0.0505
    taken = 0
    while pacer.due(now):
        pacer.stepped()
        taken += 1
    assert taken == 51 and pacer.lag_resets == 0
    # More than MAX_LAG late: the backlog is dropped, counted, and the schedule restarts.
    now += MAX_LAG + 0.05
    assert pacer.due(now)
    assert pacer.lag_resets == 1
    # bound: ~4 roundings of <= 0.2 s: 4 x eps/2 x 0.2 s = 9e-17 s; x100 (a step off: 1e-3)
    assert pacer.dropped_wall == pytest.approx(MAX_LAG + 0.05 - 0.5e-3, abs=1e-14)
    pacer.stepped()
    assert not pacer.due(now)


def test_as_fast_as_possible_is_always_due():
    pacer = Pacer(dt=1e-3, real_time_factor=0.0)
    pacer.restart(0.0)
    assert pacer.period == 0.0 and pacer.due(-1.0)


def test_outputs_fall_on_whole_multiples_of_their_period():
    dt = 1e-3
    due = [k for k in range(1, 51) if output_due((k - 1) * dt, k * dt, 100.0)]
    assert due == [10, 20, 30, 40, 50]
    assert all(output_due((k - 1) * dt, k * dt, 1000.0) for k in range(1, 100))
    assert all(output_due((k - 1) * dt, k * dt, 5000.0) for k in range(1, 100))
    # After a change of dt the grid stays on simulated time.
    t = 0.013
    due = []
    for _ in range(20):
        if output_due(t, t + 2.5e-3, 100.0):
            due.append(round(t + 2.5e-3, 6))
        t += 2.5e-3
    assert due == [0.0205, 0.0305, 0.0405, 0.0505, 0.0605]


def test_window_counts_overruns_against_the_budget():
    w = WindowStats()
    for cost in (0.5e-3, 1.5e-3, 0.9e-3, 2e-3):
        w.record_step(cost, budget=1e-3)
    assert (w.steps, w.overruns, w.step_cost_max) == (4, 2, 2e-3)
    w.record_step(5.0, budget=0.0)   # as fast as possible: no budget, no overrun
    assert w.overruns == 2
