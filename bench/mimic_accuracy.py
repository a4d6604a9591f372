"""
Mimic joints: accuracy against the joint-space model with the mimic joints eliminated.

Not a speed benchmark: the figures the README and the issue quote for mimic joints,
from the scenes of ``test/test_mimic_joints.py`` and its reference (the test suite's
``joint_space_reference``: ``M_r = Tᵀ M T``, ``h_r = Tᵀ h``, RNEA/CRBA, its own URDF
parser), so the numbers and the tests' bounds come from one place:

* two 2-link arms on the world whose second elbow, a slider, follows the first's
  angle (``q_f = 0.05 q_l + 0.02``: a row over four bodies), swinging under gravity
  for 0.4 s: the largest joint error at dt = 4e-3 and 2e-3 against DOP853 on the
  reduced model (rtol = atol = 1e-12), their ratio (2^order), and |Φ| of the mimic
  row beside the hinges' at the end;
* arm7's gripper (right finger mimics the left; 9 joints, a closure row of the loop
  solve) at random states and efforts: ``q̈`` against the reduced model, and the
  efforts read back against ``M q̈ + h`` (the generalized forces on each coordinate).

The tables go to stdout and to ``bench/out/mimic_accuracy.md``. Run:
``python bench/mimic_accuracy.py``.
"""

from __future__ import annotations

from pathlib import Path
import sys
import tempfile

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'test'))   # the tests' scenes

from joint_space_reference import JointSpaceModel, urdf_path  # noqa: E402
import numpy as np  # noqa: E402
from robot_helpers import joint_accelerations  # noqa: E402
from test_mimic_joints import (load, reduced_accelerations, reduced_reference,  # noqa: E402
                               two_arms)

OUT = Path(__file__).resolve().parent / 'out'
INTEGRATORS = ['symplectic_euler', 'lie_poisson2', 'lie_poisson4', 'rkmk4']


def convergence(tmp: Path) -> list:
    """Rows of the four-body mimic's convergence table, one per integrator."""
    text = two_arms(k=0.05, c=0.02, follower='prismatic')
    ref = JointSpaceModel.from_urdf(text)
    start = {'a_shoulder': 0.4, 'a_elbow': -0.6, 'b_shoulder': -0.3}
    rows = []
    for integrator in INTEGRATORS:
        errors = []
        for dt in (4e-3, 2e-3):
            sim = load(text, tmp, integrator=integrator, dt=dt, initial_positions=start)
            names, js0 = sim.joint_names(), sim.joint_state()
            if not errors:
                expected = reduced_reference(ref, names, js0.positions, js0.velocities, 0.4)
            sim.step(int(round(0.4 / dt)))
            errors.append(float(np.max(np.abs(sim.joint_state().positions - expected))))
        solver = sim.dynamics.solver
        phi = np.abs(solver.violation(sim.state))
        mimic = solver.constraints.rows_of('b_elbow_mimic')
        rows.append((integrator, errors[0], errors[1], errors[0] / errors[1],
                     float(phi[mimic].max()), float(np.delete(phi, mimic).max())))
    return rows


def gripper(seeds=(1, 2, 3)) -> tuple:
    """Largest relative q̈ and effort errors of arm7's gripper over ``seeds``."""
    ref = JointSpaceModel.from_urdf(open(urdf_path('arm7.urdf')).read())
    worst_qdd = worst_effort = 0.0
    for seed in seeds:
        rng = np.random.default_rng(seed)
        sim = load('arm7.urdf')
        names = sim.joint_names()
        q = ref.expand(np.concatenate([rng.uniform(-2.5, 2.5, 7), rng.uniform(0.0, 0.04, 1)]))
        qd = ref.mimic_matrix @ np.concatenate([rng.normal(size=7), 0.1 * rng.normal(size=1)])
        tau = rng.uniform(-5.0, 5.0, 9)
        leaders = [i for i, n in enumerate(names) if n != 'finger_joint2']
        sim.set_joint_state({names[i]: q[i] for i in leaders}, {names[i]: qd[i] for i in leaders})
        sim.set_joint_efforts(dict(zip(names, tau)))
        sim.step()
        js = sim.joint_state()
        expected = reduced_accelerations(ref, names, js.positions, js.velocities,
                                         tau - ref.damping * js.velocities)
        got = joint_accelerations(sim)
        worst_qdd = max(worst_qdd, np.max(np.abs(got - expected)) / np.max(np.abs(expected)))
        M, h = ref.mass_matrix(js.positions), ref.bias(js.positions, js.velocities)
        worst_effort = max(worst_effort,
                           np.max(np.abs(js.efforts - (M @ got + h))) / np.max(np.abs(M @ got)))
    return float(worst_qdd), float(worst_effort)


def main() -> int:
    """Print and write the tables."""
    with tempfile.TemporaryDirectory() as tmp:
        rows = convergence(Path(tmp))
    lines = ['| integrator | error, dt 4e-3 | error, dt 2e-3 | ratio | mimic \\|Φ\\| | '
             'hinges \\|Φ\\| |', '|---|---|---|---|---|---|']
    lines += [f'| {r[0]} | {r[1]:.2e} | {r[2]:.2e} | {r[3]:.1f} | {r[4]:.1e} | {r[5]:.1e} |'
              for r in rows]
    qdd, effort = gripper()
    lines += ['', f'arm7 gripper, 3 random states: max |q̈ − q̈_reduced| / max |q̈| = {qdd:.1e}; '
                  f'max |effort − (M q̈ + h)| / max |M q̈| = {effort:.1e}']
    text = '\n'.join(lines) + '\n'
    print(text, end='')
    OUT.mkdir(exist_ok=True)
    (OUT / 'mimic_accuracy.md').write_text(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
