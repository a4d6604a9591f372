"""The checks of joint commands (``~/joint_commands``, ``<group>/commands``), without DDS."""

import math

import numpy as np
import pytest
from rigid_body_sim.ros.inputs import check_group_command, check_joint_command, Rejected, \
    Rejection

NAN, INF = math.nan, math.inf
#: A position joint, a velocity joint and an effort joint (as Simulation.joint_interfaces()).
INTERFACES = {'p': 'position', 'v': 'velocity', 'e': 'effort'}
LIMITS = {'p': 100.0, 'v': 100.0, 'e': 100.0}
EMPTY = np.zeros(0)


def _command(name, position=(), velocity=(), effort=()):
    return check_joint_command(name, np.array(position, dtype=float),
                               np.array(velocity, dtype=float),
                               np.array(effort, dtype=float), INTERFACES, LIMITS)


def test_each_joint_takes_the_entry_of_its_own_interface():
    got = _command(['e', 'p', 'v'], position=[NAN, 0.5, NAN], velocity=[NAN, NAN, -2.0],
                   effort=[3.0, NAN, NAN])
    assert got == {'e': 3.0, 'p': 0.5, 'v': -2.0}
    assert list(got) == ['e', 'p', 'v']   # (the message's order)


def test_the_arrays_of_other_interfaces_may_be_empty():
    assert _command(['p'], position=[0.25]) == {'p': 0.25}
    assert _command(['v'], velocity=[1.0]) == {'v': 1.0}
    assert _command(['e'], effort=[-1.0]) == {'e': -1.0}
    assert _command(['p', 'e'], position=[0.1, NAN], effort=[NAN, 2.0]) == {'p': 0.1, 'e': 2.0}


def test_limits_bound_efforts_only():
    assert _command(['p'], position=[1e6]) == {'p': 1e6}
    assert _command(['e'], effort=[-100.0]) == {'e': -100.0}


@pytest.mark.parametrize('kwargs, cause, message', [
    ({'name': []}, Rejection.BAD_JOINT_COMMAND, r'^name: empty'),
    ({'name': ['p', 'p'], 'position': [0.1, 0.2]}, Rejection.BAD_JOINT_COMMAND,
     r"^name\[1\]: joint 'p' is named twice"),
    ({'name': ['x'], 'effort': [1.0]}, Rejection.UNKNOWN_JOINT,
     r"^name\[0\]: unknown joint 'x'; joints: \['p', 'v', 'e'\]"),
    ({'name': ['e'], 'position': [0.5]}, Rejection.WRONG_INTERFACE,
     r"^position\[0\] \(e\): 0.5 given, but joint 'e' has the effort interface"),
    ({'name': ['e', 'p'], 'position': [NAN, 0.5], 'effort': [1.0, 2.0]},
     Rejection.WRONG_INTERFACE, r"^effort\[1\] \(p\): 2.0 given, but joint 'p' has the "
                                r'position interface: give its value in position\[1\]'),
    ({'name': ['v'], 'position': [INF], 'velocity': [1.0]}, Rejection.WRONG_INTERFACE,
     r"^position\[0\] \(v\): inf given, but joint 'v' has the velocity interface"),
    ({'name': ['p'], 'effort': [NAN]}, Rejection.JOINT_COMMAND_LENGTHS,
     r'^position: empty, but name\[0\] \(p\) has the position interface'),
    ({'name': ['e']}, Rejection.JOINT_COMMAND_LENGTHS,
     r'^effort: empty, but name\[0\] \(e\) has the effort interface'),
    ({'name': ['p', 'e'], 'position': [0.1]}, Rejection.JOINT_COMMAND_LENGTHS,
     r'^position: 1 values for 2 names'),
    ({'name': ['e'], 'effort': [1.0], 'velocity': [NAN, NAN]},
     Rejection.JOINT_COMMAND_LENGTHS, r'^velocity: 2 values for 1 names'),
    ({'name': ['p'], 'position': [NAN]}, Rejection.NON_FINITE_TARGET,
     r'^position\[0\] \(p\): must be finite, got nan'),
    ({'name': ['e', 'v'], 'velocity': [NAN, -INF], 'effort': [1.0, NAN]},
     Rejection.NON_FINITE_TARGET, r'^velocity\[1\] \(v\): must be finite, got -inf'),
    ({'name': ['e'], 'effort': [INF]}, Rejection.NON_FINITE_EFFORT,
     r'^effort\[0\] \(e\): must be finite, got inf'),
    ({'name': ['p', 'e'], 'position': [0.0, NAN], 'effort': [NAN, 101.0]},
     Rejection.EFFORT_TOO_LARGE, r'^effort\[1\] \(e\): magnitude 101 exceeds 100'),
])
def test_a_bad_command_is_rejected_naming_field_index_and_problem(kwargs, cause, message):
    with pytest.raises(Rejected, match=message) as info:
        _command(**kwargs)
    assert info.value.cause is cause


def test_the_lengths_are_checked_before_the_names():
    with pytest.raises(Rejected) as info:
        _command(['x', 'x'], effort=[1.0])
    assert info.value.cause is Rejection.JOINT_COMMAND_LENGTHS


GROUP = ('arm', ('b', 'a'), 'position')


def _group(data, interface='position', limits=None):
    name, joints, _ = GROUP
    return check_group_command(name, joints, interface, np.array(data, dtype=float),
                               limits or {'a': 10.0, 'b': 10.0})


def test_a_group_command_is_in_the_groups_joint_order():
    got = _group([0.5, -0.25])
    assert got == {'b': 0.5, 'a': -0.25} and list(got) == ['b', 'a']


def test_nan_in_a_group_command_keeps_that_joints_command():
    assert _group([NAN, 0.3]) == {'a': 0.3}
    assert _group([NAN, NAN]) == {}


@pytest.mark.parametrize('data, interface, cause, message', [
    ([0.1], 'position', Rejection.GROUP_COMMAND_SIZE,
     r"^data: 1 values for the 2 joints of group 'arm' \['b', 'a'\] \(position\)"),
    ([], 'velocity', Rejection.GROUP_COMMAND_SIZE, r'^data: 0 values for the 2 joints'),
    ([0.1, 0.2, 0.3], 'effort', Rejection.GROUP_COMMAND_SIZE, r'^data: 3 values'),
    ([0.1, INF], 'position', Rejection.NON_FINITE_TARGET,
     r'^data\[1\] \(a\): must be finite, got inf'),
    ([-INF, NAN], 'velocity', Rejection.NON_FINITE_TARGET, r'^data\[0\] \(b\)'),
    ([INF, 1.0], 'effort', Rejection.NON_FINITE_EFFORT, r'^data\[0\] \(b\)'),
    ([1.0, -10.5], 'effort', Rejection.EFFORT_TOO_LARGE,
     r'^data\[1\] \(a\): magnitude 10.5 exceeds 10'),
])
def test_a_bad_group_command_is_rejected(data, interface, cause, message):
    with pytest.raises(Rejected, match=message) as info:
        _group(data, interface)
    assert info.value.cause is cause


def test_limits_do_not_bound_group_targets():
    assert _group([1e3, -1e3], 'velocity') == {'b': 1e3, 'a': -1e3}
