"""
Holonomic constraints Φ(x_g, R) = 0 between bodies or a body and the world.

Each constraint contributes rows to the system of the seed's eq. 69::

    m ẍ_g + (∂Φ/∂x_g)ᵀ λ = f,     J dΩ/dt + Ω × JΩ + (∂Φ/∂Θ)ᵀ λ = τ,     Φ = 0,

with the Jacobian taken with respect to the centre-of-mass displacement δx_g
(world frame) and the body-frame rotation δΘ (``δR = R hat(δΘ)``, eq. 13; here
in the principal frame). The generalized velocity of body i is
``ν_i = (v_com_world, Ω_principal)``, column block ``6 i .. 6 i + 5`` of the
Jacobian ``G``. Differentiating ``Φ`` twice gives ``G ν̇ + γ = Φ̈`` with the
velocity-product term ``γ = Ġ ν``.

Joint types are built from four row primitives, evaluated for all rows at once
by the compiled kernels of :mod:`.kernels.rows` (no Python loop over
constraints):

* ``point``: ``P_a − P_b`` (3 rows), anchor points ``P = x_g + R r``;
* ``dot``: ``(R_b e) · (R_a s)`` for unit vectors ``s`` in a and ``e`` in b;
* ``line``: ``(R_b e) · (P_a − P_b)`` (minus an offset: a slider's coordinate);
* ``distance``: ``|P_a − P_b| − L``;
* ``angle``: the rotation of ``R_a s`` about the axis ``R_b (e × e2)``, from
  ``R_b e``, minus a target (a hinge's coordinate).

=========  ==================================================  ====
type       rows                                                 DOF
=========  ==================================================  ====
ball       point                                                3
hinge      point + dot(k_a, e1_b) + dot(k_a, e2_b)              5
slider     dot(k_a,e1_b) + dot(k_a,e2_b) + dot(e1_a,e2_b)
           + line(e1_b) + line(e2_b)                            5
fixed      point + the three dots of slider                     6
planar     dot(k_a, e1_b) + dot(k_a, e2_b) + line(k_b)          3
distance   distance                                             1
drive      angle (rotary joint) or line (prismatic joint), with     1
           the joint coordinate's target, which may move at a rate
           (``c(t) = c₀ + ċ (t − t₀)``, exact velocity drives); made
           by command groups of ``mode: exact`` (:mod:`.robots`), not
           by users
mimic      a joint coordinate minus ``k`` times another's: one       1
           row over up to four bodies (the angle or line of the
           follower's pair plus a weighted *coupling part* on the
           leader's pair); made by URDF ``<mimic>`` (:mod:`.robots`)
generic    a user function Φ(x_a, R_a, x_b, R_b) (finite-difference Jacobian
           and γ unless given), evaluated one constraint at a time
=========  ==================================================  ====

Here ``k`` is the joint axis and ``(k, e1, e2)`` a right-handed orthonormal
frame fixed in each body when the constraint is added. The world is body index
``n`` (a virtual body with ``x = 0``, ``R = I``, ``ν = 0`` and no columns).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import enum
from typing import Any, Callable, Optional, Sequence

import numpy as np
import scipy.sparse as sp

from . import rotation as so3
from .bodies import BodySet, State
from .errors import SpecError
from .kernels.layout import PAR_C0, PAR_RATE, PAR_SCALAR, PAR_T0
from .kernels.rows import (KIND_ANGLE, KIND_DISTANCE, KIND_DOT, KIND_LINE, KIND_POINT,
                           pack_rows, rows_geometry, rows_rates)
from .validate import finite_array, finite_scalar, positive_scalar


#: m: how far from the world origin a joint's points may lie. Beyond it a coordinate's
#: rounding (one ulp is 1.2e-10 m at 1e6 m, 1.2e-4 m at 1e12 m) nears the 1e-8 m within
#: which a constraint must be satisfiable to be added (``CONSISTENCY_TOLERANCE`` of
#: :class:`.solver.ConstraintSolver`), and the drift bounds we state no longer hold.
MAX_JOINT_DISTANCE = 1e6


class JointType(enum.Enum):
    """Constraint (joint) types."""

    BALL = 'ball'
    HINGE = 'hinge'
    SLIDER = 'slider'
    FIXED = 'fixed'
    PLANAR = 'planar'
    DISTANCE = 'distance'
    GENERIC = 'generic'
    #: A joint coordinate held at a target (:class:`DriveGeometry`): made by the
    #: command groups of ``mode: exact``, not named by users.
    DRIVE = 'drive'
    #: A joint coordinate tied to another's (:class:`Coupling`): made by URDF mimic
    #: joints, not named by users.
    MIMIC = 'mimic'

    @classmethod
    def parse(cls, value: Any, field_name: str = 'type') -> 'JointType':
        """Return the joint type of a JointType or of its name (not 'drive', 'mimic': internal)."""
        if isinstance(value, JointType):
            return value
        known = [t.value for t in cls if t not in (cls.DRIVE, cls.MIMIC)]
        if value == cls.DRIVE.value:
            raise SpecError(field_name, f"'drive' constraints are made by command groups of "
                                        f"mode 'exact' (robots); known types: {known}")
        if value == cls.MIMIC.value:
            raise SpecError(field_name, f"'mimic' constraints are made by URDF mimic joints "
                                        f'(robots); known types: {known}')
        try:
            return cls(value)
        except ValueError:
            raise SpecError(field_name, f'unknown constraint type {value!r}; known: '
                                        f'{known}') from None


@dataclass(frozen=True)
class DriveGeometry:
    """
    Where a joint coordinate lives on its two bodies: what a ``drive`` constraint holds.

    Vectors and points are in each body's own frame (body b the world: world
    frame), as :mod:`.robots` knows them from the URDF. The coordinate is zero in
    the URDF's zero configuration.

    Parameters
    ----------
    rotary : bool
        True: the angle ``atan2((R_b e2_b)·(R_a e1_a), (R_b e1_b)·(R_a e1_a))``
        (revolute, continuous); False: the slide ``(R_b k_b)·(P_a − P_b)``
        (prismatic), ``P_a = x_a + R_a p_a``, ``P_b = x_b + R_b p_b``.
    e1_a : array_like, shape (3,)
        Rotary: the joint frame's first perpendicular axis in body a.
    e1_b, e2_b : array_like, shape (3,)
        Rotary: the joint frame's perpendicular axes (at zero angle) in body b.
    k_b : array_like, shape (3,)
        Prismatic: the axis in body b.
    p_a, p_b : array_like, shape (3,)
        m, prismatic: the points whose separation along ``k_b`` is the slide.
    target : float
        rad or m: the coordinate held (when the constraint is added).
    rate : float
        rad/s or m/s: how fast the target moves (an exact velocity drive), from
        the time the constraint is added: ``c(t) = target + rate (t − t_added)``.

    """

    rotary: bool
    e1_a: Any = (0.0, 0.0, 0.0)
    e1_b: Any = (0.0, 0.0, 0.0)
    e2_b: Any = (0.0, 0.0, 0.0)
    k_b: Any = (0.0, 0.0, 0.0)
    p_a: Any = (0.0, 0.0, 0.0)
    p_b: Any = (0.0, 0.0, 0.0)
    target: float = 0.0
    rate: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, 'rotary', bool(self.rotary))
        for key in ('e1_a', 'e1_b', 'e2_b', 'k_b', 'p_a', 'p_b'):
            object.__setattr__(self, key, finite_array(getattr(self, key), key, (3,)))
        object.__setattr__(self, 'target', finite_scalar(self.target, 'target'))
        object.__setattr__(self, 'rate', finite_scalar(self.rate, 'rate'))
        units = ('e1_a', 'e1_b', 'e2_b') if self.rotary else ('k_b',)
        for key in units:
            if abs(float(np.linalg.norm(getattr(self, key))) - 1.0) > 1e-9:
                raise SpecError(key, f'must be a unit vector, got {getattr(self, key).tolist()}')


@dataclass(frozen=True)
class Coupling:
    """
    The leader's side of a ``mimic`` constraint ``Φ = Φ_f − k Φ_l``.

    ``Φ_f`` is the follower's coordinate minus the constraint's ``drive.target``
    and ``Φ_l`` the leader's minus ``drive.target`` here (the angles each taken in
    (−π, π], so both targets are chosen near where the joints move: :mod:`.robots`
    takes the middle of the leader's limits and ``offset + k`` times it for the
    follower, and the row is the URDF's ``q_f = k q_l + offset`` exactly while the
    leader stays within π of that middle).

    Parameters
    ----------
    body_a : str
        The leader joint's child.
    body_b : str or None
        Its parent; None for the world.
    drive : DriveGeometry
        Where the leader's coordinate lives on them, and its reference (``target``).
    multiplier : float
        ``k``: the follower moves ``k`` times the leader (any non-zero finite number).

    """

    body_a: str
    body_b: Optional[str]
    drive: DriveGeometry
    multiplier: float

    def __post_init__(self) -> None:
        if not isinstance(self.drive, DriveGeometry):
            raise SpecError('coupling.drive', f'expected a DriveGeometry, got {self.drive!r}')
        k = finite_scalar(self.multiplier, 'coupling.multiplier')
        if k == 0.0:
            raise SpecError('coupling.multiplier', 'must be non-zero (a zero multiplier '
                                                   'holds the follower still: a drive)')
        object.__setattr__(self, 'multiplier', k)


@dataclass(frozen=True)
class Constraint:
    """
    A constraint as a user describes it.

    Parameters
    ----------
    name : str
        Unique among the simulation's constraints.
    type : JointType or str
        'ball', 'hinge', 'slider', 'fixed', 'planar', 'distance' or 'generic'.
    body_a : str
    body_b : str, optional
        The second body; None (or 'world') for the world.
    anchor_world : array_like, shape (3,), optional
        m: the joint point, world frame, at the time the constraint is added
        (it is then satisfied exactly).
    anchor_a_body, anchor_b_body : array_like, shape (3,), optional
        m: the joint point in each body's frame (body b = world: world frame).
        Instead of ``anchor_world``; the constraint may then start violated, and
        its violation decays smoothly (see :mod:`.solver`). Default: each body's
        origin.
    axis_world : array_like, shape (3,), optional
        Joint axis (hinge, slider; planar: the plane's normal), world frame at
        the time of adding; any non-zero length. Required for hinge, slider and
        planar.
    length : float, optional
        m, for distance: default the current distance between the anchors.
    drive : DriveGeometry, optional
        For drive and mimic (and only for them): the joint coordinate held and its
        target (mimic: the follower's coordinate between ``body_a`` and ``body_b``).
    coupling : Coupling, optional
        For mimic (and only for it): the leader's coordinate and the multiplier.
    function : callable, optional
        For generic: ``phi(x_a, R_a, x_b, R_b) -> ndarray (k,)`` with centre of
        mass positions ``x`` (3,) and body-frame rotation matrices ``R`` (3, 3)
        (``x_b = 0``, ``R_b = I`` for the world).
    jacobian : callable, optional
        For generic: same arguments, returns ``(k, 12)``: derivatives with
        respect to ``[δx_a, δΘ_a, δx_b, δΘ_b]``, ``δΘ`` in each body frame
        (``δR = R hat(δΘ)``). Finite differences when omitted.

    """

    name: str
    type: Any  # noqa: A003 - the key of scene files and of the ROS service
    body_a: str
    body_b: Optional[str] = None
    anchor_world: Any = None
    anchor_a_body: Any = None
    anchor_b_body: Any = None
    axis_world: Any = None
    length: Any = None
    function: Optional[Callable] = None
    jacobian: Optional[Callable] = None
    drive: Optional[DriveGeometry] = None
    coupling: Optional[Coupling] = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SpecError('name', f'must be a non-empty string, got {self.name!r}')
        jt = JointType.parse(self.type)
        object.__setattr__(self, 'type', jt)
        if self.body_b == 'world':
            object.__setattr__(self, 'body_b', None)
        if not isinstance(self.body_a, str) or not self.body_a or self.body_a == 'world':
            raise SpecError('body_a', f'must name a body, got {self.body_a!r}')
        if self.body_b is not None and (not isinstance(self.body_b, str) or not self.body_b):
            raise SpecError('body_b', f"must name a body, or be None or 'world', "
                                      f'got {self.body_b!r}')
        if self.body_a == self.body_b:
            raise SpecError('body_b', f'a body cannot be constrained to itself ({self.body_a!r})')
        if self.anchor_world is not None:
            if self.anchor_a_body is not None or self.anchor_b_body is not None:
                raise SpecError('anchor_world', 'give anchor_world or anchor_a_body/'
                                                'anchor_b_body, not both')
            object.__setattr__(self, 'anchor_world',
                               finite_array(self.anchor_world, 'anchor_world', (3,)))
        for key in ('anchor_a_body', 'anchor_b_body'):
            value = getattr(self, key)
            object.__setattr__(self, key, np.zeros(3) if value is None
                               else finite_array(value, key, (3,)))
        if jt in (JointType.HINGE, JointType.SLIDER, JointType.PLANAR):
            if self.axis_world is None:
                raise SpecError('axis_world', f'required for a {jt.value} constraint')
        if self.axis_world is not None:
            axis = finite_array(self.axis_world, 'axis_world', (3,))
            norm = float(np.linalg.norm(axis))
            if not norm > 1e-12:   # (norm inf: components near the float limit)
                raise SpecError('axis_world', f'zero-length axis {axis.tolist()} (shorter '
                                              f'than 1e-12)')
            axis = axis / np.max(np.abs(axis))   # (no overflow in the norm below)
            object.__setattr__(self, 'axis_world', axis / np.linalg.norm(axis))
        if self.length is not None:
            if jt is not JointType.DISTANCE:
                raise SpecError('length', f'only for distance constraints, not {jt.value}')
            object.__setattr__(self, 'length', positive_scalar(self.length, 'length'))
        if jt is JointType.GENERIC:
            if not callable(self.function):
                raise SpecError('function', 'a generic constraint needs a callable '
                                            'phi(x_a, R_a, x_b, R_b)')
            if self.jacobian is not None and not callable(self.jacobian):
                raise SpecError('jacobian', f'must be callable, got {self.jacobian!r}')
        elif self.function is not None or self.jacobian is not None:
            raise SpecError('function', f'only for generic constraints, not {jt.value}')
        if (jt in (JointType.DRIVE, JointType.MIMIC)) != isinstance(self.drive, DriveGeometry):
            raise SpecError('drive', 'drive and mimic constraints need a DriveGeometry, and '
                                     f'only they have one (type {jt.value}, drive '
                                     f'{self.drive!r})')
        if (jt is JointType.MIMIC) != isinstance(self.coupling, Coupling):
            raise SpecError('coupling', 'a mimic constraint needs its Coupling, and only it '
                                        f'has one (type {jt.value}, coupling '
                                        f'{self.coupling!r})')


def perpendicular_frame(k: np.ndarray) -> np.ndarray:
    """Right-handed orthonormal frame ``(k, e1, e2)`` as rows, from a unit vector k (3,)."""
    helper = np.eye(3)[np.argmin(np.abs(k))]
    e1 = so3.cross(k, helper)
    e1 /= np.linalg.norm(e1)
    return np.array([k, e1, so3.cross(k, e1)])


# Systems of at most this many rows use dense linear algebra over the bodies
# they touch; larger ones the linear-time tree solve (chains and trees, see
# tree_solve.py) or, with a closed loop, scipy.sparse.
DENSE_ROWS = 48


class JacobianStructure:
    """
    The sparsity pattern of ``G``, fixed while the constraint set is unchanged.

    Dense over the touched bodies when ``m <= DENSE_ROWS`` (faster for small
    systems), otherwise CSR; in both cases the index arithmetic is done once
    here and each evaluation only fills in values.
    """

    def __init__(self, rows: np.ndarray, cols: np.ndarray, m: int, n: int) -> None:
        self.m, self.n = m, n
        self.dense_mode = m <= DENSE_ROWS
        if self.dense_mode:
            self.bodies_used = np.unique(cols // 6)
            compact = np.zeros(n + 1, dtype=int)
            compact[self.bodies_used] = np.arange(len(self.bodies_used))
            self.width = 6 * len(self.bodies_used)
            self.flat = rows * self.width + 6 * compact[cols // 6] + cols % 6
        else:
            # Entries in CSR order; a coupled row (mimic) may give one entry twice (two
            # parts on one body): they are summed.
            keys, self.entry = np.unique(rows.astype(np.int64) * (6 * n) + cols,
                                         return_inverse=True)
            self.entry = self.entry.ravel()
            self.n_entries = len(keys)
            self.indices = keys % (6 * n)
            self.indptr = np.concatenate(
                [[0], np.cumsum(np.bincount(keys // (6 * n), minlength=m))]).astype(np.int64)


class RowJacobian:
    """
    The constraint Jacobian ``G`` (m, 6 n) at one configuration.

    Parameters
    ----------
    structure : JacobianStructure
    values : ndarray
        Entries in the order of the structure's pattern.

    """

    def __init__(self, structure: JacobianStructure, values: np.ndarray) -> None:
        self.structure = st = structure
        self.m, self.n = st.m, st.n
        self.dense_mode = st.dense_mode
        if self.dense_mode:
            self.bodies_used = st.bodies_used
            # (Summed: a coupled row may give one entry twice.)
            matrix = np.bincount(st.flat, weights=values, minlength=st.m * st.width)
            self.matrix = matrix.reshape(st.m, st.width)
        else:
            self.matrix = sp.csr_matrix(
                (np.bincount(st.entry, weights=values, minlength=st.n_entries), st.indices,
                 st.indptr), shape=(st.m, 6 * st.n))

    def _cols(self, x6: np.ndarray) -> np.ndarray:
        return (x6[self.bodies_used] if self.dense_mode else x6).ravel()

    def matvec(self, x6: np.ndarray) -> np.ndarray:
        """``G x`` for generalized vectors ``x6`` (n, 6); returns (m,)."""
        return self.matrix @ self._cols(x6)

    def rmatvec(self, lam: np.ndarray) -> np.ndarray:
        """``Gᵀ λ`` as (n, 6)."""
        y = self.matrix.T @ lam
        if not self.dense_mode:
            return y.reshape(-1, 6)
        out = np.zeros((self.n, 6))
        out[self.bodies_used] = y.reshape(-1, 6)
        return out

    def schur(self, minv6: np.ndarray, other: Optional['RowJacobian'] = None):
        """``G M⁻¹ Hᵀ`` with ``H = other`` (default ``G``); ``minv6`` (n, 6)."""
        h = self if other is None else other
        w = self._cols(minv6)
        if self.dense_mode:
            return (self.matrix * w) @ h.matrix.T
        return (self.matrix.multiply(w[None, :]) @ h.matrix.T).tocsc()

    def toarray(self) -> np.ndarray:
        """``G`` as a dense (m, 6 n) array (for tests and reactions)."""
        out = np.zeros((self.m, 6 * self.n))
        if self.dense_mode:
            cols = (6 * self.bodies_used[:, None] + np.arange(6)).ravel()
            out[:, cols] = self.matrix
            return out
        return self.matrix.toarray()


class Geometry:
    """
    Φ and G of all constraints at one configuration, and what the rates need.

    Attributes
    ----------
    pos : ndarray, shape (n, 3)
    quat : ndarray, shape (n, 4)
        The configuration.
    phi : ndarray, shape (m,)
    jacobian : RowJacobian
    g_builtin : ndarray, shape (2, m_builtin, 6)
        Jacobian blocks of the built-in rows on body a (``[0]``) and body b
        (``[1]``, also computed for the world), as :func:`.kernels.rows.rows_geometry`
        returns them.
    g_generic : list of ndarray, shape (k, 12)
        Jacobians of the generic constraints, in row order.
    g_coupling : ndarray, shape (2, e, 6)
        Blocks of the coupling parts (mimic rows' leader sides), weighted, on their
        bodies a and b.

    """

    def __init__(self, owner: 'ConstraintSet', pos: np.ndarray, quat: np.ndarray) -> None:
        self.owner, self.pos, self.quat = owner, pos, quat
        self.phi: np.ndarray = np.zeros(0)
        self.jacobian: Optional[RowJacobian] = None
        self.g_builtin = np.zeros((2, 0, 6))
        self.g_generic: list = []
        self.g_coupling = np.zeros((2, 0, 6))
        self.n = len(pos)
        self._frames: Optional[tuple] = None

    @property
    def frames(self) -> tuple:
        """Positions (n+1, 3) and principal rotations (n+1, 3, 3), the world last."""
        if self._frames is None:
            x = np.vstack([self.pos, np.zeros((1, 3))])
            R = np.concatenate([so3.quat_to_matrix(self.quat), np.eye(3)[None]])
            self._frames = (x, R)
        return self._frames

    def rates(self, vel: np.ndarray, omega: np.ndarray,
              need_gamma: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """``Φ̇ = G ν`` and ``γ = Ġ ν`` (zeros if not ``need_gamma``), each (m,)."""
        cs = self.owner
        mb = cs.n_builtin_rows
        phi_dot, gamma = np.empty(cs.n_rows), np.zeros(cs.n_rows)
        if mb:
            rows_rates(self.pos, self.quat, np.ascontiguousarray(vel, dtype=float),
                       np.ascontiguousarray(omega, dtype=float), cs.row_kind, cs.row_comp,
                       cs.row_a, cs.row_b, cs.row_par, self.g_builtin[0], self.g_builtin[1],
                       bool(need_gamma), phi_dot[:mb], gamma[:mb])
        e = len(cs.x_row)
        if e:
            # Coupling parts: Φ̇ from their weighted blocks, γ weighted here.
            x_dot, x_gamma = np.empty(e), np.zeros(e)
            rows_rates(self.pos, self.quat, np.ascontiguousarray(vel, dtype=float),
                       np.ascontiguousarray(omega, dtype=float), cs.x_kind, cs.x_comp,
                       cs.x_a, cs.x_b, cs.x_par, self.g_coupling[0], self.g_coupling[1],
                       bool(need_gamma), x_dot, x_gamma)
            np.add.at(phi_dot, cs.x_row, x_dot)
            np.add.at(gamma, cs.x_row, cs.x_weight * x_gamma)
        if not cs.generic:
            return phi_dot, gamma
        n = self.n
        x, R = self.frames
        v = np.vstack([vel, np.zeros((1, 3))])
        w = np.vstack([np.einsum('nij,nj->ni', R[:n], omega), np.zeros((1, 3))])
        start = mb
        for res, g in zip(cs.generic, self.g_generic):
            stop = start + res.n_rows
            rate = g[:, :6] @ np.concatenate([vel[res.a], omega[res.a]])
            if res.b < n:
                rate += g[:, 6:] @ np.concatenate([vel[res.b], omega[res.b]])
            phi_dot[start:stop] = rate
            if need_gamma:
                gamma[start:stop] = cs.generic_rows(res, x, R, v, w, True)[2]
            start = stop
        return phi_dot, gamma


@dataclass
class Evaluation:
    """
    Constraint rows at a state (m rows, n bodies).

    Attributes
    ----------
    phi : ndarray, shape (m,)
    jacobian : RowJacobian
        ``G``, shape (m, 6 n).
    phi_dot : ndarray, shape (m,)
        ``G ν``.
    gamma : ndarray, shape (m,)
        ``Ġ ν``, the velocity-product term of ``Φ̈``.

    """

    phi: np.ndarray
    jacobian: RowJacobian
    phi_dot: np.ndarray
    gamma: np.ndarray


@dataclass
class ResolvedConstraint:
    """A constraint bound to body indices and principal-frame vectors."""

    spec: Constraint
    a: int
    b: int
    point: Optional[tuple] = None          # (r_a, r_b)
    dots: list = field(default_factory=list)   # [(s_a, e_b, target)]
    lines: list = field(default_factory=list)  # [(r_a, r_b, e_b, offset)]
    angles: list = field(default_factory=list)  # [(s_a, e_b, e2_b, target)]
    # A drive's target (in angles or lines) is c at time t0; it moves at rate ċ.
    motion: tuple = (0.0, 0.0)              # (ċ, t0)
    distance: Optional[tuple] = None       # (r_a, r_b, L)
    n_rows: int = 0                        # generic: length of Φ
    anchor: tuple = ()                     # (r_a, r_b): anchor lever arms, principal frames
    rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    # mimic: the coupling part (kind, a, b, r_a, r_b, s, e, e2, scalar, weight) of its row
    coupled: Optional[tuple] = None
    coupled_anchor: tuple = ()             # mimic: the leader's joint point on its a and b


class ConstraintSet:
    """
    The constraints of a simulation, resolved to flat arrays of rows.

    Parameters
    ----------
    bodies : BodySet

    Attributes
    ----------
    n_rows : int
        m, the rows of Φ: the built-in rows first, then the generic ones.
    n_builtin_rows : int
        The point, dot, line, distance and angle rows (in this order).
    row_kind, row_comp, row_a, row_b : ndarray, shape (n_builtin_rows,), int64
    row_par : ndarray, shape (n_builtin_rows, kernels.layout.PAR_WIDTH)
        The built-in rows as :mod:`.kernels.rows` takes them (layout there): a
        drive's scalar is its target at :attr:`time`, its rate the target's.
    time : float
        s: the time the drives' targets in ``row_par`` are of (see
        :meth:`drive_targets_at`).
    moving : bool
        Some drive's target moves (an exact velocity drive with a rate).
    x_kind, x_comp, x_a, x_b, x_par : ndarray, shape (e,) and (e, PAR_WIDTH)
        The coupling parts (mimic rows' leader sides), built-in rows too.
    x_row : ndarray, shape (e,), int64
        The row each coupling part adds to.
    x_weight : ndarray, shape (e,)
        Each part's weight (``−k``).

    """

    def __init__(self, bodies: BodySet) -> None:
        self.bodies = bodies
        self._resolved: dict[str, ResolvedConstraint] = {}
        self.n_rows = 0
        self.time = 0.0
        self._build()

    # -- adding and removing (between steps) -----------------------------------------------

    def __len__(self) -> int:
        """Return the number of constraints."""
        return len(self._resolved)

    def __contains__(self, name: str) -> bool:
        """Tell whether a constraint called ``name`` exists."""
        return name in self._resolved

    @property
    def resolved(self) -> tuple:
        """Return the constraints bound to bodies (:class:`ResolvedConstraint`), as added."""
        return tuple(self._resolved.values())

    @property
    def generic(self) -> tuple:
        """Return the resolved generic constraints in row order (after the built-in rows)."""
        return self._gen

    @property
    def names(self) -> list[str]:
        """Constraint names in the order they were added."""
        return list(self._resolved)

    def spec(self, name: str) -> Constraint:
        """Return the user's description of constraint ``name``."""
        return self._get(name).spec

    def rows_of(self, name: str) -> np.ndarray:
        """Row indices of constraint ``name`` in Φ, G and λ."""
        return self._get(name).rows

    def anchors(self, name: str) -> tuple:
        """
        Bodies of constraint ``name`` and where its anchor sits on each.

        Returns
        -------
        tuple
            ``((a, r_a), (b, r_b))``: body indices (``b == len(bodies)`` is the
            world) and each anchor's lever arm, ndarray, shape (3,), m, from the
            body's centre of mass in its principal frame (for the world, the
            anchor's world position). Fixed when the constraint was added. A mimic
            constraint has four: its follower joint's two, then its leader's.

        """
        res = self._get(name)
        out = ((res.a, res.anchor[0]), (res.b, res.anchor[1]))
        if res.coupled is not None:
            out += tuple(zip(res.coupled[1:3], res.coupled_anchor))
        return out

    def _get(self, name: str) -> ResolvedConstraint:
        try:
            return self._resolved[name]
        except (KeyError, TypeError):
            raise SpecError('name', f'no constraint named {name!r}; constraints: '
                                    f'{list(self._resolved)}') from None

    def add(self, spec: Constraint, state: State) -> None:
        """Add ``spec``, fixing its body-frame vectors from ``state``."""
        self.add_all([spec], state)

    def add_all(self, specs: Sequence[Constraint], state: State, field: str = '') -> None:
        """
        Add ``specs`` in order, as :meth:`add` each, with the row tables built once.

        All or none: an error names ``field[i]`` (``field`` given) of the one at fault,
        and the set is as it was.
        """
        added = []
        frames = None   # (the bodies' frames at the state, made once for all of them)
        try:
            for i, spec in enumerate(specs):
                try:
                    if not isinstance(spec, Constraint):
                        raise SpecError('constraint', f'expected a Constraint, got {spec!r}')
                    if spec.name in self._resolved:
                        raise SpecError('name', f'duplicate constraint name {spec.name!r}')
                    if frames is None:
                        frames = self._frames(state) + (
                            np.concatenate([self.bodies.R_body_principal, np.eye(3)[None]]),
                            np.vstack([self.bodies.com_body, np.zeros((1, 3))]))
                    res = self._resolve(spec, state, frames)
                    if spec.type is JointType.GENERIC:
                        # Evaluate once: validates the function and fixes its number of rows.
                        res.n_rows = len(self.generic_rows(res, *frames[:2])[0])
                except SpecError as exc:
                    raise exc.within(f'{field}[{i}]') if field else exc from None
                self._resolved[spec.name] = res
                added.append(spec.name)
        except BaseException:
            for name in added:
                del self._resolved[name]
            raise
        self._build()

    def set_drive_targets(self, names: list, targets: np.ndarray, time: float,
                          rates: Optional[np.ndarray] = None) -> np.ndarray:
        """
        Set the targets of ``drive`` constraints (between steps); returns their rows.

        Parameters
        ----------
        names : list of str
            Drive constraints.
        targets : ndarray, shape (k,)
            rad or m, finite (the caller validates them): each target at ``time``.
        time : float
            s: when the targets are those; the set's targets are then of this time
            (:meth:`drive_targets_at`).
        rates : ndarray, shape (k,), optional
            rad/s or m/s: how fast each target moves from ``time`` on (default 0:
            held).

        Returns
        -------
        ndarray of int, shape (k,)
            Each drive's row in Φ, G and λ (a built-in row: its ``row_par`` scalar is
            the target, its rate the rate). Only those change: ``G`` does not depend
            on them.

        """
        rows = np.empty(len(names), dtype=int)
        rates = np.zeros(len(names)) if rates is None else rates
        for i, (name, target, rate) in enumerate(zip(names, targets, rates)):
            res = self._drive(name)
            target = float(target)
            if res.angles:
                res.angles[0] = res.angles[0][:3] + (target,)
            else:
                res.lines[0] = res.lines[0][:3] + (target,)
            res.motion = (float(rate), float(time))
            rows[i] = res.rows[0]
        self._drive_anchors()
        self.drive_targets_at(time)
        return rows

    def drive_targets(self, names: list, time: float) -> np.ndarray:
        """Targets (k,) of ``drive`` constraints at ``time`` (s), rad or m."""
        out = np.empty(len(names))
        for i, name in enumerate(names):
            res = self._drive(name)
            rate, t0 = res.motion
            target = res.angles[0][3] if res.angles else res.lines[0][3]
            out[i] = target + rate * (float(time) - t0)
        return out

    def drive_motions(self, names: list) -> list:
        """Return ``(c₀, ċ, t₀)`` of ``drive`` constraints: ``c(t) = c₀ + ċ (t − t₀)``."""
        out = []
        for name in names:
            res = self._drive(name)
            rate, t0 = res.motion
            out.append((res.angles[0][3] if res.angles else res.lines[0][3], rate, t0))
        return out

    def drive_rates(self, names: list) -> np.ndarray:
        """Rates (k,) of ``drive`` constraints' targets, rad/s or m/s."""
        return np.array([self._drive(name).motion[0] for name in names], dtype=float)

    def drive_targets_at(self, time: float) -> np.ndarray:
        """
        Put the drives' targets at ``time`` (s) into ``row_par``; returns the drives' rows.

        ``c(t) = c₀ + ċ (t − t₀)`` from each drive's target ``c₀`` set at ``t₀``: a
        function of time, so a step redone, sub-stepped, or taken twice from one
        state (the accuracy knob's doubling) sees the same targets.
        """
        rows = self._anchors[0]
        self.time = float(time)
        if len(rows):
            # The kernels' expression (kernels.constrained_step._targets_at), bit for bit.
            p = self.row_par
            p[rows, PAR_SCALAR] = p[rows, PAR_C0] + p[rows, PAR_RATE] * (
                self.time - p[rows, PAR_T0])
        return rows

    @property
    def drive_rows(self) -> np.ndarray:
        """Return the drives' rows (k,) in Φ, G and λ, in the order they were added."""
        return self._anchors[0]

    def _drive(self, name: str) -> ResolvedConstraint:
        res = self._get(name)
        if res.spec.type is not JointType.DRIVE:
            raise SpecError('name', f'constraint {name!r} is a {res.spec.type.value}, '
                                    f'not a drive')
        return res

    def _drive_anchors(self) -> None:
        """Collect each drive's row, target c₀, rate ċ and time t₀ as arrays."""
        drives = [r for r in self._resolved.values() if r.spec.type is JointType.DRIVE]
        self._anchors = (
            np.array([r.rows[0] for r in drives], dtype=int),
            np.array([r.angles[0][3] if r.angles else r.lines[0][3] for r in drives]),
            np.array([r.motion[0] for r in drives]), np.array([r.motion[1] for r in drives]))
        self.moving = bool(np.any(self._anchors[2] != 0.0))
        if len(drives):
            rows = self._anchors[0]
            self.row_par[rows, PAR_C0] = self._anchors[1]
            self.row_par[rows, PAR_RATE] = self._anchors[2]
            self.row_par[rows, PAR_T0] = self._anchors[3]

    def remove(self, name: str) -> Constraint:
        """Remove constraint ``name``; returns its spec."""
        res = self._get(name)
        del self._resolved[name]
        self._build()
        return res.spec

    def _frames(self, state: State) -> tuple:
        """Positions (n+1, 3) and principal rotations (n+1, 3, 3), the world last."""
        x = np.vstack([state.pos_com_world, np.zeros((1, 3))])
        R = np.concatenate([so3.quat_to_matrix(state.quat_principal_world), np.eye(3)[None]])
        return x, R

    def _resolve(self, spec: Constraint, state: State, frames: tuple) -> ResolvedConstraint:
        """Resolve ``spec`` at ``state``; ``frames``: its :meth:`_frames`, then V and com."""
        bodies = self.bodies
        n = len(bodies)
        a = bodies.lookup(spec.body_a, 'body_a')
        b = n if spec.body_b is None else bodies.lookup(spec.body_b, 'body_b')
        x, R, V, com = frames

        def local_point(i: int, p_world: np.ndarray) -> np.ndarray:
            return R[i].T @ (p_world - x[i])

        def body_point(i: int, p_body: np.ndarray) -> np.ndarray:
            return V[i].T @ (p_body - com[i])

        if spec.anchor_world is not None:
            r_a, r_b = local_point(a, spec.anchor_world), local_point(b, spec.anchor_world)
        else:
            r_a, r_b = body_point(a, spec.anchor_a_body), body_point(b, spec.anchor_b_body)
        if spec.type is not JointType.GENERIC:
            for field_name, i, r in (('anchor_a_body', a, r_a), ('anchor_b_body', b, r_b)):
                point = x[i] + R[i] @ r
                far = float(np.max(np.abs(point)))
                if not far <= MAX_JOINT_DISTANCE:
                    raise SpecError(
                        'anchor_world' if spec.anchor_world is not None else field_name,
                        f'the joint point {point.tolist()} m (world) has a coordinate of '
                        f'{far:.3g} m, outside the range of +-{MAX_JOINT_DISTANCE:g} m in '
                        f'which joints are supported (farther out, the rounding of a '
                        f'coordinate nears the 1e-8 m to which a joint must hold)')
        res = ResolvedConstraint(spec, a, b, anchor=(r_a, r_b))
        jt = spec.type
        if jt in (JointType.HINGE, JointType.SLIDER, JointType.FIXED, JointType.PLANAR):
            axis = spec.axis_world if spec.axis_world is not None else np.array([0.0, 0.0, 1.0])
            k, e1, e2 = perpendicular_frame(axis)
            fa = [R[a].T @ v for v in (k, e1, e2)]
            fb = [R[b].T @ v for v in (k, e1, e2)]
            # (s in a, e in b): k_a ⟂ e1_b, k_a ⟂ e2_b fix the axis; e1_a ⟂ e2_b the angle.
            res.dots = [(fa[0], fb[1], 0.0), (fa[0], fb[2], 0.0)]
            if jt in (JointType.SLIDER, JointType.FIXED):
                res.dots.append((fa[1], fb[2], 0.0))
            if jt is JointType.SLIDER:
                res.lines = [(r_a, r_b, fb[1], 0.0), (r_a, r_b, fb[2], 0.0)]
            if jt is JointType.PLANAR:
                # The anchors stay in the plane through b's anchor normal to k_b.
                res.lines = [(r_a, r_b, fb[0], 0.0)]
        if jt in (JointType.DRIVE, JointType.MIMIC):
            dg = spec.drive
            res.motion = (dg.rate, float(state.time))
            if dg.rotary:
                res.angles = [(V[a].T @ dg.e1_a, V[b].T @ dg.e1_b, V[b].T @ dg.e2_b,
                               dg.target)]
            else:
                res.lines = [(body_point(a, dg.p_a), body_point(b, dg.p_b), V[b].T @ dg.k_b,
                              dg.target)]
        if jt is JointType.MIMIC:
            cp = spec.coupling
            la = bodies.lookup(cp.body_a, 'coupling.body_a')
            lb = n if cp.body_b is None else bodies.lookup(cp.body_b, 'coupling.body_b')
            if la == lb:
                raise SpecError('coupling.body_b', f'a joint coordinate needs two bodies, '
                                                   f'got {cp.body_a!r} twice')
            dg = cp.drive
            res.coupled_anchor = (body_point(la, dg.p_a), body_point(lb, dg.p_b))
            if dg.rotary:
                res.coupled = (KIND_ANGLE, la, lb, None, None, V[la].T @ dg.e1_a,
                               V[lb].T @ dg.e1_b, V[lb].T @ dg.e2_b, dg.target, -cp.multiplier)
            else:
                res.coupled = (KIND_LINE, la, lb, *res.coupled_anchor, None, V[lb].T @ dg.k_b,
                               None, dg.target, -cp.multiplier)
        if jt in (JointType.BALL, JointType.HINGE, JointType.FIXED):
            res.point = (r_a, r_b)
        if jt is JointType.DISTANCE:
            pa, pb = x[a] + R[a] @ r_a, x[b] + R[b] @ r_b
            length = spec.length if spec.length is not None else float(np.linalg.norm(pa - pb))
            if not length > 1e-9:
                raise SpecError('length', 'the anchors coincide: a distance constraint needs '
                                          'a positive length')
            res.distance = (r_a, r_b, length)
        return res

    def _build(self) -> None:
        """Rebuild the flat row arrays and row numbering (not on the hot path)."""
        res = list(self._resolved.values())
        pts = [r for r in res if r.point is not None]
        dots = [(r, d) for r in res for d in r.dots]
        lines = [(r, ln) for r in res for ln in r.lines]
        dists = [r for r in res if r.distance is not None]
        angles = [(r, g) for r in res for g in r.angles]
        gens = [r for r in res if r.spec.type is JointType.GENERIC]

        # Built-in rows, one entry each: point block (x, y, z per point), dots, lines,
        # distances, angles.
        table = [(KIND_POINT, c, r.a, r.b, r.point[0], r.point[1], None, None, None, 0.0)
                 for r in pts for c in range(3)]
        table += [(KIND_DOT, 0, r.a, r.b, None, None, d[0], d[1], None, d[2]) for r, d in dots]
        table += [(KIND_LINE, 0, r.a, r.b, ln[0], ln[1], None, ln[2], None, ln[3])
                  for r, ln in lines]
        table += [(KIND_DISTANCE, 0, r.a, r.b, r.distance[0], r.distance[1], None, None, None,
                   r.distance[2]) for r in dists]
        table += [(KIND_ANGLE, 0, r.a, r.b, None, None, g[0], g[1], g[2], g[3])
                  for r, g in angles]
        # Flat row arrays for the kernels of .kernels.rows (and a compiled step).
        self.row_kind, self.row_comp, self.row_a, self.row_b, self.row_par = pack_rows(table)
        coupled = [r for r in res if r.coupled is not None]
        self.x_kind, self.x_comp, self.x_a, self.x_b, self.x_par = pack_rows(
            [(c[0], 0, c[1], c[2], *c[3:9]) for c in (r.coupled for r in coupled)])
        self.x_weight = np.array([r.coupled[9] for r in coupled], dtype=float)
        self.n_builtin_rows = len(table)
        self._gen = tuple(gens)
        # Row numbering: point, dot, line, distance and angle blocks, generic.
        rows: dict[str, list] = {r.spec.name: [] for r in res}
        start = 0
        for r in pts:
            rows[r.spec.name] += [start, start + 1, start + 2]
            start += 3
        for r, _ in dots:
            rows[r.spec.name].append(start)
            start += 1
        for r, _ in lines:
            rows[r.spec.name].append(start)
            start += 1
        for r in dists:
            rows[r.spec.name].append(start)
            start += 1
        for r, _ in angles:
            rows[r.spec.name].append(start)
            start += 1
        self._gen_start = start
        for r in gens:
            rows[r.spec.name] += list(range(start, start + r.n_rows))
            start += r.n_rows
        for r in res:
            r.rows = np.array(rows[r.spec.name], dtype=int)
        self.n_rows = start
        # A mimic constraint has one row: its coupling part adds to it.
        self.x_row = np.array([r.rows[0] for r in coupled], dtype=np.int64)
        # The drives' targets at the set's time, and their rates.
        self._drive_anchors()
        self.drive_targets_at(self.time)
        # Bodies that take part in any constraint (others need no constraint work).
        self.touched = np.unique(np.concatenate(
            [np.array([r.a, r.b], dtype=int) for r in res]
            + [np.array(r.coupled[1:3], dtype=int) for r in coupled]
            or [np.zeros(0, dtype=int)]))
        self.touched = self.touched[self.touched < len(self.bodies)]
        self._pattern()
        self.version = getattr(self, 'version', 0) + 1

    # -- evaluation (hot path: compiled kernels over the built-in rows) --------------------

    def _pattern(self) -> None:
        """
        Compute the fixed sparsity pattern of G and where its values come from.

        The pattern lists, per primitive block (points, dots, lines, distances,
        then each generic constraint, then the coupling parts), the entries on
        body a then those on body b, row by row, dropping the world's.
        ``_value_index`` maps each kept entry into the flat buffer of
        :meth:`geometry`: the built-in blocks ``Ga`` (m_builtin, 6) and ``Gb``
        (m_builtin, 6) raveled one after the other, then per generic constraint
        its (k, 6) blocks on a and on b, then the coupling parts' (e, 6) blocks
        on a and on b. A coupling part may share a body with its row's own
        part: :class:`JacobianStructure` sums such entries.
        """
        n = len(self.bodies)
        mb = self.n_builtin_rows
        six = np.arange(6)
        rows, cols, keep, src = [], [], [], []
        # Built-in blocks: runs of equal kind (the rows are ordered by kind).
        cuts = np.flatnonzero(np.diff(self.row_kind)) + 1
        blocks = [(r, self.row_a[r], self.row_b[r], 6 * r[:, None] + six,
                   6 * mb + 6 * r[:, None] + six)
                  for r in np.split(np.arange(mb), cuts) if len(r)]
        offset = 12 * mb
        for res in self._gen:
            r, k = res.rows, res.n_rows
            blocks.append((r, np.full(k, res.a), np.full(k, res.b),
                           offset + np.arange(6 * k), offset + 6 * k + np.arange(6 * k)))
            offset += 12 * k
        e = len(self.x_row)
        if e:
            # The coupling parts' blocks (weighted) on their rows, after the generic ones.
            x = np.arange(e)
            blocks.append((self.x_row, self.x_a, self.x_b, offset + 6 * x[:, None] + six,
                           offset + 6 * e + 6 * x[:, None] + six))
        for r, a, b, src_a, src_b in blocks:
            for body, origin in ((a, src_a), (b, src_b)):
                rows.append(np.repeat(r, 6))
                cols.append((6 * body[:, None] + six).ravel())
                keep.append(np.repeat(body < n, 6))
                src.append(origin.ravel())
        cat = (lambda x, dt: np.concatenate(x).astype(dt) if x else np.zeros(0, dtype=dt))
        self._keep = cat(keep, bool)
        self._rows = cat(rows, int)[self._keep]
        self._cols = cat(cols, int)[self._keep]
        self._value_index = cat(src, int)[self._keep]
        self._structure = JacobianStructure(self._rows, self._cols, self.n_rows, n)
        # Bodies of every row, generic ones included (the tree solve's graph).
        self.all_row_a = np.concatenate(
            [self.row_a] + [np.full(res.n_rows, res.a) for res in self._gen]).astype(np.int64)
        self.all_row_b = np.concatenate(
            [self.row_b] + [np.full(res.n_rows, res.b) for res in self._gen]).astype(np.int64)

    def geometry(self, pos: np.ndarray, quat: np.ndarray) -> 'Geometry':
        """
        Φ and G at a configuration of all bodies (velocity terms via ``rates``).

        Parameters
        ----------
        pos : ndarray, shape (n, 3)
            Centre-of-mass positions, world frame.
        quat : ndarray, shape (n, 4)
            Principal-frame orientations.

        """
        # Copies: the Geometry keeps the configuration for ``rates``.
        pos = np.array(pos, dtype=float, order='C')
        quat = np.array(quat, dtype=float, order='C')
        geo = Geometry(self, pos, quat)
        mb = self.n_builtin_rows
        phi = np.empty(self.n_rows)
        g = np.empty((2, mb, 6))
        if mb:
            rows_geometry(pos, quat, self.row_kind, self.row_comp, self.row_a, self.row_b,
                          self.row_par, phi[:mb], g[0], g[1])
        flat = g.ravel()
        if self._gen:
            x, R = geo.frames
            parts, start = [flat], mb
            for res in self._gen:
                phi_g, g_g, _ = self.generic_rows(res, x, R)
                phi[start:start + res.n_rows] = phi_g
                parts += [g_g[:, :6].ravel(), g_g[:, 6:].ravel()]
                geo.g_generic.append(g_g)
                start += res.n_rows
            flat = np.concatenate(parts)
        e = len(self.x_row)
        if e:
            x_phi, xg = np.empty(e), np.empty((2, e, 6))
            rows_geometry(pos, quat, self.x_kind, self.x_comp, self.x_a, self.x_b, self.x_par,
                          x_phi, xg[0], xg[1])
            np.add.at(phi, self.x_row, self.x_weight * x_phi)
            xg *= self.x_weight[None, :, None]
            geo.g_coupling = xg
            flat = np.concatenate([flat, xg.ravel()])
        geo.phi, geo.g_builtin = phi, g
        geo.jacobian = RowJacobian(self._structure, flat[self._value_index])
        return geo

    def evaluate(self, pos: np.ndarray, quat: np.ndarray, vel: np.ndarray,
                 omega: np.ndarray, need_gamma: bool = True) -> Evaluation:
        """
        Φ, G, Φ̇ and γ = Ġν at a state of all bodies.

        Parameters
        ----------
        pos, vel, omega : ndarray, shape (n, 3)
            Centre-of-mass position and velocity (world), Ω (principal).
        quat : ndarray, shape (n, 4)
            Principal-frame orientations.
        need_gamma : bool
            Skip γ when only Φ, G and Φ̇ are wanted (projections).

        """
        geo = self.geometry(pos, quat)
        phi_dot, gamma = geo.rates(vel, omega, need_gamma)
        return Evaluation(geo.phi, geo.jacobian, phi_dot, gamma)

    # -- generic constraints ---------------------------------------------------------------

    def generic_rows(self, res: ResolvedConstraint, x: np.ndarray, R: np.ndarray,
                     v: Optional[np.ndarray] = None, w: Optional[np.ndarray] = None,
                     need_gamma: bool = False, need_jacobian: bool = True) -> tuple:
        """
        Φ (k,), G (k, 12) in principal coordinates and γ (k,) of a generic constraint.

        Parameters
        ----------
        res : ResolvedConstraint
            One of :attr:`generic`.
        x : ndarray, shape (n + 1, 3)
            Centre-of-mass positions (m, world), the world's (zeros) last.
        R : ndarray, shape (n + 1, 3, 3)
            Principal-frame rotations, the world's (identity) last.
        v, w : ndarray, shape (n + 1, 3), optional
            Velocities (m/s) and angular velocities (rad/s), both world frame,
            the world's last; needed for γ.
        need_gamma : bool
            Compute γ (else returned as None).
        need_jacobian : bool
            False skips the finite-difference G (returned as None) when only γ
            is wanted and the user gave no Jacobian function.

        """
        spec = res.spec
        n = len(self.bodies)
        a, b = res.a, res.b
        V = [self.bodies.R_body_principal[i] if i < n else np.eye(3) for i in (a, b)]

        def phi_at(xa, Ra, xb, Rb) -> np.ndarray:
            # R are principal rotations: the user sees body-frame rotations R Vᵀ.
            try:
                out = np.asarray(spec.function(xa, Ra @ V[0].T, xb, Rb @ V[1].T), dtype=float)
            except SpecError:
                raise
            except Exception as exc:  # noqa: B902 - a user function may raise anything
                raise SpecError('function', f'raised {type(exc).__name__}: {exc}') from None
            if out.ndim != 1 or not len(out) or not np.all(np.isfinite(out)):
                raise SpecError('function', f'must return a non-empty 1-D array of finite '
                                            f'numbers, got {out!r}')
            return out

        xa, Ra, xb, Rb = x[a], R[a], x[b], R[b]
        phi = phi_at(xa, Ra, xb, Rb)
        if res.n_rows and len(phi) != res.n_rows:
            raise SpecError('function', f'returned {len(phi)} values, earlier {res.n_rows}')
        if spec.jacobian is not None:
            def jac_at(xa, Ra, xb, Rb) -> np.ndarray:
                g = np.asarray(spec.jacobian(xa, Ra @ V[0].T, xb, Rb @ V[1].T), dtype=float)
                if g.shape != (len(phi), 12) or not np.all(np.isfinite(g)):
                    raise SpecError('jacobian', f'must return finite numbers of shape '
                                                f'({len(phi)}, 12), got shape {g.shape}')
                g = g.copy()
                g[:, 3:6] = g[:, 3:6] @ V[0]    # δΘ_body = V δΘ_principal
                g[:, 9:12] = g[:, 9:12] @ V[1]
                return g
            G = jac_at(xa, Ra, xb, Rb)
        else:
            jac_at = None
            G = np.zeros((len(phi), 12)) if need_jacobian else None
            for blk, (i, xi, Ri) in enumerate(((a, xa, Ra), (b, xb, Rb))):
                if i >= n or not need_jacobian:
                    continue
                scale = max(1.0, float(np.linalg.norm(xi)))
                for j in range(3):
                    h = 1e-6 * scale
                    dx = np.zeros(3)
                    dx[j] = h
                    args_p = [xa, Ra, xb, Rb]
                    args_m = [xa, Ra, xb, Rb]
                    args_p[2 * blk], args_m[2 * blk] = xi + dx, xi - dx
                    G[:, 6 * blk + j] = (phi_at(*args_p) - phi_at(*args_m)) / (2 * h)
                    h = 1e-6
                    rot = so3.quat_to_matrix(so3.exp_quat(np.eye(3)[j] * h))
                    args_p = [xa, Ra, xb, Rb]
                    args_m = [xa, Ra, xb, Rb]
                    args_p[2 * blk + 1], args_m[2 * blk + 1] = Ri @ rot, Ri @ rot.T
                    G[:, 6 * blk + 3 + j] = (phi_at(*args_p) - phi_at(*args_m)) / (2 * h)
        if not need_gamma:
            return phi, G, None
        # γ = Ġν: derivative along the curve of zero acceleration
        # x(t) = x + t v, R(t) = R exp(t hat(Ω)).
        Om = [Ri.T @ wi for Ri, wi in ((Ra, w[a]), (Rb, w[b]))]

        def curve(t: float) -> tuple:
            return (xa + t * v[a], Ra @ so3.quat_to_matrix(so3.exp_quat(t * Om[0])),
                    xb + t * v[b], Rb @ so3.quat_to_matrix(so3.exp_quat(t * Om[1])))

        speed = max(1e-12, float(np.linalg.norm(np.concatenate([v[a], Om[0], v[b], Om[1]]))))
        nu = np.concatenate([v[a], Om[0], v[b], Om[1]])
        if jac_at is not None:
            h = 1e-5 / speed
            gam = (jac_at(*curve(h)) @ nu - jac_at(*curve(-h)) @ nu) / (2 * h)
        else:
            h = 1e-4 / speed
            gam = (phi_at(*curve(h)) - 2.0 * phi + phi_at(*curve(-h))) / h**2
        return phi, G, gam
