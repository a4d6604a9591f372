"""
Per-step cost of a few constrained scenes, for comparing two checkouts side by side.

Each scene exercises one path of the constraint solve: a pendulum (dense), the
four-bar (loop), hinge chains of 10 and 50 links (tree), and the 7-DOF test arm
without its fingers' mimic (tree; ``test/urdf/arm7.urdf``). Per scene: 200 steps
of warm-up, then the median of 7 repetitions of 300 ``Simulation.step`` calls, in
µs a step, printed as one JSON line.

To compare a change with its base, run this script on each checkout in turn,
several rounds interleaved (the machine's load moves absolute times; compare the
rounds side by side)::

    git worktree add /tmp/base <rev>
    for r in 1 2 3; do for c in /tmp/base .; do
        ./dev.sh python bench/step_cost.py $c; done; done

``CHECKOUT`` (default: this one) is put first on ``sys.path``, so its own
``rigid_body_sim`` is timed (its compiled kernels: the first run compiles them).
"""

from __future__ import annotations

import json
from pathlib import Path
import re
import sys
import tempfile
import time


def main(argv=None) -> int:
    """Time the scenes of the checkout given (default: this one) and print them."""
    argv = sys.argv[1:] if argv is None else argv
    checkout = Path(argv[0] if argv else Path(__file__).resolve().parent.parent).resolve()
    sys.path.insert(0, str(checkout))
    sys.path.insert(1, str(checkout / 'bench'))
    import numpy as np
    from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
    from rigid_body_sim.core.mechanisms import four_bar
    from rigid_body_sim.scene import scene_from_dict
    from constraints import hinge_chain  # noqa: I100 - the checkout's bench/constraints.py

    tmp = Path(tempfile.mkdtemp())

    def arm7():
        text = (checkout / 'test' / 'urdf' / 'arm7.urdf').read_text()
        path = tmp / 'arm7.urdf'
        path.write_text(re.sub(r'<mimic[^>]*/>', '', text))   # the fingers apart
        data = {'dt': 1e-3, 'robots': [{'urdf': str(path)}],
                'effects': {'gravity': {'g_world': [0.0, 0.0, -9.81]}}}
        return scene_from_dict(data, str(tmp / 'scene.yaml')).simulation

    def pendulum():
        bob = RigidBody('bob', 1.0, [1e-3] * 3, position_world=[0.5, 0.0, -0.5])
        return Simulation([bob], [Gravity()], 'lie_poisson2', 1e-3,
                          [Constraint('rod', 'ball', 'bob', None, anchor_world=[0.0, 0.0, 0.0])])

    scenes = {'pendulum (dense)': pendulum,
              'four-bar (loop)': lambda: four_bar('lie_poisson2', 1e-3),
              'chain 10': lambda: hinge_chain(10, 'lie_poisson2'),
              'chain 50 (tree)': lambda: hinge_chain(50, 'lie_poisson2'),
              'arm7 free fingers (tree)': arm7}
    out = {'checkout': str(checkout)}
    for name, build in scenes.items():
        sim = build()
        sim.step(200)
        reps = []
        for _ in range(7):
            t0 = time.perf_counter()
            sim.step(300)
            reps.append((time.perf_counter() - t0) / 300 * 1e6)
        out[name] = round(float(np.median(reps)), 2)
    print(json.dumps(out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
