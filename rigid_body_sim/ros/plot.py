"""
Plot a bag of the simulator node's topics: one PNG to look at rather than read.

Usage: ``plot BAG [--node /rigid_body_sim] [--bodies B ...] [-o OUT.png]``.
BAG is a rosbag2 folder (or one of its ``.mcap`` / ``.db3`` files) holding the
node's ``<node>/body_states`` and, when recorded, ``<node>/metrics``,
``<node>/constraints/<C>/wrench``, ``<node>/bodies/<B>/wrench`` and the
service events of ``reset``, ``add_constraint`` and ``remove_constraint``, and of
the standard's ``spawn_entity`` and ``delete_entity`` (in the node's namespace). The
panels share the simulation time axis (header stamps, not the time the bag
received a message): body positions x, y, z; how far each body has turned
from its first orientation; energy; energy change; constraint violation (log
scale); reaction force magnitude per constraint. Wrench inputs are shaded
while they hold; resets, constraint changes, spawns and deletions are lines across
all panels. Bodies spawned or deleted during the recording are drawn while they
exist; without ``--bodies`` the first bodies to appear are drawn.
A panel without data is left out, and the title says so. Without ``-o`` the
picture goes next to the bag, ``BAG.png``. Exit code 2 for a missing or
unreadable bag, one without body states, an unknown ``--node`` or body.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path
import re
import sys
from typing import Optional, Sequence

import numpy as np
from rosbags.rosbag2 import Reader, ReaderError

from .bag import typestore

BODY_STATES = 'rigid_body_sim_interfaces/msg/BodyStates'
METRICS = 'rigid_body_sim_interfaces/msg/Metrics'
WRENCH = 'geometry_msgs/msg/WrenchStamped'
METRIC_FIELDS = ('total_energy', 'kinetic_energy', 'potential_energy', 'energy_change',
                 'constraint_violation')
#: Without ``--bodies``, at most this many bodies are drawn (the first ones of the bag).
MAX_BODIES = 8
#: The node's services whose calls are marked on the time axis (from their service events).
SERVICES = ('reset', 'add_constraint', 'remove_constraint')
#: The ROS simulator interface's calls marked alike (under the node's namespace).
STANDARD_SERVICES = ('spawn_entity', 'delete_entity')
#: simulation_interfaces/msg/Result: RESULT_OK.
RESULT_OK = 1


class PlotError(Exception):
    """A bag that cannot be plotted as asked; the message names the path and the reason."""


@dataclass
class Reaction:
    """The reaction force of one constraint over time, one sample per stamp."""

    t: np.ndarray            # (n,) s, simulation time
    force: np.ndarray        # (n, 3) N, in the axes of ``frames[k]``
    frames: list             # frame_id of the message each sample comes from

    @property
    def magnitude(self) -> np.ndarray:
        """|F| in N (the same in any axes)."""
        return np.linalg.norm(self.force, axis=1)


@dataclass
class WrenchInputs:
    """The wrench messages sent to one body (``<node>/bodies/<B>/wrench``)."""

    t: np.ndarray            # (n,) s, simulation time at which the node received them
    force: np.ndarray        # (n, 3) N
    torque: np.ndarray       # (n, 3) N m
    frames: list             # frame_id of each message


@dataclass
class ServiceEvent:
    """A call of the node's reset, add_constraint, remove_constraint, spawn or delete."""

    t: float                 # s, simulation time at which the bag received the reply
    service: str             # one of SERVICES or STANDARD_SERVICES
    name: str                # the constraint's or entity's name ('' for reset)
    success: bool
    message: str


@dataclass
class BagSeries:
    """Everything :func:`read_bag` extracted and :func:`draw` plots."""

    bag: Path
    node: str                                   # the node prefix plotted, e.g. /rigid_body_sim
    nodes: list                                 # all node prefixes with body_states
    world_frame: str
    all_bodies: list                            # every body name in body_states
    bodies: list                                # the ones extracted
    t: np.ndarray                               # (n,) s, body_states stamps
    position: dict = field(default_factory=dict)     # body -> (n, 3) m, NaN where absent
    orientation: dict = field(default_factory=dict)  # body -> (n, 4) (x, y, z, w)
    metrics: Optional[dict] = None              # 't' and METRIC_FIELDS -> (m,) arrays
    reactions: dict = field(default_factory=dict)    # constraint -> Reaction
    inputs: dict = field(default_factory=dict)       # body -> WrenchInputs
    events: list = field(default_factory=list)       # ServiceEvent, in bag order
    #: s: stamps of the first state after each reset (the reset state), in time order.
    resets: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def restarts(self) -> np.ndarray:
        """Return the indices into ``t`` where an episode starts anew (a reset, time back)."""
        back = np.flatnonzero(np.diff(self.t) < 0) + 1
        at = np.searchsorted(self.t, self.resets) if np.all(np.diff(self.t) >= 0) else []
        at = [i for i in at if 0 < i < len(self.t)]
        return np.unique(np.concatenate([back, at]).astype(int))

    def orientation_angle_deg(self, body: str) -> tuple[np.ndarray, Optional[np.ndarray]]:
        """Return the orientation panel's angle of a body: see :func:`orientation_angle_deg`."""
        return orientation_angle_deg(self.orientation[body], self.restarts())


#: rad: rotations whose axes all lie within this of one fixed axis are planar motion.
AXIS_TOLERANCE = 1e-3
#: rad: rotations smaller than this have too uncertain an axis to judge planarity.
ANGLE_FOR_AXIS = 1e-2


def orientation_angle_deg(quat_xyzw: np.ndarray,
                          restarts: Sequence[int] = ()) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """
    Return how far a body has turned from its first (finite) orientation, in degrees.

    The rotation since the start, ``q q0*`` (world axes), has an angle and an
    axis. When every sample's axis is one fixed axis (within
    :data:`AXIS_TOLERANCE`: planar motion, a hinge, a pendulum swinging in a
    plane) the angle is signed about that axis and unwrapped, so a swing reads
    as a swing and a spin as a steady climb; that axis (unit, its largest
    component positive) is returned too. Otherwise the angle is unsigned, 0 to
    180 degrees (``2 atan2(|vector part|, |scalar part|)``, accurate near 0 and
    180), and the axis is None.

    Parameters
    ----------
    quat_xyzw : ndarray, shape (n, 4)
        Orientations (x, y, z, w), body to world; NaN rows where the body is absent.
    restarts : sequence of int
        Indices where the motion jumps (a reset): the signed angle is unwrapped
        within each episode only, each one starting in (-180, 180] degrees.

    Returns
    -------
    angle : ndarray, shape (n,)
        deg; NaN where the orientation is.
    axis : ndarray, shape (3,), or None

    """
    q = np.asarray(quat_xyzw, dtype=float)
    finite = np.all(np.isfinite(q), axis=1)
    angle = np.full(len(q), np.nan)
    if not np.any(finite):
        return angle, None
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x0, y0, z0, w0 = q[np.flatnonzero(finite)[0]]
    x, y, z, w = q.T
    # Hamilton product q * conj(q0), scalar last: the rotation since the start, world axes.
    v = np.stack([-w * x0 + x * w0 - y * z0 + z * y0,
                  -w * y0 + x * z0 + y * w0 - z * x0,
                  -w * z0 - x * y0 + y * x0 + z * w0], axis=1)
    r = w * w0 + x * x0 + y * y0 + z * z0
    s = np.linalg.norm(v, axis=1)
    unsigned = 2.0 * np.arctan2(s, np.abs(r))
    turned = finite & (unsigned > ANGLE_FOR_AXIS)
    if np.any(turned):
        axes = v[turned] / s[turned, None]
        axis = axes[0] * np.sign(axes[0][np.argmax(np.abs(axes[0]))])
        if np.all(np.abs(axes @ axis) >= np.cos(AXIS_TOLERANCE)):
            # q and -q are one rotation: the sign of r picks the angle in [-pi, pi].
            signed = 2.0 * np.arctan2(np.sign(r + (r == 0)) * (v @ axis), np.abs(r))
            for part in np.split(np.arange(len(q)), list(restarts)):
                part = part[finite[part]]
                angle[part] = np.degrees(np.unwrap(signed[part], period=2.0 * np.pi))
            return angle, axis
    angle[finite] = np.degrees(unsigned[finite])
    return angle, None


def axis_name(axis: np.ndarray) -> str:
    """Return ``+y`` for a unit axis along a world axis, else its rounded components."""
    k = int(np.argmax(np.abs(axis)))
    if abs(axis[k]) > np.cos(AXIS_TOLERANCE):
        return ('+' if axis[k] > 0 else '-') + 'xyz'[k]
    return '[' + ', '.join(f'{c:.2f}' for c in axis) + ']'


def _seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _open(path: Path) -> Reader:
    if not path.exists():
        raise PlotError(f'{path}: no such bag (a rosbag2 folder or its .mcap file)')
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError, ValueError) as exc:
        raise PlotError(f'{path}: not a readable rosbag2 bag ({exc})') from None
    return reader


def node_prefixes(connections) -> list:
    """Return the sorted node prefixes (``/ns/node``) that have a ``body_states`` topic."""
    return sorted({c.topic[:-len('/body_states')] for c in connections
                   if c.topic.endswith('/body_states') and c.msgtype == BODY_STATES})


def read_bag(path, node: Optional[str] = None,
             bodies: Optional[Sequence[str]] = None) -> BagSeries:
    """
    Return the series a plot of the bag at ``path`` shows.

    Parameters
    ----------
    path : str or Path
        A rosbag2 folder, or one ``.mcap`` / ``.db3`` file of it.
    node : str, optional
        The node prefix (``/rigid_body_sim``, ``/robot1/rigid_body_sim``); default:
        the first, alphabetically, of those with a ``body_states`` topic.
    bodies : sequence of str, optional
        Bodies to extract; default: the first :data:`MAX_BODIES` of the bag.

    Raises
    ------
    PlotError
        No such bag, no ``body_states`` in it, an unknown node or body.

    """
    path = Path(path)
    reader = _open(path)
    try:
        return _read(reader, path, node, bodies)
    finally:
        reader.close()


def _read(reader: Reader, path: Path, node: Optional[str],
          bodies: Optional[Sequence[str]]) -> BagSeries:
    connections = list(reader.connections)
    nodes = node_prefixes(connections)
    if not nodes:
        raise PlotError(f'{path}: no <node>/body_states topic ({BODY_STATES}) in this bag; '
                        f'topics: {", ".join(sorted({c.topic for c in connections})) or "none"}')
    if node is None:
        node = nodes[0]
    else:
        node = '/' + node.strip('/') if node.strip('/') else ''
        if node not in nodes:
            raise PlotError(f'{path}: no node {node!r} with body_states; nodes: '
                            f'{", ".join(nodes)}')
    store = typestore()
    states_topic, metrics_topic = f'{node}/body_states', f'{node}/metrics'
    reaction_re = re.compile(re.escape(node) + r'/constraints/([^/]+)/wrench')
    input_re = re.compile(re.escape(node) + r'/bodies/([^/]+)/wrench')
    service_re = re.compile(re.escape(node) + r'/(' + '|'.join(SERVICES) + ')/_service_event')
    namespace = node.rsplit('/', 1)[0]   # (the standard's services are the node's siblings)
    standard_re = re.compile(re.escape(namespace) + r'/(' + '|'.join(STANDARD_SERVICES)
                             + ')/_service_event')
    wanted = [c for c in connections
              if (c.topic == states_topic and c.msgtype == BODY_STATES)
              or (c.topic == metrics_topic and c.msgtype == METRICS)
              or (c.msgtype == WRENCH and (reaction_re.fullmatch(c.topic)
                                           or input_re.fullmatch(c.topic)))
              or ((service_re.fullmatch(c.topic) or standard_re.fullmatch(c.topic))
                  and c.msgtype.endswith('_Event'))]

    stamps, logtimes = [], []
    all_bodies: list = []
    chosen = list(dict.fromkeys(bodies)) if bodies else []
    position: dict = {b: [] for b in chosen}
    orientation: dict = {b: [] for b in chosen}
    world_frame = None
    index: dict = {}
    names_seen: list = []
    metrics: dict = {'t': [], 'step_count': []}
    metrics.update((name, []) for name in METRIC_FIELDS)
    reactions: dict = {}    # constraint -> [(stamp, [(force, frame), ...]), ...]
    inputs: dict = {}       # body -> [(logtime, stamp, force, torque, frame), ...]
    calls: dict = {}        # (service, client, sequence) -> [request name, (logtime, reply)]
    nan3, nan4 = np.full(3, np.nan), np.full(4, np.nan)
    # One pass over the bag (reading it is most of the cost for large bags).
    for conn, logtime, raw in reader.messages(connections=wanted):
        msg = store.deserialize_cdr(raw, conn.msgtype)
        topic = conn.topic
        if topic == states_topic:
            names = list(msg.names)
            if names != names_seen:
                names_seen = names
                index = {n: i for i, n in enumerate(names)}
                all_bodies.extend(n for n in names if n not in all_bodies)
                # Without --bodies, the first MAX_BODIES to appear (spawned ones too),
                # NaN before they did.
                for n in names:
                    if not bodies and n not in position and len(chosen) < MAX_BODIES:
                        chosen.append(n)
                        position[n] = [nan3] * len(stamps)
                        orientation[n] = [nan4] * len(stamps)
            if world_frame is None and msg.header.frame_id:
                world_frame = msg.header.frame_id
            stamps.append(_seconds(msg.header.stamp))
            logtimes.append(logtime)
            pos = np.asarray(msg.position, dtype=float).reshape(-1, 3)
            quat = np.asarray(msg.orientation, dtype=float).reshape(-1, 4)
            for body in chosen:
                i = index.get(body)
                position[body].append(nan3 if i is None else pos[i])
                orientation[body].append(nan4 if i is None else quat[i])
        elif topic == metrics_topic:
            metrics['t'].append(_seconds(msg.header.stamp))
            metrics['step_count'].append(msg.step_count)
            for name in METRIC_FIELDS:
                metrics[name].append(getattr(msg, name))
        elif reaction_re.fullmatch(topic):
            groups = reactions.setdefault(reaction_re.fullmatch(topic).group(1), [])
            stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
            f = msg.wrench.force
            if not groups or groups[-1][0] != stamp:
                groups.append((stamp, []))
            groups[-1][1].append(((f.x, f.y, f.z), msg.header.frame_id))
        elif input_re.fullmatch(topic):
            w = msg.wrench
            inputs.setdefault(input_re.fullmatch(topic).group(1), []).append(
                (logtime, _seconds(msg.header.stamp), (w.force.x, w.force.y, w.force.z),
                 (w.torque.x, w.torque.y, w.torque.z), msg.header.frame_id))
        else:
            # Server and client sides both record a call; one entry per call, its first
            # reply (the server's, sent before the client receives it).
            info = msg.info
            matched = service_re.fullmatch(topic) or standard_re.fullmatch(topic)
            call = calls.setdefault((matched.group(1), bytes(info.client_gid),
                                     info.sequence_number), ['', None])
            if msg.request:
                call[0] = getattr(msg.request[0], 'name', '') or \
                    getattr(msg.request[0], 'entity', '')
            if msg.response and call[1] is None:
                call[1] = (logtime, msg.response[0])

    if not stamps:
        raise PlotError(f'{path}: {states_topic} has no messages')
    if not chosen:
        raise PlotError(f'{path}: {states_topic} names no bodies')
    unknown = [b for b in chosen if b not in all_bodies]
    if unknown:
        raise PlotError(f'{path}: no body {", ".join(map(repr, unknown))} in '
                        f'{states_topic}; bodies: {", ".join(all_bodies)}')
    series = BagSeries(bag=path, node=node, nodes=nodes, world_frame=world_frame or 'world',
                       all_bodies=all_bodies, bodies=chosen, t=np.array(stamps),
                       position={b: np.array(v) for b, v in position.items()},
                       orientation={b: np.array(v) for b, v in orientation.items()})
    if metrics['t']:
        series.metrics = {k: np.array(v, dtype=float) for k, v in metrics.items()}
    for name in sorted(reactions):
        # Per stamp the world-frame message if there is one, else the first one.
        picked = [next((m for m in group if m[1] == series.world_frame), group[0])
                  for _, group in reactions[name]]
        series.reactions[name] = Reaction(
            t=np.array([sec + ns * 1e-9 for (sec, ns), _ in reactions[name]]),
            force=np.array([f for f, _ in picked], dtype=float),
            frames=[frame for _, frame in picked])
    # Wrench inputs and service calls: the node ignores input stamps (ros2 topic pub
    # leaves them 0) and acts on both before its next step, so their time is the
    # simulation time at which the bag received them, interpolated between the body
    # states around it (for inputs their stamps when the bag's receive times run back).
    logtimes = np.array(logtimes, dtype=np.int64)
    monotonic = bool(logtimes[-1] > logtimes[0] and np.all(np.diff(logtimes) >= 0))

    def sim_time(received: Sequence[int]) -> np.ndarray:
        return np.interp(np.array(received, dtype=np.int64) - logtimes[0],
                         logtimes - logtimes[0], series.t)

    for body in sorted(inputs):
        if body not in chosen:
            continue
        rows = inputs[body]
        series.inputs[body] = WrenchInputs(
            t=sim_time([r[0] for r in rows]) if monotonic else np.array([r[1] for r in rows]),
            force=np.array([r[2] for r in rows], dtype=float),
            torque=np.array([r[3] for r in rows], dtype=float),
            frames=[r[4] for r in rows])
    replies = sorted(((reply[0], service, name, reply[1])
                      for (service, _, _), (name, reply) in calls.items() if reply),
                     key=lambda r: r[0])
    if monotonic or len(logtimes) == 1:
        series.events = [ServiceEvent(t=float(sim_time([logtime])[0]), service=service,
                                      name=getattr(response, 'entity_name', '') or name,
                                      **_outcome(response))
                         for logtime, service, name, response in replies]
    # Resets: where the step count since the last reset drops, else the reset calls.
    if series.metrics is not None and len(series.metrics['t']) > 1:
        m = series.metrics
        series.resets = m['t'][1:][np.diff(m['step_count']) < 0]
    else:
        series.resets = np.array([e.t for e in series.events
                                  if e.service == 'reset' and e.success])
    return series


def _outcome(response) -> dict:
    """Return ``success`` and ``message`` of a reply (ours, or the standard's ``result``)."""
    if hasattr(response, 'success'):
        return {'success': bool(response.success), 'message': response.message}
    return {'success': response.result.result == RESULT_OK,
            'message': response.result.error_message}


#: How a call is marked on the time axis: its sign before the name.
MARKS = {'add_constraint': '+ ', 'remove_constraint': '\u2212 ', 'spawn_entity': 'spawned ',
         'delete_entity': 'deleted '}


def _broken(t: np.ndarray, y: np.ndarray,
            resets: Sequence[float] = ()) -> tuple[np.ndarray, np.ndarray]:
    """
    Insert NaN where the motion is not continuous, so that no line spans the jump.

    That is before each reset state (``resets``, stamps), where time runs back
    (a reset to time 0) and across a gap of more than 5 typical sample periods
    (a topic not published, e.g. a constraint removed for a while).
    """
    if len(t) < 2:
        return t, y
    dt = np.diff(t)
    positive = dt[dt > 0]
    limit = 5.0 * np.median(positive) if len(positive) else np.inf
    cut = set((np.flatnonzero((dt < 0) | (dt > limit)) + 1).tolist())
    if len(resets) and np.all(dt >= 0):
        cut.update(i for i in np.searchsorted(t, resets).tolist() if 0 < i < len(t))
    if not cut:
        return t, y
    cut = sorted(cut)
    return (np.insert(t.astype(float), cut, np.nan),
            np.insert(y.astype(float), cut, np.nan, axis=0))


def _spans(inputs: WrenchInputs, t_end: float, resets: Sequence[float] = ()) -> list:
    """Return (start, end) of each non-zero wrench input: held until the next message or reset."""
    out = []
    ends = list(inputs.t[1:]) + [max(t_end, inputs.t[-1])]
    for start, end, f, tau in zip(inputs.t, ends, inputs.force, inputs.torque):
        if np.any(f) or np.any(tau):
            end = min([end] + [r for r in resets if start < r])
            out.append((start, end))
    return out


#: m: a coordinate that moves less than this for every body drawn gets no panel.
STILL = 1e-9
#: in: the figure's width, a panel's height (times its weight) and the gap between panels.
WIDTH, PANEL_HEIGHT, GAP = 11.0, 1.6, 0.5


def draw(series: BagSeries, out: Path) -> list:
    """Draw the figure of ``series`` into the PNG ``out``; return the names of the panels."""
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.ticker import FormatStrFormatter, MaxNLocator

    body_colour = {b: colormaps['tab10'](i % 10) for i, b in enumerate(series.bodies)}
    notes = []
    if np.any(np.diff(series.t) < 0):
        notes.append('time set back to 0 by resets: the episodes overlap')
    # Position: one panel per coordinate that moves (a still one is named in the title).
    spread = {axis: max(float(np.nanmax(p[:, k]) - np.nanmin(p[:, k]))
                        if np.any(np.isfinite(p[:, k])) else 0.0
                        for p in series.position.values())
              for k, axis in enumerate('xyz')}
    moving = [a for a in 'xyz' if spread[a] > STILL] or ['x', 'y', 'z']
    still = [a for a in 'xyz' if a not in moving]
    panels = [(a, 1.0) for a in moving] + [('orientation', 1.2)]
    m = series.metrics
    if m is None:
        notes.append('no metrics in the bag: no energy or constraint violation panels')
    else:
        panels += [('energy', 1.2), ('energy change', 0.9)]
        if np.any(m['constraint_violation'] > 0):
            panels.append(('constraint violation', 1.1))
        else:
            notes.append('constraint violation 0 throughout')
    if series.reactions:
        panels.append(('reaction forces', 1.3))
    else:
        notes.append('no constraint reactions in the bag')

    # Laid out in inches (faster than a layout engine, and every figure alike): panels
    # stacked on the left, legends in the right margin, titles in the gaps.
    heights = [PANEL_HEIGHT * h for _, h in panels]
    head = 0.75 + (0.25 if notes else 0.0)
    size = (WIDTH, head + sum(heights) + GAP * (len(panels) - 1) + 0.6)
    fig = Figure(figsize=size, dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False, gridspec_kw={
        'height_ratios': heights, 'left': 0.9 / size[0], 'right': 1.0 - 2.45 / size[0],
        'top': 1.0 - head / size[1], 'bottom': 0.6 / size[1],
        'hspace': GAP / np.mean(heights)})[:, 0]
    ax_of = dict(zip((name for name, _ in panels), axes))
    t_end = float(np.nanmax(series.t))
    side = {'loc': 'upper left', 'bbox_to_anchor': (1.005, 1.0), 'fontsize': 9,
            'frameon': False, 'title_fontsize': 9}

    def title(ax, text: str) -> None:
        ax.set_title(text, loc='left', fontsize=10)

    def broken(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _broken(t, y, series.resets)

    # Calls that change the scene: a line across every panel, named in the top one.
    marks = [(float(r), 'reset', '--') for r in series.resets]
    for e in series.events:
        if e.service != 'reset':
            marks.append((e.t, MARKS[e.service] + e.name + ('' if e.success else ' (refused)'),
                          ':'))
    for ax in axes:
        ax.grid(True, alpha=0.3)
        for body, inputs in series.inputs.items():
            for start, end in _spans(inputs, t_end, series.resets):
                ax.axvspan(start, end, color=body_colour[body], alpha=0.13, lw=0)
        for t, _, style in marks:
            ax.axvline(t, color='0.3', ls=style, lw=1.0, zorder=1)

    for axis in moving:
        ax = ax_of[axis]
        k = 'xyz'.index(axis)
        for body in series.bodies:
            ax.plot(*broken(series.t, series.position[body][:, k]), color=body_colour[body],
                    lw=1.4)
        ax.set_ylabel(f'{axis} [m]')
    top = ax_of[moving[0]]
    text = f'Position of each body frame origin in the world frame ({series.world_frame})'
    if still:
        values = sorted({float(np.nanmean(p[:, 'xyz'.index(a)]))
                         for a in still for p in series.position.values()})
        same = f' = {values[0]:.6g} m' if len(values) == 1 else ''
        text += f'; {" and ".join(still)} constant{same} for every body'
    title(top, text)
    handles = [Line2D([], [], color=body_colour[b], lw=2, label=b) for b in series.bodies]
    if series.inputs:
        for body, inputs in series.inputs.items():
            pushing = np.any(inputs.force != 0, axis=1) | np.any(inputs.torque != 0, axis=1)
            for mask, face in ((pushing, body_colour[body]), (~pushing, 'white')):
                top.plot(inputs.t[mask], np.full(int(mask.sum()), 0.95), 'v', ms=8, mfc=face,
                         color=body_colour[body], transform=top.get_xaxis_transform(),
                         clip_on=False, zorder=5)
        handles += [Patch(color='0.5', alpha=0.3, label='wrench input held'),
                    Line2D([], [], color='0.3', marker='v', ls='', label='wrench message'),
                    Line2D([], [], color='0.3', mfc='white', marker='v', ls='',
                           label='zero wrench (release)')]
    for t, text, _ in marks:
        top.text(t, 0.04, text, rotation=90, ha='right', va='bottom', fontsize=8,
                 color='0.2', transform=top.get_xaxis_transform(), zorder=6,
                 bbox={'facecolor': 'white', 'alpha': 0.75, 'lw': 0, 'pad': 1.0})
    if marks:
        handles.append(Line2D([], [], color='0.3', ls='--', lw=1, label='reset'))
        calls = {e.service for e in series.events}
        if calls & set(SERVICES[1:]):
            handles.append(Line2D([], [], color='0.3', ls=':', lw=1,
                                  label='constraint added (+)\nor removed (−)'))
        if calls & set(STANDARD_SERVICES):
            handles.append(Line2D([], [], color='0.3', ls=':', lw=1,
                                  label='entity spawned\nor deleted'))
    top.legend(handles=handles, title='body', **side)

    ax = ax_of['orientation']
    planar, turning = {}, []
    low, high = 0.0, 0.0
    for body in series.bodies:
        angle, axis = series.orientation_angle_deg(body)
        if axis is None:
            turning.append(body)
        else:
            planar[body] = axis_name(axis)
        ax.plot(*broken(series.t, angle), color=body_colour[body], lw=1.4,
                label=body if axis is None else f'{body} (about {planar[body]})')
        if np.any(np.isfinite(angle)):
            low, high = min(low, float(np.nanmin(angle))), max(high, float(np.nanmax(angle)))
    ax.set_ylabel('angle [deg]')
    if not planar:
        title(ax, 'Orientation: angle turned from the first orientation (0 to 180 deg)')
    elif not turning and len(set(planar.values())) == 1:
        title(ax, f'Orientation: angle turned from the first orientation, about the world '
                  f'{next(iter(planar.values()))} axis (planar motion; unwrapped)')
    else:
        title(ax, 'Orientation: angle turned from the first orientation (signed about the '
                  "legend's axis: planar motion; else 0 to 180 deg)")
        ax.legend(**side)
    if high - low >= 90.0:
        # Ticks on multiples of 45 or 90 degrees where they fit.
        ax.yaxis.set_major_locator(MaxNLocator(nbins=6, steps=[1, 1.5, 3, 4.5, 9, 10]))

    if m is not None:
        ax = ax_of['energy']
        ax.plot(*broken(m['t'], m['total_energy']), color='black', lw=1.8, label='total')
        ax.plot(*broken(m['t'], m['kinetic_energy']), color='tab:red', lw=1.2,
                label='kinetic')
        ax.plot(*broken(m['t'], m['potential_energy']), color='tab:blue', lw=1.2,
                label='potential')
        ax.set_ylabel('energy [J]')
        title(ax, 'Energy of the scene')
        ax.legend(**side)

        ax = ax_of['energy change']
        change = m['energy_change']
        ax.plot(*broken(m['t'], change), color='black', lw=1.2)
        ax.axhline(0.0, color='0.5', lw=0.8)
        ax.set_ylabel('ΔE [J]')
        ax.yaxis.set_major_formatter(FormatStrFormatter('%.3g'))   # no offset text
        worst = float(np.max(np.abs(change)))
        start = float(np.max(np.abs(m['total_energy'] - change)))
        relative = f', {100.0 * worst / start:.2g} % of |E0|' if start > 0 else ''
        title(ax, f'Energy change since the last reset or spawn or deletion (largest |ΔE| '
                  f'{worst:.3g} J{relative})')

        if 'constraint violation' in ax_of:
            ax = ax_of['constraint violation']
            v = m['constraint_violation']
            ax.semilogy(*broken(m['t'], np.where(v > 0, v, np.nan)), color='tab:purple',
                        lw=1.2)
            ax.set_ylabel('max |Φ| [m, rad]')
            title(ax, f'Constraint violation, the largest |Φ| of all constraints (log scale; '
                      f'largest {np.max(v):.3g})')

    if series.reactions:
        ax = ax_of['reaction forces']
        colours = colormaps['Dark2']
        for i, (name, r) in enumerate(series.reactions.items()):
            frames = sorted(set(r.frames))
            where = 'on the world' if frames == [series.world_frame] else \
                f'on {", ".join(frames)}'
            ax.plot(*broken(r.t, r.magnitude), color=colours(i % 8), lw=1.3,
                    label=f'{name} ({where})')
        ax.set_ylabel('|F| [N]')
        title(ax, 'Reaction force magnitude of each constraint')
        ax.legend(title='constraint', **side)

    axes[-1].set_xlabel('simulation time [s]')
    t_start = float(np.nanmin(series.t))
    axes[-1].set_xlim(t_start, t_end if t_end > t_start else t_start + 1.0)
    shown = (f'{len(series.bodies)} of {len(series.all_bodies)} bodies'
             if len(series.bodies) < len(series.all_bodies) else
             f'{len(series.bodies)} bod{"y" if len(series.bodies) == 1 else "ies"}')
    heading = (f'{series.bag.name}: {series.node}, {shown}, '
               f'{np.nanmin(series.t):.4g} to {t_end:.4g} s of simulation time')
    fig.suptitle(heading + ('\n' + '; '.join(notes) if notes else ''), fontsize=12,
                 y=1.0 - 0.12 / size[1], va='top')
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    return [name for name, _ in panels]


def default_output(bag: Path) -> Path:
    """
    Return ``BAG.png`` beside the bag folder.

    For a storage file inside a bag folder (beside its ``metadata.yaml``), beside
    that folder; for a lone ``.mcap`` file, the file's name with ``.png``.
    """
    bag = Path(bag)
    if bag.is_file():
        if not (bag.parent / 'metadata.yaml').is_file():
            return bag.with_suffix('.png')
        bag = bag.parent
    bag = bag.resolve() if bag.name in ('', '.', '..') else bag
    return bag.parent / (bag.name + '.png')


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='plot', description=__doc__.strip().splitlines()[0])
    p.add_argument('bag', help='rosbag2 folder (or its .mcap file)')
    p.add_argument('--bodies', nargs='+', metavar='B',
                   help=f'bodies to plot (names, or comma-separated); default: all, at '
                        f'most the first {MAX_BODIES}')
    p.add_argument('--node', help='node prefix, e.g. /robot1/rigid_body_sim (default: the '
                                  'first with body_states)')
    p.add_argument('-o', '--output', help='PNG to write (default: BAG.png beside the bag)')
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Plot a bag into a PNG and print a one-line summary; returns the exit code."""
    args = _parser().parse_args(argv)
    bodies = [b for item in args.bodies or [] for b in item.split(',') if b]
    bag = Path(args.bag)
    out = Path(args.output) if args.output else default_output(bag)
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print('plot: error: matplotlib is not installed (pip install matplotlib)',
              file=sys.stderr)
        return 2
    try:
        series = read_bag(bag, args.node, bodies or None)
        panels = draw(series, out)
    except PlotError as exc:
        print(f'plot: error: {exc}', file=sys.stderr)
        return 2
    except OSError as exc:
        print(f'plot: error: {out}: cannot write ({exc.strerror or exc})', file=sys.stderr)
        return 2
    extra = ''
    if len(series.nodes) > 1:
        extra = f' (of nodes {", ".join(series.nodes)}; pick with --node)'
    if len(series.bodies) < len(series.all_bodies) and not bodies:
        extra += f' (first {MAX_BODIES} of {len(series.all_bodies)} bodies; pick with --bodies)'
    n_inputs = sum(len(i.t) for i in series.inputs.values())
    n_calls = sum(e.service in SERVICES[1:] for e in series.events)
    n_entities = sum(e.service in STANDARD_SERVICES for e in series.events)
    n_resets = len(series.resets)
    marked = [f'{n} {what}{"s" * (n != 1)}' for n, what in (
        (n_inputs, 'wrench input'), (n_resets, 'reset'), (n_calls, 'constraint call'),
        (n_entities, 'spawn or delete call')) if n]
    reactions = f' ({", ".join(series.reactions)})' if series.reactions else ''
    print(f'plot: {out}: {series.node}{extra}, {len(series.t)} states '
          f'{np.nanmin(series.t):.6g}..{np.nanmax(series.t):.6g} s, '
          f'bodies {", ".join(series.bodies)}; panels: {", ".join(panels)}{reactions}'
          + (f'; {", ".join(marked)}' if marked else ''), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
