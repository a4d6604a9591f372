"""The README's Python example runs as written, and its commands are the real ones."""

from pathlib import Path
import re

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
