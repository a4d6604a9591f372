"""
One simulation as the node serves it, without the transport: shared by the node and the runner.

It holds what the node adds to a :class:`~rigid_body_sim.core.Simulation`: the
published clock (monotonic across resets unless ``reset_time``), the step count
since the last reset, the energy at the last reset, the queue of wrench
messages (the latest per body) and of joint commands (efforts, position and
velocity targets: the latest per joint), both applied before the next step,
the checks of inputs with their rejection counts, and which outputs a step
makes due. The node (:mod:`.node`) drives it from DDS and the wall clock; the
experiment runner (:mod:`.experiment`) from a schedule, in lockstep. So both
apply inputs and publish outputs the same way.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Optional

import numpy as np

from . import conversions as conv
from .inputs import check_group_command, check_joint_command, check_name_token, \
    check_wrench, constraint_from_request, Rejected, Rejection, shown
from .outputs import body_topic, constraint_topic, group_topic, Outputs
from .pacing import output_due, Totals
from ..core import DivergenceError, InconsistentConstraintError, SpecError
from ..scene import Scene


class Due(NamedTuple):
    """Which outputs a step made due."""

    clock: bool
    state: bool     # poses, twists, body states, reactions, metrics, markers
    joints: bool    # joint_states
    tf: bool        # /tf


class Session:
    """
    A scene's simulation with the node's clock, input queue and output schedule.

    Parameters
    ----------
    scene : Scene
    settings : Settings
        The node's parameters (physics_rate, integrator, world_frame, limits, ...).
    dt : float, optional
        s: the step, exactly (the runner's ``--dt``); default ``1 / physics_rate``.
    node_name : str
        The fully qualified name of the node whose private topics carry the
        bodies' and constraints' names, and in whose namespace the command
        groups' topics are (their lengths are checked against it).

    Raises
    ------
    SpecError
        A body, constraint or command group name that cannot be part of a ROS
        topic name.

    """

    def __init__(self, scene: Scene, settings: Any, dt: Optional[float] = None,
                 node_name: str = '/rigid_body_sim') -> None:
        self.node_name = node_name
        for name in scene.simulation.bodies.names:
            check_name_token(name, f'scene {scene.source}: body name',
                             self.full_topic(body_topic(name, 'wrench')))
        for name in scene.simulation.constraint_names:
            check_name_token(name, f'scene {scene.source}: constraint name',
                             self.full_topic(constraint_topic(name)))
        #: {group: (joints in the order of its commands, interface)}
        self.groups = {name: (tuple(g.joints), g.interface.value)
                       for name, g in scene.simulation.command_groups().items()}
        #: The robots there now, in the order of ``sim.robots``: (prefix, ParsedUrdf).
        self.robots = list(scene.robots)
        self.models = list(scene.simulation.robots)   # (whose the robots above are)
        for name in self.groups:
            check_name_token(name, f'scene {scene.source}: command group name',
                             self.full_relative_topic(group_topic(name)))
        self.scene = scene
        self.sim = scene.simulation
        self.settings = settings
        self.dt = dt
        self.scene_dt = self.sim.dt
        self.scene_integrator = self.sim.integrator_name
        self.scene_tolerance = self.sim.accuracy().tolerance
        self.configure()
        self.outputs = Outputs(self.sim, scene.shapes, settings.world_frame, self.robots)
        self.outputs.collision_markers = settings.collision_markers
        self.totals = Totals()
        self.pending: dict = {}   # body -> (force, torque, frame): the latest message
        self.superseded = 0       # wrench messages replaced before a step used them
        self.pending_commands: dict = {}   # joint -> effort or target: the latest command
        self.efforts_superseded = 0       # joint efforts replaced before a step used them
        self.targets_superseded = 0       # position/velocity targets replaced alike
        self.group_noops = 0              # <group>/commands messages of NaN only
        #: {joint: 'effort' | 'position' | 'velocity'}; joints outside groups take efforts
        self.interfaces = self.sim.joint_interfaces()
        self._rotary = dict(zip(self.sim.joints.names, self.sim.joints.rotary.tolist()))
        self.offset_ns = 0        # published time = this + the simulation's own time
        self.step_count = 0       # steps since the last reset
        self.diverged: Optional[str] = None
        self.energy0 = self.sim.diagnostics().total_energy

    def configure(self) -> None:
        """Apply physics_rate, integrator and tolerance (between steps; time stays continuous)."""
        s = self.settings
        self.sim.set_step(self.dt or 1.0 / s.physics_rate, s.integrator or self.scene_integrator)
        self.sim.set_tolerance(s.tolerance or self.scene_tolerance)
        if hasattr(self, 'outputs'):
            self.outputs.world_frame = s.world_frame
            self.outputs.collision_markers = s.collision_markers

    def check_settings(self, settings: Any) -> None:
        """
        Raise SpecError unless :meth:`configure` could apply ``settings``.

        The servos' gains must stay stable at the new step and integrator
        (:meth:`~rigid_body_sim.core.robots.JointDrives.check_stability`).
        """
        self.sim.check_step(self.dt or 1.0 / settings.physics_rate,
                            settings.integrator or self.scene_integrator)

    def full_topic(self, private: str) -> str:
        """Return the fully qualified name of a private topic ``~/...`` of the node."""
        return self.node_name.rstrip('/') + private[1:]

    def full_relative_topic(self, relative: str) -> str:
        """Return the fully qualified name of a topic relative to the node's namespace."""
        return self.node_name.rsplit('/', 1)[0] + '/' + relative

    # -- time -----------------------------------------------------------------------------

    def now_ns(self) -> int:
        """Return the published simulation time (ns)."""
        return self.offset_ns + int(round(self.sim.time * conv.NANOSECONDS))

    def seconds(self) -> float:
        """Return the published simulation time (s)."""
        return self.now_ns() / conv.NANOSECONDS

    def stamp(self):
        """Return the published simulation time as a ``builtin_interfaces/Time``."""
        return conv.time_msg_ns(self.now_ns())

    # -- inputs ---------------------------------------------------------------------------

    def queue_wrench(self, body: str, force: np.ndarray, torque: np.ndarray,
                     frame_id: str) -> None:
        """
        Check a wrench message on ``~/bodies/<body>/wrench`` and queue it for the next step.

        Raises
        ------
        Rejected
            NaN, inf, beyond the limits, or an unknown frame (counted).

        """
        s = self.settings
        try:
            frame = check_wrench(force, torque, frame_id, body, s.world_frame, s.max_force,
                                 s.max_torque)
        except Rejected as exc:
            self.totals.reject(exc.cause.value)
            raise
        if body in self.pending:
            self.superseded += 1   # two messages between steps: the later one wins
        self.pending[body] = (force, torque, frame)

    def effort_limits(self) -> dict:
        """``{joint: max_torque (revolute, continuous) or max_force (prismatic)}`` now."""
        s = self.settings
        return {name: s.max_torque if rotary else s.max_force
                for name, rotary in self._rotary.items()}

    def queue_joint_command(self, names: list, positions: np.ndarray,
                            velocities: np.ndarray, efforts: np.ndarray) -> dict:
        """
        Check a ``~/joint_commands`` message's arrays; queue its commands for the next step.

        Each joint is commanded through its interface (:data:`interfaces`): the
        entry of its own array, NaN or nothing in the others (see
        :func:`.inputs.check_joint_command`). Returns the ``{joint: command}``
        queued; joints not named keep their commands.

        Raises
        ------
        Rejected
            No names, mismatched lengths, a joint named twice, an unknown joint,
            a value on another interface than the joint's, NaN or inf where a
            value is required, beyond max_torque or max_force (counted); nothing
            is queued.

        """
        try:
            commands = check_joint_command(names, positions, velocities, efforts,
                                           self.interfaces, self.effort_limits())
        except Rejected as exc:
            self.totals.reject(exc.cause.value)
            raise
        self._queue(commands)
        return commands

    def queue_group_command(self, group: str, data: np.ndarray) -> dict:
        """
        Check a ``<group>/commands`` message's data; queue its commands for the next step.

        ``data``: one value per joint of the group, in its order, for its
        interface; NaN keeps a joint's command. Returns the ``{joint: command}``
        queued (empty for a message of NaN only: counted in :attr:`group_noops`).

        Raises
        ------
        Rejected
            A wrong size, inf, beyond max_torque or max_force (counted);
            nothing is queued.

        """
        joints, interface = self.groups[group]
        try:
            commands = check_group_command(group, joints, interface, data,
                                           self.effort_limits())
        except Rejected as exc:
            self.totals.reject(exc.cause.value)
            raise
        if not commands:
            self.group_noops += 1
        self._queue(commands)
        return commands

    def _queue(self, commands: dict) -> None:
        """Queue checked commands; count those that replace one no step has used."""
        for name in commands:
            if name in self.pending_commands:
                if self.interfaces[name] == 'effort':
                    self.efforts_superseded += 1
                else:
                    self.targets_superseded += 1
        self.pending_commands.update(commands)

    def apply_pending(self) -> None:
        """Apply the queued wrenches (each at its body frame's origin, held) and commands."""
        timeout = self.settings.wrench_timeout or None
        for body, (force, torque, frame) in self.pending.items():
            self.sim.apply_wrench(body, force, torque, frame=frame, point_body=(0.0, 0.0, 0.0),
                                  duration=timeout, key=f'topic:{body}')
        self.pending.clear()
        if self.pending_commands:
            commands, self.pending_commands = self.pending_commands, {}
            self.sim.command_joints(commands)   # (held until the next command per joint)

    def reset(self, time: Optional[bool] = None, scene: bool = False) -> None:
        """
        Back to the initial state; time runs on unless ``time`` (default: ``reset_time``).

        ``time``: the published clock restarts at 0 too. ``scene``: the scene as it was
        loaded (bodies spawned since removed, removed ones back); else the bodies there
        now, spawned ones where they were spawned. The caller follows a change of bodies
        (:meth:`bodies_changed`).
        """
        if self.settings.reset_time if time is None else time:
            self.offset_ns = 0
        else:   # the initial state is stamped one step after the last state
            self.offset_ns = self.now_ns() + int(round(self.sim.dt * conv.NANOSECONDS))
        # (both keep dt and the integrator; clear joint commands, counters)
        self.sim.reset_scene() if scene else self.sim.reset()
        self.pending.clear()
        self.pending_commands.clear()
        self.diverged = None
        self.step_count = 0
        self.energy0 = self.sim.diagnostics().total_energy

    def check_constraint(self, request: Any):
        """
        Check every field of an ``AddConstraint`` request; return its core spec.

        Changes nothing: the caller creates what the constraint needs (its
        reaction publisher), then :meth:`commit_constraint`.

        Raises
        ------
        Rejected
            Unknown body, a malformed field, a duplicate name (counted).

        """
        try:
            spec = constraint_from_request(
                request, self.sim.bodies.names,
                lambda name: self.full_topic(constraint_topic(name)))
            if spec.name in self.sim.constraint_names:
                raise Rejected(Rejection.BAD_CONSTRAINT,
                               f'name: a constraint {spec.name!r} exists already')
        except Rejected as exc:
            self.totals.reject(exc.cause.value)
            raise
        return spec

    def commit_constraint(self, spec: Any) -> int:
        """
        Add a checked constraint (:meth:`check_constraint`); return its rows.

        All or nothing: on any error the simulation is as before.

        Raises
        ------
        Rejected
            Inconsistent with the constraints present, or refused by the core
            (an anchor out of range, coinciding anchors; counted).

        """
        sim = self.sim
        before = sim.state
        try:
            sim.add_constraint(spec)
        except SpecError as exc:
            cause = Rejection.INCONSISTENT_CONSTRAINT \
                if isinstance(exc, InconsistentConstraintError) else Rejection.BAD_CONSTRAINT
            self.totals.reject(cause.value)
            raise Rejected(cause, str(exc)) from None
        except BaseException:   # (a bug: leave no half-added constraint behind)
            if spec.name in sim.constraint_names:
                sim.remove_constraint(spec.name)
            sim.state = before
            raise
        return sim.constraint_rows(spec.name)

    def add_constraint(self, request: Any) -> int:
        """Check and add a constraint from an ``AddConstraint`` request; return its rows."""
        return self.commit_constraint(self.check_constraint(request))

    def remove_constraint(self, name: str) -> int:
        """Remove a constraint; return its rows. Raises Rejected if there is none."""
        if name not in self.sim.constraint_names:
            self.totals.reject(Rejection.UNKNOWN_CONSTRAINT.value)
            raise Rejected(Rejection.UNKNOWN_CONSTRAINT,
                           f'name: no constraint {shown(name)}; present: '
                           f'{self.sim.constraint_names}')
        rows = self.sim.constraint_rows(name)
        self.sim.remove_constraint(name)
        return rows

    # -- stepping -------------------------------------------------------------------------

    def bodies_changed(self, markers: Optional[dict] = None, scene: bool = False,
                       robots: Optional[dict] = None) -> None:
        """
        Follow bodies and robots added or removed (a spawn, a deletion, a scene reset).

        ``markers``: ``{body: (shape, dims)}`` of bodies added (their marker shapes);
        ``scene``: the scene as loaded is back (its own marker shapes); ``robots``:
        ``{name: (prefix, ParsedUrdf)}`` of robots added. The outputs, command groups
        and joint interfaces are rebuilt for what is there now; inputs queued for
        bodies or joints gone are dropped.
        """
        names = set(self.sim.bodies.names)
        now = dict(self.scene.shapes)
        if not scene:
            now.update(self.outputs.shapes)
        shapes = {b: m for b, m in {**now, **(markers or {})}.items() if b in names}
        collision = self.outputs.collision_markers
        # The robots: (prefix, URDF) by robot name, as the simulation has them now.
        known = {m.spec.name: r for m, r in zip(self.models, self.robots)}
        if scene:
            known.update({m.spec.name: r for m, r in zip(self.sim.robots, self.scene.robots)})
        known.update(robots or {})
        self.robots = [known[m.spec.name] for m in self.sim.robots]
        self.models = list(self.sim.robots)
        self.groups = {name: (tuple(g.joints), g.interface.value)
                       for name, g in self.sim.command_groups().items()}
        self.interfaces = self.sim.joint_interfaces()
        self._rotary = dict(zip(self.sim.joints.names, self.sim.joints.rotary.tolist()))
        self.pending_commands = {j: c for j, c in self.pending_commands.items()
                                 if j in self.interfaces}
        self.outputs = Outputs(self.sim, shapes, self.settings.world_frame, self.robots)
        self.outputs.collision_markers = collision
        self.pending = {b: v for b, v in self.pending.items() if b in names}
        # (the energy drift reported is measured from the bodies there now)
        self.energy0 = self.sim.diagnostics().total_energy

    def restart_clock(self) -> None:
        """Restart the published clock at 0 now, the simulation where it is."""
        self.offset_ns = -int(round(self.sim.time * conv.NANOSECONDS))

    def advance(self) -> Due:
        """
        Apply queued inputs and take one step; return which outputs are due.

        Raises
        ------
        DivergenceError
            The step gave a non-finite state; the state stays at the last finite one
            and :attr:`diverged` says why.

        """
        self.apply_pending()
        t_before = self.sim.time
        try:
            self.sim.step()
        except DivergenceError as exc:
            self.diverged = str(exc)
            raise
        self.step_count += 1
        t_after = self.sim.time
        s = self.settings
        return Due(output_due(t_before, t_after, s.clock_rate),
                   output_due(t_before, t_after, s.publish_rate),
                   output_due(t_before, t_after, s.joint_state_rate_hz),
                   output_due(t_before, t_after, s.tf_rate_hz))

    def snapshot(self, **which) -> list:
        """Return ``[(private topic, message)]`` of one publish (see Outputs.snapshot)."""
        metrics = which.pop('metrics', True)
        return self.outputs.snapshot(
            self.stamp(), metrics=(self.step_count, self.energy0) if metrics else None,
            **which)
