"""
Run a scene in lockstep under a scripted schedule and record it as a rosbag2 bag (MCAP).

Usage::

    experiment SCENE.yaml --schedule SCHEDULE.yaml --bag OUT [--duration S]
               [--integrator NAME] [--dt S] [--publish-rate HZ] [--node NAME]

No wall clock and no DDS: the simulation steps as fast as it can, and the bag
holds the messages the node would publish for the same run (the same topics
under ``--node``, default ``/rigid_body_sim``; the same types and header stamps
in simulation time; ``/clock`` every step up to 1 kHz, the state at
``--publish-rate``, all topics as if subscribed), plus the schedule's inputs as
the messages that would have carried them: wrenches on ``~/bodies/<B>/wrench``
and the service calls as the service events ``ros2 bag record --all-services``
records (``~/add_constraint/_service_event``, ...; request and response), and
joint commands on ``~/joint_commands``. With robots, also ``joint_states`` and
``/tf`` with every state, and ``robot_description`` and ``/tf_static`` once (as
the node publishes them, ``tf: links``). Bag time is simulation time.
``/diagnostics`` (about the wall clock) is not written. The summary's largest
violation is over the published states (every ``1 / publish_rate``). The scene
and schedule files go into the bag's ``metadata.yaml`` (``custom_data``). Same
inputs, same bag, bit for bit.

A schedule file::

    duration: 6.0                 # s, optional (default: the scene's)
    events:                       # at: s of simulation time; applied before the
      - at: 0.5                   # first step that starts at or after it
        wrench: {body: bob, force: [0, 4, 0], torque: [0, 0, 0], frame: world,
                 duration: 0.1}   # frame: world or the body; no duration: held
      - at: 2.0
        remove_constraint: pivot
      - at: 3.0
        add_constraint: {name: tether, type: distance, body_a: bob, body_b: world,
                         anchor_b_body: [0, 0, 1]}
      - at: 4.0
        reset: true
      - at: 4.5                   # robots: joints through their interfaces (effort,
        joints: {joint1: 0.3}     # or a servo's or exact drive's target), held

Every error in a schedule (a key, a body or constraint name, a value, a
constraint removed that does not exist then) is refused before anything runs,
naming the file, the key path and the problem. Whether an added constraint is
consistent with the others depends on the state at that time: like the node,
the runner then records the refusal and runs on.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import json
from pathlib import Path
import sys
import time
from typing import Any, Optional, Sequence

import numpy as np
from rigid_body_sim_interfaces.srv import AddConstraint, RemoveConstraint
from rosgraph_msgs.msg import Clock
from service_msgs.msg import ServiceEventInfo
from std_msgs.msg import Header, String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from . import conversions as conv
from .bag import BagWriter
from .inputs import check_wrench, constraint_from_request, INTERFACE_FIELDS, Rejected
from .outputs import body_topic, JOINT_COMMANDS_TOPIC, JOINT_STATES_TOPIC, \
    ROBOT_DESCRIPTION_TOPIC, TF_STATIC_TOPIC, TF_TOPIC
from .session import Session
from .settings import Settings
from ..core import DivergenceError, INTEGRATORS, SpecError
from ..core.validate import finite_array, finite_scalar, positive_scalar
from ..scene import load_scene, SceneError, YamlLoader
from ..urdf import prefixed_xml

SCHEDULE_KEYS = ('duration', 'events')
EVENT_KINDS = ('wrench', 'add_constraint', 'remove_constraint', 'reset', 'joints')
WRENCH_KEYS = ('body', 'force', 'torque', 'frame', 'duration')
ADD_KEYS = tuple(AddConstraint.Request.get_fields_and_field_types())


class ScheduleError(ValueError):
    """A schedule that cannot run: ``"<file>: <key path>: <problem>"``."""


@dataclass
class Event:
    """One scheduled input, at simulation time ``at`` (s)."""

    at: float
    kind: str
    payload: Any
    release: bool = False   # the zero wrench that ends a pulse

    def order(self) -> tuple:
        """
        Sort key: by time to 1 ns, a pulse's release before new inputs at that time.

        (0.2 + 0.1 is 0.30000000000000004: without this the release of a pulse
        would land after, and cancel, a new wrench scheduled at 0.3.)
        """
        return (round(self.at, 9), not self.release)


def load_schedule(path: Path, body_names: Sequence[str], constraint_names: Sequence[str],
                  settings: Settings, joint_names: Sequence[str] = ()
                  ) -> tuple[list, Optional[float]]:
    """
    Read and check a schedule file; return its events in time order and its duration.

    ``joint_names``: the robots' joints, which ``joints`` events may command.

    Raises
    ------
    ScheduleError
        Naming the file, the key path and the problem.

    """
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ScheduleError(f'{path}: cannot read: {exc.strerror}') from None
    try:
        import yaml
        data = yaml.load(text, Loader=YamlLoader)
    except Exception as exc:  # noqa: B902 - any YAML error: report it, run nothing
        raise ScheduleError(f'{path}: not valid YAML: {exc}') from None
    try:
        return _events(data, body_names, constraint_names, settings, joint_names)
    except SpecError as exc:
        raise ScheduleError(f'{path}: {exc}') from None


def _events(data: Any, bodies: Sequence[str], constraints: Sequence[str],
            settings: Settings, joints: Sequence[str] = ()) -> tuple[list, Optional[float]]:
    if not isinstance(data, dict):
        raise SpecError('', f'expected a mapping with key events, got {data!r}')
    unknown = [k for k in data if k not in SCHEDULE_KEYS]
    if unknown:
        raise SpecError(str(unknown[0]), f'unknown key; expected one of {list(SCHEDULE_KEYS)}')
    duration = positive_scalar(data['duration'], 'duration') if 'duration' in data else None
    items = data.get('events')
    if not isinstance(items, list):
        raise SpecError('events', f'expected a list of events, got {items!r}')
    events = []
    for i, item in enumerate(items):
        field = f'events[{i}]'
        if not isinstance(item, dict):
            raise SpecError(field, f'expected a mapping, got {item!r}')
        kinds = [k for k in item if k != 'at']
        bad = [k for k in kinds if k not in EVENT_KINDS]
        if bad:
            raise SpecError(f'{field}.{bad[0]}',
                            f'unknown key; expected at and one of {list(EVENT_KINDS)}')
        if len(kinds) != 1:
            raise SpecError(field, f'expected at and exactly one of {list(EVENT_KINDS)}, got '
                                   f'{kinds or "none"}')
        if 'at' not in item:
            raise SpecError(f'{field}.at', 'missing (required): the time in s')
        at = finite_scalar(item['at'], f'{field}.at')
        if at < 0.0:
            raise SpecError(f'{field}.at', f'must be >= 0, got {at!r}')
        kind = kinds[0]
        value = item[kind]
        field = f'{field}.{kind}'
        if kind == 'wrench':
            events += _wrench_events(at, value, field, bodies, settings)
        elif kind == 'add_constraint':
            events.append(Event(at, kind, _add_request(value, field, bodies)))
        elif kind == 'remove_constraint':
            if not isinstance(value, str) or not value:
                raise SpecError(field, f'expected a constraint name, got {value!r}')
            events.append(Event(at, kind, value))
        elif kind == 'joints':
            events.append(Event(at, kind, _joint_values(value, field, joints)))
        elif value is not True:
            raise SpecError(field, f'expected true, got {value!r}')
        else:
            events.append(Event(at, kind, None))
    events.sort(key=Event.order)   # stable: events at one time keep their file order
    _check_names(events, list(constraints), items)
    return events, duration


def _joint_values(value: Any, field: str, joints: Sequence[str]) -> dict:
    """Check a ``joints`` event: ``{joint: value}`` of known joints, finite values."""
    if not isinstance(value, dict) or not value:
        raise SpecError(field, f'expected a mapping joint -> command, got {value!r}')
    out = {}
    for name, v in value.items():
        if name not in joints:
            raise SpecError(f'{field}.{name}', f'unknown joint; joints: {list(joints)}')
        out[name] = finite_scalar(v, f'{field}.{name}')
    return out


def _wrench_events(at: float, value: Any, field: str, bodies: Sequence[str],
                   settings: Settings) -> list:
    if not isinstance(value, dict):
        raise SpecError(field, f'expected a mapping, got {value!r}')
    unknown = [k for k in value if k not in WRENCH_KEYS]
    if unknown:
        raise SpecError(f'{field}.{unknown[0]}',
                        f'unknown key; expected one of {list(WRENCH_KEYS)}')
    body = value.get('body')
    if body not in bodies:
        raise SpecError(f'{field}.body', f'unknown body {body!r}; known bodies: '
                                         f'{list(bodies)}')
    force = finite_array(value.get('force', (0.0, 0.0, 0.0)), f'{field}.force', (3,))
    torque = finite_array(value.get('torque', (0.0, 0.0, 0.0)), f'{field}.torque', (3,))
    frame = value.get('frame', 'world')
    frame_id = settings.world_frame if frame == 'world' else frame
    try:
        check_wrench(force, torque, frame_id, body, settings.world_frame, settings.max_force,
                     settings.max_torque)
    except Rejected as exc:
        what = str(exc).split(':', 1)
        key = {'header.frame_id': 'frame'}.get(what[0], what[0].split('.')[-1])
        raise SpecError(f'{field}.{key}', what[1].strip()) from None
    on = Event(at, 'wrench', (body, force, torque, frame_id))
    if 'duration' not in value:
        return [on]
    d = positive_scalar(value['duration'], f'{field}.duration')
    return [on, Event(at + d, 'wrench', (body, np.zeros(3), np.zeros(3), frame_id),
                      release=True)]


def _add_request(value: Any, field: str, bodies: Sequence[str]) -> AddConstraint.Request:
    if not isinstance(value, dict):
        raise SpecError(field, f'expected a mapping, got {value!r}')
    unknown = [k for k in value if k not in ADD_KEYS]
    if unknown:
        raise SpecError(f'{field}.{unknown[0]}',
                        f'unknown key; expected some of {list(ADD_KEYS)}')
    request = AddConstraint.Request()
    for key, item in value.items():
        try:
            if key in ('anchor_world', 'anchor_a_body', 'anchor_b_body', 'axis_world'):
                setattr(request, key, [float(x) for x in finite_array(
                    item, f'{field}.{key}', (len(item),) if isinstance(item, list) else (3,))])
            elif key == 'length':
                setattr(request, key, finite_scalar(item, f'{field}.{key}'))
            elif not isinstance(item, str):
                raise SpecError(f'{field}.{key}', f'expected a string, got {item!r}')
            else:
                setattr(request, key, item)
        except (TypeError, AssertionError):
            raise SpecError(f'{field}.{key}', f'invalid value {item!r}') from None
    try:
        constraint_from_request(request, bodies)
    except Rejected as exc:
        raise SpecError(field, str(exc)) from None
    return request


def _check_names(events: list, present: list, items: list) -> None:
    """Follow the constraint names through the schedule: adds new, removes present."""
    initial = list(present)
    for event in events:
        if event.kind == 'add_constraint':
            if event.payload.name in present:
                raise SpecError(_where(event, items), f'a constraint {event.payload.name!r} '
                                                      f'exists already at t = {event.at:g} s')
            present.append(event.payload.name)
        elif event.kind == 'remove_constraint':
            if event.payload not in present:
                raise SpecError(_where(event, items), f'no constraint {event.payload!r} at '
                                                      f't = {event.at:g} s; present: '
                                                      f'{present}')
            present.remove(event.payload)
        elif event.kind == 'reset':
            present[:] = initial


def _after_the_run(events: list, duration: float, dt: float) -> list:
    """
    Return the inputs a run would never apply: those after the start of its last step.

    The run takes ``round(duration / dt)`` steps; a reset stamps the initial state one
    step after the last (time runs on), so each reset applied moves the later steps,
    the last one included, one ``dt`` later.
    """
    last = (int(round(duration / dt)) - 1) * dt
    late = []
    for e in sorted(events, key=Event.order):
        if round(e.at, 9) > last + 1e-9 * max(1.0, abs(last)):
            if not e.release:
                late.append(e)
        elif e.kind == 'reset':
            last += dt
    return late


def _where(event: Event, items: list) -> str:
    for i, item in enumerate(items):
        if isinstance(item, dict) and event.kind in item and item.get('at') == event.at:
            return f'events[{i}].{event.kind}'
    return event.kind


class Runner:
    """
    Step a Session under a schedule and write what the node would publish into a bag.

    Parameters
    ----------
    session : Session
    events : list of Event
    writer : BagWriter
    node : str
        Fully qualified name of the node the bag's topics belong to.

    """

    def __init__(self, session: Session, events: list, writer: BagWriter,
                 node: str = '/rigid_body_sim') -> None:
        self.session = session
        self.events = list(events)
        self.writer = writer
        self.node = node.rstrip('/')
        self.namespace = self.node.rsplit('/', 1)[0]   # '' for the root namespace
        self.sequence = 0
        self.largest_violation = 0.0
        self.last_metrics = None
        self.refused: list = []

    def topic(self, name: str) -> str:
        """Resolve a topic name: private (``~/...``), relative or absolute, as the node's."""
        if name.startswith('~'):
            return self.node + name[1:]
        return name if name.startswith('/') else f'{self.namespace}/{name}'

    def run(self, duration: float, progress=None) -> int:
        """Run until ``duration`` s of simulated time have passed; return the steps taken."""
        session = self.session
        n_steps = int(round(duration / session.sim.dt))
        self._write_clock()
        self._write_robots()
        self._write_state()
        t0 = time.perf_counter()
        last_report = t0
        for k in range(n_steps):
            self._apply_due_events()
            due = session.advance()
            if due.clock:
                self._write_clock()
            if due.state:
                self._write_state()
            now = time.perf_counter()
            if progress and now - last_report > 2.0:
                progress(k + 1, n_steps, now - t0)
                last_report = now
        return n_steps

    def _apply_due_events(self) -> None:
        now = self.session.seconds()
        tolerance = 1e-9 * max(1.0, abs(now))
        while self.events and round(self.events[0].at, 9) <= now + tolerance:
            event = self.events.pop(0)
            getattr(self, f'_do_{event.kind}')(event.payload)

    def _do_wrench(self, payload: tuple) -> None:
        body, force, torque, frame_id = payload
        header = Header(stamp=self.session.stamp(), frame_id=frame_id)
        msg = conv.wrench_stamped(header, force, torque)
        self.writer.write_msg(self.topic(body_topic(body, 'wrench')), self.session.now_ns(),
                              msg)
        self.session.queue_wrench(body, force, torque, frame_id)

    def _do_add_constraint(self, request: AddConstraint.Request) -> None:
        response = AddConstraint.Response()
        try:
            response.rows_added = self.session.add_constraint(request)
            response.success = True
            response.message = f'added {request.type} constraint {request.name!r} ' \
                               f'({response.rows_added} rows)'
        except Rejected as exc:
            response.success, response.message = False, str(exc)
            self.refused.append(f't = {self.session.seconds():g} s: add_constraint '
                                f'{request.name!r}: {exc}')
        self._service_events(AddConstraint, '~/add_constraint', request, response)

    def _do_remove_constraint(self, name: str) -> None:
        request = RemoveConstraint.Request(name=name)
        response = RemoveConstraint.Response()
        try:   # (checked up front; absent only if its add was refused at run time)
            response.rows_removed = self.session.remove_constraint(name)
            response.success = True
            response.message = f'removed constraint {name!r} ({response.rows_removed} rows)'
        except Rejected as exc:
            response.success, response.message = False, str(exc)
            self.refused.append(f't = {self.session.seconds():g} s: remove_constraint '
                                f'{name!r}: {exc}')
        self._service_events(RemoveConstraint, '~/remove_constraint', request, response)

    def _do_joints(self, values: dict) -> None:
        """Command joints through their interfaces, as a ``~/joint_commands`` message."""
        interfaces = self.session.interfaces
        names = list(values)
        arrays = {}
        for field in INTERFACE_FIELDS:
            mine = [interfaces[n] == field for n in names]
            arrays[field] = (np.array([values[n] if m else np.nan for n, m in zip(names, mine)])
                             if any(mine) else np.zeros(0))
        msg = conv.joint_state(Header(stamp=self.session.stamp()), names, arrays['position'],
                               arrays['velocity'], arrays['effort'])
        self.writer.write_msg(self.topic(JOINT_COMMANDS_TOPIC), self.session.now_ns(), msg)
        try:   # the node's checks (max_torque, max_force), applied before the next step
            self.session.queue_joint_command(names, arrays['position'], arrays['velocity'],
                                             arrays['effort'])
        except Rejected as exc:
            self.refused.append(f't = {self.session.seconds():g} s: joints: {exc}')

    def _do_reset(self, _: Any) -> None:
        request = Trigger.Request()
        self.session.reset()
        response = Trigger.Response(success=True, message='reset to the initial state')
        self._service_events(Trigger, '~/reset', request, response)
        self._write_clock()
        self._write_state()

    def _service_events(self, srv_type: Any, service: str, request: Any,
                        response: Any) -> None:
        """Write the request-received and response-sent events of one call."""
        self.sequence += 1
        stamp = self.session.stamp()
        topic = self.topic(service) + '/_service_event'
        for event_type, req, resp in ((ServiceEventInfo.REQUEST_RECEIVED, [request], []),
                                      (ServiceEventInfo.RESPONSE_SENT, [], [response])):
            event = srv_type.Event(request=req, response=resp)
            event.info = ServiceEventInfo(event_type=event_type, stamp=stamp,
                                          sequence_number=self.sequence)
            self.writer.write_msg(topic, self.session.now_ns(), event)

    def _write_clock(self) -> None:
        self.writer.write_msg('/clock', self.session.now_ns(), Clock(clock=self.session.stamp()))

    def _write_robots(self) -> None:
        """Write robot_description (the first robot's, prefixed) and /tf_static, once."""
        robots = self.session.scene.robots
        if not robots:
            return
        t, stamp = self.session.now_ns(), self.session.stamp()
        prefix, parsed = robots[0]
        self.writer.write_msg(self.topic(ROBOT_DESCRIPTION_TOPIC), t,
                              String(data=prefixed_xml(parsed.xml, prefix)))
        self.writer.write_msg(TF_STATIC_TOPIC, t, TFMessage(
            transforms=self.session.outputs.static_transforms(stamp)))

    def _write_state(self) -> None:
        t = self.session.now_ns()
        for topic, msg in self.session.snapshot():
            self.writer.write_msg(self.topic(topic), t, msg)
            if topic == '~/metrics':
                self.largest_violation = max(self.largest_violation, msg.constraint_violation)
                self.last_metrics = msg
        stamp = self.session.stamp()
        if self.session.sim.joint_names():   # (as the node: joint_states with joints,
            self.writer.write_msg(self.topic(JOINT_STATES_TOPIC), t,   # /tf with robots)
                                  self.session.outputs.joint_states(stamp))
        if self.session.scene.robots:
            self.writer.write_msg(TF_TOPIC, t, TFMessage(
                transforms=self.session.outputs.transforms(stamp)))


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='experiment', description=__doc__.splitlines()[1])
    p.add_argument('scene', help='scene YAML file')
    p.add_argument('--schedule', required=True, help='schedule YAML file (inputs over time)')
    p.add_argument('--bag', required=True, help='bag folder to write (must not exist)')
    p.add_argument('--duration', type=float,
                   help="simulated seconds (default: the schedule's, else the scene's)")
    p.add_argument('--integrator', choices=sorted(INTEGRATORS),
                   help="override the scene's integrator")
    p.add_argument('--dt', type=float, help="override the scene's step size (s)")
    p.add_argument('--publish-rate', type=float, default=100.0,
                   help='Hz of simulated time for the state topics (default 100, as the node)')
    p.add_argument('--node', default='/rigid_body_sim',
                   help='node name the topics belong to (default /rigid_body_sim)')
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run an experiment; returns the exit code (2: a bad scene, schedule or option)."""
    args = _parser().parse_args(argv)
    try:
        scene = load_scene(args.scene)
        sim = scene.simulation
        dt = sim.dt if args.dt is None else args.dt
        settings = Settings.from_values({
            'physics_rate': 1.0 / positive_scalar(dt, '--dt'),   # (the exact dt: Session)
            'publish_rate': positive_scalar(args.publish_rate, '--publish-rate'),
            'integrator': args.integrator or ''})
        events, schedule_duration = load_schedule(
            Path(args.schedule), sim.bodies.names, sim.constraint_names, settings,
            sim.joint_names())
        duration = args.duration or schedule_duration or scene.duration
        positive_scalar(duration, '--duration')
        late = _after_the_run(events, duration, dt)
        if late and not args.duration:
            raise ScheduleError(
                f'{args.schedule}: events: the {late[0].kind} at t = {late[0].at:g} s comes '
                f"after the run's last step (duration {duration:g} s, dt {dt:g} s) and would "
                "never be applied; lengthen the schedule's duration: or move the event")
        if late:   # a shorter run asked for on the command line: say what it leaves out
            print(f'experiment: note: --duration {duration:g} s ends the run before '
                  f'{len(late)} scheduled input(s) (the first: {late[0].kind} at t = '
                  f'{late[0].at:g} s); they are not applied', file=sys.stderr)
        if Path(args.bag).exists():
            raise SpecError('--bag', f'{args.bag} exists already; choose a new bag folder')
    except (SceneError, ScheduleError, SpecError) as exc:
        print(f'experiment: error: {exc}', file=sys.stderr)
        return 2
    session = Session(scene, settings, dt=dt)
    metadata = {
        'rigid_body_sim.scene': Path(args.scene).read_text(),
        'rigid_body_sim.schedule': Path(args.schedule).read_text(),
        'rigid_body_sim.run': json.dumps({
            'scene': Path(args.scene).name, 'schedule': Path(args.schedule).name,
            'duration': duration, 'dt': sim.dt, 'integrator': sim.integrator_name,
            'publish_rate': settings.publish_rate, 'node': args.node}, sort_keys=True),
    }
    print(f'experiment: scene {scene.name!r} ({len(sim.bodies)} bodies, '
          f'{len(sim.constraint_names)} constraints), {len(events)} scheduled inputs, '
          f'{sim.integrator_name} at dt {sim.dt:g} s for {duration:g} s -> {args.bag}',
          flush=True)

    def progress(done: int, total: int, wall: float) -> None:
        print(f'  t = {done * sim.dt:.3f} s of {duration:g} s ({100 * done / total:.0f} %), '
              f'{wall:.1f} s wall', flush=True)
    t0 = time.perf_counter()
    with BagWriter(Path(args.bag), metadata) as writer:
        runner = Runner(session, events, writer, args.node)
        try:
            steps = runner.run(duration, progress)
        except DivergenceError as exc:
            print(f'experiment: the run diverged: {exc}; the bag holds what came before',
                  file=sys.stderr)
            return 1
    wall = time.perf_counter() - t0
    m = runner.last_metrics
    print(f'done: {steps} steps in {wall:.2f} s wall ({steps * sim.dt / wall:.1f}x real '
          f'time); energy change {m.energy_change:+.3e} J since the last reset; largest '
          f'constraint violation {runner.largest_violation:.2e}; '
          f'{sum(writer.counts.values())} messages on {len(writer.counts)} topics')
    for line in runner.refused:
        print(f'refused: {line}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
