"""
``sim_node`` with faults injected, for the tests only: ``python faulty_node.py --ros-args ...``.

The environment variable ``FAULTS`` lists ``module:Class.method`` targets under
``rigid_body_sim`` (comma separated). Once the node's loop runs (start-up goes as
usual), each target raises ``RuntimeError('injected fault in <target>')`` instead
of running, so a test can see what a request that fails inside the node gets
back (a reply, ``success: false``, the reason) and that it changed nothing.
"""

import importlib
import os
import sys

_ARMED = []   # non-empty once SimNode.run has started


def _raiser(name, original):
    def fault(self, *args, **kwargs):
        if _ARMED:
            raise RuntimeError(f'injected fault in {name}')
        return original(self, *args, **kwargs)
    return fault


def inject(spec: str) -> None:
    """Replace each target named in ``spec`` by a method that raises once armed."""
    from rigid_body_sim.ros import node
    for target in filter(None, spec.split(',')):
        module_name, _, attribute = target.partition(':')
        cls_name, _, method = attribute.partition('.')
        cls = getattr(importlib.import_module(f'rigid_body_sim.{module_name}'), cls_name)
        setattr(cls, method, _raiser(target, getattr(cls, method)))
    run = node.SimNode.run

    def armed_run(self):
        _ARMED.append(True)
        return run(self)
    node.SimNode.run = armed_run


if __name__ == '__main__':
    from rigid_body_sim.ros import entry

    def main(stop):
        inject(os.environ.get('FAULTS', ''))
        from rigid_body_sim.ros import node
        return node.main(stop=stop)
    sys.exit(entry.run('sim_node', main))
