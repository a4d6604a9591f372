"""
Joint coordinates of one-coordinate joints from the bodies' outputs, compiled.

``out`` (n, O_WIDTH) holds the poses and twists of the body frames
(:data:`.layout.OUTPUT`); ``joint`` (k, J_WIDTH) each joint (:data:`.layout.JOINT`).
The world is body index n: at the origin, unrotated, at rest. A rotary joint's
angle is the rotation of the child relative to the joint frame on the parent
about the axis, ``atan2(e2·R e1, e1·R e1)`` with ``R = R_jointᵀ R_child``; a
prismatic joint's slide is ``axis · R_jointᵀ (p_child − p_joint)``. Rates: the
axis (world) dotted with the relative angular velocity, or with the child
origin's velocity relative to the parent body's frame.
"""

from __future__ import annotations

import math

from numba import njit
import numpy as np

from .layout import (J_AXIS, J_CHILD, J_E1, J_E2, J_P_JP, J_PARENT, J_R_JP, J_ROTARY,
                     J_VELOCITY_LIMIT, J_WATCH_HIGH, J_WATCH_LOW, O_ANG_VEL_WORLD,
                     O_ORIGIN_VEL_WORLD, O_ORIGIN_WORLD, O_QUAT_BODY_WORLD)
from .so3 import quat_matrix

TWO_PI = 2.0 * math.pi


@njit(cache=True)
def _frame(out: np.ndarray, i: int, p: np.ndarray, R: np.ndarray, v: np.ndarray,
           w: np.ndarray) -> None:
    """Pose and twist of body i (the world when i == n) into p, R, v, w."""
    if i >= out.shape[0]:
        R[:, :] = 0.0
        for r in range(3):
            R[r, r] = 1.0
            p[r] = v[r] = w[r] = 0.0
        return
    quat_matrix(out[i, O_QUAT_BODY_WORLD:O_QUAT_BODY_WORLD + 4], R)
    for r in range(3):
        p[r] = out[i, O_ORIGIN_WORLD + r]
        v[r] = out[i, O_ORIGIN_VEL_WORLD + r]
        w[r] = out[i, O_ANG_VEL_WORLD + r]


@njit(cache=True)
def joint_coordinates(out: np.ndarray, joint: np.ndarray, unwrap: bool,
                      positions: np.ndarray, rates: np.ndarray) -> int:
    """
    Write each joint's coordinate and rate; return how many rates exceed their limit.

    With ``unwrap``, ``positions`` holds the previous (unwrapped) coordinates and
    each angle is moved by whole turns to the one nearest it.
    """
    pa, pb = np.empty(3), np.empty(3)
    va, vb = np.empty(3), np.empty(3)
    wa, wb = np.empty(3), np.empty(3)
    Ra, Rb = np.empty((3, 3)), np.empty((3, 3))
    Rj, pj, u = np.empty((3, 3)), np.empty(3), np.empty(3)
    over = 0
    for k in range(joint.shape[0]):
        row = joint[k]
        _frame(out, int(row[J_CHILD]), pa, Ra, va, wa)
        _frame(out, int(row[J_PARENT]), pb, Rb, vb, wb)
        for r in range(3):
            pj[r] = pb[r]
            for c in range(3):
                pj[r] += Rb[r, c] * row[J_P_JP + c]
                s = 0.0
                for m in range(3):
                    s += Rb[r, m] * row[J_R_JP + 3 * m + c]
                Rj[r, c] = s
        # The axis in the world, and the relative motion along or about it.
        rate = 0.0
        if row[J_ROTARY] > 0.0:
            # u = Ra e1 (world), then Rjᵀ u = R e1 with R = Rjᵀ Ra, along e1 and e2.
            ce, se = 0.0, 0.0
            for m in range(3):
                u[m] = Ra[m, 0] * row[J_E1] + Ra[m, 1] * row[J_E1 + 1] \
                    + Ra[m, 2] * row[J_E1 + 2]
            for c in range(3):
                x = Rj[0, c] * u[0] + Rj[1, c] * u[1] + Rj[2, c] * u[2]   # (Rjᵀ u)_c
                ce += row[J_E1 + c] * x
                se += row[J_E2 + c] * x
            q = math.atan2(se, ce)
            if unwrap:
                q += TWO_PI * np.round((positions[k] - q) / TWO_PI)
            for r in range(3):
                axis_w = Rj[r, 0] * row[J_AXIS] + Rj[r, 1] * row[J_AXIS + 1] \
                    + Rj[r, 2] * row[J_AXIS + 2]
                rate += axis_w * (wa[r] - wb[r])
        else:
            q = 0.0
            d0, d1, d2 = pa[0] - pb[0], pa[1] - pb[1], pa[2] - pb[2]
            # Child origin relative to the parent's frame: v_a − v_b − w_b × (p_a − p_b).
            g0 = va[0] - vb[0] - (wb[1] * d2 - wb[2] * d1)
            g1 = va[1] - vb[1] - (wb[2] * d0 - wb[0] * d2)
            g2 = va[2] - vb[2] - (wb[0] * d1 - wb[1] * d0)
            for r in range(3):
                axis_w = Rj[r, 0] * row[J_AXIS] + Rj[r, 1] * row[J_AXIS + 1] \
                    + Rj[r, 2] * row[J_AXIS + 2]
                q += axis_w * (pa[r] - pj[r])
                rate += axis_w * (g0 if r == 0 else g1 if r == 1 else g2)
        positions[k] = q
        rates[k] = rate
        if abs(rate) > row[J_VELOCITY_LIMIT]:
            over += 1
    return over


@njit(cache=True)
def joint_coordinates_within(out: np.ndarray, joint: np.ndarray, previous: np.ndarray,
                             positions: np.ndarray, rates: np.ndarray) -> int:
    """
    :func:`joint_coordinates` unwrapped near ``previous``, if all lie in their windows.

    Writes ``positions`` and ``rates``; returns how many rates exceed their limit, or
    −1 when a coordinate lies outside its joint's ``[watch_low, watch_high]``
    (:data:`.layout.JOINT`). One comparison per joint: what a step whose limits are
    all inactive pays for watching them.
    """
    positions[:] = previous
    over = joint_coordinates(out, joint, True, positions, rates)
    for k in range(positions.shape[0]):
        x = positions[k]
        if x < joint[k, J_WATCH_LOW] or x > joint[k, J_WATCH_HIGH]:
            return -1
    return over


@njit(cache=True)
def any_beyond(q: np.ndarray, idx: np.ndarray, low: np.ndarray, high: np.ndarray) -> bool:
    """Tell whether some ``q[idx[j]]`` lies below ``low[j]`` or above ``high[j]``."""
    for j in range(idx.shape[0]):
        x = q[idx[j]]
        if x < low[j] or x > high[j]:
            return True
    return False
