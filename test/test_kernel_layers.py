"""The kernel package imports nothing above it, and the kernel cache covers all of it."""

import ast
from pathlib import Path

import pytest

from rigid_body_sim.core import kernel_cache

KERNELS = Path(__file__).resolve().parents[1] / 'rigid_body_sim' / 'core' / 'kernels'
# What a kernel module may import: the compiler, arrays, and the standard library's
# arithmetic and bookkeeping (no scipy: the kernels are the whole solve).
ALLOWED = {'__future__', 'enum', 'math', 'numba', 'numpy', 'typing', 'weakref'}


def _modules():
    return sorted(KERNELS.glob('*.py'))


def violations(source: str, siblings: set) -> list:
    """Return the imports of a kernel module's ``source`` that reach outside the package."""
    bad = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            bad += [a.name for a in node.names if a.name.split('.')[0] not in ALLOWED]
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ''
            if node.level == 0 and module.split('.')[0] not in ALLOWED:
                bad.append(module)
            elif node.level > 1 or (node.level == 1 and module
                                    and module.split('.')[0] not in siblings):
                bad.append('.' * node.level + module)
    return bad


@pytest.mark.parametrize('path', _modules(), ids=lambda p: p.stem)
def test_a_kernel_module_imports_only_its_siblings_and_the_allowed_libraries(path):
    siblings = {p.stem for p in _modules()}
    assert violations(path.read_text(), siblings) == []


def test_the_check_refuses_imports_from_above():
    siblings = {'rows', 'views'}
    source = ('from __future__ import annotations\nimport numpy as np\nfrom . import rows\n'
              'from .views import raw\nfrom ..solver import ConstraintSolver\n'
              'from .integrators import Integrator\nimport scipy.linalg\n'
              'from rigid_body_sim.core import bodies\n')
    assert violations(source, siblings) == [
        '..solver', '.integrators', 'scipy.linalg', 'rigid_body_sim.core']


def test_the_kernel_cache_hashes_every_module_of_the_package():
    names = kernel_cache.kernel_modules()
    assert names == sorted(p.stem for p in _modules())
    assert {'free_step', 'constrained_step', 'rows', 'tree_solve', 'loop_solve'} <= set(names)
