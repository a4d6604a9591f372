"""
The tree solve in inertia form inside the step (issue 19): the rule, the multipliers, the fallback.

A tree-solved component whose joints are all built-in fixed, hinge, ball or slider
joints, each tree hanging from the world by one joint or free-floating, factorizes
its symmetric systems by eliminating each joint's freedoms
(:mod:`rigid_body_sim.core.kernels.nullspace_solve`,
whose premise tests are ``test_nullspace_premise.py``). Here the step's own use of
it is checked: which components take it, that the multipliers a step uses (read with
``ConstraintSolver.multipliers``, the step's own kernels) match an extended-precision
reference of the step's own system, and that a freedom with next to no inertia falls
back to the row-space solve, counted.

Bound. The premise measured the inertia-form solve within 5.5e-14 (relative, ∞-norm)
of the double-double reference over every joint type, and asserts 2e-13 (room for
another CPU's rounding); the same kernels solve here, so the same bound applies. The
row-space solve is checked by the same reference only through the triangle
inequality: its own error reaches 3e-12 on hinge chains and 2.6e-10 on chains of
fixed joints (the premise's figures), so agreement between the two is bounded by the
sum of both errors.
"""

from nullspace_scenes import Mechanism, unit
import numpy as np
import pytest
from rigid_body_sim.core import Constraint, Gravity, RigidBody, Simulation
from rigid_body_sim.core.kernels.constrained_step import CURRENT
from rigid_body_sim.core.kernels.layout import Solve, V_RHS
from rigid_body_sim.core.mechanisms import four_bar, ring
from test_mimic_joints import load as load_robot

EPS = np.finfo(float).eps
NEW_BOUND = 2e-13   # the premise's bound on the inertia-form solve (module docstring)
LINK = 0.1   # m


class StepBlocks(Mechanism):
    """The system a component's last solve had: its rows' blocks, inverse masses, rhs."""

    def __init__(self, views):   # noqa: D107 - not a random mechanism: the step's arrays
        jac = views['jac']
        self.a, self.b = views['row_a'].copy(), views['row_b'].copy()
        self.Ga, self.Gb = jac[CURRENT, 0].copy(), jac[CURRENT, 1].copy()
        self.minv6 = views['minv'].copy()
        self.n = self.minv6.shape[0]
        self.rhs = views['vm'][V_RHS].copy()
        self.own = views['row_owner'].copy()

    def dense_A(self):
        """Return ``A = G M⁻¹ Gᵀ`` and ``G`` (m, 6n), each row the sum of its parts."""
        n, m = self.n, self.rhs.size
        G = np.zeros((m, 6 * n + 6))
        for r in range(self.a.size):   # a part on one body adds to its row's entries there
            G[self.own[r], 6 * self.a[r]:6 * self.a[r] + 6] += self.Ga[r]
            G[self.own[r], 6 * self.b[r]:6 * self.b[r] + 6] += self.Gb[r]
        G = G[:, :6 * n]
        return G @ (self.minv6.ravel()[:, None] * G.T), G


def mechanism(seed, kinds, parents, spin_tip=None):
    """
    Build a random 3-D mechanism of rods on the joints ``kinds``, released under gravity.

    Body i hangs from ``parents[i]`` (-1: the world; -2: nothing) at a random anchor; masses 0.1 to
    10 kg; random joint axes; random angular velocities (projected onto the joints).
    ``spin_tip`` (kg m²): the last body is a thin rod of this axial moment on a hinge
    about its own axis, tilted in the world: a freedom with next to no inertia.
    """
    rng = np.random.default_rng(seed)
    n = len(parents)
    pos, anchors = np.zeros((n, 3)), np.zeros((n, 3))
    bodies, joints = [], []
    for i, p in enumerate(parents):
        base = np.zeros(3) if p < 0 else pos[p]
        direction = unit(rng.normal(size=3))
        anchors[i] = base + (0.5 * LINK * unit(rng.normal(size=3)) if p >= 0 else 0.0)
        pos[i] = anchors[i] + 0.5 * LINK * direction
        axis = unit(rng.normal(size=3))
        mass = 10.0 ** rng.uniform(-1.0, 1.0)
        moments = np.sort(mass * LINK ** 2 * 10.0 ** rng.uniform(-2.3, -1.1, size=3))
        moments[0] = max(moments[0], moments[2] - moments[1])   # the triangle inequality
        orientation = unit(rng.normal(size=4))
        if spin_tip is not None and i == n - 1:
            axis = direction
            moments = np.array([spin_tip, 1e-3, 1e-3])
            # The principal x axis along the rod: the rotation taking x to ``direction``.
            half = unit(np.array([1.0, 0.0, 0.0]) + direction)
            orientation = np.append(np.cross([1.0, 0.0, 0.0], half), half[0])
        bodies.append(RigidBody(f'b{i}', mass, moments, position_world=pos[i],
                                orientation_xyzw=orientation,
                                angular_velocity_body=rng.normal(size=3)))
        if p != -2:   # -2: a free-floating root, joined to nothing
            joints.append(Constraint(f'j{i}', kinds[i], f'b{i}', None if p < 0 else f'b{p}',
                                     anchor_world=anchors[i], axis_world=axis))
    return lambda method='lie_poisson2': Simulation(bodies, [Gravity()], method, 1e-3, joints)


def chain(n):
    """Parents of a chain of n bodies."""
    return [i - 1 for i in range(n)]


def tree(rng, n):
    """Parents of a random tree of n bodies (each a random earlier one)."""
    return [-1] + [int(rng.integers(0, i)) for i in range(1, n)]


def solve_at(build, inertia_form, steps=5):
    """After ``steps`` steps: λ of the next kick, the component's system and counters."""
    sim = build()
    solver = sim.dynamics.solver
    solver.inertia_form = inertia_form
    sim.step(steps)
    lam = solver.multipliers(sim.dynamics, sim.state)
    (comp,) = solver.kernel_setup().components
    return lam[comp.rows], StepBlocks(comp.views), comp, solver.counters


def relative(x, ref):
    """Return max |x − ref| / max |ref|."""
    return float(np.max(np.abs(x - ref)) / np.max(np.abs(ref)))


def with_rope(build, tip):
    """Return ``build`` with the tip's joint replaced by a distance row (a rope)."""
    def rebuilt(method='lie_poisson2'):
        sim = build(method)
        sim.remove_constraint(f'j{tip}')
        sim.add_constraint(Constraint('rope', 'distance', f'b{tip}', f'b{tip - 1}'))
        return sim
    return rebuilt


CASES = {
    'hinge chain 10': lambda: mechanism(1, ['hinge'] * 10, chain(10)),
    'mixed chain 12': lambda: mechanism(
        2, ['hinge', 'ball', 'slider', 'fixed'] * 3, chain(12)),
    'hinge tree 30': lambda: mechanism(3, ['hinge'] * 30, tree(np.random.default_rng(3), 30)),
    'mixed tree 20': lambda: mechanism(
        4, ['fixed', 'hinge', 'ball', 'slider', 'hinge'] * 4,
        tree(np.random.default_rng(4), 20)),
    'free mixed tree 16': lambda: mechanism(
        5, ['hinge', 'ball', 'slider', 'fixed'] * 4,
        [-2] + tree(np.random.default_rng(5), 16)[1:]),
    'mixed chain 12, a rope at the tip': lambda: with_rope(mechanism(
        6, ['hinge', 'ball', 'slider', 'fixed'] * 3, chain(12)), 11),
}


@pytest.mark.parametrize('case', sorted(CASES))
def test_the_step_solves_in_inertia_form_to_the_reference(case):
    build = CASES[case]()
    new, system, comp, counters = solve_at(build, True)
    assert comp.solve == Solve.TREE and comp.views['nullspace_child'].size > 0   # recognized
    assert counters.inertia_form_fallbacks == 0
    ref, cond = system.reference(system.rhs[:, None])
    ref = ref[:, 0]
    assert np.max(np.abs(ref)) > 0.0
    new_err = relative(new, ref)
    assert new_err < NEW_BOUND, (new_err, cond)   # bound: the module docstring
    # The row-space path on the same state: the same system (to the last bit: the
    # same steps before, whose kicks differ by rounding, move the state by rounding),
    # so its multipliers agree within both errors.
    old, old_system, old_comp, _ = solve_at(build, False)
    assert old_comp.views['nullspace_child'].size == 0
    old_ref = old_system.reference(old_system.rhs[:, None])[0][:, 0]
    old_err = relative(old, old_ref)
    # bound: |new − old| <= |new − ref| + |ref − old_ref| + |old_ref − old|, where
    # the two references are exact for states that differ by the rounding of the
    # steps before (propagated: their own difference is measured, not assumed).
    assert relative(new, old) <= new_err + old_err + relative(ref, old_ref) + 1e-15


@pytest.mark.parametrize('rank_rtol', [1e-12, 1e-300])
def test_a_freedom_without_inertia_is_solved_or_falls_back_counted(rank_rtol):
    # A rod on a hinge about its own axis with an axial moment of 1e-18 kg m² (1e-15 of
    # its others): the hinge's pivot D = nᵀ I^A n is ~1e-16 of its scale (measured).
    # With the default rank_rtol (1e-12) the factorization falls back to the row-space
    # solve, counted; with the test off (1e-300) the inertia form solves it, and to the
    # same bound as any other mechanism (D is the tip's own moment, exact to rounding:
    # nothing cancels in it, so the fallback is a safety net for D = 0, not a need).
    build = mechanism(5, ['hinge'] * 6, chain(6), spin_tip=1e-18)
    sim = build()
    solver = sim.dynamics.solver
    solver.rank_rtol = rank_rtol
    before = solver.counters.inertia_form_fallbacks
    sim.step(2)
    fell_back = solver.counters.inertia_form_fallbacks > before   # the steps' kicks
    lam = solver.multipliers(sim.dynamics, sim.state)
    (comp,) = solver.kernel_setup().components
    assert comp.views['nullspace_child'].size > 0   # recognized
    assert fell_back == (rank_rtol == 1e-12)
    system = StepBlocks(comp.views)
    ref, cond = system.reference(system.rhs[:, None])
    err = relative(lam[comp.rows], ref[:, 0])
    # bound: the row-space solve's normwise bound 2 cond(A) eps (cond measured here),
    # and for the inertia form the module docstring's
    assert err < (2.0 * cond * EPS if fell_back else NEW_BOUND), err


def test_the_rule_names_what_takes_the_row_space_solve():
    rng = np.random.default_rng(6)

    def setup(replace=None, parents=None, n=8):
        parents = chain(n) if parents is None else parents
        build = mechanism(int(rng.integers(1 << 30)), ['hinge'] * n, parents)
        sim = build()
        if replace is not None:   # the tip's hinge replaced by another constraint
            sim.remove_constraint('j7')
            sim.add_constraint(replace(sim))
        (comp,) = sim.dynamics.solver.kernel_setup().components
        return comp

    assert setup().views['nullspace_child'].size == 8
    # A distance row (the tip on a rope): in inertia form (the range-space step).
    comp = setup(lambda sim: Constraint('rope', 'distance', 'b7', 'b6'))
    assert comp.solve == Solve.TREE and comp.views['nullspace_child'].size == 8
    # A generic row (the same rope as a user's function): neither.

    def rope(sim):
        length = np.linalg.norm(sim.pose('b7')[0] - sim.pose('b6')[0])
        return Constraint('rope', 'generic', 'b7', 'b6',
                          function=lambda xa, Ra, xb, Rb: np.array([np.linalg.norm(xa - xb)
                                                                    - length]))

    comp = setup(rope)
    assert comp.solve == Solve.TREE and comp.views['nullspace_child'].size == 0
    # A free-floating tree (its root joined to nothing): in inertia form, the root a
    # joint-less entry (8 entries for 7 joints).
    comp = setup(parents=[-2] + list(range(7)))
    assert comp.solve == Solve.TREE and comp.views['nullspace_child'].size == 8


def kept_condition(system):
    """Return A's condition over its singular values above 1e-13 of the largest."""
    sv = np.linalg.svd(system.dense_A()[0], compute_uv=False)
    return sv[0] / sv[sv > 1e-13 * sv[0]][-1]


def test_a_loop_solves_its_spanning_forest_in_inertia_form():
    # arm7: its fingers' mimic row is the loop solve's one closure row, over a forest of
    # nine recognized joints: the full system has full rank, and the reference holds it.
    # (Its joint friction off: a joint held by its sticking row is not a recognized joint
    # of the inertia form yet, and the component would take the row-space path.)
    new, system, comp, counters = solve_at(lambda: load_robot('arm7.urdf', friction=False),
                                           True, steps=3)
    assert comp.solve == Solve.LOOP and comp.views['nullspace_child'].size == 9
    ref = system.reference(system.rhs[:, None])[0][:, 0]
    # bound: the module docstring's; the closure row's complement is formed from the
    # forest's solves (each within it) and solved densely (cond(A) eps relative, below)
    assert relative(new, ref) < NEW_BOUND + 2.0 * kept_condition(system) * EPS


@pytest.mark.parametrize('scene', ['four_bar', 'ring'])
def test_a_loop_with_redundant_rows_agrees_with_the_row_space_forest(scene):
    # A planar loop modelled in 3-D has redundant closure rows: the minimum-norm λ of a
    # truncated SVD of the closure complement, from either forest solve.
    build = {'four_bar': lambda: four_bar('lie_poisson2', 1e-3),
             'ring': lambda: ring(12, 'lie_poisson2')}[scene]
    new, system, comp, _ = solve_at(build, True, steps=3)
    assert comp.solve == Solve.LOOP and comp.views['nullspace_child'].size > 0
    old, *_ = solve_at(build, False, steps=3)
    # bound: both are backward stable for the kept part of A (redundant rows out), whose
    # condition is measured: normwise 2 cond eps each, and the same again for the states,
    # which the steps before moved by rounding
    assert relative(new, old) < 8.0 * kept_condition(system) * EPS
