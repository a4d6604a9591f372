"""
Rigid-body specifications and the state arrays of all bodies.

Frames
------
* **world**: the fixed inertial frame (REP 103: x forward, z up, SI units).
* **body**: the user's frame of a body (its origin and axes, as in a URDF
  link). The user gives the centre-of-mass offset ``com_body`` and the inertia
  tensor about the centre of mass in this frame.
* **principal**: origin at the centre of mass, axes along the principal axes of
  inertia, so the inertia tensor is ``diag(J)``. Internally every body lives in
  this frame (Euler's equations become element-wise); ``R_body_principal`` is a
  fixed rotation applied on input and output, as URDF's ``<inertial origin>``.

State (all bodies at once; ``n`` bodies)
----------------------------------------
``pos_com_world`` (n, 3), ``quat_principal_world`` (n, 4, scalar-last; maps
principal-frame coordinates to world), ``vel_com_world`` (n, 3), and
``ang_vel_principal`` (n, 3): the seed's body-frame angular velocity Ω, in the
principal frame. See :mod:`rigid_body_sim.core.rotation` for the quaternion
convention. The four are views of one buffer, ``State.y`` (13 n floats), which
is what a step copies and hands to its compiled kernel.

"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import numpy as np

from . import rotation as so3
from .errors import SpecError
from .kernels import free_step
from .kernels.layout import OUTPUT, STATE
from .validate import finite_array, positive_scalar, unit_quaternion

# Relative tolerances for properties of the inertia tensor given by a user in
# decimal text: asymmetry or a triangle-inequality deficit smaller than this
# fraction of the largest moment is rounding, not physics.
INERTIA_RTOL = 1e-9
# Principal moments equal to this relative tolerance make a body isotropic:
# its gyroscopic term Ω × JΩ is then zero and is never evaluated.
ISOTROPY_RTOL = 1e-12
# Masses (kg) and inertia entries (kg m²) must lie in [1/LIMIT, LIMIT]: far beyond
# any body (a 1 µm grain has about 1e-27 kg m²), and narrow enough that inverses,
# squares and the products of a step stay finite in double precision.
MAGNITUDE_LIMIT = 1e100


def _in_range(x: float, field_name: str, what: str) -> None:
    if not 1.0 / MAGNITUDE_LIMIT <= x <= MAGNITUDE_LIMIT:
        raise SpecError(field_name, f'{what} {x!r} is outside [{1.0 / MAGNITUDE_LIMIT:g}, '
                                    f'{MAGNITUDE_LIMIT:g}]: inverses and products would '
                                    f'overflow or lose all precision')


def inertia_matrix(value: Any, field_name: str = 'inertia') -> np.ndarray:
    """
    Return a (3, 3) inertia tensor from a (3, 3) matrix or 3 principal moments.

    Raises
    ------
    SpecError
        If the tensor is not finite, not symmetric, not positive definite, or
        violates the triangle inequality ``J_a + J_b >= J_c`` that every real
        mass distribution obeys.

    """
    arr = np.array(value, dtype=float) if _is_numeric(value) else None
    if arr is not None and arr.shape == (3,):
        mat = np.diag(finite_array(value, field_name, (3,)))
    else:
        mat = finite_array(value, field_name, (3, 3))
    scale = float(np.max(np.abs(mat)))
    if scale > MAGNITUDE_LIMIT:
        _in_range(scale, field_name, 'largest entry')
    asym = np.abs(mat - mat.T)
    if np.max(asym) > INERTIA_RTOL * scale:
        i, j = np.unravel_index(np.argmax(asym), asym.shape)
        raise SpecError(field_name, f'not symmetric: [{i}][{j}] = {mat[i, j]:.9g} but '
                                    f'[{j}][{i}] = {mat[j, i]:.9g}')
    mat = 0.5 * (mat + mat.T)
    moments = np.linalg.eigvalsh(mat)
    if not moments[0] > 0.0:
        raise SpecError(field_name, f'not positive definite: principal moments {moments.tolist()}')
    _in_range(float(moments[0]), field_name, 'smallest principal moment')
    if moments[0] + moments[1] < moments[2] * (1.0 - INERTIA_RTOL):
        raise SpecError(field_name, f'violates the triangle inequality: principal moments '
                                    f'{moments.tolist()} have J1 + J2 < J3, which no mass '
                                    f'distribution has')
    return mat


def _mass(value: Any) -> float:
    mass = positive_scalar(value, 'mass')
    _in_range(mass, 'mass', 'mass')
    return mass


def _is_numeric(value: Any) -> bool:
    try:
        np.array(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def principal_axes(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Principal moments (ascending) and axes of a symmetric positive-definite tensor.

    Parameters
    ----------
    inertia : ndarray, shape (3, 3) or (n, 3, 3)
        Symmetric positive-definite inertia tensor (or a stack of them).

    Returns
    -------
    moments : ndarray, shape (3,)
    R_body_principal : ndarray, shape (3, 3)
        Proper rotation (det +1) whose columns are the principal axes in the
        body frame, so ``inertia == R diag(moments) Rᵀ``.

    """
    moments, axes = np.linalg.eigh(inertia)
    flip = np.linalg.det(axes) < 0.0   # (a stack of tensors (n, 3, 3) too)
    axes[..., 2] *= np.where(flip, -1.0, 1.0)[..., None]
    return moments, axes


def top_axes(moments: np.ndarray) -> np.ndarray:
    """
    Return the distinct principal axis of each symmetric top, −1 for the other bodies.

    A body is a symmetric top (a rod, a disc, a cylinder) when it is not isotropic
    and two of its principal moments agree to ``ISOTROPY_RTOL`` of the largest, the
    tolerance that already makes three equal moments isotropic: an inertia given
    with two equal moments comes out of :func:`principal_axes` equal to about
    1e-16 (the eigensolver's rounding), and the drift's exact top flow then uses
    their mean, the exact flow of a body whose moments differ from the given ones
    by less than 1e-12 relative (the isotropic path's approximation too).

    Parameters
    ----------
    moments : ndarray, shape (n, 3)
        Principal moments.

    Returns
    -------
    ndarray of int, shape (n,)
        The axis (0, 1, 2) whose moment differs from the other two's, or −1.

    """
    moments = np.asarray(moments, dtype=float).reshape(-1, 3)
    high = moments.max(axis=1)
    tol = ISOTROPY_RTOL * high
    # gaps[:, a]: the other two moments' difference (the smallest: the first of equals)
    gaps = np.abs(moments[:, [1, 2, 0]] - moments[:, [2, 0, 1]])
    axis = np.argmin(gaps, axis=1)
    top = (high - moments.min(axis=1) > tol) & (gaps[np.arange(len(moments)), axis] <= tol)
    return np.where(top, axis, -1)   # (isotropic, or no two moments equal: −1)


@dataclass(frozen=True)
class RigidBody:
    """
    One rigid body as a user describes it (validated on construction).

    Parameters
    ----------
    name : str
        Unique, non-empty.
    mass : float
        kg, > 0.
    inertia : array_like, shape (3, 3) or (3,)
        kg m², about the centre of mass, axes of the body frame; 3 values are
        the diagonal.
    com_body : array_like, shape (3,)
        m, centre of mass in the body frame (offset from the body origin).
    position_world : array_like, shape (3,)
        m, initial position of the body origin.
    orientation_xyzw : array_like, shape (4,)
        Initial orientation of the body frame in the world (unit quaternion).
    linear_velocity_world : array_like, shape (3,)
        m/s, initial velocity of the body origin, world frame.
    angular_velocity_body : array_like, shape (3,)
        rad/s, initial angular velocity in the body frame.

    """

    name: str
    mass: float
    inertia: Any
    com_body: Any = (0.0, 0.0, 0.0)
    position_world: Any = (0.0, 0.0, 0.0)
    orientation_xyzw: Any = (0.0, 0.0, 0.0, 1.0)
    linear_velocity_world: Any = (0.0, 0.0, 0.0)
    angular_velocity_body: Any = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SpecError('name', f'must be a non-empty string, got {self.name!r}')
        conv = {
            'mass': _mass(self.mass),
            'inertia': inertia_matrix(self.inertia, 'inertia'),
            'com_body': finite_array(self.com_body, 'com_body', (3,)),
            'position_world': finite_array(self.position_world, 'position_world', (3,)),
            'orientation_xyzw': unit_quaternion(self.orientation_xyzw, 'orientation_xyzw'),
            'linear_velocity_world': finite_array(self.linear_velocity_world,
                                                  'linear_velocity_world', (3,)),
            'angular_velocity_body': finite_array(self.angular_velocity_body,
                                                  'angular_velocity_body', (3,)),
        }
        for key, value in conv.items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, key, value)


class _Outputs:
    """
    The outputs of one state (see :meth:`BodySet.outputs`) and what they belong to.

    They are kept with the state's buffer they were computed from: a step
    replaces a state's buffer, it does not modify it.
    """

    #: The column ranges of ``out`` (:data:`.kernels.layout.OUTPUT`), in its order.
    _PARTS = tuple(OUTPUT.ranges())
    NOTHING = (None, None)

    def __init__(self, n: int, quat_body_principal: np.ndarray, com_body: np.ndarray) -> None:
        self.out = np.empty((n, OUTPUT.width))
        # Per body, made when first read (a scene rebuilt around a spawn makes none).
        self._views: dict = {None: tuple(self.out[:, a:b] for a, b in self._PARTS)}
        self.frames = np.ascontiguousarray(np.hstack([quat_body_principal, com_body]))
        self.key: tuple = self.NOTHING
        #: Read since the last step: the next step's kernel computes them.
        self.wanted = False

    def views(self, body: Optional[int]) -> tuple:
        """Return the views of ``out``'s parts, of body index ``body`` (None: all)."""
        v = self._views.get(body)
        if v is None:
            v = self._views[body] = tuple(self.out[body, a:b] for a, b in self._PARTS)
        return v

    def adopt(self, state: 'State') -> None:
        """Record that ``out`` now holds the outputs of ``state``."""
        self.key = (state, state.y)


class State:
    """
    Dynamic state of all bodies at one time (see the module docstring for frames).

    The four arrays are contiguous views into one buffer ``y`` of ``13 n`` floats:
    positions, quaternions, velocities and Ω, body after body within each. A
    step copies one array and hands one to its kernel instead of four (a compiled
    call costs about 65 ns per array argument, a copy 0.15 µs). A step replaces
    a state's buffer and never modifies it; assigning an array to one of the
    four attributes gives the state a new buffer too, so that caches kept for
    ``y`` (the outputs, the last kick) see the change.

    Parameters
    ----------
    time : float
        s.
    pos_com_world, quat_principal_world, vel_com_world, ang_vel_principal : array_like
        Shapes (n, 3), (n, 4), (n, 3), (n, 3); copied into the buffer.

    """

    __slots__ = ('time', 'y', '_parts')

    def __init__(self, time: float, pos_com_world: Any, quat_principal_world: Any,
                 vel_com_world: Any, ang_vel_principal: Any) -> None:
        parts = (pos_com_world, quat_principal_world, vel_com_world, ang_vel_principal)
        n = len(pos_com_world)
        for name, part, width in zip(self._NAMES, parts, self._WIDTHS):
            if np.shape(part) != (n, width):
                raise ValueError(f'{name}: expected shape ({n}, {width}), got {np.shape(part)}')
        self.time = time
        self.y = np.concatenate([np.asarray(p, dtype=float).reshape(-1) for p in parts])
        self._parts: Optional[tuple] = None

    _NAMES = ('pos_com_world', 'quat_principal_world', 'vel_com_world', 'ang_vel_principal')
    _WIDTHS = (3, 4, 3, 3)

    @classmethod
    def of(cls, time: float, y: np.ndarray) -> 'State':
        """Return the state at ``time`` whose buffer is ``y`` (not copied)."""
        s = cls.__new__(cls)
        s.time, s.y, s._parts = time, y, None
        return s

    @property
    def parts(self) -> tuple:
        """``(pos_com_world, quat_principal_world, vel_com_world, ang_vel_principal)``."""
        p = self._parts
        if p is None:
            y = self.y
            n = len(y) // STATE.width
            p = self._parts = tuple(y[k * n:end * n].reshape(n, end - k)
                                    for k, end in STATE.ranges())
        return p

    def _replaced(self, k: int, value: Any) -> None:
        parts = list(self.parts)
        parts[k] = value
        fresh = State(self.time, *parts)
        self.y, self._parts = fresh.y, None

    pos_com_world = property(lambda self: self.parts[0],
                             lambda self, v: self._replaced(0, v),
                             doc='Centre-of-mass positions (n, 3), world frame (m).')
    quat_principal_world = property(lambda self: self.parts[1],
                                    lambda self, v: self._replaced(1, v),
                                    doc='Principal-frame orientations (n, 4, xyzw).')
    vel_com_world = property(lambda self: self.parts[2],
                             lambda self, v: self._replaced(2, v),
                             doc='Centre-of-mass velocities (n, 3), world frame (m/s).')
    ang_vel_principal = property(lambda self: self.parts[3],
                                 lambda self, v: self._replaced(3, v),
                                 doc='Angular velocities Ω (n, 3), principal frame (rad/s).')

    def copy(self) -> 'State':
        """Deep copy."""
        return State.of(self.time, self.y.copy())

    def __repr__(self) -> str:
        return (f'State(time={self.time!r}, pos_com_world={self.pos_com_world!r}, '
                f'quat_principal_world={self.quat_principal_world!r}, '
                f'vel_com_world={self.vel_com_world!r}, '
                f'ang_vel_principal={self.ang_vel_principal!r})')


@dataclass
class BodySet:
    """
    Constant properties of ``n`` bodies as arrays, in the principal frame.

    Attributes
    ----------
    names : list of str
    mass : ndarray, shape (n,)
    inv_mass : ndarray, shape (n,)
    moments : ndarray, shape (n, 3)
        Principal moments J.
    R_body_principal : ndarray, shape (n, 3, 3)
    quat_body_principal : ndarray, shape (n, 4)
    com_body : ndarray, shape (n, 3)
    anisotropic : ndarray of int, shape (k,)
        Indices of bodies whose principal moments differ (gyroscopic term
        non-zero); isotropic bodies are skipped in every gyroscopic evaluation.

    """

    names: list[str]
    mass: np.ndarray
    inv_mass: np.ndarray
    moments: np.ndarray
    R_body_principal: np.ndarray
    quat_body_principal: np.ndarray
    com_body: np.ndarray
    anisotropic: np.ndarray
    index: dict[str, int] = field(default_factory=dict)
    _outputs: Any = field(default=None, repr=False, compare=False)
    _top: Any = field(default=None, repr=False, compare=False)

    @classmethod
    def from_bodies(cls, bodies: Sequence[RigidBody]) -> 'BodySet':
        """Build the arrays from validated :class:`RigidBody` specs."""
        if len(bodies) == 0:
            raise SpecError('bodies', 'a scene needs at least one body')
        index: dict[str, int] = {}
        for i, b in enumerate(bodies):
            if not isinstance(b, RigidBody):
                raise SpecError(f'bodies[{i}]', f'expected a RigidBody, got {type(b).__name__}')
            if b.name in index:
                raise SpecError(f'bodies[{i}].name', f'duplicate body name {b.name!r}')
            index[b.name] = i
        # (one batched eigendecomposition: a rebuild around a spawn redoes every body's)
        moments, axes = principal_axes(np.array([b.inertia for b in bodies]))
        mass = np.array([b.mass for b in bodies])
        spread = moments.max(axis=1) - moments.min(axis=1)
        aniso = np.flatnonzero(spread > ISOTROPY_RTOL * moments.max(axis=1))
        return cls(names=[b.name for b in bodies], mass=mass, inv_mass=1.0 / mass,
                   moments=moments, R_body_principal=axes,
                   quat_body_principal=so3.matrix_to_quat(axes),
                   com_body=np.array([b.com_body for b in bodies]), anisotropic=aniso,
                   index=index)

    def __len__(self) -> int:
        """Return the number of bodies."""
        return len(self.names)

    def top_axes(self) -> np.ndarray:
        """
        Return :func:`top_axes` of ``moments`` (read only), kept while they are the same.

        The kernel model is rebuilt whenever a wrench changes, a contact step's
        forces up to tens of times a step; the axes cost 30 µs of numpy there each
        time (a quadruped), the key of the moments' bytes under 1 µs.
        """
        key = self.moments.tobytes()
        if self._top is None or self._top[0] != key:
            top = top_axes(self.moments)
            top.flags.writeable = False
            self._top = (key, top)
        return self._top[1]

    def lookup(self, name: str, field_name: str = 'body') -> int:
        """Index of the body called ``name``; SpecError naming ``field_name`` if unknown."""
        try:
            return self.index[name]
        except (KeyError, TypeError):
            raise SpecError(field_name, f'unknown body {name!r}; known bodies: '
                                        f'{sorted(self.index)}') from None

    def initial_state(self, bodies: Sequence[RigidBody]) -> State:
        """State at t = 0 from the user-frame initial conditions of ``bodies``."""
        q_wb = np.array([b.orientation_xyzw for b in bodies])
        R_wb = so3.quat_to_matrix(q_wb)
        w_world = np.einsum('nij,nj->ni', R_wb,
                            np.array([b.angular_velocity_body for b in bodies]))
        return self.state_from_origins(0.0, np.array([b.position_world for b in bodies]), q_wb,
                                       np.array([b.linear_velocity_world for b in bodies]),
                                       w_world)

    def state_from_origins(self, time: float, pos_origin_world: np.ndarray,
                           quat_body_world: np.ndarray, vel_origin_world: np.ndarray,
                           ang_vel_world: np.ndarray) -> State:
        """
        State of the body frames' poses and twists (the inverse of :meth:`outputs`).

        Parameters
        ----------
        time : float
            s, the state's time.
        pos_origin_world : ndarray, shape (n, 3)
            m, each body origin.
        quat_body_world : ndarray, shape (n, 4)
            Body-frame orientations, xyzw.
        vel_origin_world, ang_vel_world : ndarray, shape (n, 3)
            m/s and rad/s, world frame: of each body origin, and angular.

        """
        q_wb = so3.quat_normalize(np.asarray(quat_body_world, dtype=float))
        R_wb = so3.quat_to_matrix(q_wb)
        com_world_offset = np.einsum('nij,nj->ni', R_wb, self.com_body)
        w_body = np.einsum('nji,nj->ni', R_wb, ang_vel_world)
        return State(
            time,
            pos_com_world=pos_origin_world + com_world_offset,
            quat_principal_world=so3.quat_normalize(
                so3.quat_multiply(q_wb, self.quat_body_principal)),
            vel_com_world=vel_origin_world + so3.cross(ang_vel_world, com_world_offset),
            ang_vel_principal=np.einsum('nji,nj->ni', self.R_body_principal, w_body),
        )

    # -- outputs in the user's body frame -------------------------------------------------

    def outputs(self, state: State, body: Optional[int] = None) -> tuple:
        """
        Poses and twists in the user's body frames; see ``kernels.free_step.outputs``.

        Returns views (into one (n, 19) array) of the body-origin positions,
        orientations (xyzw), world origin velocities, world angular velocities,
        body-frame origin velocities and body-frame angular velocities: of every
        body, or of body index ``body`` alone. Computed by one compiled call and
        kept for the state it was computed for (a node reads pose and twist after
        every step); read-only to callers, who copy what they keep.
        """
        c = self._outputs or self._new_outputs()
        c.wanted = True
        k = c.key
        if not (k[0] is state and k[1] is state.y):
            free_step.state_outputs(state.y, c.frames, c.out)
            c.adopt(state)
        return c.views(body)

    def want_outputs(self) -> bool:
        """
        Tell whether a step's kernel computes the outputs of the new state.

        When the outputs of the state a step starts from were read (a node, a
        controller's loop), the step's kernel computes those of the new state too,
        into ``outputs_cache.out`` (n, 19), and the caller keeps them with
        ``outputs_cache.adopt(new_state)``; otherwise they are computed at the
        read (a node that steps ten times between publishes).
        """
        c = self._outputs or self._new_outputs()
        if not c.wanted:
            return False
        c.wanted = False
        c.key = _Outputs.NOTHING   # the kernel overwrites them
        return True

    def _new_outputs(self) -> '_Outputs':
        self._outputs = _Outputs(len(self), self.quat_body_principal, self.com_body)
        return self._outputs

    @property
    def outputs_cache(self) -> '_Outputs':
        """
        Return the outputs kept for one state: ``out`` (n, 19), see :meth:`outputs`.

        ``frames`` (n, 7) is the principal frame in the body frame (xyzw), then
        the centre of mass in the body frame: what the kernels compute them from.
        """
        return self._outputs or self._new_outputs()

    def pose_world(self, state: State) -> tuple[np.ndarray, np.ndarray]:
        """Body-origin positions (n, 3) and body-frame orientations (n, 4, xyzw) in world."""
        out = self.outputs(state)
        return out[0].copy(), out[1].copy()

    def twist_world(self, state: State) -> tuple[np.ndarray, np.ndarray]:
        """Velocity of each body origin (n, 3) and angular velocity (n, 3), world frame."""
        out = self.outputs(state)
        return out[2].copy(), out[3].copy()

    def twist_body(self, state: State) -> tuple[np.ndarray, np.ndarray]:
        """Origin velocity (n, 3) and angular velocity (n, 3), both in the body frame."""
        out = self.outputs(state)
        return out[4].copy(), out[5].copy()
