"""
The standard interface packages the node needs beyond the wheels' (vendor/) are the standard.

``vendor/tf2_msgs`` stands in for ``tf2_msgs`` where the environment has none (the PyPI
wheels); dev.sh builds it only then. These tests hold for whichever ``tf2_msgs`` the
environment has: the message must be the standard one, field for field and by type hash,
or RViz and tf2 would not match our /tf publishers. ``vendor/simulation_interfaces`` stands
in for the ROS simulator interface (release 1.0.0, as Jazzy carries it) alike: every one of
its types must have the standard's type hash, or clients of the standard would not match
our services.
"""

import json
from pathlib import Path
import subprocess

import pytest

serialization = pytest.importorskip('rclpy.serialization',
                                    reason='rclpy not installed: run ./dev.sh test')
packages = pytest.importorskip('ament_index_python.packages')

#: The RIHS01 type hash of ROS 2 Jazzy's tf2_msgs/msg/TFMessage, as Jazzy systems advertise
#: it (``ros2 topic info -v /tf``, ``type_description_hash`` in rosbag2 metadata; several
#: independent public sources agree). Our vendored build computes the same.
JAZZY_TF_MESSAGE_HASH = \
    'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087'


def _tf_message():
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        pytest.fail('tf2_msgs is not importable: ./dev.sh setup builds vendor/tf2_msgs '
                    'where the environment has none')
    return TFMessage


def test_tf_message_has_exactly_the_standard_field():
    TFMessage = _tf_message()
    assert TFMessage.get_fields_and_field_types() == {
        'transforms': 'sequence<geometry_msgs/TransformStamped>'}
    assert list(TFMessage().transforms) == []


def _transform(parent: str, child: str, sec: int, xyz, xyzw):
    from geometry_msgs.msg import TransformStamped
    t = TransformStamped()
    t.header.stamp.sec, t.header.stamp.nanosec = sec, 250_000_000
    t.header.frame_id = parent
    t.child_frame_id = child
    t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = xyz
    r = t.transform.rotation
    r.x, r.y, r.z, r.w = xyzw
    return t


def test_tf_message_round_trips_through_serialization():
    TFMessage = _tf_message()
    msg = TFMessage(transforms=[
        _transform('world', 'base_link', 7, (0.5, -1.25, 1e-300), (0.0, 0.0, 0.0, 1.0)),
        _transform('base_link', 'link1', 7, (0.0, 0.0, 0.333), (0.5, -0.5, 0.5, 0.5)),
    ])
    data = serialization.serialize_message(msg)
    back = serialization.deserialize_message(data, TFMessage)
    assert back == msg
    assert [(t.header.frame_id, t.child_frame_id) for t in back.transforms] == [
        ('world', 'base_link'), ('base_link', 'link1')]
    assert back.transforms[0].transform.translation.z == 1e-300
    assert back.transforms[1].header.stamp.nanosec == 250_000_000
    assert serialization.deserialize_message(
        serialization.serialize_message(TFMessage()), TFMessage) == TFMessage()


def test_tf_message_type_hash_is_jazzys():
    # The hash generated at build time ...
    share = Path(packages.get_package_share_directory('tf2_msgs'))
    description = json.loads((share / 'msg' / 'TFMessage.json').read_text())
    hashes = {h['type_name']: h['hash_string'] for h in description['type_hashes']}
    assert hashes['tf2_msgs/msg/TFMessage'] == JAZZY_TF_MESSAGE_HASH
    # ... is the one the middleware advertises for a publisher (what other nodes match on).
    import rclpy
    from ros_harness import random_domain
    TFMessage = _tf_message()
    context = rclpy.context.Context()
    rclpy.init(context=context, domain_id=random_domain())
    try:
        node = rclpy.create_node('tf_hash_probe', context=context, enable_rosout=False,
                                 start_parameter_services=False)
        node.create_publisher(TFMessage, 'tf_hash_probe', 1)
        infos = node.get_publishers_info_by_topic('tf_hash_probe')
        assert [(i.topic_type, str(i.topic_type_hash)) for i in infos] == [
            ('tf2_msgs/msg/TFMessage', JAZZY_TF_MESSAGE_HASH)]
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_the_node_executable_sees_tf2_msgs():
    # The environment the tests (and ./dev.sh run) start sim_node in, and its interpreter.
    try:
        prefix = Path(packages.get_package_prefix('rigid_body_sim'))
    except packages.PackageNotFoundError:
        pytest.skip('rigid_body_sim is not built: run ./dev.sh test (colcon build)')
    script = prefix / 'lib' / 'rigid_body_sim' / 'sim_node'
    interpreter = script.read_text().splitlines()[0].removeprefix('#!').split()
    code = 'from tf2_msgs.msg import TFMessage; print(TFMessage.__module__)'
    done = subprocess.run([*interpreter, '-c', code], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == 'tf2_msgs.msg._tf_message'


#: The standard's own type hashes: test/data/simulation_interfaces_1.0.0_hashes.json (how
#: they were obtained is written in it: the upstream 1.0.0 package's build).
SIMULATION_HASHES = json.loads(
    (Path(__file__).parent / 'data' / 'simulation_interfaces_1.0.0_hashes.json').read_text()
)['hashes']


def test_simulation_interfaces_are_release_1_0_0_by_every_type_hash():
    # Every message, service (request, response, event) and action type (goal, result,
    # feedback and the action's own services and messages) of the package the environment
    # has, vendored or not, against the standard release's: 92 types.
    try:
        share = Path(packages.get_package_share_directory('simulation_interfaces'))
    except packages.PackageNotFoundError:
        pytest.fail('simulation_interfaces is not installed: ./dev.sh setup builds '
                    'vendor/simulation_interfaces where the environment has none')
    found = {}
    for description in sorted(share.glob('*/*.json')):
        for entry in json.loads(description.read_text())['type_hashes']:
            if entry['type_name'].startswith('simulation_interfaces/'):
                found[entry['type_name']] = entry['hash_string']
    assert len(SIMULATION_HASHES) == 92
    assert found == SIMULATION_HASHES


def test_simulation_interfaces_fields_are_the_standards():
    from simulation_interfaces.msg import EntityState, Result, SimulatorFeatures
    from simulation_interfaces.srv import SpawnEntity, StepSimulation
    assert Result.get_fields_and_field_types() == {'result': 'uint8', 'error_message': 'string'}
    assert (Result.RESULT_OK, Result.RESULT_NOT_FOUND, Result.RESULT_INCORRECT_STATE) == (1, 2, 3)
    assert EntityState.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'pose': 'geometry_msgs/Pose',
        'twist': 'geometry_msgs/Twist', 'acceleration': 'geometry_msgs/Accel'}
    assert SimulatorFeatures.STEP_SIMULATION_ACTION == 33
    assert StepSimulation.Request().steps == 1   # (the standard's default)
    assert SpawnEntity.Response.INVALID_POSE == 109
