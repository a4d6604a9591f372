"""
Compiled kernels for the built-in constraint rows (point, dot, line, distance, angle).

The built-in rows of a :class:`~.constraints.ConstraintSet` are described by
flat arrays, one entry per row, built once when the constraint set changes;
the kernels evaluate all rows in one call. They take only numpy arrays and
scalars, so a compiled integrator step can call them too, and they run
unchanged as plain Python under ``NUMBA_DISABLE_JIT=1``.

Row description (m built-in rows)
---------------------------------
``kind`` : int64 (m,)
    ``KIND_POINT`` (0), ``KIND_DOT`` (1), ``KIND_LINE`` (2),
    ``KIND_DISTANCE`` (3) or ``KIND_ANGLE`` (4).
``comp`` : int64 (m,)
    The component (0, 1, 2: x, y, z, world frame) of a point row; 0 otherwise.
``a``, ``b`` : int64 (m,)
    Body indices; ``b == n`` is the world (``x = 0``, ``R = I``, ``ν = 0``).
``par`` : float64 (m, ``PAR_WIDTH``)
    Principal-frame vectors and a scalar; unused entries are zero:

    ============  =========  =====================================================
    columns       name       used by
    ============  =========  =====================================================
    0:3           ``r_a``    point, line, distance: anchor lever arm in body a
    3:6           ``r_b``    point, line, distance: anchor lever arm in body b
    6:9           ``s``      dot, angle: unit vector in body a
    9:12          ``e``      dot, line, angle: unit vector in body b
    12:15         ``e2``     angle: a second unit vector in body b, ``⟂ e``
    15            scalar     dot: target ``c``; line: offset ``c``; distance: length
                             ``L``; angle: target ``c`` (rad)
    16            rate       ``ċ``, how fast the scalar moves (1/s; m/s or rad/s for
                             an exact velocity drive's line or angle row), else 0
    ============  =========  =====================================================

Rows, with anchors ``P = x + R r``, ``d = P_a − P_b``, ``u = R_a s``,
``ε = R_b e``, ``ε₂ = R_b e2``:

* point: ``Φ = d[comp]``;
* dot: ``Φ = ε · u − c``;
* line: ``Φ = ε · d − c`` (a slider's joint coordinate when it drives one);
* distance: ``Φ = |d| − L``;
* angle: ``Φ = wrap(θ − c)``, ``θ = atan2(ε₂ · u, ε · u)`` the rotation of ``u``
  about ``ε × ε₂`` (a hinge's joint angle), the difference taken in ``(−π, π]``:
  a driven hinge goes the shorter way to its target (``c`` may count turns).

A row whose scalar moves (``rate`` ``ċ``: an exact velocity drive's target
``c(t)``) has ``Φ̇ = G ν − ċ`` (and ``c̈ = 0``: ``γ`` is unchanged); the scalar
itself is the target at the time of the configuration, which the caller moves
(:func:`.constrained_step._targets_at` inside a step).

The Jacobian rows are with respect to ``(δx_com_world, δΘ_principal)`` of each
body (``δR = R hat(δΘ)``): ``Ga`` (m, 6) on body a, ``Gb`` (m, 6) on body b
(computed for the world too; the caller drops those entries). Rotations are
those of :func:`..rotation.quat_to_matrix` (quaternions ``(x, y, z, w)``,
principal frame to world).
"""

from __future__ import annotations

from numba import njit
import numpy as np

from .layout import PAR_E, PAR_E2, PAR_RA, PAR_RATE, PAR_RB, PAR_S, PAR_SCALAR, PAR_WIDTH
from .so3 import quat_matrix

KIND_POINT, KIND_DOT, KIND_LINE, KIND_DISTANCE, KIND_ANGLE = 0, 1, 2, 3, 4

# Guards the division by a distance row's current length (as the numpy version did).
_TINY = 1e-300


def pack_rows(rows: list) -> tuple:
    """
    Flat arrays of built-in rows (not on the hot path).

    Parameters
    ----------
    rows : list of tuple
        ``(kind, comp, a, b, r_a, r_b, s, e, e2, scalar)`` or ``(..., scalar, rate)``
        per row; vectors (3,) or None for zero; ``rate`` 0 when not given.

    Returns
    -------
    kind, comp, a, b : ndarray, shape (m,), int64
    par : ndarray, shape (m, PAR_WIDTH), float64

    """
    m = len(rows)
    kind = np.zeros(m, dtype=np.int64)
    comp = np.zeros(m, dtype=np.int64)
    a = np.zeros(m, dtype=np.int64)
    b = np.zeros(m, dtype=np.int64)
    par = np.zeros((m, PAR_WIDTH))
    for k, row in enumerate(rows):
        kd, c, ia, ib, r_a, r_b, s, e, e2, scalar = row[:10]
        kind[k], comp[k], a[k], b[k] = kd, c, ia, ib
        for col, vec in ((PAR_RA, r_a), (PAR_RB, r_b), (PAR_S, s), (PAR_E, e), (PAR_E2, e2)):
            if vec is not None:
                par[k, col:col + 3] = vec
        par[k, PAR_SCALAR] = scalar
        par[k, PAR_RATE] = row[10] if len(row) > 10 else 0.0
    return kind, comp, a, b, par


@njit(cache=True)
def frames(quat: np.ndarray, R: np.ndarray) -> None:
    """
    Fill the rotations of the n bodies and the world.

    Parameters
    ----------
    quat : ndarray, shape (n, 4)
        Principal-frame orientations ``(x, y, z, w)``.
    R : ndarray, shape (n + 1, 3, 3)
        Output: principal-to-world rotations, ``R[n] = I``.

    """
    n = quat.shape[0]
    for i in range(n):
        quat_matrix(quat[i], R[i])
    for j in range(3):
        for k in range(3):
            R[n, j, k] = 1.0 if j == k else 0.0


@njit(cache=True)
def _rot(R: np.ndarray, i: int, par: np.ndarray, k: int, col: int) -> tuple:
    """``R[i] @ par[k, col:col + 3]`` as a 3-tuple."""
    v0, v1, v2 = par[k, col], par[k, col + 1], par[k, col + 2]
    return (R[i, 0, 0] * v0 + R[i, 0, 1] * v1 + R[i, 0, 2] * v2,
            R[i, 1, 0] * v0 + R[i, 1, 1] * v1 + R[i, 1, 2] * v2,
            R[i, 2, 0] * v0 + R[i, 2, 1] * v1 + R[i, 2, 2] * v2)


@njit(cache=True)
def _rot_t(R: np.ndarray, i: int, v: tuple) -> tuple:
    """``R[i].T @ v`` as a 3-tuple."""
    return (R[i, 0, 0] * v[0] + R[i, 1, 0] * v[1] + R[i, 2, 0] * v[2],
            R[i, 0, 1] * v[0] + R[i, 1, 1] * v[1] + R[i, 2, 1] * v[2],
            R[i, 0, 2] * v[0] + R[i, 1, 2] * v[1] + R[i, 2, 2] * v[2])


@njit(cache=True)
def _vec(arr: np.ndarray, i: int) -> tuple:
    """Row ``arr[i]`` (3,) as a 3-tuple."""
    return (arr[i, 0], arr[i, 1], arr[i, 2])


@njit(cache=True)
def _body_vec(arr: np.ndarray, i: int) -> tuple:
    """Row ``arr[i]`` of an (n, 3) array of the bodies as a 3-tuple; zero for the world."""
    if i < arr.shape[0]:
        return (arr[i, 0], arr[i, 1], arr[i, 2])
    return (0.0, 0.0, 0.0)


@njit(cache=True)
def _cross(p: tuple, q: tuple) -> tuple:
    return (p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0])


@njit(cache=True)
def _dot(p: tuple, q: tuple) -> float:
    return p[0] * q[0] + p[1] * q[1] + p[2] * q[2]


@njit(cache=True)
def _add(p: tuple, q: tuple) -> tuple:
    return (p[0] + q[0], p[1] + q[1], p[2] + q[2])


@njit(cache=True)
def _sub(p: tuple, q: tuple) -> tuple:
    return (p[0] - q[0], p[1] - q[1], p[2] - q[2])


@njit(cache=True)
def _scale(s: float, p: tuple) -> tuple:
    return (s * p[0], s * p[1], s * p[2])


@njit(cache=True)
def _over(p: tuple, s: float) -> tuple:
    return (p[0] / s, p[1] / s, p[2] / s)


@njit(cache=True)
def _pick(p: tuple, c: int) -> float:
    """Component ``c`` (0, 1, 2) of a 3-tuple."""
    if c == 0:
        return p[0]
    if c == 1:
        return p[1]
    return p[2]


@njit(cache=True)
def _put(out: np.ndarray, k: int, lin: tuple, ang: tuple) -> None:
    """``out[k] = (lin, ang)``."""
    out[k, 0], out[k, 1], out[k, 2] = lin[0], lin[1], lin[2]
    out[k, 3], out[k, 4], out[k, 5] = ang[0], ang[1], ang[2]


@njit(cache=True)
def _angle_gradient(u: tuple, eps: tuple, eps2: tuple, x: float, y: float) -> tuple:
    """
    ``∂θ/∂ω_a`` (world), ``θ = atan2(y, x)``, ``x = ε · u``, ``y = ε₂ · u``.

    With ``δu = δω_a × u``: ``δx = δω_a · (u × ε)``, ``δy = δω_a · (u × ε₂)``, so
    ``g = u × (x ε₂ − y ε) / (x² + y²)``; ``∂θ/∂ω_b = −g`` (ε, ε₂ turn with b). For a
    hinge holding its axis, ``g`` is the axis ``ε × ε₂``.
    """
    r2 = max(x * x + y * y, _TINY)
    w = _sub(_scale(x, eps2), _scale(y, eps))
    return _over(_cross(u, w), r2)


@njit(cache=True)
def _angle_gamma(u: tuple, eps: tuple, eps2: tuple, w_a: tuple, w_b: tuple) -> float:
    """
    ``γ = ġ · (ω_a − ω_b)`` of an angle row, ``g`` of :func:`_angle_gradient`.

    Along ``u̇ = ω_a × u``, ``ε̇ = ω_b × ε`` (``Ṙ Ω = 0``, so this is all of ``Ġ ν``):
    ``g = u × w / r²`` with ``w = x ε₂ − y ε``, ``r² = x² + y²``, and
    ``ġ = (u̇ × w + u × ẇ) / r² − g ṙ² / r²``.
    """
    x, y = _dot(eps, u), _dot(eps2, u)
    r2 = max(x * x + y * y, _TINY)
    u_dot = _cross(w_a, u)
    e_dot, e2_dot = _cross(w_b, eps), _cross(w_b, eps2)
    x_dot = _dot(e_dot, u) + _dot(eps, u_dot)
    y_dot = _dot(e2_dot, u) + _dot(eps2, u_dot)
    w = _sub(_scale(x, eps2), _scale(y, eps))
    w_dot = _sub(_add(_scale(x_dot, eps2), _scale(x, e2_dot)),
                 _add(_scale(y_dot, eps), _scale(y, e_dot)))
    g = _over(_cross(u, w), r2)
    r2_dot = 2.0 * (x * x_dot + y * y_dot)
    g_dot = _sub(_over(_add(_cross(u_dot, w), _cross(u, w_dot)), r2), _scale(r2_dot / r2, g))
    return _dot(g_dot, _sub(w_a, w_b))


@njit(cache=True)
def rows_geometry(pos: np.ndarray, quat: np.ndarray, kind: np.ndarray, comp: np.ndarray,
                  a: np.ndarray, b: np.ndarray, par: np.ndarray, phi_out: np.ndarray,
                  Ga_out: np.ndarray, Gb_out: np.ndarray) -> None:
    """
    Φ and the Jacobian blocks of the built-in rows at a configuration.

    Parameters
    ----------
    pos : ndarray, shape (n, 3)
        Centre-of-mass positions, world frame.
    quat : ndarray, shape (n, 4)
        Principal-frame orientations ``(x, y, z, w)``.
    kind, comp, a, b : ndarray, shape (m,), int64
        The row description (see the module docstring).
    par : ndarray, shape (m, PAR_WIDTH)
        Row parameters (see the module docstring).
    phi_out : ndarray, shape (m,)
        Output: Φ.
    Ga_out, Gb_out : ndarray, shape (m, 6)
        Output: ``∂Φ/∂(δx, δΘ)`` of body a and of body b (also for the world).

    """
    R = np.empty((pos.shape[0] + 1, 3, 3))
    frames(quat, R)
    framed_geometry(pos, R, kind, comp, a, b, par, phi_out, Ga_out, Gb_out)


@njit(cache=True)
def framed_geometry(pos: np.ndarray, R: np.ndarray, kind: np.ndarray, comp: np.ndarray,
                    a: np.ndarray, b: np.ndarray, par: np.ndarray, phi_out: np.ndarray,
                    Ga_out: np.ndarray, Gb_out: np.ndarray) -> None:
    """
    :func:`rows_geometry` with the rotations ``R`` (n + 1, 3, 3) of :func:`frames` given.

    The compiled step keeps ``R`` in its workspace: no allocation per call.
    """
    zero = (0.0, 0.0, 0.0)
    for k in range(kind.shape[0]):
        i, j, kd = a[k], b[k], kind[k]
        if kd == KIND_DOT:
            u = _rot(R, i, par, k, PAR_S)
            eps = _rot(R, j, par, k, PAR_E)
            ue = _cross(u, eps)
            phi_out[k] = _dot(eps, u) - par[k, PAR_SCALAR]
            _put(Ga_out, k, zero, _rot_t(R, i, ue))
            _put(Gb_out, k, zero, _scale(-1.0, _rot_t(R, j, ue)))
            continue
        if kd == KIND_ANGLE:
            u = _rot(R, i, par, k, PAR_S)
            eps = _rot(R, j, par, k, PAR_E)
            eps2 = _rot(R, j, par, k, PAR_E2)
            x, y = _dot(eps, u), _dot(eps2, u)
            c = par[k, PAR_SCALAR]
            cc, sc = np.cos(c), np.sin(c)
            # θ − c in (−π, π]: (x, y) turned back by c.
            phi_out[k] = np.arctan2(y * cc - x * sc, x * cc + y * sc)
            g = _angle_gradient(u, eps, eps2, x, y)
            _put(Ga_out, k, zero, _rot_t(R, i, g))
            _put(Gb_out, k, zero, _scale(-1.0, _rot_t(R, j, g)))
            continue
        r_a = (par[k, PAR_RA], par[k, PAR_RA + 1], par[k, PAR_RA + 2])
        r_b = (par[k, PAR_RB], par[k, PAR_RB + 1], par[k, PAR_RB + 2])
        d = _sub(_add(_body_vec(pos, i), _rot(R, i, par, k, PAR_RA)),
                 _add(_body_vec(pos, j), _rot(R, j, par, k, PAR_RB)))
        if kd == KIND_POINT:
            c = comp[k]
            unit = (1.0 if c == 0 else 0.0, 1.0 if c == 1 else 0.0, 1.0 if c == 2 else 0.0)
            phi_out[k] = _pick(d, c)
            # Row c of -R hat(r) is r × (row c of R).
            _put(Ga_out, k, unit, _cross(r_a, (R[i, c, 0], R[i, c, 1], R[i, c, 2])))
            _put(Gb_out, k, _scale(-1.0, unit),
                 _scale(-1.0, _cross(r_b, (R[j, c, 0], R[j, c, 1], R[j, c, 2]))))
            continue
        if kd == KIND_LINE:
            nrm = _rot(R, j, par, k, PAR_E)
            phi_out[k] = _dot(nrm, d) - par[k, PAR_SCALAR]
        else:
            length = np.sqrt(_dot(d, d))
            nrm = _over(d, max(length, _TINY))
            phi_out[k] = length - par[k, PAR_SCALAR]
        ang_b = _scale(-1.0, _cross(r_b, _rot_t(R, j, nrm)))
        if kd == KIND_LINE:
            # The line direction turns with body b.
            ang_b = _add(ang_b, _rot_t(R, j, _cross(nrm, d)))
        _put(Ga_out, k, nrm, _cross(r_a, _rot_t(R, i, nrm)))
        _put(Gb_out, k, _scale(-1.0, nrm), ang_b)


@njit(cache=True)
def rows_rates(pos: np.ndarray, quat: np.ndarray, vel: np.ndarray, omega: np.ndarray,
               kind: np.ndarray, comp: np.ndarray, a: np.ndarray, b: np.ndarray,
               par: np.ndarray, Ga: np.ndarray, Gb: np.ndarray, need_gamma: bool,
               phi_dot_out: np.ndarray, gamma_out: np.ndarray) -> None:
    """
    ``Φ̇ = G ν − ċ`` and ``γ = Ġ ν`` of the built-in rows (``ċ``: the rows' ``rate``).

    Parameters
    ----------
    pos : ndarray, shape (n, 3)
        Centre-of-mass positions, world frame.
    quat : ndarray, shape (n, 4)
        Principal-frame orientations ``(x, y, z, w)``.
    vel : ndarray, shape (n, 3)
        Centre-of-mass velocities, world frame.
    omega : ndarray, shape (n, 3)
        Angular velocities Ω, principal frame.
    kind, comp, a, b : ndarray, shape (m,), int64
        The row description (see the module docstring).
    par : ndarray, shape (m, PAR_WIDTH)
        Row parameters (see the module docstring).
    Ga, Gb : ndarray, shape (m, 6)
        The Jacobian blocks of :func:`rows_geometry` at ``pos``, ``quat``.
    need_gamma : bool
        False: γ is set to zero.
    phi_dot_out : ndarray, shape (m,)
        Output: Φ̇ (``G ν`` less the rate of a moving target).
    gamma_out : ndarray, shape (m,)
        Output: γ, the velocity-product term of ``Φ̈ = G ν̇ + γ``.

    """
    n = pos.shape[0]
    R = np.empty((n + 1, 3, 3))
    frames(quat, R)
    framed_rates(pos, vel, omega, R, np.empty((n + 1, 3)), kind, comp, a, b, par, Ga, Gb,
                 need_gamma, phi_dot_out, gamma_out)


@njit(cache=True)
def framed_rates(pos: np.ndarray, vel: np.ndarray, omega: np.ndarray, R: np.ndarray,
                 w: np.ndarray, kind: np.ndarray, comp: np.ndarray, a: np.ndarray,
                 b: np.ndarray, par: np.ndarray, Ga: np.ndarray, Gb: np.ndarray,
                 need_gamma: bool, phi_dot_out: np.ndarray, gamma_out: np.ndarray) -> None:
    """
    :func:`rows_rates` with the rotations ``R`` (n + 1, 3, 3) of :func:`frames` given.

    ``w`` (n + 1, 3) is scratch (overwritten: the world-frame angular velocities).
    The compiled step keeps ``R`` and ``w`` in its workspace: no allocation per call.
    """
    n = pos.shape[0]
    # World-frame angular velocities ω = R Ω; the world's are zero.
    for i in range(n):
        for r in range(3):
            w[i, r] = (R[i, r, 0] * omega[i, 0] + R[i, r, 1] * omega[i, 1]
                       + R[i, r, 2] * omega[i, 2])
    for r in range(3):
        w[n, r] = 0.0
    for k in range(kind.shape[0]):
        i, j, kd = a[k], b[k], kind[k]
        rate = 0.0
        for c in range(3):
            rate += Ga[k, c] * vel[i, c] + Ga[k, 3 + c] * omega[i, c]
        if j < n:
            for c in range(3):
                rate += Gb[k, c] * vel[j, c] + Gb[k, 3 + c] * omega[j, c]
        phi_dot_out[k] = rate - par[k, PAR_RATE]
        if not need_gamma:
            gamma_out[k] = 0.0
            continue
        w_a, w_b = _vec(w, i), _vec(w, j)
        if kd == KIND_DOT:
            u = _rot(R, i, par, k, PAR_S)
            eps = _rot(R, j, par, k, PAR_E)
            wbe, wau = _cross(w_b, eps), _cross(w_a, u)
            gamma_out[k] = (_dot(u, _cross(w_b, wbe)) + 2.0 * _dot(wbe, wau)
                            + _dot(eps, _cross(w_a, wau)))
            continue
        if kd == KIND_ANGLE:
            gamma_out[k] = _angle_gamma(_rot(R, i, par, k, PAR_S), _rot(R, j, par, k, PAR_E),
                                        _rot(R, j, par, k, PAR_E2), w_a, w_b)
            continue
        lever_a = _rot(R, i, par, k, PAR_RA)
        lever_b = _rot(R, j, par, k, PAR_RB)
        wva, wvb = _cross(w_a, lever_a), _cross(w_b, lever_b)
        # Centripetal part of d̈: ω_a × (ω_a × R_a r_a) − ω_b × (ω_b × R_b r_b).
        centripetal = _sub(_cross(w_a, wva), _cross(w_b, wvb))
        if kd == KIND_POINT:
            gamma_out[k] = _pick(centripetal, comp[k])
            continue
        d = _sub(_add(_body_vec(pos, i), lever_a), _add(_body_vec(pos, j), lever_b))
        d_dot = _sub(_add(_body_vec(vel, i), wva), _add(_body_vec(vel, j), wvb))
        if kd == KIND_LINE:
            eps = _rot(R, j, par, k, PAR_E)
            wbe = _cross(w_b, eps)
            gamma_out[k] = (_dot(d, _cross(w_b, wbe)) + 2.0 * _dot(wbe, d_dot)
                            + _dot(eps, centripetal))
        else:
            length = np.sqrt(_dot(d, d))
            nrm = _over(d, max(length, _TINY))
            nd = _dot(nrm, d_dot)
            gamma_out[k] = (_dot(nrm, centripetal)
                            + (_dot(d_dot, d_dot) - nd * nd) / max(length, _TINY))
