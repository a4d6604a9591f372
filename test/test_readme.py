"""The README's and docs pages' Python examples run as written, and their commands are real."""

from pathlib import Path
import re

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / 'README.md').read_text()
#: The Markdown pages besides the README (the generated ones included: they link too).
DOCS = sorted((ROOT / 'docs').glob('*.md'))
PAGES = [ROOT / 'README.md', *DOCS]


def _python_blocks(text: str) -> list:
    return re.findall(r'```python\n(.*?)```', text, flags=re.S)


def test_python_example_runs():
    blocks = _python_blocks(README)
    assert blocks, 'the README has a Python example'
    for block in blocks:
        exec(compile(block, 'README.md', 'exec'), {})


@pytest.mark.parametrize('page', DOCS, ids=lambda p: p.name)
def test_docs_python_examples_run(page):
    for block in _python_blocks(page.read_text()):
        exec(compile(block, str(page.relative_to(ROOT)), 'exec'), {})


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / '.ci' / 'run').read_text()
    assert './dev.sh test' in README
    assert 'exec ./dev.sh test' in ci


def _examples(text: str) -> list:
    """Return a page's `ros2 topic pub` and `ros2 service call` lines."""
    pattern = r'^ros2 (topic pub --once|service call) (\S+) (\S+) "(.*)"$'
    return re.findall(pattern, text, flags=re.M)


def _fill(msg, values: dict, path: str = ''):
    """Set ``values`` on ``msg`` as ros2cli does; fail on a field the type lacks."""
    fields = msg.get_fields_and_field_types()
    for key, value in values.items():
        assert key in fields, f'{path}{key}: no such field in {type(msg).__name__}'
        if isinstance(value, dict):
            _fill(getattr(msg, key), value, f'{path}{key}.')
        else:
            setattr(msg, key, value)


def _check_examples(examples: list) -> set:
    """Fill each example's real message or request type; return the (kind, name) pairs."""
    import importlib
    import yaml
    kinds = set()
    for kind, name, type_name, text in examples:
        package, sub, cls = type_name.split('/')
        module = importlib.import_module(f'{package}.{sub}')
        msg_type = getattr(module, cls)
        msg = msg_type() if sub == 'msg' else msg_type.Request()
        _fill(msg, yaml.safe_load(text) or {})
        kinds.add((kind, name.rsplit('/', 1)[-1]))
    return kinds


def test_ros2_examples_fill_the_real_message_types():
    pytest.importorskip('rclpy')
    examples = _examples(README)
    assert len(examples) >= 8
    kinds = _check_examples(examples)
    for service in ('reset', 'pause', 'step', 'add_constraint', 'remove_constraint'):
        assert ('service call', service) in kinds, f'no example for ~/{service}'


def test_docs_ros2_examples_fill_the_real_message_types():
    examples = [e for page in DOCS for e in _examples(page.read_text())]
    if not examples:
        pytest.skip('no docs page has a ros2 topic pub / service call example')
    pytest.importorskip('rclpy')
    _check_examples(examples)


def _anchors(text: str) -> set:
    """Return the anchors GitHub gives a page's headings (outside code blocks)."""
    text = re.sub(r'```.*?```', '', text, flags=re.S)
    return {re.sub(r'[^\w\- ]', '', h.strip().lower()).replace(' ', '-')
            for h in re.findall(r'^#{1,6} (.*)$', text, flags=re.M)}


@pytest.mark.parametrize('page', PAGES, ids=lambda p: p.name)
def test_relative_links_resolve(page):
    text = re.sub(r'```.*?```', '', page.read_text(), flags=re.S)
    for target in re.findall(r'\]\(([^)\s]+)\)', text):
        if re.match(r'[a-z]+:', target):
            continue   # (an external address)
        path, _, anchor = target.partition('#')
        linked = (page.parent / path).resolve() if path else page
        assert linked.exists(), f'{page.name}: link to {target}: no such file'
        if anchor and linked.suffix == '.md':
            assert anchor in _anchors(linked.read_text()), \
                f'{page.name}: link to {target}: no such heading in {linked.name}'
