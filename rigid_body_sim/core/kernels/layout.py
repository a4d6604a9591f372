"""
Every buffer layout the kernels share with Python, declared once.

The kernels read their data from flat arrays: a component's ~75 arrays packed
into one float64 and one int64 buffer, tables of array addresses, and model
arrays whose columns mean different things. Each layout is declared here once,
as names (and, for packed arrays, dtype and dimensions), and everything that
depends on the order is generated from the declaration at import:

* the slot and column indices, as module integers (``PHI``, ``P_OMEGA``,
  ``B_INV_MASS``, ...) imported by the kernels by name; numba reads module
  integers as compile-time constants, so a named index costs nothing at run
  time, and a misspelt one fails at import;
* the checks of :meth:`Layout.check` and :meth:`Table.pin`, which take arrays
  by name and refuse a missing, extra or mis-shaped one naming it.

The codes Python and the kernels exchange are :class:`enum.IntEnum`:
:class:`Count` (the work tally's slots), :class:`Solve` (how a component's
systems are solved); the method codes are :class:`.methods.Method`.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from .views import Pinned


class Field(NamedTuple):
    """One array of a packed layout: its name, ``'f'`` (float64) or ``'i'`` (int64), ndim."""

    name: str
    kind: str
    ndim: int


class Layout:
    """
    Named arrays packed one after another into a float64 and an int64 buffer.

    Parameters
    ----------
    name : str
        What the layout is of (error messages).
    fields : sequence of (name, kind, ndim)
        In packing order; names unique.

    """

    def __init__(self, name: str, fields: Sequence[tuple]) -> None:
        self.name = name
        self.fields = tuple(Field(*f) for f in fields)
        names = [f.name for f in self.fields]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f'{name}: fields declared twice: {twice}')
        for f in self.fields:
            if f.kind not in ('f', 'i') or not 1 <= f.ndim <= 4:
                raise ValueError(f'{name}.{f.name}: kind must be f or i and ndim 1 to 4')
        self.index = {f.name: k for k, f in enumerate(self.fields)}

    def __len__(self) -> int:
        return len(self.fields)

    def constants(self, prefix: str = '') -> dict:
        """``{PREFIX + NAME: slot}`` for every field (upper-case names)."""
        return {prefix + f.name.upper(): k for k, f in enumerate(self.fields)}

    def check(self, arrays: Mapping[str, np.ndarray]) -> list:
        """
        Return ``arrays`` in layout order, after checking names, dtypes and dimensions.

        Raises ValueError naming the first missing, unknown or mis-shaped array.
        Boolean arrays are accepted for int64 fields (as 0 and 1).
        """
        unknown = sorted(set(arrays) - set(self.index))
        missing = [f.name for f in self.fields if f.name not in arrays]
        if unknown or missing:
            raise ValueError(f'{self.name}: unknown arrays {unknown}, missing {missing}')
        out = []
        for f in self.fields:
            a = np.asarray(arrays[f.name])
            if a.ndim != f.ndim:
                raise ValueError(f'{self.name}.{f.name}: expected {f.ndim} dimensions, '
                                 f'got shape {a.shape}')
            kinds = ('f',) if f.kind == 'f' else ('i', 'b')
            if a.dtype.kind not in kinds:
                raise ValueError(f'{self.name}.{f.name}: expected '
                                 f'{"float64" if f.kind == "f" else "int64"}, got {a.dtype}')
            out.append(a)
        return out


class Table:
    """
    The slots of an address table (:class:`.views.Pinned`): arrays, then integers.

    Parameters
    ----------
    name : str
        What the table is for (error messages).
    arrays : sequence of str
        The arrays whose addresses come first, in order (float64 unless listed in
        ``int_arrays``).
    values : sequence of str
        The integers after them, in order.
    int_arrays : sequence of str
        The arrays that are int64 (the kernel reads them with ``pinned_int``).

    """

    def __init__(self, name: str, arrays: Sequence[str], values: Sequence[str],
                 int_arrays: Sequence[str] = ()) -> None:
        self.name = name
        self.arrays, self.values = tuple(arrays), tuple(values)
        self.int_arrays = frozenset(int_arrays)
        names = self.arrays + self.values
        if len(set(names)) != len(names) or 'key' in names:
            raise ValueError(f'{name}: a slot is declared twice (or named key)')
        if not self.int_arrays <= set(self.arrays):
            raise ValueError(f'{name}: int_arrays must be among the arrays')

    def constants(self, prefix: str) -> dict:
        """``{PREFIX + NAME: slot}`` for every array and value."""
        return {prefix + n.upper(): k for k, n in enumerate(self.arrays + self.values)}

    def pin(self, key: object = None, **named):
        """Return a :class:`.views.Pinned` of the named arrays and values, in table order."""
        given = set(named)
        want = set(self.arrays) | set(self.values)
        if given != want:
            raise ValueError(f'{self.name}: unknown slots {sorted(given - want)}, '
                             f'missing {sorted(want - given)}')
        for n in self.arrays:
            want = np.int64 if n in self.int_arrays else np.float64
            if np.asarray(named[n]).dtype != want:
                raise ValueError(f'{self.name}.{n}: expected {np.dtype(want)}, '
                                 f'got {np.asarray(named[n]).dtype}')
        return Pinned([named[n] for n in self.arrays], [int(named[n]) for n in self.values],
                      key=key)


class Columns:
    """
    Named column ranges of a model array: ``(name, width)`` one after another.

    Generates ``PREFIX + NAME`` (the first column of each) and ``PREFIX + 'WIDTH'``.
    """

    def __init__(self, name: str, columns: Sequence[tuple]) -> None:
        self.name = name
        self.start, self.widths, k = {}, {}, 0
        for column, width in columns:
            if column in self.start:
                raise ValueError(f'{name}: column {column!r} declared twice')
            self.start[column], self.widths[column] = k, int(width)
            k += int(width)
        self.width = k

    def ranges(self) -> list:
        """``(first, end)`` column of each named range, in order."""
        return [(k, k + self.widths[n]) for n, k in self.start.items()]

    def row(self, **values) -> np.ndarray:
        """Return the named scalar columns as an array (width,); ValueError names a wrong one."""
        given, want = set(values), set(self.start)
        if given != want:
            raise ValueError(f'{self.name}: unknown columns {sorted(given - want)}, '
                             f'missing {sorted(want - given)}')
        out = np.empty(self.width)
        for name, k in self.start.items():
            out[k:k + self.widths[name]] = values[name]   # a scalar fills a range of 1
        return out

    def constants(self, prefix: str) -> dict:
        """``{PREFIX + NAME: first column}`` and ``{PREFIX + 'WIDTH': width}``."""
        out = {prefix + n.upper(): k for n, k in self.start.items()}
        out[prefix + 'WIDTH'] = self.width
        return out


class Count(IntEnum):
    """Slots of the work tally (an int64 array the kernels add to)."""

    #: Full right-hand sides.
    RHS = 0
    #: Kick evaluations (position-dependent wrenches).
    KICK = 1
    #: Bodies whose gyroscopic term or free-rotor sub-flow was computed.
    GYRO = 2
    #: Orientations updated by an exponential map.
    ROT = 3
    #: Exact damping flows.
    FLOW = 4
    #: Kicks that applied damping (the constrained splittings).
    DAMP_IN_KICK = 5
    #: Constraint geometry evaluations.
    GEOMETRY = 6
    #: Factorizations of ``G M⁻¹ Hᵀ``.
    FACTORIZATIONS = 7
    #: Factorizations that found redundant rows.
    RANK_DEFICIENT = 8
    #: SHAKE's last-resort projections.
    FALLBACKS = 9
    #: Acceleration-level solves.
    ACC_SOLVES = 10
    #: SHAKE's Newton iterations.
    POS_ITERATIONS = 11
    #: Velocity projections.
    VEL_PROJECTIONS = 12
    #: Sub-steps taken.
    SUBSTEPS = 13
    #: Steps redone with twice the sub-steps.
    RETRIES = 14
    #: Steps whose sub-steps were capped at max_substeps (each then turns by more than
    #: max_rotation): the bound on the work of one step, reported, never silent.
    CAPPED = 15
    #: (Sub)steps whose positions SHAKE (or its last-resort projection) left above the
    #: tolerance after max_iterations: less accurate, reported, never silent.
    UNCONVERGED = 16
    #: Symmetric factorizations in inertia form that fell back to the row-space tree solve
    #: (a joint's freedom with next to no inertia, see constrained_step._sym_factor).
    INERTIA_FALLBACKS = 17


N_COUNTS = len(Count)


class Solve(IntEnum):
    """How a component's systems are solved."""

    #: Densely (few rows).
    DENSE = 0
    #: By the tree solve (a forest).
    TREE = 1
    #: By the tree solve of a spanning forest and the Schur complement of the rows
    #: that close loops (:mod:`.loop_solve`).
    LOOP = 2


# -- model arrays (built by Dynamics.kernel_model) -----------------------------------------

#: ``body`` (n, B_WIDTH): mass, 1/mass, principal moments J (3), damping coefficients,
#: and the rotor's kind: 0.0 isotropic (no gyroscopic term), 1.0 asymmetric, or
#: ``ROTOR_TOP + a`` for a symmetric top whose distinct principal axis is ``a`` (the
#: other two moments equal, see bodies.top_axes): its drift is one exact flow.
BODY = Columns('body', [('mass', 1), ('inv_mass', 1), ('moments', 3), ('c_lin', 1),
                        ('c_ang', 1), ('anisotropic', 1)])
#: The ``anisotropic`` code of a symmetric top whose distinct axis is 0 (1, 2: + 1, + 2).
ROTOR_TOP = 2.0
#: ``wrench`` (k, W_WIDTH), one row per force element acting in the step. ``kind``
#: WRENCH_APPLIED: body index, 1.0 if force and torque are in the principal frame,
#: force (3), torque (3), point of application (3, principal, from the centre).
#: ``kind`` WRENCH_DRIVE: a joint's drive between ``body`` (the child) and ``parent`` (the
#: world when >= n), :mod:`.drives`: whether it rotates; the axis in the child's and
#: the parent's principal frames; the joint frame's e1 in the child and e1, e2 in the
#: parent (angles); the joint point's lever arms on the child and, at q = 0, on the
#: parent (principal frames, from the centres; world coordinates for the world); the
#: angle the unwrapped angle is taken near (``center``), the servo's gains and targets,
#: the passive damping and the largest actuator effort.
WRENCH = Columns('wrench', [('body', 1), ('in_body', 1), ('force', 3), ('torque', 3),
                            ('point', 3), ('kind', 1), ('parent', 1), ('rotary', 1),
                            ('k_child', 3), ('k_parent', 3), ('e1_child', 3),
                            ('e1_parent', 3), ('e2_parent', 3), ('r_child', 3),
                            ('r_parent', 3), ('center', 1), ('kp', 1), ('kd', 1),
                            ('damping', 1), ('q_target', 1), ('v_target', 1),
                            ('effort_max', 1)])
#: Kinds of wrench rows.
WRENCH_APPLIED, WRENCH_DRIVE = 0, 1
#: ``frames`` (n, FR_WIDTH): the principal frame in the user's body frame (xyzw), then
#: the centre of mass in the body frame (m).
FRAME = Columns('frame', [('quat_body_principal', 4), ('com_body', 3)])
#: ``out`` (n, O_WIDTH) of free_step.outputs: poses and twists in the user's body frames.
OUTPUT = Columns('output', [('origin_world', 3), ('quat_body_world', 4),
                            ('origin_vel_world', 3), ('ang_vel_world', 3),
                            ('origin_vel_body', 3), ('ang_vel_body', 3)])
#: ``joint`` (k, J_WIDTH) of :mod:`.joints`: a one-coordinate joint's bodies (the world
#: is index n), whether it rotates, the joint frame in the parent body's frame (position,
#: rotation row by row), the frame (axis, e1, e2) in the joint frame, the speed limit,
#: and the window the coordinate is watched in (a limited joint's bounds widened by the
#: tolerance, ±inf otherwise: :func:`.joints.joint_coordinates_within`).
JOINT = Columns('joint', [('parent', 1), ('child', 1), ('rotary', 1), ('p_jp', 3),
                          ('R_jp', 9), ('axis', 3), ('e1', 3), ('e2', 3),
                          ('velocity_limit', 1), ('watch_low', 1), ('watch_high', 1)])
#: ``row_par`` (m, PAR_WIDTH) of the constraint rows (:mod:`.rows`): the lever arms on
#: bodies a and b (principal frames), the axes s and e, a second axis e2 of body b (angle
#: rows), a scalar (a length, a cosine, a joint drive's target), and how that scalar
#: moves with time t: ``scalar = c0 + rate (t − t0)`` (``rate`` ċ, 1/s: an exact velocity
#: drive's target velocity, 0 otherwise; then ``Φ̇ = G ν − ċ``, and a step puts the
#: scalar at the time of each configuration it evaluates).
ROW_PARAMETERS = Columns('row par', [('ra', 3), ('rb', 3), ('s', 3), ('e', 3), ('e2', 3),
                                     ('scalar', 1), ('rate', 1), ('c0', 1), ('t0', 1)])
#: ``par`` of the constrained kernels: the solver's and the integrator's settings, and the
#: times (s) a step starts and ends at (moving drive targets, see ``ROW_PARAMETERS``).
PAR = Columns('par', [('tau', 1), ('omega', 1), ('pos_tol', 1), ('max_it', 1),
                      ('rank_rtol', 1), ('reg', 1), ('closing', 1), ('max_rot', 1),
                      ('max_sub', 1), ('t_start', 1), ('t_end', 1)])

#: A state buffer ``y`` (13 n) of :class:`..bodies.State`: blocks of n rows each, in
#: this order (``S_POS`` etc. are each block's first entry divided by n).
STATE = Columns('state', [('pos', 3), ('quat', 4), ('vel', 3), ('om', 3)])

# -- a component's packed arrays (constrained_step.pack) ------------------------------------

#: The rows ``(kind, comp, a, b, par)`` of :mod:`.rows`, and the coupling parts.
#: A component has ``m`` rows (multipliers) and ``m + e`` *parts*: part ``r < m`` is row
#: ``r``'s own (a built-in or generic row on bodies ``row_a[r]``, ``row_b[r]``); the ``e``
#: parts after them add to rows that couple more than two bodies (a mimic joint: ``Φ =
#: q_m − k q − c`` over the mimic's two bodies and its leader's two). Part ``m + x`` is the
#: built-in row ``(x_kind, x_comp, row_a, row_b, x_par)[x]`` times ``x_weight[x]``, added to
#: row ``row_owner[m + x]`` (``row_owner[r] = r`` for ``r < m``). ``G`` (``jac``) holds every
#: part's blocks on its two bodies; Φ, λ and the solves have the ``m`` rows.
ROWS = (('kind', 'i', 1), ('comp', 'i', 1), ('row_a', 'i', 1), ('row_b', 'i', 1),
        ('row_par', 'f', 2), ('row_owner', 'i', 1), ('x_kind', 'i', 1), ('x_comp', 'i', 1),
        ('x_par', 'f', 2), ('x_weight', 'f', 1))
#: The workspace (constrained_step.workspace).
WORKSPACE = (('phi', 'f', 2), ('jac', 'f', 4), ('vm', 'f', 2), ('gt_lambda', 'f', 2),
             ('free_acc', 'f', 2), ('force', 'f', 2), ('torque', 'f', 2), ('minv', 'f', 2),
             ('factor_state', 'i', 1), ('watch', 'i', 1), ('xvec', 'f', 2))
#: The rows of the workspace's ``vm`` (4, m): Φ̇ and γ of the rows, a right-hand side,
#: and a solution; the rows of its ``xvec`` (3, e): Φ, Φ̇ and γ of the coupling parts
#: (unweighted); and the entries of its ``factor_state`` (2,): whether the symmetric
#: factor is of the current geometry, and its mode.
VM_ROWS = ('phi_dot', 'gamma', 'rhs', 'solution')
XVEC_ROWS = ('x_phi', 'x_phi_dot', 'x_gamma')
FACTOR_STATE_ENTRIES = ('valid', 'mode')
#: The scratch arrays (constrained_step.scratch).
SCRATCH = (('frames', 'f', 3), ('omega_world', 'f', 2), ('jr', 'f', 3), ('g2', 'f', 3),
           ('vectors', 'f', 2), ('body_vectors', 'f', 3), ('quats', 'f', 2),
           ('stages', 'f', 4), ('rotor', 'f', 2))
#: A dense factor storage (constrained_step.dense_storage).
DENSE = Layout('dense storage', (('f', 'f', 2), ('piv', 'i', 1), ('u', 'f', 2),
                                 ('s', 'f', 1), ('vt', 'f', 2)))
#: A tree storage (constrained_step.tree_storage): the forest's structure, its
#: factors, and for closed loops the closure rows and the Schur complement's arrays.
TREE = Layout('tree storage', (
    ('group_ptr', 'i', 1), ('group_rows', 'i', 1), ('group_child', 'i', 1),
    ('group_parent', 'i', 1), ('row_side', 'i', 1), ('s', 'f', 3), ('piv', 'i', 2),
    ('p', 'f', 3), ('q', 'f', 3), ('b', 'f', 4), ('w', 'f', 3), ('e', 'f', 3),
    ('tmp', 'f', 1), ('closure', 'i', 1), ('x', 'f', 2), ('y', 'f', 2), ('work', 'f', 1),
    ('g', 'f', 3), ('z', 'f', 1), ('xc', 'f', 1)))
#: The null-space (inertia-form) storage (constrained_step.nullspace_storage) of a forest
#: whose joints are all recognized (:func:`.nullspace_solve.nullspace_structure`): per
#: joint, leaves first, its child and parent body, type and rows by slot and which block
#: is the child's (a free-floating tree's root: an entry of type FREE, without rows);
#: the symmetric factors (articulated inertias, S, U, D, the joint vectors) and the
#: solve's workspace (:mod:`.nullspace_solve`); SHAKE's unsymmetric ones
#: (``shake_*``, :mod:`.nullspace_shake`) and the start configuration's rotations. Empty
#: (no joints) when the component takes the row-space tree solve.
_FACTORS = (('ia', 'f', 3), ('js', 'f', 3), ('ju', 'f', 3), ('jd', 'f', 3), ('jv', 'f', 3),
            ('work', 'f', 2), ('p', 'f', 2), ('acc', 'f', 2), ('jg', 'f', 2), ('jq', 'f', 2))
NULLSPACE = Layout('null-space storage', (
    ('child', 'i', 1), ('parent', 'i', 1), ('type', 'i', 1), ('rows', 'i', 2),
    ('cside', 'i', 2)) + _FACTORS + tuple((f'shake_{f[0]}',) + f[1:] for f in _FACTORS)
    + (('frames_start', 'f', 3),))
#: Which of a component's two storages of each kind: the general factorizations
#: (SHAKE's), and the symmetric factor kept for the current geometry.
STORAGES = ('general', 'symmetric')
COMPONENT = Layout('component', ROWS + WORKSPACE + SCRATCH + tuple(
    (f'{st}_dense_{f.name}', f.kind, f.ndim) for st in STORAGES for f in DENSE.fields)
    + tuple((f'{st}_tree_{f.name}', f.kind, f.ndim) for st in STORAGES for f in TREE.fields)
    + tuple((f'nullspace_{f.name}', f.kind, f.ndim) for f in NULLSPACE.fields))

#: A packed buffer's layout table (n_arrays, L_WIDTH), one row per array of
#: :data:`COMPONENT`: its first entry in its buffer, then its shape (up to 4 dimensions).
LAYOUT_TABLE = Columns('layout table', [('offset', 1), ('shape', 4)])
#: The context a constrained step passes to its helpers: the component's packed buffers and
#: their layout table (see constrained_step.pack), the key of its generic rows (-1 if none)
#: and its :class:`Solve`.
CONTEXT = ('floats', 'ints', 'layout', 'key', 'solve')

# -- address tables ---------------------------------------------------------------------------

#: free_step.free_table / pinned_free_step.
FREE_TABLE = Table('free-step table',
                   ('body', 'gforce', 'wrench', 'kick', 'counts', 'ws', 'frames', 'out'),
                   ('n_wrench', 'flags', 'method', 'n_counts', 'n_ws'), int_arrays=('counts',))
#: constrained_step.component_table / pinned_packed_step.
COMPONENT_TABLE = Table('component table',
                        ('body', 'gforce', 'wrench', 'par', 'floats', 'ints', 'layout', 'lam',
                         'counts', 'frames', 'out'),
                        ('n_wrench', 'flags', 'method', 'solve', 'generic', 'n_par',
                         'n_floats', 'n_ints', 'n_layout', 'n_lam', 'n_counts'),
                        int_arrays=('ints', 'layout', 'counts'))

# The generated indices, as module integers (compile-time constants to numba).
_GROUPS = (
    BODY.constants('B_'), WRENCH.constants('W_'), PAR.constants('P_'),
    ROW_PARAMETERS.constants('PAR_'), FRAME.constants('FR_'), OUTPUT.constants('O_'),
    JOINT.constants('J_'), STATE.constants('S_'),
    {'V_' + n.upper(): k for k, n in enumerate(VM_ROWS)},
    {'XV_' + n[2:].upper(): k for k, n in enumerate(XVEC_ROWS)},
    {'FS_' + n.upper(): k for k, n in enumerate(FACTOR_STATE_ENTRIES)},
    COMPONENT.constants(), DENSE.constants('D_'), TREE.constants('T_'),
    NULLSPACE.constants('NS_'),
    {'CX_' + n.upper(): k for k, n in enumerate(CONTEXT)},
    LAYOUT_TABLE.constants('L_'),
    FREE_TABLE.constants('FT_'), COMPONENT_TABLE.constants('CT_'),
    # Where each storage starts in COMPONENT, and how many slots one takes.
    {'DENSE0': COMPONENT.index['general_dense_f'], 'DENSE_SLOTS': len(DENSE),
     'TREE0': COMPONENT.index['general_tree_group_ptr'], 'TREE_SLOTS': len(TREE),
     'NULLSPACE0': COMPONENT.index['nullspace_child']},
    # Which storage (GENERAL or SYMMETRIC).
    {st.upper(): k for k, st in enumerate(STORAGES)},
)
_CONSTANTS = {}
for _group in _GROUPS:
    _clash = (set(_group) & set(_CONSTANTS)) | (set(_group) & set(globals()))
    if _clash:
        raise ValueError(f'generated names clash: {sorted(_clash)}')
    _CONSTANTS.update(_group)
globals().update(_CONSTANTS)
__all__ = ['BODY', 'COMPONENT', 'COMPONENT_TABLE', 'CONTEXT', 'Columns', 'Count', 'DENSE',
           'Field', 'FRAME', 'FREE_TABLE', 'JOINT', 'Layout', 'LAYOUT_TABLE', 'N_COUNTS',
           'NULLSPACE', 'OUTPUT', 'PAR',
           'ROTOR_TOP', 'ROW_PARAMETERS', 'Solve', 'STATE', 'STORAGES', 'Table', 'TREE', 'WRENCH',
           'WRENCH_APPLIED', 'WRENCH_DRIVE', *_CONSTANTS]
