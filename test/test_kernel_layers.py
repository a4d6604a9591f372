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


def test_slot_indices_are_generated_from_the_one_declaration():
    from rigid_body_sim.core.kernels import layout
    assert layout.COMPONENT.fields[layout.PHI].name == 'phi'
    assert layout.COMPONENT.fields[layout.TREE0 + layout.TREE_SLOTS + layout.T_XC].name == (
        'symmetric_tree_xc')
    assert layout.TREE0 + layout.TREE_SLOTS * 2 == layout.NULLSPACE0
    assert layout.COMPONENT.fields[layout.NULLSPACE0 + layout.NS_SHAKE_JQ].name == (
        'nullspace_shake_jq')
    assert layout.NULLSPACE0 + len(layout.NULLSPACE) == len(layout.COMPONENT)
    assert layout.COMPONENT.fields[layout.DENSE0 + layout.DENSE_SLOTS + layout.D_VT].name == (
        'symmetric_dense_vt')
    assert layout.BODY.width == layout.B_WIDTH == 8
    assert layout.N_COUNTS == len(layout.Count)


def _component(m=3, n=2):
    from rigid_body_sim.core.kernels import constrained_step as ck
    from rigid_body_sim.core.graph import tree_structure
    import numpy as np
    a, b = np.zeros(m, dtype=np.int64), np.full(m, n, dtype=np.int64)
    st = tree_structure(a[:0], b[:0], n)
    rows = {'kind': a.copy(), 'comp': a.copy(), 'row_a': a, 'row_b': b,
            'row_par': np.zeros((m, 13)), 'row_owner': np.arange(m), 'x_kind': a[:0],
            'x_comp': a[:0], 'x_par': np.zeros((0, 13)), 'x_weight': np.zeros(0), 'key': -1}
    body = np.ones((n, 8))
    trees = tuple(ck.tree_storage(st, np.zeros(0, dtype=np.int64), m, n) for _ in range(2))
    trees = (trees, ck.nullspace_storage(None, n))
    return ck, rows, ck.workspace(n, m, body), (ck.dense_storage(m), ck.dense_storage(m)), trees


def test_pack_takes_arrays_by_name_and_returns_named_views():
    ck, rows, ws, dense, trees = _component()
    packed, views = ck.pack(rows, ws, dense, *trees)
    assert packed[0] == -1
    views['phi'][1, 2] = 7.0
    from rigid_body_sim.core.kernels.layout import L_OFFSET, PHI
    start = packed[3][PHI, L_OFFSET]
    assert packed[1][start + 1 * 3 + 2] == 7.0   # phi (3, m) row-major in the float buffer


def test_pack_refuses_a_missing_or_misshapen_array_naming_it():
    ck, rows, ws, dense, trees = _component()
    del ws['vm']
    with pytest.raises(ValueError, match=r"missing \['vm'\]"):
        ck.pack(rows, ws, dense, *trees)
    ck, rows, ws, dense, trees = _component()
    ws['minv'] = ws['minv'].ravel()
    with pytest.raises(ValueError, match=r'component\.minv: expected 2 dimensions'):
        ck.pack(rows, ws, dense, *trees)
    ck, rows, ws, dense, trees = _component()
    ws['watch'] = ws['watch'].astype(float)
    with pytest.raises(ValueError, match=r'component\.watch: expected int64'):
        ck.pack(rows, ws, dense, *trees)


def test_a_layout_refuses_a_name_declared_twice_and_a_table_an_unknown_slot():
    import numpy as np
    from rigid_body_sim.core.kernels import layout
    with pytest.raises(ValueError, match=r"declared twice: \['phi'\]"):
        layout.Layout('x', (('phi', 'f', 1), ('phi', 'f', 2)))
    with pytest.raises(ValueError, match=r"unknown slots \['bodies'\], missing \['body'\]"):
        layout.FREE_TABLE.pin(bodies=np.zeros(1), gforce=0, wrench=0, kick=0, counts=0, ws=0,
                              frames=0, out=0, n_wrench=0, flags=0, method=0, n_counts=0,
                              n_ws=0)
    with pytest.raises(ValueError, match=r"unknown columns \['dt'\]"):
        layout.PAR.row(dt=1.0)
    with pytest.raises(ValueError, match=r"column 'a' declared twice"):
        layout.Columns('x', [('a', 1), ('a', 3)])
    arrays = {n: np.zeros(1) for n in layout.FREE_TABLE.arrays}
    values = dict.fromkeys(layout.FREE_TABLE.values, 0)
    with pytest.raises(ValueError, match=r'free-step table\.counts: expected int64'):
        layout.FREE_TABLE.pin(**arrays, **values)
    arrays['counts'] = np.zeros(1, dtype=np.int64)
    assert len(layout.FREE_TABLE.pin(**arrays, **values).table) == len(arrays) + len(values)
