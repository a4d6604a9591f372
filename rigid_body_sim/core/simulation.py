"""
The facade a user scripts: build a scene, step it, apply wrenches, read state, reset.

Example:
-------
>>> from rigid_body_sim.core import RigidBody, Simulation, Gravity
>>> sim = Simulation([RigidBody('ball', mass=1.0, inertia=[0.1, 0.1, 0.1])],
...                  effects=[Gravity((0.0, 0.0, -9.81))], integrator='lie_poisson2', dt=1e-3)
>>> sim.step(1000)
>>> position, orientation_xyzw = sim.pose('ball')
>>> round(float(position[2]), 6)   # -g t² / 2 at t = 1 s
-4.905

Inputs and outputs are in the user's body frame (origin and axes of each body
as given); the core works in principal frames internally (see
:mod:`.bodies`). Changes (wrenches, reset) take effect between steps.

"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
import math
from typing import Any, Optional, Sequence

import numpy as np

from . import rotation as so3
from .accuracy import AccuracyReport, DEFAULT_BUDGET, ErrorControl
from .bodies import BodySet, RigidBody, State
from .constraints import Constraint, ConstraintSet, JointType
from .contact_step import ContactRecord, ContactRows, ContactSteps, ContactWrenches
from .diagnostics import diagnose, Diagnostics
from .dynamics import Dynamics
from .effects import AppliedWrenches, Damping, Effect
from .errors import DivergenceError, InconsistentConstraintError, SpecError
from .integrators import integrator_class
from .joint_events import JointEvents
from .kernels import free_step
from .limits import (DriveEfforts, ENGAGED, JointFriction, JointLimits, limit_name,
                     restitution_of, SceneJoint, stick_name)
from .robots import (build_robot, CommandGroup, drive_name, Interface, Joint, JointDrives,
                     JointSpace, JointSpec, JointState, mimic_name, RobotSpec, rpy_matrix)
from .shapes import ALL_BITS, CollisionShape, ContactDetector, Contacts
from .solver import ConstraintSolver
from .validate import finite_scalar, positive_scalar


def _finite(s: State) -> bool:
    """Tell whether every number of a state is finite."""
    return free_step.all_finite(*s.parts)


def _non_finite_bodies(s: State) -> np.ndarray:
    return np.flatnonzero(~np.all([np.all(np.isfinite(a), axis=1) for a in s.parts], axis=0))


def _unbound_copy(effect: Effect) -> Effect:
    """Return a deep copy of an effect without the bodies it is bound to (bound anew)."""
    bodies = getattr(effect, 'bodies', None)
    return copy.deepcopy(effect, {} if bodies is None else {id(bodies): None})


def _moved(parts: tuple, index: Any, into: tuple) -> State:
    """
    Return ``into``'s state (its time, parts copied) with body ``k`` of ``parts`` at ``index[k]``.

    ``parts``: a state's four arrays in the old order; ``index[k]``, body ``k``'s row now
    (negative: gone). The rows carried are copied bit for bit.
    """
    time, into = into
    index = np.asarray(index, dtype=np.int64)
    old = np.flatnonzero(index >= 0)
    new = [p.copy() for p in into]
    for whole, part in zip(new, parts):
        whole[index[old]] = part[old]
    return State(time, *new)


@dataclass(frozen=True)
class Reaction:
    """
    Wrench a constraint exerts on one body (world frame).

    Attributes
    ----------
    force_world : ndarray, shape (3,)
        N.
    torque_com_world : ndarray, shape (3,)
        N m, about the body's centre of mass.
    torque_anchor_world : ndarray, shape (3,)
        N m, about the joint anchor on this body.
    anchor_world : ndarray, shape (3,)
        m, where the anchor on this body is now.

    """

    force_world: np.ndarray
    torque_com_world: np.ndarray
    torque_anchor_world: np.ndarray
    anchor_world: np.ndarray


class Simulation:
    """
    Rigid bodies, the effects that act on them, and a fixed-step integrator.

    Parameters
    ----------
    bodies : sequence of RigidBody
    effects : sequence of Effect
        Only these are evaluated (e.g. no gravity term unless Gravity is listed).
    integrator : str
        A name from :data:`rigid_body_sim.core.integrators.INTEGRATORS`.
    dt : float
        Step size (s), > 0.
    constraints : sequence of Constraint
        Added in order at t = 0 (anchors and axes given in the world frame
        refer to the initial poses); initial velocities that disagree with them
        are reconciled as by :meth:`add_constraint`.
    constraint_time_constant : float
        s: a violated constraint returns to Φ = 0 along ``exp(-t / this)``
        (see :mod:`.solver`).
    tolerance : float, optional
        The accuracy knob: each step of ``dt`` is taken in as many sub-steps as
        an error estimate says keep the local error per unit time below this
        (SI units; see :mod:`.accuracy`). None: every step is one integrator step.
    tolerance_budget : int
        Most sub-steps a step may take under the knob (a power of two).
    robots : sequence of RobotSpec
        Robots (links and joints, as parsed from URDF by :mod:`rigid_body_sim.scene`):
        their bodies and joints are added after ``bodies`` and ``constraints``
        (see :mod:`.robots` for the conversion), and their one-coordinate
        joints are read and commanded with :meth:`joint_state`,
        :meth:`set_joint_state`, :meth:`set_joint_efforts` and :meth:`command_joints`.
    command_groups : sequence of CommandGroup
        The robots' joints commanded by position or velocity (servos); the
        others take efforts.
    _converted : dict, optional
        Internal: robots already converted (a rebuild around a spawn passes its own).
    _plans : dict, optional
        Internal: the compiled steps' components already planned and packed, by content
        (:attr:`.ConstraintSolver.plans`; a rebuild around a spawn passes its own).

    """

    def __init__(self, bodies: Sequence[RigidBody], effects: Sequence[Effect] = (),
                 integrator: str = 'lie_poisson2', dt: float = 1e-3,
                 constraints: Sequence[Constraint] = (),
                 constraint_time_constant: float = 0.05, tolerance: Optional[float] = None,
                 tolerance_budget: int = DEFAULT_BUDGET,
                 robots: Sequence[RobotSpec] = (),
                 command_groups: Sequence[CommandGroup] = (),
                 scene_joints: Sequence[SceneJoint] = (),
                 shapes: Sequence[CollisionShape] = (), _converted: Optional[dict] = None,
                 _plans: Optional[dict] = None
                 ) -> None:
        self.dt = positive_scalar(dt, 'dt')
        #: What the scene was built of, for a spawn or a removal (:meth:`add_body`).
        self._built = {'bodies': list(bodies), 'effects': list(effects),
                       'shapes': list(shapes), 'constraints': list(constraints),
                       'robots': list(robots), 'command_groups': list(command_groups),
                       'scene_joints': list(scene_joints),
                       'constraint_time_constant': constraint_time_constant,
                       'tolerance_budget': tolerance_budget}
        #: What the scene was first built of (:meth:`reset_scene`).
        self._origin = {'bodies': list(bodies), 'effects': list(effects),
                        'constraints': list(constraints),
                        'constraint_time_constant': constraint_time_constant,
                        'tolerance_budget': tolerance_budget, 'robots': list(robots),
                        'command_groups': list(command_groups),
                        'scene_joints': list(scene_joints), 'shapes': list(shapes)}
        #: Each robot spec's conversion, ``{id(spec): (spec, RobotModel)}``: a rebuild
        #: around a spawn takes the robots already there from it (:meth:`_rebuilt`).
        self._converted: dict = {k: v for k, v in (_converted or {}).items()
                                 if any(v[0] is r for r in robots)}
        #: Bodies and robots added at run time (:meth:`add_body`, :meth:`add_robot`),
        #: in order.
        self._spawned: list = []
        self._spawned_robots: list = []
        bodies, constraints = list(bodies), list(constraints)
        self.robots = []
        taken = {b.name: 'a body of the scene' for b in bodies if isinstance(b, RigidBody)}
        for i, robot in enumerate(robots):
            if not isinstance(robot, RobotSpec):
                raise SpecError(f'robots[{i}]', f'expected a RobotSpec, got {robot!r}')
            try:
                model = self._convert(robot)
            except SpecError as exc:
                raise exc.within(f'robots[{i}]') from None
            for body in model.bodies:
                if body.name in taken:
                    raise SpecError(f'robots[{i}]', f'body {body.name!r} of robot '
                                                    f'{robot.name!r} has the name of '
                                                    f'{taken[body.name]}: give the robot a '
                                                    f"prefix (e.g. '{robot.name}_')")
                taken[body.name] = f'a link of robot {robot.name!r}'
            self.robots.append(model)
            bodies += model.bodies
            constraints += model.constraints
        self._switching: tuple = (None, 0, [])
        self._control = (None if tolerance is None
                         else ErrorControl(tolerance, tolerance_budget))
        self._specs = list(bodies)
        self.bodies = BodySet.from_bodies(self._specs)
        effects = list(effects)
        for i, effect in enumerate(effects):
            if not isinstance(effect, Effect):
                raise SpecError(f'effects[{i}]', f'expected an Effect, got {effect!r}')
            try:
                effect.bind(self.bodies)
            except SpecError as exc:
                raise exc.within(f'effects[{i}]') from None
        self._scene_joints = self._build_scene_joints(scene_joints, constraints)
        self.joints = JointSpace(self.bodies.names, self.robots,
                                 [joint for joint, _ in self._scene_joints])
        # Mimic joints: one row each, with the robots' joints (they must hold from the start).
        self._mimic_names = [mimic_name(self.joints.names[f]) for f, _, _, _ in self.joints.mimics]
        constraints += self.joints.mimic_constraints()
        self.drives: Optional[JointDrives] = None
        if len(self.joints) or command_groups:
            drives = JointDrives(self.joints, command_groups)
            drives.bind(self.bodies)
            self.drives = drives
            if len(drives.rows_of):
                effects.append(drives)   # only where a joint is damped or servoed
        shapes = list(shapes) + self._robot_shapes()
        #: Every collision shape of the scene and its robots (colliding or not).
        self.shapes: tuple = tuple(shapes)
        detector = self._contact_detector(shapes, constraints)
        contact_wrenches = None
        if detector is not None:
            contact_wrenches = ContactWrenches()
            contact_wrenches.bind(self.bodies)
            effects.append(contact_wrenches)
        self.dynamics = Dynamics(self.bodies, effects)
        self.integrator = integrator_class(integrator)(self.dynamics)
        self._initial_wrenches = [self._wrench_rows(e) for e in effects]
        self.dynamics.solver = ConstraintSolver(self.bodies, ConstraintSet(self.bodies),
                                                time_constant=constraint_time_constant,
                                                tally=self.dynamics.tally)
        self.dynamics.solver.dt = self.dt
        self.dynamics.solver.plans = dict(_plans or {})
        self._asked: list = []   # (robot spec, model) of robot_model's last questions
        self._initial_constraints = list(constraints)
        names = {c.name for c in constraints if isinstance(c, Constraint)}
        #: Joints held by driving constraints (command groups of mode 'exact').
        self._exact = (np.zeros(0, dtype=int) if self.drives is None
                       else np.flatnonzero(self.drives.exact))
        self._drive_names = [drive_name(self.joints.names[i]) for i in self._exact]
        for i, name in zip(self._exact, self._drive_names):
            if name in names:
                raise SpecError(f'command_groups.{self.drives.group_of[self.joints.names[i]]}',
                                f'the exact drive of joint {self.joints.names[i]!r} is the '
                                f'constraint {name!r}, but a constraint of that name exists')
        self.limits: Optional[JointLimits] = None
        self.friction: Optional[JointFriction] = None
        #: The effort limits of the exact drives (None: no exact drive is limited).
        self.drive_efforts: Optional[DriveEfforts] = None
        if len(self.joints):
            self.limits = self._joint_limits()
            self.friction = self._joint_friction()
            self.drive_efforts = self._drive_efforts()
        #: The joints' limits, friction, drives' effort limits and their events (None: none).
        self.events: Optional[JointEvents] = None
        if self.limits is not None or self.friction is not None \
                or self.drive_efforts is not None:
            self.events = JointEvents(self, self.limits, self.friction, self.drive_efforts)
            for name in sorted(self.events.reserved() & names):
                raise SpecError('constraints', f'{name!r} is the name of a row that holds a '
                                               f'joint on its limit or its friction: rename '
                                               f'the constraint')
        #: The contacts' steps (None: no shape collides with anything).
        self.contact: Optional[ContactSteps] = None
        if detector is not None:
            self.contact = ContactSteps(self, detector, contact_wrenches)
        self._tracking = len(self.joints) > 0
        self.reset()

    def _convert(self, robot: RobotSpec) -> Any:
        """Return ``build_robot(robot)``, from :attr:`_converted` if it was (a fresh copy)."""
        done = self._converted.get(id(robot))
        if done is None or done[0] is not robot:
            done = self._converted[id(robot)] = (robot, build_robot(robot))
        # (its notes are the simulation's to add to: a list of its own)
        return replace(done[1], notes=list(done[1].notes))

    def _joint_friction(self) -> Optional[JointFriction]:
        """Build the robots' joint Coulomb friction (None: none)."""
        js = self.joints
        force = np.array([j.spec.friction for j in js.joints]).reshape(len(js))
        for model in self.robots:
            if not model.spec.enforce_friction:
                force[[js.index[j.name] for j in model.joints if j.name in js.index]] = 0.0
        for joint, spec in self._scene_joints:   # (inf: locked, which a JointSpec cannot say)
            force[js.index[joint.name]] = spec.friction
        if self.drives is not None:
            force[self.drives.exact] = 0.0
        for f, _, _, _ in js.mimics:
            force[f] = 0.0
        friction = JointFriction(js, force)
        return friction if len(friction) else None

    def _build_scene_joints(self, specs: Sequence[SceneJoint], constraints: list) -> list:
        """
        Make the scene's hinges and sliders with limits or friction joints: ``[(Joint, spec)]``.

        The joint frame is the child's (``body_a``) frame as the scene starts, on the
        parent (``body_b``, or the world): the coordinate is 0 there.
        """
        by_name = {c.name: c for c in constraints if isinstance(c, Constraint)}
        bodies = {b.name: b for b in self._specs if isinstance(b, RigidBody)}
        taken = {j.name for m in self.robots for j in m.joints}
        out = []
        for k, spec in enumerate(specs):
            where = f'scene_joints[{k}]'
            if not isinstance(spec, SceneJoint):
                raise SpecError(where, f'expected a SceneJoint, got {spec!r}')
            c = by_name.get(spec.constraint)
            if c is None or c.type not in (JointType.HINGE, JointType.SLIDER):
                known = sorted(n for n, x in by_name.items()
                               if x.type in (JointType.HINGE, JointType.SLIDER))
                raise SpecError(f'{where}.constraint', f'no hinge or slider constraint named '
                                                       f'{spec.constraint!r}; hinges and '
                                                       f'sliders: {known}')
            if spec.constraint in taken:
                raise SpecError(f'{where}.constraint', f'{spec.constraint!r} is also the name '
                                                       f'of a robot joint or another scene '
                                                       f'joint')
            taken.add(spec.constraint)
            a, b = bodies[c.body_a], None if c.body_b is None else bodies[c.body_b]
            R_a = so3.quat_to_matrix(np.asarray(a.orientation_xyzw))
            p_a = np.asarray(a.position_world, dtype=float)
            if b is None:
                p, R = p_a.copy(), R_a
            else:
                R_b = so3.quat_to_matrix(np.asarray(b.orientation_xyzw))
                p, R = R_b.T @ (p_a - np.asarray(b.position_world)), R_b.T @ R_a
            axis = R_a.T @ np.asarray(c.axis_world)
            kind = 'revolute' if c.type is JointType.HINGE else 'prismatic'
            joint_spec = JointSpec(spec.constraint, kind, c.body_b or 'world', c.body_a,
                                   axis=axis, lower=spec.lower, upper=spec.upper)
            out.append((Joint(spec.constraint, joint_spec, c.body_b, c.body_a, (p, R),
                              joint_spec.axis), spec))
        return out

    def _drive_efforts(self) -> Optional[DriveEfforts]:
        """Build the effort limits of the exact drives (None: none is limited)."""
        js = self.joints
        if not len(self._exact):
            return None
        enforce = np.zeros(len(js), dtype=bool)
        for model in self.robots:
            enforce[[js.index[j.name] for j in model.joints if j.name in js.index]] = \
                model.spec.enforce_efforts
        limited = [int(i) for i in self._exact
                   if enforce[i] and np.isfinite(js.effort_limit[i])]
        if not limited:
            return None
        return DriveEfforts([drive_name(n) for n in js.names], np.array(limited, dtype=int),
                            js.effort_limit)

    def _joint_limits(self) -> Optional[JointLimits]:
        """Build the enforced joint limits of the robots (None: none); validate restitutions."""
        js = self.joints
        limited = np.zeros(len(js), dtype=bool)
        restitution = np.zeros(len(js))
        for r, model in enumerate(self.robots):
            own = [j for j in model.joints if j.name in js.index]
            urdf_names = [j.spec.name for j in own]
            values = restitution_of(model.spec.limit_restitution, urdf_names,
                                    f'robots[{r}].limit_restitution')
            for j, e in zip(own, values):
                i = js.index[j.name]
                limited[i] = model.spec.enforce_limits
                restitution[i] = e
        for joint, spec in self._scene_joints:
            i = js.index[joint.name]
            limited[i], restitution[i] = True, spec.restitution
        if self.drives is not None:
            limited &= ~self.drives.exact
        for f, _, _, _ in js.mimics:
            limited[f] = False
        limits = JointLimits(js, limited, restitution)
        return limits if len(limits) else None

    def _robot_shapes(self) -> list:
        """Return the robots' link collision shapes on their bodies (specs' ``collisions``)."""
        out = []
        for r, model in enumerate(self.robots):
            spec = model.spec
            # Without self collision the robot's shapes share a group bit of their own
            # that their mask leaves out: they meet every other shape, not each other.
            bit = 1 << (1 + r % 30)
            opts = spec.collision_options
            surface = {k: opts[k] for k in ('friction', 'restitution') if k in opts}
            bits = {k: opts[k] for k in ('group', 'mask') if k in opts}
            if not spec.self_collide:
                group, mask = bits.get('group', 0), bits.get('mask', ALL_BITS)
                if group & mask:
                    raise SpecError(f'robots.{spec.name}.collisions.mask',
                                    f'shares bits {group & mask} with the group {group}: the '
                                    f"robot's links would meet each other, and self_collide "
                                    f'is false')
                bits = {'group': group | bit, 'mask': mask & ~bit}
            count: dict = {}
            for link, kind, size, xyz, rpy in spec.collisions:
                k = count[link] = count.get(link, -1) + 1   # (the link's k-th <collision>)
                frame = model.links[link]
                if frame.body is None:
                    # A link fixed to the world (a fixed base) is the world: its shapes
                    # would meet its children at their joints. Named, not simulated.
                    model.notes.append(f'<collision> of link {spec.prefix + link!r} not '
                                       f'simulated (fixed to the world)')
                    continue
                R = frame.rotation @ rpy_matrix(rpy)
                where = f'robots.{spec.name}.links.{link}.collision'
                try:
                    if kind == 'box':
                        dims = {'size': tuple(size)}
                    elif kind == 'cylinder':
                        dims = {'radius': size[0], 'length': size[1]}
                    elif kind == 'sphere':
                        dims = {'radius': size[0]}
                    elif kind == 'mesh':   # (its file, its scale)
                        dims = {'mesh': size[0], 'scale': size[1]}
                    else:
                        raise SpecError('kind', f"expected 'box', 'cylinder', 'sphere' or "
                                                f"'mesh', got {kind!r}")
                    out.append(CollisionShape(
                        kind, frame.body, position_body=frame.position + frame.rotation @ xyz,
                        orientation_xyzw=so3.matrix_to_quat(R), name=f'{spec.prefix}{link}/'
                        f'collision{k}', **dims, **bits,
                        **{**surface, **opts.get('links', {}).get(link, {})}))
                except SpecError as exc:
                    raise exc.within(where) from None
        return out

    def _contact_detector(self, shapes: Sequence[CollisionShape],
                          constraints: list) -> Optional[ContactDetector]:
        """
        Return the detector of ``shapes`` (None: none collides).

        Bodies joined by a constraint (a joint) never collide with each other, as in
        MuJoCo and Gazebo; a body jointed to the world still meets the world's shapes,
        but one welded to it (a ``fixed`` constraint: a robot's fixed base) is part of
        the world and does not (as MuJoCo's bodies without joints).
        """
        shapes = list(shapes)
        for i, shape in enumerate(shapes):
            if not isinstance(shape, CollisionShape):
                raise SpecError(f'shapes[{i}]', f'expected a CollisionShape, got {shape!r}')
        if not any(s.collide for s in shapes):
            return None
        return ContactDetector(shapes, self.bodies.names, self._exclusions(constraints))

    @staticmethod
    def _exclusions(constraints: Sequence) -> list:
        """Return the body pairs that never collide: joined, or both welded to the world."""
        world = (None, 'world')
        joined = [c for c in constraints if isinstance(c, Constraint)]
        excluded = {tuple(sorted((c.body_a, c.body_b))) for c in joined
                    if c.body_b not in world and c.body_a not in world and c.body_a != c.body_b}
        # The bodies welded to the world, directly or through a chain of welds: static,
        # part of the world, they meet neither its shapes nor each other.
        welded: set = set()
        grew = True
        while grew:
            grew = False
            for c in joined:
                if c.type is not JointType.FIXED:
                    continue
                ends = {c.body_a, c.body_b}
                held = {e for e in ends if e in world or e in welded}
                for e in ends - held if held else ():
                    if e not in world:
                        welded.add(e)
                        grew = True
        static = sorted(welded)
        return sorted(excluded) + [(b, None) for b in static] + [
            (a, b) for i, a in enumerate(static) for b in static[i + 1:]]

    def _specs_now(self, without: Optional[str] = None) -> list:
        """Return the descriptions of the constraints present (but ``without``)."""
        cs = self.dynamics.solver.constraints
        return [cs.spec(name) for name in cs.names if name != without]

    # -- time stepping --------------------------------------------------------------------

    @property
    def time(self) -> float:
        """Return the simulation time in seconds."""
        return self.state.time

    @property
    def integrator_name(self) -> str:
        """Name of the integrator in use."""
        return self.integrator.name

    def step(self, n: int = 1) -> None:
        """Take ``n`` steps of size ``dt``."""
        if type(n) is not int and (isinstance(n, bool) or not isinstance(n, np.integer)) \
                or n < 0:
            raise SpecError('n', f'must be a non-negative integer, got {n!r}')
        dyn = self.dynamics
        dt = dyn.solver.dt = self.dt
        # The effects that switch between steps (time-dependent ones: wrench tables).
        effects = dyn.effects
        cached = self._switching
        if cached[0] is not effects or cached[1] != len(effects):
            cached = self._switching = (effects, len(effects), [
                e for e in effects if type(e).begin_step is not Effect.begin_step])
        switching = cached[2]
        events = self.events
        # Contact steps no event interrupts run in the compiled kernel, several at once when
        # nothing between them needs Python (no switching effects, joints or wrenches).
        batch = self.contact is not None and not switching and not self._tracking \
            and (self._wrenches is None or not len(self._wrenches))
        done = 0
        while done < n:
            steps = self._steps
            if switching:
                mid = self._time_base + (steps + 0.5) * dt
                # Every effect must see the new step: no short-circuit.
                switched = [effect.begin_step(mid) for effect in switching]
                if any(switched):
                    dyn.changed()
            # Time as base + steps * dt, not a running sum: no rounding drift.
            t_end = self._time_base + (steps + 1) * dt
            seen, tracked = None, False
            if self.contact is not None:
                taken, new = self.contact.compiled_steps(
                    self.state, n - done if batch else 1, self._time_base, steps)
                if taken > 1:   # (batch: nothing below applies)
                    self.state = new
                    self._steps = steps + taken
                    done += taken
                    continue
                if not taken:
                    new = self.contact.step(self.state, t_end)
            elif events is None:
                new = self._advance(self.state, dt, t_end)
            elif self.joints.tracked and events.quiet():
                # Inactive limits: the step, and its coordinates checked against the
                # bounds in the kernel that reads them; the events' loop only past one.
                start = self.state
                new = self._advance(start, dt, t_end)
                self.bodies.outputs(new)
                tracked = self.joints.advance(self.bodies.outputs_cache.out)
                if not tracked:
                    new, seen = events.step(start, t_end, first=new)
            else:
                new, seen = events.step(self.state, t_end)
            self.state = new
            self._steps = steps + 1
            done += 1
            if self._tracking:
                if seen is not None:   # the events' check read the coordinates at new
                    self.bodies.outputs(new)
                    self.joints.adopt(*seen)
                elif not tracked:
                    self.bodies.outputs(new)
                    self.joints.track(self.bodies.outputs_cache.out)
                if self.drives is not None and self.drives.recenter(self.joints.positions):
                    dyn.changed()
            if self._wrenches is not None and len(self._wrenches):
                if self._wrenches.remove_expired(new.time):
                    # What reads the model between steps (reactions) must not see them.
                    self.dynamics.changed()

    def _advance(self, state: State, dt: float, t_end: float) -> State:
        """One step of the integrator (under the knob, if on) from ``state``; checked finite."""
        integrator, control = self.integrator, self._control
        try:
            if control is None:
                new = integrator.step(state, dt, t_end)
                # A plain step's kernels tell whether the new state is finite.
                finite = integrator.finite
                if finite is None:
                    finite = _finite(new)
            else:
                new = control.step(integrator, state, dt, t_end)
                finite = _finite(new)
        except np.linalg.LinAlgError:
            # A factorization met non-finite numbers: the step diverged on the way.
            raise DivergenceError(state.time, self._moving_fastest()) from None
        if not finite:
            bad = _non_finite_bodies(new)
            raise DivergenceError(state.time, [self.bodies.names[i] for i in bad])
        return new

    def _moving_fastest(self) -> list:
        """Name the body turning fastest (where a divergence most likely began)."""
        rates = np.linalg.norm(self.state.ang_vel_principal, axis=1)
        return [self.bodies.names[int(np.argmax(rates))]]

    def set_step(self, dt: Optional[float] = None, integrator: Optional[str] = None) -> None:
        """
        Change the step size and/or the integrator between steps.

        Time stays continuous: later steps end at ``now + k * dt``. Both values are
        validated before either changes.
        """
        new_dt, cls = self.check_step(dt, integrator)
        if new_dt != self.dt:
            self._time_base = self.time
            self._steps = 0
            self.dt = new_dt
            self.dynamics.solver.dt = new_dt
        if cls is not None and cls is not type(self.integrator):
            self.integrator = cls(self.dynamics)

    def check_step(self, dt: Optional[float] = None, integrator: Optional[str] = None) -> tuple:
        """
        Raise SpecError unless :meth:`set_step` would take these; changes nothing.

        The step must be positive, the integrator known, and the joints' servos
        stable with both (:meth:`.robots.JointDrives.check_stability`). Returns the
        step (s) and the integrator class (None: unchanged).
        """
        new_dt = self.dt if dt is None else positive_scalar(dt, 'dt')
        cls = integrator_class(integrator) if integrator is not None else None
        if self.drives is not None:
            self.drives.check_stability(self.state, new_dt,
                                        cls.name if cls is not None else self.integrator.name)
        return new_dt, cls

    def command_groups(self) -> dict:
        """Return ``{name: CommandGroup}``: the scene's command groups, joints in command order."""
        return {} if self.drives is None else dict(self.drives.groups)

    def set_tolerance(self, tolerance: Optional[float], budget: Optional[int] = None,
                      estimator: Optional[str] = None) -> None:
        """
        Turn the accuracy knob on (a tolerance), change it, or off (None), between steps.

        ``budget``: most sub-steps a step may take (default: as before, else
        1024). ``estimator``: ``'embedded'`` or ``'doubling'`` alone (default:
        as before, else both where the integrator has an embedded pair, the
        pair checking steps of one sub-step and doubling beyond, and doubling
        otherwise; see :mod:`.accuracy`).
        """
        if tolerance is None:
            self._control = None
        elif self._control is None:
            self._control = ErrorControl(tolerance, DEFAULT_BUDGET if budget is None else budget,
                                         estimator)
        else:   # keeps the sub-step count and the tallies
            self._control.retune(tolerance, budget, estimator)

    def accuracy(self) -> AccuracyReport:
        """Return what the accuracy knob did (tolerance None when it is off)."""
        if self._control is None:
            return AccuracyReport(None, math.nan, 1, 1, 0, 0, 0.0)
        return self._control.report()

    def run(self, duration: float) -> None:
        """Step until ``duration`` (s) more has elapsed (rounded to whole steps)."""
        d = positive_scalar(duration, 'duration')
        self.step(int(round(d / self.dt)))

    def reset(self) -> None:
        """Back to the initial state; applied wrenches return to the scene's own."""
        #: Constraints added at run time: ``{name: (spec, the state it was anchored at)}``.
        self._added: dict = {}
        #: Names of constraints removed at run time (a rebuild removes them again).
        self._removed: set = set()
        self.dynamics.discard_effect_work()   # the counters restart from zero
        self.state: State = self.bodies.initial_state(self._specs)
        if self._control is not None:
            self._control.reset()
        self._steps = 0          # steps of the current dt since _time_base
        self._time_base = 0.0    # s: when dt was last changed
        for effect, rows in zip(self.dynamics.effects, self._initial_wrenches):
            if rows is not None:
                effect.restore(rows)
        # Effects added at run time (a lazily created wrench table) are dropped.
        self.dynamics.effects = self.dynamics.effects[:len(self._initial_wrenches)]
        self._wrenches = next((e for e in self.dynamics.effects
                               if isinstance(e, AppliedWrenches)), None)
        for effect in self.dynamics.effects:
            effect.reset_counters()
        self.dynamics.counters.reset()
        solver = self.dynamics.solver
        solver.constraints = ConstraintSet(self.bodies)
        solver.counters.reset()
        # (the row tables built once: a rebuild around a spawn adds every constraint anew)
        solver.constraints.add_all(self._initial_constraints, self.state, 'constraints')
        if not solver.consistent(self.state):
            index, residual = solver.first_inconsistent(self._initial_constraints, self.state)
            raise self._inconsistent(self._initial_constraints[index].name,
                                     f'constraints[{index}]', 'no simulation was built', residual)
        self.dynamics.changed()
        self._reconcile_velocities()
        self.joints.reset()
        if len(self.joints):
            self.joints.track(self._outputs_now())
        if self.drives is not None:
            self.drives.hold(self.joints.positions)
            self.drives.check_stability(self.state, self.dt, self.integrator.name)
        if len(self._exact):
            # Exact drives hold the initial positions; driven joints start at rest.
            solver.constraints.add_all(self.drives.drive_constraints(self.joints.positions),
                                       self.state)
            self.dynamics.changed()
            self._reconcile_velocities()
        if self.contact is not None:
            self.contact.detector.exclude(self._exclusions(self._specs_now()))
            self.contact.reset()
        if self.events is not None:
            for part in (self.limits, self.friction, self.drive_efforts):
                if part is not None:
                    part.reset()
            self.events.reset_counters()
            self.events.from_state()

    def _inconsistent(self, name: str, field: str, outcome: str,
                      residual: float) -> InconsistentConstraintError:
        others = [n for n in self.dynamics.solver.constraints.names if n != name]
        return InconsistentConstraintError(
            field, f'constraint {name!r} is inconsistent with {others}: no configuration '
                   f'satisfies them all (the closest leaves max |Φ| = {residual:.3g} m or '
                   f'rad); {outcome}')

    @staticmethod
    def _wrench_rows(effect: Effect) -> Optional[list]:
        return effect.snapshot() if isinstance(effect, AppliedWrenches) else None

    # -- inputs ---------------------------------------------------------------------------

    def apply_wrench(self, body: str, force: Any = (0.0, 0.0, 0.0),
                     torque: Any = (0.0, 0.0, 0.0), frame: str = 'world',
                     point_body: Any = None, duration: Optional[float] = None,
                     start: Optional[float] = None, key: Optional[str] = None) -> None:
        """
        Apply a force (at ``point_body``, default the centre of mass) and a torque.

        Parameters
        ----------
        body : str
            Name of the body.
        force, torque : array_like, shape (3,)
            N, N m.
        frame : {'world', 'body'}
            Frame of ``force`` and ``torque``.
        point_body : array_like, shape (3,), optional
            m, in the body frame.
        duration : float, optional
            s; None: until cleared or reset.
        start : float, optional
            s, simulation time; default now.
        key : str, optional
            Replaces the wrench applied earlier with the same key (a held input,
            e.g. the latest message on a topic); with zero force and torque it
            only removes that one. Wrenches without a key add up.

        """
        if self._wrenches is None:
            self._wrenches = AppliedWrenches()
            self._wrenches.bind(self.bodies)
            self.dynamics.add_effect(self._wrenches)
        self._wrenches.add(body, force, torque, frame, point_body,
                           self.time if start is None else start, duration, key)
        self.dynamics.changed()

    def clear_wrenches(self, body: Optional[str] = None) -> None:
        """Remove applied wrenches (of one body, or all)."""
        if self._wrenches is not None:
            self._wrenches.clear(body)
            self.dynamics.changed()
            if self.events is not None:   # (the joints' friction is not an applied wrench)
                self.events.restore_friction()

    # -- joint space (robots) -------------------------------------------------------------

    def joint_names(self) -> list:
        """
        Names of the joints: the robots' revolute, continuous and prismatic ones (URDF order).

        Then the scene's hinges and sliders with limits or friction (named as their
        constraints: :class:`.limits.SceneJoint`).
        """
        return list(self.joints.names)

    def joint_state(self, names: Optional[Sequence[str]] = None) -> JointState:
        """
        Positions, velocities and efforts of the joints now (all, or ``names``).

        Positions are 0 in the URDF's zero configuration; angles count turns.
        Efforts: the effort command that acted over the last step, plus the joint's
        servo and damping at the current state (what a joint torque sensor reads),
        an exact drive's multiplier, a bound's while the joint touches it and its
        friction (the sticking row's multiplier, or ``−F`` along the slip; see
        :mod:`.limits`), and a mimic row's (on the follower and, times ``k``, on the
        leader).
        """
        js = self.joints.state(self._outputs_now(), self.time - 0.5 * self.dt)
        efforts = js.efforts
        if self.drives is not None and len(self.drives.rows_of):
            efforts = efforts + self.drives.efforts(js.positions, js.velocities)
        rows = self.events is not None and self.events.holds()
        if len(self._exact) or self._mimic_names or rows:
            solver = self.dynamics.solver
            lam = solver.multipliers(self.dynamics, self.state)
            efforts = efforts.copy()
        if self.events is not None:
            # Bounds and sticking friction: rows Φ = q − c, each −λ along q, as an exact
            # drive's; slipping friction: −F d.
            extra = self.events.efforts(lam if rows else None)
            if extra is not None:
                efforts = efforts + extra
        if len(self._exact):
            # An exact drive's effort is its row's multiplier: Φ = q − q*, so the
            # generalized force its reaction −Gᵀλ applies along q is −λ; a saturated
            # drive's is its effort limit, ±E.
            dr = self.drive_efforts
            for i, name in zip(self._exact, self._drive_names):
                if dr is not None and dr.mode[i] != ENGAGED:
                    efforts[i] += dr.mode[i] * dr.effort[i]
                else:
                    efforts[i] -= lam[solver.constraints.rows_of(name)[0]]
        if self._mimic_names:
            # A mimic row Φ = q_f − k q_l − c applies −λ along q_f and kλ along q_l.
            for (f, leader, k, _), name in zip(self.joints.mimics, self._mimic_names):
                lam_r = lam[solver.constraints.rows_of(name)[0]]
                efforts[f] -= lam_r
                efforts[leader] += k * lam_r
        js = JointState(js.names, js.positions, js.velocities, efforts)
        if names is None:
            return js
        idx = [self.joints.lookup(name, f'names[{i}]') for i, name in enumerate(names)]
        return JointState([js.names[i] for i in idx], js.positions[idx], js.velocities[idx],
                          js.efforts[idx])

    def _outputs_now(self) -> np.ndarray:
        """Return the bodies' outputs (n, O_WIDTH) of the current state."""
        self.bodies.outputs(self.state)
        return self.bodies.outputs_cache.out

    def set_joint_state(self, positions: dict, velocities: Optional[dict] = None) -> None:
        """
        Move the robots' bodies to joint coordinates, by forward kinematics, between steps.

        Parameters
        ----------
        positions : dict
            ``{joint: q}`` (rad or m); joints not named keep theirs.
        velocities : dict, optional
            ``{joint: q̇}`` (rad/s or m/s); joints not named keep theirs.

        Notes
        -----
        Every value is validated before anything changes. Floating bases keep
        their pose and twist; the children of floating and planar joints keep
        their pose and twist relative to their parent. Exact drives take the new
        positions as their targets: position drives hold them, velocity drives move
        them on at their commanded velocity from now. A velocity given for a driven
        joint is projected, with the rest of the velocities, onto the drive's (0,
        or the velocity drive's ``v*``). Mimic joints follow their leaders (a value
        given for one that contradicts its leader's is refused).

        """
        if not isinstance(positions, dict):
            raise SpecError('positions', f'expected a mapping joint -> position, '
                                         f'got {positions!r}')
        velocities = {} if velocities is None else velocities
        if not isinstance(velocities, dict):
            raise SpecError('velocities', f'expected a mapping joint -> velocity, '
                                          f'got {velocities!r}')
        pose = self.joints.poses_for(self._outputs_now(), positions, velocities)
        self.state = self.bodies.state_from_origins(self.time, *pose)
        self.dynamics.changed()
        self.joints.tracked = False   # the new angles are taken as they are
        self.joints.track(self._outputs_now())
        for name, value in positions.items():
            i = self.joints.index[name]
            if self.joints.rotary[i]:
                # Keep the turns the caller asked for (the tracked angle is wrapped).
                self.joints.positions[i] += 2.0 * np.pi * np.round(
                    (float(value) - self.joints.positions[i]) / (2.0 * np.pi))
        if self.drives is not None:
            self.drives.center[:] = self.joints.positions
            if self.events is not None:   # a state set by hand: its drives hold it
                self.events.engage_all()
            if len(self._exact):   # exact drives start where the joints were set
                self.dynamics.solver.set_drive_targets(
                    self._drive_names, self.joints.positions[self._exact], self.time,
                    self._drive_rates(self._exact))
            self.dynamics.changed()
        if self.events is not None:
            self.events.from_state()
        # (after the drives' targets: the projection onto Φ̇ = −ωΦ must see them)
        self._reconcile_velocities()

    # -- bodies added and removed at run time ---------------------------------------------

    def add_body(self, body: RigidBody, shapes: Sequence[CollisionShape] = (),
                 allow_overlap: bool = False) -> None:
        """
        Add a free body and its collision shapes between steps (a spawn).

        The body starts from its own initial conditions (``position_world``, ...); the
        others go on from where they are, bit for bit, with their constraints (those
        added at run time too, anchored as they were), applied wrenches, the time, the
        step and the accuracy knob; robots' joints keep their coordinates (turns
        included), commands, drive targets, held bounds, sticks, slips and saturated
        drives (:meth:`.JointEvents.carry`). The simulation is rebuilt around it from what
        did not change (each shape's numbers, the robots' conversions, and the compiled
        steps' components it leaves as they were, copied: :attr:`.ConstraintSolver.plans`;
        the work counters and the contacts' warm start restart). A reset (:meth:`reset`)
        puts it back where it was spawned; :meth:`remove_spawned` removes every spawned
        body and robot.

        Raises
        ------
        SpecError
            Not a RigidBody, a name taken, a shape on another body or invalid, or the new
            body's shapes overlapping another's deeper than the contacts' tolerance
            (``allow_overlap`` False). Nothing changes then.

        """
        if not isinstance(body, RigidBody):
            raise SpecError('body', f'expected a RigidBody, got {body!r}')
        if body.name in self.bodies.index:
            raise SpecError('body.name', f'{body.name!r} is taken; bodies: '
                                         f'{list(self.bodies.names)}')
        shapes = list(shapes)
        for i, shape in enumerate(shapes):
            if not isinstance(shape, CollisionShape) or shape.body != body.name:
                raise SpecError(f'shapes[{i}]', f'expected a CollisionShape on body '
                                                f'{body.name!r}, got {shape!r}')
        new = self._rebuilt((), bodies=self._built['bodies'] + [body],
                            shapes=self._built['shapes'] + shapes)
        if not allow_overlap and shapes:
            new._refuse_overlap([body.name], 'body.position_world')
        new._spawned = self._spawned + [body.name]
        new._spawned_robots = list(self._spawned_robots)
        new._origin = self._origin
        self._adopt(new)

    def add_robot(self, robot: RobotSpec, command_groups: Sequence[CommandGroup] = (),
                  allow_overlap: bool = False) -> None:
        """
        Add a robot (its links, joints, shapes, limits, friction, drives) between steps.

        It starts from its spec (base pose, initial joint positions and velocities); the
        rest goes on as for :meth:`add_body`. ``command_groups`` command its joints
        (names as in the simulation, its prefix included); its other joints take
        efforts. :meth:`remove_robot` removes it.

        Raises
        ------
        SpecError
            Not a RobotSpec, a robot or link name taken, a group name taken or naming a
            joint of another robot, servos unstable at the step, or its shapes
            overlapping another's (``allow_overlap`` False). Nothing changes then.

        """
        if not isinstance(robot, RobotSpec):
            raise SpecError('robot', f'expected a RobotSpec, got {robot!r}')
        # Converted once (robot_model's, if it was asked about), then kept by the rebuild
        # only: a refusal keeps none, and a spec changed in place after it is converted anew.
        model = next((m for spec, m in self._asked if spec is robot), None)
        self._asked = [(spec, m) for spec, m in self._asked if spec is not robot]
        taken = [m.spec.name for m in self.robots]
        if robot.name in taken:
            raise SpecError('robot.name', f'{robot.name!r} is taken; robots: {taken}')
        groups = list(command_groups)
        for g, group in enumerate(groups):
            if not isinstance(group, CommandGroup):
                raise SpecError(f'command_groups[{g}]', f'expected a CommandGroup, got '
                                                        f'{group!r}')
            if group.name in self.command_groups():
                raise SpecError(f'command_groups[{g}].name', f'{group.name!r} is taken; '
                                                             f'groups: '
                                                             f'{sorted(self.command_groups())}')
            for j, name in enumerate(group.joints):
                if name in self.joints.index:
                    raise SpecError(f'command_groups[{g}].joints[{j}]',
                                    f'{name!r} is a joint already in the simulation; a '
                                    f"spawned robot's groups command its own joints")
        try:
            model = build_robot(robot) if model is None else model
        except SpecError as exc:
            raise exc.within('robot') from None
        taken = sorted(self.row_names(model) & self.taken_names())
        if taken:
            raise SpecError('robot', f'its joints would make constraints named {taken}, '
                                     f'names of constraints (or of rows) already in the '
                                     f'simulation: give the robot a prefix')
        try:
            new = self._rebuilt((), robots=self._built['robots'] + [robot],
                                groups=self._built['command_groups'] + groups,
                                converted={**self._converted, id(robot): (robot, model)})
        except SpecError as exc:
            if exc.field.startswith('robots['):   # (the new robot's: as ``robot``)
                raise exc.within('robot') from None
            raise
        links = [b.name for b in new.robots[-1].bodies]
        if not allow_overlap and new.shapes:
            new._refuse_overlap(links, 'robot.base_xyz')
        new._spawned = list(self._spawned)
        new._spawned_robots = self._spawned_robots + [robot.name]
        new._origin = self._origin
        self._adopt(new)

    def robot_model(self, robot: RobotSpec) -> Any:
        """
        Return a robot spec's model (:func:`.robots.build_robot`), converted once.

        The last specs asked about are kept (by identity, a few), so that checking a
        robot before :meth:`add_robot` (its names, :meth:`row_names`) and adding it
        convert it once: a spec is not to be changed in between. ``add_robot`` takes
        its model out. Raises SpecError as ``build_robot`` does.
        """
        for spec, model in self._asked:
            if spec is robot:
                return model
        model = build_robot(robot)
        self._asked = [(robot, model)] + self._asked[:3]
        return model

    @staticmethod
    def row_names(model: Any) -> set:
        """
        Return the constraint names a robot model's joints may take (a RobotModel's).

        Its joints' constraints, and per one-coordinate joint its mimic row, exact drive,
        bound and stick (whether it has them or not).
        """
        rows = {c.name for c in model.constraints if isinstance(c, Constraint)}
        for j in model.joints:
            rows |= {mimic_name(j.name), drive_name(j.name), limit_name(j.name),
                     stick_name(j.name)}
        return rows

    def _refuse_overlap(self, names: list, field: str) -> None:
        """Raise SpecError if shapes of bodies ``names`` overlap others deeper than allowed."""
        if self.contact is None:
            return
        con = self.contact.detect(self.state)
        mine = np.isin(con.body_a, [self.bodies.index[n] for n in names]) | np.isin(
            con.body_b, [self.bodies.index[n] for n in names])
        deep = (con.depth > self.contact.location) & mine
        if np.any(deep):
            k = int(np.argmax(np.where(deep, con.depth, -np.inf)))
            shapes = [s.name for s in self.contact.detector.shapes]
            what = repr(names[0]) if len(names) == 1 else 'the robot'
            raise SpecError(field, f'{what} would overlap: {shapes[con.shape_a[k]]!r} and '
                                   f'{shapes[con.shape_b[k]]!r} by {con.depth[k]:.3g} m')

    def remove_body(self, name: str) -> list:
        """
        Remove a body, its shapes and the constraints that hold it, between steps.

        Returns the names of the constraints removed with it (the scene's and those
        added at run time; a scene joint's limits and friction go with its hinge or
        slider). Effects naming it forget it (a damping's list, the applied wrenches on
        it). The others go on as for :meth:`add_body`.

        Raises
        ------
        SpecError
            An unknown body, or a robot's link (:meth:`remove_robot` removes robots).

        """
        self.bodies.lookup(name, 'name')
        owner = self._robot_of(name)
        if owner is not None:
            raise SpecError('name', f'{name!r} is a link of robot {owner!r}: remove the robot')
        gone = self._constraints_of({name})
        new = self._rebuilt((name,), bodies=[b for b in self._built['bodies'] if b.name != name],
                            shapes=[s for s in self._built['shapes'] if s.body != name])
        new._spawned = [b for b in self._spawned if b != name]
        new._spawned_robots = list(self._spawned_robots)
        new._origin = self._origin
        self._adopt(new)
        return gone

    def remove_robot(self, name: str) -> list:
        """
        Remove robot ``name`` (links, joints, shapes, its command groups), between steps.

        Returns the names of the other constraints removed with it (scene constraints
        or constraints added at run time that hold one of its links). Groups keep their
        other joints (a group of its joints only goes). The rest goes on as for
        :meth:`add_body`.

        Raises
        ------
        SpecError
            An unknown robot.

        """
        models = {m.spec.name: m for m in self.robots}
        if name not in models:
            raise SpecError('name', f'no robot {name!r}; robots: {sorted(models)}')
        model = models[name]
        links = {b.name for b in model.bodies}
        joints = {j.name for j in model.joints}
        gone = [c for c in self._constraints_of(links) if c in self._built_names()]
        groups = []
        for group in self._built['command_groups']:
            kept = [j for j in group.joints if j not in joints]
            if kept:
                groups.append(group if len(kept) == len(group.joints)
                              else replace(group, joints=kept))
        new = self._rebuilt(tuple(links), robots=[r for r in self._built['robots']
                                                  if r.name != name], groups=groups)
        new._spawned = list(self._spawned)
        new._spawned_robots = [r for r in self._spawned_robots if r != name]
        new._origin = self._origin
        self._adopt(new)
        return gone

    def _robot_of(self, body: str) -> Optional[str]:
        """Return the name of the robot whose link ``body`` is (None: none)."""
        return next((m.spec.name for m in self.robots if any(b.name == body for b in m.bodies)),
                    None)

    def taken_names(self) -> set:
        """
        Return the constraint names a spawned robot's rows may not take.

        The constraints present, added at run time or the scene's (removed or not), and
        every robot's possible rows (:meth:`row_names`: its joints, mimic rows, exact
        drives, bounds and sticks, present or not).
        """
        out = set(self.constraint_names) | set(self._added) | self._built_names()
        for model in self.robots:
            out |= self.row_names(model)
        return out

    def _built_names(self) -> set:
        """Return the names of the constraints that are not a robot's own (a user's)."""
        return {c.name for c in self._built['constraints'] if isinstance(c, Constraint)} \
            | set(self._added)

    def _constraints_of(self, bodies: set) -> list:
        """Return the names of the constraints present that hold one of ``bodies``."""
        specs = [self.constraint_spec(c) for c in self.constraint_names]
        return [c.name for c in specs if c.body_a in bodies or c.body_b in bodies]

    def remove_spawned(self) -> list:
        """Remove every body and robot added at run time; return their names (bodies first)."""
        bodies, robots = list(self._spawned), list(self._spawned_robots)
        if bodies or robots:
            links = {b.name for m in self.robots if m.spec.name in robots for b in m.bodies}
            joints = {j.name for m in self.robots if m.spec.name in robots for j in m.joints}
            groups = [g for g in self._built['command_groups'] if not set(g.joints) & joints]
            new = self._rebuilt(tuple(bodies) + tuple(links),
                                bodies=[b for b in self._built['bodies'] if b.name not in bodies],
                                shapes=[s for s in self._built['shapes'] if s.body not in bodies],
                                robots=[r for r in self._built['robots'] if r.name not in robots],
                                groups=groups)
            new._origin = self._origin
            self._adopt(new)
        return bodies + robots

    @property
    def scene_changed(self) -> bool:
        """Tell whether bodies or robots were added or removed since the scene was built."""
        return [b.name for b in self._built['bodies']] \
            != [b.name for b in self._origin['bodies']] \
            or [r.name for r in self._built['robots']] \
            != [r.name for r in self._origin['robots']] \
            or bool(self._spawned) or bool(self._spawned_robots)

    def reset_scene(self) -> None:
        """
        Back to the scene as it was built: bodies spawned since removed, removed ones back.

        The step, the integrator and the accuracy knob stay as they are now. Without a
        change of bodies it is :meth:`reset`.
        """
        if not self.scene_changed:
            self.reset()
            return
        origin = dict(self._origin)
        origin['effects'] = [_unbound_copy(e) for e in origin['effects']]
        control = self._control
        new = Simulation(integrator=self.integrator_name, dt=self.dt,
                         tolerance=None if control is None else control.tolerance, **origin)
        new._origin = self._origin
        if control is not None:   # (its budget and estimator as now; its state afresh)
            new._control = copy.deepcopy(control)
            new._control.reset()
        self._adopt(new)

    @property
    def spawned(self) -> list:
        """Return the names of the bodies added at run time, in order."""
        return list(self._spawned)

    @property
    def spawned_robots(self) -> list:
        """Return the names of the robots added at run time, in order."""
        return list(self._spawned_robots)

    def _rebuilt(self, removed: tuple, bodies: Optional[list] = None,
                 shapes: Optional[list] = None, robots: Optional[list] = None,
                 groups: Optional[list] = None, converted: Optional[dict] = None
                 ) -> 'Simulation':
        """
        Return a simulation of these parts that goes on from this one's state.

        ``bodies``, ``shapes`` (the scene's), ``robots`` and command ``groups``: as now if
        None. ``removed``: bodies gone (robots' links too; their constraints, wrenches,
        damping and scene joints go with them). This one is not changed (its effects
        are copied before they are bound anew).
        """
        built = self._built
        bodies = built['bodies'] if bodies is None else bodies
        shapes = built['shapes'] if shapes is None else shapes
        robots = built['robots'] if robots is None else robots
        groups = built['command_groups'] if groups is None else groups
        gone = set(removed)
        effects = []
        for effect in built['effects']:
            effect = _unbound_copy(effect)
            if isinstance(effect, Damping) and effect.body_names is not None:
                effect.body_names = [b for b in effect.body_names if b not in gone]
            if isinstance(effect, AppliedWrenches):
                effect._pending = [e for e in effect._pending if e.get('body') not in gone]
            effects.append(effect)

        def touches(c: Any) -> bool:
            return isinstance(c, Constraint) and (c.body_a in gone or c.body_b in gone)

        constraints = [c for c in built['constraints'] if not touches(c)]
        kept = {c.name for c in constraints if isinstance(c, Constraint)}
        scene_joints = [j for j in built['scene_joints']
                        if not isinstance(j, SceneJoint) or j.constraint in kept]
        control = self._control
        new = Simulation(bodies, effects, self.integrator_name, self.dt, constraints,
                         built['constraint_time_constant'],
                         None if control is None else control.tolerance,
                         built['tolerance_budget'], robots=robots, command_groups=groups,
                         scene_joints=scene_joints, shapes=shapes,
                         _converted=self._converted if converted is None else converted,
                         _plans=self.dynamics.solver.plans)
        # Its state: this one's, body by body (bit for bit), at this time and step count.
        index = [new.bodies.index.get(name, -1) for name in self.bodies.names]
        new.state = _moved(self.state.parts, index, (self.state.time, new.state.parts))
        new._steps, new._time_base = self._steps, self._time_base
        new._control = copy.deepcopy(self._control)   # (its budget, estimator and state)
        # Constraints: the scene's removed at run time stay removed; those added at run
        # time are anchored anew where they were (their positions then, mapped).
        solver = new.dynamics.solver
        new._removed = self._removed & set(solver.constraints.names)   # (of those still here)
        for name in sorted(new._removed):   # (a scene's, or a robot joint's)
            solver.constraints.remove(name)
        for name, (spec, at) in self._added.items():
            if name in solver.constraints.names:   # (a scene's removed and added anew)
                solver.constraints.remove(name)
            if touches(spec):
                continue
            anchored = _moved(at.parts, index, (at.time, new.state.parts))
            solver.constraints.add(spec, anchored)
            new._added[name] = (spec, anchored)
        new.dynamics.changed()
        new._carry_joints(self)
        if new.contact is not None:
            new.contact.detector.exclude(new._exclusions(new._specs_now()))
        # Applied wrenches (the scene's tables and the one applied through the API), on
        # the same bodies.
        old_tables = [e for e in self.dynamics.effects if isinstance(e, AppliedWrenches)]
        new_tables = [e for e in new.dynamics.effects if isinstance(e, AppliedWrenches)]
        for k, table in enumerate(old_tables):
            if k >= len(new_tables):
                added = AppliedWrenches()
                added.bind(new.bodies)
                new.dynamics.add_effect(added)
                new_tables.append(added)
                new._wrenches = new._wrenches or added
            rows = [(index[row[0]],) + tuple(row[1:]) for row in table.snapshot()
                    if index[row[0]] >= 0]
            new_tables[k].restore(rows)
        if new.contact is not None and self.contact is not None:
            # The contacts' warm start (the last step's normal impulses, by shape pair and
            # point): the next step's friction fixed point starts where it would have.
            where = {s.name: k for k, s in enumerate(new.contact.detector.shapes)}
            shapes_then = [s.name for s in self.contact.detector.shapes]
            sa, sb, pt, pn = self.contact._warm
            a = np.array([where.get(shapes_then[k], -1) for k in sa], dtype=np.int64)
            b = np.array([where.get(shapes_then[k], -1) for k in sb], dtype=np.int64)
            keep = (a >= 0) & (b >= 0)
            new.contact._warm = (a[keep], b[keep], pt[keep], pn[keep])
            lazy = self.contact._lazy
            if lazy is not None:   # (the compiled steps': remapped as it is, built when read)
                new.contact._lazy = self._lazy_in(new, lazy, index, where)
            else:
                rec = self.contact.record
                if rec.rows is not None and len(rec.rows):
                    new.contact.record = self._record_in(new, rec, index, where)
        new.dynamics.changed()
        return new

    def _carry_joints(self, old: 'Simulation') -> None:
        """
        Take the joints' state from ``old`` (this is it rebuilt), joint by joint (by name).

        The unwrapped coordinates (turns), held effort commands, servo targets, exact
        drives' target motions, and the events' rows and modes (:meth:`.JointEvents.carry`);
        a spawned robot's joints keep what its reset gave them. The state is carried first.
        """
        js, was = self.joints, old.joints
        if not len(js):
            return
        pairs = [(i, was.index[n]) for i, n in enumerate(js.names) if n in was.index]
        here = np.array([i for i, _ in pairs], dtype=int)
        there = np.array([k for _, k in pairs], dtype=int)
        js.positions[here] = was.positions[there]
        js.track(self._outputs_now())   # (the same coordinates; their rates at the state)
        js.efforts[here] = was.efforts[there]
        js.effort_window[here] = was.effort_window[there]
        js.counters = dict(was.counters)
        if self.drives is not None and old.drives is not None:
            for part in ('q_target', 'v_target', 'center'):
                getattr(self.drives, part)[here] = getattr(old.drives, part)[there]
            motions = {}
            names_then = set(old.dynamics.solver.constraints.names)
            for name in self._drive_names:
                if name in names_then:   # (engaged; a saturated one's motion: the events')
                    motions[name] = old.dynamics.solver.drive_motions([name])[0]
            if motions:
                self.dynamics.solver.set_drive_motions(motions, self.time)
            self.dynamics.changed()
        if self.events is not None and old.events is not None:
            self.events.carry(old.events, pairs)
        elif self.events is not None:
            self.events.from_state()

    def _lazy_in(self, new: 'Simulation', lazy: tuple, index: list, where: dict) -> tuple:
        """Return the compiled steps' record ``(state, contacts, sel, force)`` in ``new``'s."""
        state, con, sel, force = lazy
        to_new = np.append(np.array(index, dtype=int), len(new.bodies.names))
        shape_to_new = self._shapes_in(where)
        sa, sb = shape_to_new[con.shape_a], shape_to_new[con.shape_b]
        ba, bb = to_new[con.body_a], to_new[con.body_b]
        good = (sa >= 0) & (sb >= 0) & (ba >= 0) & (bb >= 0)
        renumber = np.cumsum(good) - 1
        keep = good[sel]
        contacts = con._replace(shape_a=sa, shape_b=sb, body_a=ba, body_b=bb)
        contacts = type(con)(*(part[good] for part in contacts))
        return (_moved(state.parts, index, (state.time, new.state.parts)), contacts,
                renumber[sel[keep]], force[keep])

    def _shapes_in(self, where: dict) -> np.ndarray:
        """Return per shape of this one's detector its index in ``where`` (-1: gone)."""
        return np.array([where.get(s.name, -1) for s in self.contact.detector.shapes],
                        dtype=np.int64)

    def _record_in(self, new: 'Simulation', rec: ContactRecord, index: list,
                   where: dict) -> ContactRecord:
        """
        Return the last step's contact record in ``new``'s bodies and shapes.

        What reads the contact forces between steps (:meth:`accelerations`,
        :meth:`contacts`) reads them across a spawn; contacts of bodies or shapes gone
        are dropped.
        """
        rows = rec.rows
        n_new = len(new.bodies.names)
        to_new = np.append(np.array(index, dtype=int), n_new)   # (the world last)
        con = rows.contacts
        shape_to_new = self._shapes_in(where)
        sa, sb = shape_to_new[con.shape_a], shape_to_new[con.shape_b]
        ba, bb = to_new[con.body_a], to_new[con.body_b]
        keep = (sa >= 0) & (sb >= 0) & (ba >= 0) & (bb >= 0)
        rows = rows.subset(keep)
        r = len(rows.G)
        G = np.zeros((r, n_new, 6))
        there = np.asarray(index, dtype=np.int64)
        old = np.flatnonzero(there >= 0)
        G[:, there[old]] = rows.G.reshape(r, len(index), 6)[:, old]
        contacts = rows.contacts._replace(shape_a=sa[keep], shape_b=sb[keep], body_a=ba[keep],
                                          body_b=bb[keep])
        moved = ContactRows(_moved(rows.state.parts, index, (rows.state.time, new.state.parts)),
                            contacts, rows.frame, rows.lever_a, rows.lever_b, rows.mu,
                            rows.restitution, G.reshape(r, 6 * n_new), rows.sliding, rows.vn)
        return ContactRecord(rec.time, moved, rec.force[keep])

    def _adopt(self, new: 'Simulation') -> None:
        """Become ``new``: its parts refer to it, so the two share one attribute dictionary."""
        self.__dict__ = new.__dict__

    def place(self, bodies: Sequence[str], reference: str, position: Any,
              orientation_xyzw: Any, linear_velocity_world: Any = (0.0, 0.0, 0.0),
              angular_velocity_world: Any = (0.0, 0.0, 0.0)) -> None:
        """
        Move ``bodies`` as one rigid whole so ``reference`` (one of them) has a pose and twist.

        Between steps (a teleport): ``reference``'s origin goes to ``position`` (m,
        world) with its frame at ``orientation_xyzw`` (normalized), the others keep their
        pose relative to it, and the whole moves rigidly with the twist of
        ``reference``'s origin (``linear_velocity_world`` m/s, ``angular_velocity_world``
        rad/s): the bodies' motion relative to each other (a robot's joint rates) is
        stopped. Every value is checked before anything changes.

        Raises
        ------
        SpecError
            A non-finite value, a zero quaternion, an unknown body, or a body joined by a
            constraint to one outside ``bodies`` or to the world (moving them would break
            it: the constraint is named).

        """
        names = list(bodies)
        index = [self.bodies.lookup(name, 'bodies') for name in names]
        if reference not in names:
            raise SpecError('reference', f'{reference!r} is not one of the bodies moved '
                                         f'{names}')
        values = {}
        for field, value, size in (('position', position, 3),
                                   ('orientation_xyzw', orientation_xyzw, 4),
                                   ('linear_velocity_world', linear_velocity_world, 3),
                                   ('angular_velocity_world', angular_velocity_world, 3)):
            try:
                a = np.array(value, dtype=float).reshape(size)
            except (TypeError, ValueError):
                raise SpecError(field, f'expected {size} numbers, got {value!r}') from None
            if not np.all(np.isfinite(a)):
                raise SpecError(field, f'must be finite, got {a.tolist()}')
            values[field] = a
        q = values['orientation_xyzw']
        norm = float(np.linalg.norm(q))
        if not norm > 1e-6:
            raise SpecError('orientation_xyzw', f'not a rotation: its norm is {norm:.3g}')
        group = set(names)
        for name in self.dynamics.solver.constraints.names:
            spec = self.dynamics.solver.constraints.spec(name)
            ends = {spec.body_a, spec.body_b} - {None}
            if ends & group and not ends <= group or (ends & group and spec.body_b is None):
                other = spec.body_b if spec.body_a in group else spec.body_a
                raise SpecError('bodies', f'constraint {name!r} joins {sorted(ends & group)} '
                                          f'to {other or "the world"!r}: moving them alone '
                                          f'would break it')
        pos, quat, vel, omega, _, _ = (a.copy() for a in self.bodies.outputs(self.state))
        r = index[names.index(reference)]
        R_old = so3.quat_to_matrix(quat[r])
        R_new = so3.quat_to_matrix(q / norm)
        turn = R_new @ R_old.T
        rel = pos[index] - pos[r]
        pos[index] = values['position'] + rel @ turn.T
        quat[index] = so3.quat_normalize(so3.quat_multiply(
            np.tile(so3.matrix_to_quat(turn), (len(index), 1)), quat[index]))
        w = values['angular_velocity_world']
        vel[index] = values['linear_velocity_world'] + np.cross(
            w, pos[index] - values['position'])
        omega[index] = w
        moved = self.bodies.state_from_origins(self.time, pos, quat, vel, omega)
        # The other bodies keep their state bit for bit (not recomputed from their origins).
        parts = [old.copy() for old in self.state.parts]
        for whole, piece in zip(parts, moved.parts):
            whole[index] = piece[index]
        self.state = State(self.time, *parts)
        if self.contact is not None:   # (the last step's contact forces no longer apply)
            self.contact._set_forces(None)
            self.contact.record = ContactRecord(self.time)
        self.dynamics.changed()
        if len(self.joints):
            self.joints.track(self._outputs_now())
        if self.events is not None:
            self.events.from_state()

    def set_joint_efforts(self, efforts: dict, duration: Optional[float] = None) -> None:
        """
        Command joint efforts (N m or N), held until replaced, or for ``duration`` s.

        Each effort is clamped to the joint's URDF effort limit (counted in
        ``joint_counters()['clamped_efforts']``) and acts as a pair of equal and
        opposite wrenches on the joint's bodies from the next step on.
        """
        idx, clamped, wrenches = self.joints.effort_wrenches(efforts)
        start = self.time
        if duration is not None:
            duration = positive_scalar(duration, 'duration')
        for w in wrenches:
            self.apply_wrench(duration=duration, start=start, **w)
        values = np.array([float(v) for v in efforts.values()])
        end = np.inf if duration is None else start + duration
        self.joints.commanded(idx, clamped, values, start, end)

    def joint_interfaces(self) -> dict:
        """``{joint: 'effort' | 'position' | 'velocity'}``: what each joint's commands set."""
        if self.drives is None:
            return {}
        return {name: self.drives.interface[i].value for i, name in enumerate(self.joints.names)}

    def command_joints(self, values: dict) -> None:
        """
        Command joints through their interfaces: ``{joint: effort | position | velocity}``.

        Effort joints as :meth:`set_joint_efforts`; position and velocity servos
        and exact drives get a new target, held until replaced. Validated before
        anything changes. An exact position drive's target is the position; an
        exact velocity drive's target moves at the velocity from where it is now
        (the position target does not jump), from the next step on.
        """
        if not isinstance(values, dict):
            raise SpecError('values', f'expected a mapping joint -> command, got {values!r}')
        efforts, targets = {}, {}
        for name, value in values.items():
            i = self.joints.lookup(name, f'values.{name}')
            value = finite_scalar(value, f'values.{name}')
            if self.drives.interface[i] is Interface.EFFORT:
                efforts[name] = value
            else:
                targets[i] = value
        if efforts:
            self.set_joint_efforts(efforts)
        if targets:
            idx = np.array(list(targets), dtype=int)
            values = np.array(list(targets.values()))
            self.drives.set_targets(idx, values)
            exact = idx[self.drives.exact[idx]]
            if len(exact):
                names = [drive_name(self.joints.names[i]) for i in exact]
                solver = self.dynamics.solver
                velocity = self.drives.interface_is(Interface.VELOCITY)[exact]
                # A velocity drive's target continues from where it is now.
                now = np.array([self._drive_target(i, name) for i, name in zip(exact, names)])
                targets = np.where(velocity, now, values[self.drives.exact[idx]])
                rates = self._drive_rates(exact)
                engaged = (np.ones(len(exact), dtype=bool) if self.events is None
                           else self.events.set_targets(exact, targets, rates))
                if np.any(engaged):
                    solver.set_drive_targets([n for n, e in zip(names, engaged) if e],
                                             targets[engaged], self.time, rates[engaged])
                if self.events is not None:   # effort-limited drives may saturate
                    self.events.commanded(exact)
            if len(exact) < len(idx):   # servos' targets are in the model; drives' are not
                self.dynamics.changed()

    def _drive_target(self, i: int, name: str) -> float:
        """Return the target of joint ``i``'s exact drive (``name``) now, saturated or not."""
        held = None if self.events is None else self.events.drive_target(i, self.time)
        if held is not None:
            return held
        return float(self.dynamics.solver.drive_targets([name], self.time)[0])

    def _drive_rates(self, idx: np.ndarray) -> np.ndarray:
        """Rates (k,) of the exact drives of joints ``idx``: v* for velocity drives, else 0."""
        velocity = self.drives.interface_is(Interface.VELOCITY)[idx]
        return np.where(velocity, self.drives.v_target[idx], 0.0)

    def joint_counters(self) -> dict:
        """Return the counts since the last reset: clamped efforts, velocity-limit excursions."""
        return dict(self.joints.counters)

    def add_constraint(self, constraint: Constraint) -> None:
        """
        Add a constraint between steps; anchors and axes in the world refer to now.

        Bodies whose velocities disagree with the new joint are reconciled at
        once, by the mass-weighted projection onto ``Φ̇ = −ωΦ`` (a perfectly
        inelastic impact, which conserves momenta); a position violation then
        decays along ``exp(−t/τ)``.

        A constraint that cannot hold together with the others (no configuration
        satisfies them all, e.g. one body point pinned to two world points) is
        refused with a :class:`SpecError`; a redundant but consistent one (a
        closed loop, the same joint twice) is accepted.
        """
        solver = self.dynamics.solver
        constraints = solver.constraints
        if self.events is not None and isinstance(constraint, Constraint) \
                and constraint.name in self.events.reserved():
            raise SpecError('name', f'{constraint.name!r} is the name of a row that holds a '
                                    f'joint on its limit or its friction: choose another')
        constraints.add(constraint, self.state)
        try:
            residual = solver.reach(self.state)
        except BaseException:
            constraints.remove(constraint.name)
            raise
        if residual > solver.CONSISTENCY_TOLERANCE:
            constraints.remove(constraint.name)
            raise self._inconsistent(constraint.name, 'constraint', 'it was not added',
                                     residual)
        self.dynamics.changed()
        if self.events is not None:   # rows may have moved
            self.events.rows_changed()
        if self.contact is not None:   # bodies joined now never collide (only fewer pairs)
            self.contact.detector.exclude(self._exclusions(self._specs_now()))
        # (with the positions it was anchored at: a spawn rebuilds it bit for bit)
        self._added[constraint.name] = (constraint, self.state)
        self._reconcile_velocities()

    def _reconcile_velocities(self) -> None:
        if not self.dynamics.constrained:
            return
        s = self.state
        vel, om = self.dynamics.solver.project_velocities(s)
        self.state = State(s.time, s.pos_com_world, s.quat_principal_world, vel, om)

    def remove_constraint(self, name: str) -> Constraint:
        """Remove the constraint called ``name``; returns its description."""
        if name in self._drive_names:
            joint = self.joints.names[self._exact[self._drive_names.index(name)]]
            raise SpecError('name', f'{name!r} is the exact drive of joint {joint!r} (a '
                                    f'command group of mode exact): it cannot be removed')
        held = {} if self.events is None else self.events.held()
        if name in held:
            raise SpecError('name', f'{name!r} holds joint {self.joints.names[held[name]]!r} '
                                    f'on its limit or its friction while it lasts: it cannot '
                                    f'be removed')
        if name in self._mimic_names:
            joint = self.joints.names[self.joints.mimics[self._mimic_names.index(name)][0]]
            raise SpecError('name', f'{name!r} makes joint {joint!r} follow its leader (a URDF '
                                    f'mimic joint): it cannot be removed')
        if self.contact is not None:   # its bodies may collide from now on
            self.dynamics.solver.constraints.spec(name)   # (an unknown name: its error)
            self.contact.detector.exclude(self._exclusions(self._specs_now(name)))
        spec = self.dynamics.solver.constraints.remove(name)
        if self._added.pop(name, None) is None:   # (one a rebuild would make again)
            self._removed.add(name)
        self.dynamics.changed()
        if self.events is not None:   # rows may have moved
            self.events.rows_changed()
        return spec

    @property
    def constraint_names(self) -> list:
        """
        Names of the constraints, in the order they were added.

        Not the rows that hold joints on their bounds or by their friction
        (:mod:`.joint_events`): they come and go with the motion, and count as their
        joints' (reactions, violations).
        """
        names = self.dynamics.solver.constraints.names
        held = {} if self.events is None else self.events.held()
        names = [name for name in names if name not in held] if held else names
        dr = self.drive_efforts
        if dr is not None and dr.motion:   # a saturated drive is still there, its row away
            names = names + [dr.names[i] for i in dr.saturated()]
        return names

    def constraint_spec(self, name: str) -> Constraint:
        """Return the description of constraint ``name`` (a saturated drive's too)."""
        dr = self.drive_efforts
        if dr is not None:
            for i, spec in dr.specs.items():
                if dr.names[i] == name:
                    return spec
        return self.dynamics.solver.constraints.spec(name)

    def constraint_rows(self, name: str) -> int:
        """Return how many rows constraint ``name`` has (a saturated drive's one, away now)."""
        dr = self.drive_efforts
        if dr is not None and any(dr.names[i] == name for i in dr.specs):
            return 1
        return len(self.dynamics.solver.constraints.rows_of(name))

    def joint_friction(self) -> dict:
        """
        Return what the joints' Coulomb friction does now: who sticks, who slips, counters.

        ``{'sticking': [joint, ...], 'slipping': {joint: +1 | -1}, 'counters': {'sticks':
        n, 'slips': n}}`` (see :class:`.limits.JointFriction`); empty when no joint
        has friction.
        """
        fr = self.friction
        if fr is None:
            return {}
        names = self.joints.names
        return {'sticking': [names[i] for i in sorted(fr.rows)],
                'slipping': {names[i]: int(fr.mode[i]) for i in fr.slipping()},
                'counters': dict(fr.counters)}

    def contacts(self) -> dict:
        """
        Return the contacts of the latest step and the forces they carried over it.

        ``{'time': s, 'shape_a': [name], 'shape_b': [name], 'body_a': [name], 'body_b':
        [name or 'world'], 'point': (c, 3) m, 'normal': (c, 3) from b to a,
        'normal_force': (c,) N, 'friction_force': (c, 3) N, 'depth': (c,) m,
        'counters': {...}}``, world frame, at the state the step's (last) held forces
        were found (``time``): the contacts touching there and not moving apart, and
        those that carried a force over the step (also apart, or moving apart:
        :meth:`.ContactSteps._step_rows`). The force on
        shape a is ``normal_force · normal +
        friction_force``, on b its opposite. ``counters`` (since the reset): impacts,
        steps with a located impact, those cut at :data:`.contact_step.MAX_EVENTS`, the
        contact LCPs solved, their most iterations, failures and largest residual (m/s),
        the deepest penetration a step left and the projections that took it out (steps
        projected, the largest depth projected, the largest depth or lift the projection's
        passes left: ``projection_left``), the deepest overlap any step ended with (after
        its projection: ``end_depth``, the penetration a user sees), the contact operators
        built from trial steps (``stepped_responses``).
        Empty without collision shapes.
        """
        if self.contact is None:
            return {}
        rec = self.contact.record
        names = self.bodies.names + ['world']
        shapes = self.contact.detector.shapes
        out: dict = {'time': rec.time, 'counters': dict(self.contact.counters)}
        if rec.rows is None or not len(rec.rows):
            z3 = np.zeros((0, 3))
            return {**out, 'shape_a': [], 'shape_b': [], 'body_a': [], 'body_b': [],
                    'point': z3, 'normal': z3, 'normal_force': np.zeros(0),
                    'friction_force': z3, 'depth': np.zeros(0)}
        con = rec.rows.contacts
        # (a row that carried no force, its contact apart or moving apart, is none)
        keep = ((con.depth >= -self.contact.location) & (rec.rows.vn <= self.contact.rate)) \
            | np.any(rec.force != 0.0, axis=1)
        con = Contacts(*(part[keep] for part in con))
        force = rec.force[keep]
        fn = np.sum(force * con.normal, axis=1)
        return {**out, 'shape_a': [shapes[k].name for k in con.shape_a],
                'shape_b': [shapes[k].name for k in con.shape_b],
                'body_a': [names[k] for k in con.body_a],
                'body_b': [names[k] for k in con.body_b],
                'point': con.point, 'normal': con.normal, 'normal_force': fn,
                'friction_force': force - fn[:, None] * con.normal,
                'depth': con.depth}

    def complementarity(self) -> dict:
        """
        Return how well the rows with bounds kept their complementarity since the reset.

        ``{'located_steps': n, 'max_force_excess': N m or N, 'max_position_excess': rad
        or m, 'lcp_solves': n, 'lcp_residual_max': N m or N, 'lcp_failures': n}``: the
        steps in which an event was located; the largest force a row carried past its
        bound over an accepted (partial) step (a pulling bound, a stick past ``F``, a
        drive past ``E``: within :data:`.limits.FORCE_TOLERANCE` of the force's change
        over a step at a located event, more only if :data:`.limits.MAX_EVENTS` cut a
        step short; a force that jumps past its bound at an impact or a command pivots
        at once, carrying nothing); the largest excursion past a bound a step had to
        accept (0: none); the held rows' complementarity problems solved at pivots,
        impacts and bounded drives' commands (:mod:`.complementarity`), the largest
        natural-map residual of their solutions (rounding), and those that could not
        be solved or stopped at their iteration cap (then the rule without the
        problem applied: the row furthest past its bound pivots, an impact keeps every
        row, a command saturates each drive past its bound).
        Empty without limits, friction or effort-limited drives.
        """
        if self.events is None:
            return {}
        c = self.events.counters
        excess = 0.0 if self.limits is None else self.limits.counters.max_violation
        return {**c, 'max_position_excess': excess}

    def drive_saturation(self) -> dict:
        """
        Return what the exact drives' effort limits do now: who is saturated, counters.

        ``{'saturated': {joint: +1 | -1}, 'counters': {'saturations': n, 'engagements':
        n}}`` (see :class:`.limits.DriveEfforts`); empty when no exact drive has an
        effort limit.
        """
        dr = self.drive_efforts
        if dr is None:
            return {}
        names = self.joints.names
        return {'saturated': {names[i]: int(dr.mode[i]) for i in dr.saturated()},
                'counters': dict(dr.counters)}

    def joint_limits(self) -> dict:
        """
        Return what the joint limits do now: active bounds, counters, latest impacts.

        ``{'active': {joint: 'lower' | 'upper'}, 'counters': {...}, 'impacts':
        [Impact, ...]}`` (see :mod:`.limits`); empty when no joint has an enforced
        limit.
        """
        lim = self.limits
        if lim is None:
            return {}
        return {'active': {self.joints.names[i]: 'lower' if lim.active[i] > 0 else 'upper'
                           for i in np.flatnonzero(lim.active)},
                'counters': lim.counters.as_dict(), 'impacts': list(lim.impacts)}

    # -- outputs --------------------------------------------------------------------------

    def pose(self, body: Optional[str] = None) -> tuple[np.ndarray, np.ndarray]:
        """
        Position of the body origin (3,) and orientation (4,, xyzw), world frame.

        With ``body`` None, arrays of all bodies, (n, 3) and (n, 4).
        """
        bodies = self.bodies
        out = bodies.outputs(self.state, None if body is None else bodies.lookup(body))
        return out[0].copy(), out[1].copy()

    def twist(self, body: Optional[str] = None,
              frame: str = 'world') -> tuple[np.ndarray, np.ndarray]:
        """Velocity of the body origin and angular velocity, in ``frame`` ('world' or 'body')."""
        bodies = self.bodies
        if frame == 'world':
            out = bodies.outputs(self.state, None if body is None else bodies.lookup(body))
            return out[2].copy(), out[3].copy()
        if frame == 'body':
            out = bodies.outputs(self.state, None if body is None else bodies.lookup(body))
            return out[4].copy(), out[5].copy()
        raise SpecError('frame', f"must be 'world' or 'body', got {frame!r}")

    def accelerations(self) -> tuple[np.ndarray, np.ndarray]:
        """
        Accelerations now: of each body origin (n, 3, m/s²) and angular (n, 3, rad/s²), world.

        From the equations of motion at the current state: every effect, the contact
        forces as the last step held them (none after a reset or a :meth:`place`), and
        the constraints' multipliers with them.
        """
        dyn, s = self.dynamics, self.state
        pos, quat, vel, om = s.parts
        contact, lent = self.contact, False
        if contact is not None and not len(contact.wrenches):
            # The compiled steps leave the forces in their record only: lent for this.
            rec = contact.record
            if rec.rows is not None and len(rec.rows) and np.any(rec.force):
                contact._set_forces(rec.rows, rec.force)
                lent = True
        try:
            acc, om_dot = dyn.accelerations(s.time, pos, quat, vel, om)
            if dyn.constrained:
                lam = dyn.solver.multipliers(dyn, s)
                f = dyn.solver.constraints.evaluate(pos, quat, vel, om).jacobian.rmatvec(lam)
                acc = acc - dyn.bodies.inv_mass[:, None] * f[:, :3]
                om_dot = om_dot - f[:, 3:] / dyn.bodies.moments
        finally:
            if lent:
                contact._set_forces(None)
        R = so3.quat_to_matrix(quat)
        alpha = np.einsum('nij,nj->ni', R, om_dot)
        omega = np.einsum('nij,nj->ni', R, om)
        # The origin sits at r = −R_wb c from the centre of mass (c: the COM in the body
        # frame): a_o = a_c + α × r + ω × (ω × r).
        origin, _, _, _, _, _ = self.bodies.outputs(s)
        r = origin - pos
        return acc + np.cross(alpha, r) + np.cross(omega, np.cross(omega, r)), alpha

    def diagnostics(self) -> Diagnostics:
        """Energies, world-frame momenta, orthonormality and constraint violation now."""
        d = diagnose(self.bodies, self.dynamics.effects, self.state)
        d = replace(d, accuracy=self.accuracy())
        if self.dynamics.constrained:
            solver = self.dynamics.solver
            phi = solver.violation(self.state)
            if self._drive_names:   # a drive's Φ is its tracking error, not a joint's drift
                present = set(solver.constraints.names)
                phi = np.delete(phi, [solver.constraints.rows_of(name)[0]
                                      for name in self._drive_names if name in present])
            d = replace(d, constraint_violation=float(np.max(np.abs(phi), initial=0.0)))
        return d

    def constraint_violation(self) -> dict:
        """
        Largest ``|Φ|`` of each constraint now (m or dimensionless for angles).

        An exact drive's (``<joint>_drive``) is its tracking error ``|q − q*|`` (rad
        or m), which :meth:`diagnostics` leaves out of ``constraint_violation``.
        """
        solver = self.dynamics.solver
        if not self.dynamics.constrained:
            return {}
        phi = solver.violation(self.state)
        out = {name: float(np.max(np.abs(phi[solver.constraints.rows_of(name)])))
               for name in solver.constraints.names}
        if self.events is not None:   # a bound's or friction's row counts as its joint's
            for row, i in self.events.held().items():
                joint, value = self.joints.names[i], out.pop(row)
                out[joint] = max(out.get(joint, 0.0), value)
        dr = self.drive_efforts
        if dr is not None:   # a saturated drive's tracking error, its row away
            for i in dr.saturated():
                out[dr.names[i]] = abs(float(dr.error(i, self.joints.positions[i], self.time,
                                                      self.joints.rotary[i])))
        return out

    def reactions(self) -> dict:
        """
        Reaction wrench of each constraint on each of its bodies, now.

        λ is solved at the current state from the full accelerations (all
        effects, gyroscopic terms, wrenches), so these are the forces the joints
        carry at this instant.

        Returns
        -------
        dict
            ``{name: {body_name: Reaction}}`` (the world is not listed).

        """
        dr = self.drive_efforts
        if not self.dynamics.constrained and (dr is None or not dr.motion):
            return {}
        fields = {} if not self.dynamics.constrained \
            else self.dynamics.solver.reactions(self.dynamics, self.state)
        if self.events is not None and self.events.held():
            self.events.merge_reactions(fields, self.state.pos_com_world, self.bodies.lookup)
        if dr is not None and dr.motion:
            fields.update(self.events.saturated_reactions(self._outputs_now()))
        return {name: {body: Reaction(**f) for body, f in per_body.items()}
                for name, per_body in fields.items()}

    def joint_anchors(self) -> dict:
        """
        Where each constraint's anchor on its first body is now, world frame (m).

        Returns
        -------
        dict
            ``{name: ndarray (3,)}``, in the order the constraints were added.

        """
        s = self.state
        constraints = self.dynamics.solver.constraints
        out = {}
        for name in constraints.names:
            (a, r_a) = constraints.anchors(name)[0]
            lever = so3.rotate(s.quat_principal_world[a], np.asarray(r_a))
            out[name] = s.pos_com_world[a] + lever
        return out

    def work(self) -> dict:
        """Work counters: integrator totals plus each effect's evaluations."""
        self.dynamics.settle_effect_work()
        out = self.dynamics.counters.as_dict()
        for effect in self.dynamics.effects:
            out[f'{effect.name}_evaluations'] = out.get(f'{effect.name}_evaluations', 0) \
                + effect.evaluations
            out[f'{effect.name}_body_evaluations'] = \
                out.get(f'{effect.name}_body_evaluations', 0) + effect.body_evaluations
        return out
