"""
SHAKE's Newton iterations per (sub)step against how far a body turns in one.

A top (0.5 kg, moments 2e-3, 2e-3, 3e-3 kg m², or isotropic 2e-3) spins at 10
or 100 rad/s on a ball joint under gravity; the up-front sub-steps are switched
off (``max_rotation = None``) so every step turns it by ``|Ω| dt``. Printed:
position iterations and SHAKE's factorizations per (sub)step (the cap is 6: a
step that reaches it ends unconverged), retries and last-resort fallbacks, for
the anisotropic top and an isotropic body. With the rotor's sensitivity in the
Newton matrix (see ``kernels.constrained_step._rotor_jacobians``) the first
iteration is Newton's, and its factorization serves the later ones while they
converge fast: 1 to 2 iterations up to 0.25 rad a step, 2.5 at 1 rad, one
factorization. Run: ``./dev.sh python bench/shake_convergence.py`` (``./dev.sh bench``
runs it too); writes ``bench/out/shake_convergence.md``.
"""

from pathlib import Path

import numpy as np
from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
from rigid_body_sim.core import rotation as so3

OUT = Path(__file__).resolve().parent / 'out'


def top(dt: float, rate: float, isotropic: bool) -> Simulation:
    tilt = so3.exp_quat(np.array([0.0, np.radians(20.0), 0.0]))
    axis = so3.rotate(tilt, np.array([0.0, 0.0, 1.0]))
    moments = [2e-3, 2e-3, 2e-3] if isotropic else [2e-3, 2e-3, 3e-3]
    body = RigidBody('top', 0.5, moments, position_world=0.1 * axis, orientation_xyzw=tilt,
                     angular_velocity_body=[0.0, 0.0, rate])
    sim = Simulation([body], [Gravity()], 'lie_poisson2', dt,
                     [Constraint('tip', 'ball', 'top', None, anchor_world=[0.0, 0.0, 0.0])])
    sim.integrator.max_rotation = None
    return sim


def main(argv=None) -> None:
    """Print the table and write it to ``bench/out/shake_convergence.md``."""
    header = ('| rotation per step | anisotropic top: SHAKE iterations, factorizations per '
              '(sub)step | isotropic body: the same |')
    lines = [header, '|---|---|---|']
    print(header)
    for rate, dt in ((10.0, 1e-3), (100.0, 1e-3), (100.0, 2.5e-3), (100.0, 1e-2)):
        cells = []
        for isotropic in (False, True):
            sim = top(dt, rate, isotropic)
            sim.step(200)
            counters, work = sim.dynamics.solver.counters, sim.work()
            steps = max(work['substeps'], work['steps'])
            # Per (sub)step the kicks and the velocity projection share one symmetric
            # factorization; the rest are SHAKE's.
            shake = (counters.factorizations - counters.velocity_projections) / steps
            cells.append(f'{counters.position_iterations / steps:.2f}, {shake:.2f} factorized '
                         f"(retries {work['retries']}, fallbacks "
                         f'{counters.projection_fallbacks})')
        lines.append(f'| {rate * dt:.3f} rad | ' + ' | '.join(cells) + ' |')
        print(lines[-1], flush=True)
    OUT.mkdir(exist_ok=True)
    (OUT / 'shake_convergence.md').write_text('\n'.join(lines) + '\n')
    print(f'wrote {OUT / "shake_convergence.md"}')


if __name__ == '__main__':
    main()
