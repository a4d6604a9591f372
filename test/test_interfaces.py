"""The interface package rigid_body_sim_interfaces is built, and its messages round-trip."""

import array

import numpy as np
import pytest

serialization = pytest.importorskip('rclpy.serialization',
                                    reason='rclpy not installed: run ./dev.sh test')


def test_services_and_message_import():
    from rigid_body_sim_interfaces.msg import BodyStates
    from rigid_body_sim_interfaces.srv import AddConstraint, RemoveConstraint, Step
    for service in (AddConstraint, RemoveConstraint, Step):
        assert service.Request() is not None
        assert service.Response().success is False
    assert list(BodyStates().names) == []


def _bits(values) -> np.ndarray:
    return np.asarray(values, dtype=np.float64).view(np.uint64)


def test_body_states_from_numpy_round_trips_bit_for_bit():
    from rigid_body_sim_interfaces.msg import BodyStates
    rng = np.random.default_rng(20261126)
    fields = {
        'position': rng.normal(size=6),
        'orientation': rng.normal(size=8),
        'linear_velocity': np.array([0.1, -0.0, 5e-324, 1e308, -1.0 / 3.0, np.pi]),
        'angular_velocity': rng.normal(size=6) * 1e-12,
    }
    msg = BodyStates()
    msg.header.stamp.sec = 12
    msg.header.stamp.nanosec = 345_000_000
    msg.header.frame_id = 'world'
    msg.names = ['box', 'rod']
    for name, values in fields.items():
        setattr(msg, name, values)  # a numpy float64 array assigned as is

    data = serialization.serialize_message(msg)
    assert isinstance(data, bytes)
    back = serialization.deserialize_message(data, BodyStates)

    assert back == msg
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (12, 345_000_000)
    assert back.header.frame_id == 'world'
    assert list(back.names) == ['box', 'rod']
    for name, values in fields.items():
        got = getattr(back, name)
        assert isinstance(got, array.array) and got.typecode == 'd'
        np.testing.assert_array_equal(_bits(got), _bits(values), err_msg=name)


def test_add_constraint_request_fields_and_defaults():
    from rigid_body_sim_interfaces.srv import AddConstraint
    request = AddConstraint.Request()
    assert list(request.get_fields_and_field_types()) == [
        'name', 'type', 'body_a', 'body_b', 'anchor_world', 'anchor_a_body', 'anchor_b_body',
        'axis_world', 'length']
    for name in ('name', 'type', 'body_a', 'body_b'):
        assert getattr(request, name) == ''
    for name in ('anchor_world', 'anchor_a_body', 'anchor_b_body', 'axis_world'):
        assert len(getattr(request, name)) == 0, name
    assert request.length == 0.0
    response = AddConstraint.Response()
    assert (response.success, response.message, response.rows_added) == (False, '', 0)
