"""The README's Python example runs as written, and its commands are the real ones."""

from pathlib import Path
import re

import pytest

README = (Path(__file__).resolve().parents[1] / 'README.md').read_text()


def test_python_example_runs():
    blocks = re.findall(r'```python\n(.*?)```', README, flags=re.S)
    assert blocks, 'the README has a Python example'
    for block in blocks:
        exec(compile(block, 'README.md', 'exec'), {})


def test_ci_runs_the_readme_test_command():
    ci = (Path(__file__).resolve().parents[1] / '.ci' / 'run').read_text()
    assert './dev.sh test' in README
    assert 'exec ./dev.sh test' in ci


def _examples():
    """Return the README's `ros2 topic pub` and `ros2 service call` lines."""
    pattern = r'^ros2 (topic pub --once|service call) (\S+) (\S+) "(.*)"$'
    return re.findall(pattern, README, flags=re.M)


def _fill(msg, values: dict, path: str = ''):
    """Set ``values`` on ``msg`` as ros2cli does; fail on a field the type lacks."""
    fields = msg.get_fields_and_field_types()
    for key, value in values.items():
        assert key in fields, f'{path}{key}: no such field in {type(msg).__name__}'
        if isinstance(value, dict):
            _fill(getattr(msg, key), value, f'{path}{key}.')
        else:
            setattr(msg, key, value)


def test_ros2_examples_fill_the_real_message_types():
    import importlib
    import yaml
    pytest.importorskip('rclpy')
    examples = _examples()
    assert len(examples) >= 8
    kinds = set()
    for kind, name, type_name, text in examples:
        package, sub, cls = type_name.split('/')
        module = importlib.import_module(f'{package}.{sub}')
        msg_type = getattr(module, cls)
        msg = msg_type() if sub == 'msg' else msg_type.Request()
        _fill(msg, yaml.safe_load(text) or {})
        kinds.add((kind, name.rsplit('/', 1)[-1]))
    for service in ('reset', 'pause', 'step', 'add_constraint', 'remove_constraint'):
        assert ('service call', service) in kinds, f'no example for ~/{service}'
