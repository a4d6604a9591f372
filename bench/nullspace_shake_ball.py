"""
Issue 19, SHAKE: the general recursion against the anchor form on ball chains (accuracy).

:mod:`rigid_body_sim.core.kernels.nullspace_shake` eliminates a ball through its
anchors. This compares it, on SHAKE ball chains of 30 (``test/nullspace_scenes.py``:
``ShakeSystem``, drift 0.05, ``J_r`` the right Jacobians or ``I + 0.1 N(0, 1)`` on
alternate seeds; the test's seeds 400.. and more), with the general recursion written
in numpy from the same rows (``S_E``, ``S_S``, shifts and signs as ``shake_factor``
reads them): ``Ia = I^A − U_E D⁻¹ U_Sᵀ`` with ``D⁻¹`` explicit (the adjugate) or with
LU solves (``numpy.linalg``, partial pivoting), against the double-double reference.
Plain Python, no timing: ``NUMBA_DISABLE_JIT=1 python bench/nullspace_shake_ball.py``.
"""

from __future__ import annotations

from pathlib import Path
import sys

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / 'test')]
from nullspace_scenes import chain_parents, Mechanism, ShakeSystem  # noqa: E402, I100
from rigid_body_sim.core.kernels.nullspace_shake import (  # noqa: E402, I100
    shake_arrays, shake_factor, shake_solve)
from rigid_body_sim.core.kernels.nullspace_solve import (  # noqa: E402
    N_VECS, nullspace_structure, V_D, V_SIGN)


def shift(d):
    """Return ``X(d) = [[I, −[d]×], [0, I]]``."""
    X = np.eye(6)
    X[0:3, 3:6] = -np.array([[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]], [-d[1], d[0], 0.0]])
    return X


def adjugate_inverse(D):
    """Return ``D⁻¹`` (3 x 3) by the adjugate."""
    C = np.array([np.cross(D[1], D[2]), np.cross(D[2], D[0]), np.cross(D[0], D[1])])
    return C.T / (D[0] @ C[0])


def general_solve(mech, shake, nst, JS, JV, rhs, mode):
    """Solve a ball chain's SHAKE system by the general recursion (``mode``: adjugate, lu)."""
    n = mech.n
    IA = np.zeros((n, 6, 6))
    for i in range(n):
        IA[i, :3, :3] = np.eye(3) / mech.minv6[i, 0]
        IA[i, 3:, 3:] = (shake.RS[i] @ np.diag(1.0 / mech.minv6[i, 3:])
                         @ np.linalg.inv(shake.Jr[i]) @ shake.RE[i].T)
    j_child, j_parent, _, j_rows, _ = nst

    def d_inverse(D, b):
        return adjugate_inverse(D) @ b if mode == 'adjugate' else np.linalg.solve(D, b)

    factors = []
    for j, (c, p) in enumerate(zip(j_child, j_parent)):
        UE, US = IA[c] @ JS[j, :, 0:3], IA[c].T @ JS[j, :, 3:6]
        D = JS[j, :, 3:6].T @ UE
        factors.append((UE, US, D))
        if p >= 0:
            Ia = IA[c] - UE @ d_inverse(D, US.T)
            IA[p] += shift(JV[j, N_VECS + V_D]).T @ Ia @ shift(JV[j, V_D])
    out = np.empty(mech.m)
    P, Acc = np.zeros((n, 6)), np.zeros((n, 6))
    g, q0 = np.zeros((len(j_child), 6)), np.zeros((len(j_child), 3))
    for j, (c, p) in enumerate(zip(j_child, j_parent)):
        UE, US, D = factors[j]
        g[j, :3] = JV[j, V_SIGN] * rhs[j_rows[j, :3]]
        z = P[c] + IA[c] @ g[j]
        q0[j] = -d_inverse(D, JS[j, :, 3:6].T @ z)
        if p >= 0:
            P[p] += shift(JV[j, N_VECS + V_D]).T @ (z + UE @ q0[j])
    for j in range(len(j_child) - 1, -1, -1):
        c, p = j_child[j], j_parent[j]
        UE, US, D = factors[j]
        y = shift(JV[j, V_D]) @ Acc[p] if p >= 0 else np.zeros(6)
        Acc[c] = y + g[j] + JS[j, :, 0:3] @ (q0[j] - d_inverse(D, US.T @ y))
        out[j_rows[j, :3]] = JV[j, V_SIGN] * (IA[c] @ Acc[c] + P[c])[:3]
    return out


def main(seeds=12, n=30, n_rhs=4):
    """Print each seed's errors and the worst of each form."""
    worst = dict.fromkeys(('anchor', 'lu', 'adjugate'), 0.0)
    for seed in range(seeds):
        rng = np.random.default_rng(400 + seed)
        mech = Mechanism(rng, chain_parents(n), ['ball'] * n)
        shake = ShakeSystem(mech, rng, 0.05, ('right', 'random')[seed % 2])
        nst = nullspace_structure(mech.a, mech.b, mech.kind, mech.comp, mech.n)
        IA, JS, JU, JD, JV, work, P, Acc, JG, JQ = shake_arrays(n, n)
        shake_factor(*nst, shake.GaE, shake.GbE, shake.GaS, shake.GbS, shake.Jr, mech.minv6,
                     shake.RS, shake.RE, IA, JS, JU, JD, JV, work)
        rhs = rng.normal(size=(mech.m, n_rhs))
        ref, cond = shake.reference(rhs)
        line = f'seed {400 + seed}  cond(A) {cond:.1e}'
        for mode in worst:
            err = 0.0
            for q in range(n_rhs):
                col = np.ascontiguousarray(rhs[:, q])
                if mode == 'anchor':
                    lam = np.empty(mech.m)
                    shake_solve(*nst[:4], IA, JS, JU, JD, JV, P, Acc, JG, JQ, col, lam)
                else:
                    lam = general_solve(mech, shake, nst, JS, JV, col, mode)
                err = max(err, np.abs(lam - ref[:, q]).max() / np.abs(ref[:, q]).max())
            worst[mode] = max(worst[mode], err)
            line += f'  {mode} {err:.1e}'
        print(line, flush=True)
    print('worst: ' + '  '.join(f'{mode} {err:.1e}' for mode, err in worst.items()))


if __name__ == '__main__':
    main()
