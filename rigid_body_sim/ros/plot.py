"""
Plot a bag of the simulator node's topics: one PNG to look at rather than read.

Usage: ``plot BAG [--node /rigid_body_sim] [--bodies B ...] [-o OUT.png]``.
BAG is a rosbag2 folder (or one of its ``.mcap`` / ``.db3`` files) holding the
node's ``<node>/body_states`` and, when recorded, ``<node>/metrics``,
``<node>/constraints/<C>/wrench`` and ``<node>/bodies/<B>/wrench``. The
panels share the simulation time axis (header stamps, not the time the bag
received a message): body positions x, y, z; how far each body has turned
from its first orientation; energy; energy change; constraint violation (log
scale); reaction force magnitude per constraint. Wrench inputs are shaded
while they hold. A panel without data is left out, and the title says so.
Without ``-o`` the picture goes next to the bag, ``BAG.png``.
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

    def orientation_angle_deg(self, body: str) -> tuple[np.ndarray, Optional[np.ndarray]]:
        """Return the orientation panel's angle of a body: see :func:`orientation_angle_deg`."""
        return orientation_angle_deg(self.orientation[body])


#: rad: rotations whose axes all lie within this of one world axis are planar.
AXIS_TOLERANCE = 1e-3
#: rad: rotations smaller than this have too uncertain an axis to judge planarity.
ANGLE_FOR_AXIS = 1e-2


def orientation_angle_deg(quat_xyzw: np.ndarray) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """
    Return how far a body has turned from its first (finite) orientation, in degrees.

    The rotation since the start, ``q q0*`` (world axes), has an angle and an
    axis. When every sample's axis is the same world axis (within
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
            signed = 2.0 * np.arctan2(v[finite] @ axis, r[finite])
            angle[finite] = np.degrees(np.unwrap(signed, period=2.0 * np.pi))
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
    wanted = [c for c in connections
              if (c.topic == states_topic and c.msgtype == BODY_STATES)
              or (c.topic == metrics_topic and c.msgtype == METRICS)
              or (c.msgtype == WRENCH and (reaction_re.fullmatch(c.topic)
                                           or input_re.fullmatch(c.topic)))]

    stamps, logtimes = [], []
    position: dict = {}
    orientation: dict = {}
    all_bodies: list = []
    chosen: Optional[list] = None
    world_frame = None
    index: dict = {}
    names_seen: list = []
    metrics: dict = {'t': []}
    metrics.update((name, []) for name in METRIC_FIELDS)
    reactions: dict = {}    # constraint -> [[stamp, force, frame], ...], one per stamp
    inputs: dict = {}       # body -> [(logtime, stamp, force, torque, frame), ...]
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
            if chosen is None:
                # Bodies are the scene's: the first message names them all.
                chosen = list(dict.fromkeys(bodies)) if bodies else names[:MAX_BODIES]
                position = {b: [] for b in chosen}
                orientation = {b: [] for b in chosen}
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
            for name in METRIC_FIELDS:
                metrics[name].append(getattr(msg, name))
        elif reaction_re.fullmatch(topic):
            groups = reactions.setdefault(reaction_re.fullmatch(topic).group(1), [])
            stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
            f = msg.wrench.force
            if not groups or groups[-1][0] != stamp:
                groups.append((stamp, []))
            groups[-1][1].append(((f.x, f.y, f.z), msg.header.frame_id))
        else:
            w = msg.wrench
            inputs.setdefault(input_re.fullmatch(topic).group(1), []).append(
                (logtime, _seconds(msg.header.stamp), (w.force.x, w.force.y, w.force.z),
                 (w.torque.x, w.torque.y, w.torque.z), msg.header.frame_id))

    if not stamps:
        raise PlotError(f'{path}: {states_topic} has no messages')
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
    # Wrench inputs: the node ignores their stamps (ros2 topic pub leaves them 0) and
    # applies them at the next step, so their time is the simulation time at which the
    # bag received them, interpolated between the body states around it (their stamps
    # only when the bag's receive times do not increase).
    logtimes = np.array(logtimes, dtype=np.int64)
    monotonic = len(logtimes) > 1 and bool(np.all(np.diff(logtimes) > 0))
    for body in sorted(inputs):
        if body not in chosen:
            continue
        rows = inputs[body]
        received = np.array([r[0] for r in rows], dtype=np.int64) - logtimes[0]
        series.inputs[body] = WrenchInputs(
            t=(np.interp(received, logtimes - logtimes[0], series.t) if monotonic
               else np.array([r[1] for r in rows])),
            force=np.array([r[2] for r in rows], dtype=float),
            torque=np.array([r[3] for r in rows], dtype=float),
            frames=[r[4] for r in rows])
    return series


def _broken(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Insert NaN where time runs back (a reset) or skips (no messages), so no line spans it."""
    if len(t) < 3:
        return t, y
    dt = np.diff(t)
    positive = dt[dt > 0]
    limit = 5.0 * np.median(positive) if len(positive) else np.inf
    cut = np.flatnonzero((dt <= 0) | (dt > limit)) + 1
    if not len(cut):
        return t, y
    return (np.insert(t.astype(float), cut, np.nan),
            np.insert(y.astype(float), cut, np.nan, axis=0))


def _spans(inputs: WrenchInputs, t_end: float) -> list:
    """Return (start, end) of each non-zero wrench input, held until the next message."""
    out = []
    ends = list(inputs.t[1:]) + [max(t_end, inputs.t[-1])]
    for start, end, f, tau in zip(inputs.t, ends, inputs.force, inputs.torque):
        if np.any(f) or np.any(tau):
            out.append((start, end))
    return out


def draw(series: BagSeries, out: Path) -> list:
    """Draw the figure of ``series`` into the PNG ``out``; return the names of the panels."""
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    body_colour = {b: colormaps['tab10'](i % 10) for i, b in enumerate(series.bodies)}
    notes = []
    panels = [('x', 1.0), ('y', 1.0), ('z', 1.0), ('orientation', 1.1)]
    m = series.metrics
    if m is None:
        notes.append('no metrics topic: no energy or constraint violation panels')
    else:
        panels += [('energy', 1.3), ('energy change', 1.0)]
        if np.any(m['constraint_violation'] > 0):
            panels.append(('constraint violation', 1.1))
        else:
            notes.append('constraint violation 0 throughout (no constraints)')
    if series.reactions:
        panels.append(('reaction forces', 1.3))
    else:
        notes.append('no reaction wrenches recorded')

    ratios = [h for _, h in panels]
    fig = Figure(figsize=(11.0, 1.75 * sum(ratios) + 1.4), dpi=100, layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(panels), 1, sharex=True, height_ratios=ratios)
    ax_of = dict(zip((name for name, _ in panels), axes))
    t_end = float(np.nanmax(series.t))

    for name, ax in ax_of.items():
        ax.grid(True, alpha=0.3)
        for body, inputs in series.inputs.items():
            for start, end in _spans(inputs, t_end):
                ax.axvspan(start, end, color=body_colour[body], alpha=0.12, lw=0)

    for k, axis in enumerate('xyz'):
        ax = ax_of[axis]
        for body in series.bodies:
            ax.plot(*_broken(series.t, series.position[body][:, k]), color=body_colour[body],
                    lw=1.4, label=body)
        ax.set_ylabel(f'{axis} [m]')
    ax_of['x'].set_title(f'Position of the body frame origins, world frame '
                         f'({series.world_frame})', loc='left', fontsize=10)
    handles = [Line2D([], [], color=body_colour[b], lw=2, label=b) for b in series.bodies]
    if series.inputs:
        handles.append(Patch(color='0.5', alpha=0.25, label='wrench input held'))
        top = ax_of['x']
        for body, inputs in series.inputs.items():
            top.plot(inputs.t, np.full(len(inputs.t), 1.0), 'v', color=body_colour[body],
                     ms=7, transform=top.get_xaxis_transform(), clip_on=False)
        handles.append(Line2D([], [], color='0.3', marker='v', ls='', label='wrench message'))
    ax_of['x'].legend(handles=handles, loc='upper left', bbox_to_anchor=(1.005, 1.0),
                      fontsize=9, title='body', title_fontsize=9, frameon=False)

    ax = ax_of['orientation']
    top_angle = 0.0
    for body in series.bodies:
        angle = series.rotation_angle_deg(body)
        ax.plot(*_broken(series.t, angle), color=body_colour[body], lw=1.4, label=body)
        top_angle = max(top_angle, float(np.nanmax(angle)) if np.any(np.isfinite(angle)) else 0)
    ax.set_ylabel('angle [deg]')
    ax.set_title('Orientation: angle turned from the first orientation (0 to 180 deg)',
                 loc='left', fontsize=10)
    if top_angle > 60.0:
        ax.set_ylim(-5.0, 185.0)
        ax.set_yticks([0, 45, 90, 135, 180])

    if m is not None:
        ax = ax_of['energy']
        ax.plot(*_broken(m['t'], m['total_energy']), color='black', lw=1.8, label='total')
        ax.plot(*_broken(m['t'], m['kinetic_energy']), color='tab:red', lw=1.2,
                label='kinetic')
        ax.plot(*_broken(m['t'], m['potential_energy']), color='tab:blue', lw=1.2,
                label='potential')
        ax.set_ylabel('energy [J]')
        ax.set_title('Energy of the scene', loc='left', fontsize=10)
        ax.legend(loc='upper left', bbox_to_anchor=(1.005, 1.0), fontsize=9, frameon=False)

        ax = ax_of['energy change']
        change = m['energy_change']
        ax.plot(*_broken(m['t'], change), color='black', lw=1.2)
        ax.axhline(0.0, color='0.5', lw=0.8)
        ax.set_ylabel('ΔE [J]')
        worst = float(np.max(np.abs(change))) if len(change) else 0.0
        scale = float(np.max(np.abs(m['total_energy'] - change)))
        relative = f', {worst / scale:.2g} of |E0|' if scale > 0 else ''
        ax.set_title(f'Energy change since the last reset (max |ΔE| = {worst:.3g} J'
                     f'{relative}; only wrench inputs should change it)', loc='left',
                     fontsize=10)

        if 'constraint violation' in ax_of:
            ax = ax_of['constraint violation']
            v = m['constraint_violation']
            ax.semilogy(*_broken(m['t'], np.where(v > 0, v, np.nan)), color='tab:purple',
                        lw=1.2)
            ax.set_ylabel('max |Φ| [m, rad]')
            ax.set_title(f'Constraint violation, largest over all constraints (log scale; '
                         f'max {np.max(v):.3g})', loc='left', fontsize=10)

    if series.reactions:
        ax = ax_of['reaction forces']
        colours = colormaps['Dark2']
        for i, (name, r) in enumerate(series.reactions.items()):
            frames = sorted(set(r.frames))
            where = ('world frame' if frames == [series.world_frame]
                     else f'on {", ".join(frames)}')
            ax.plot(*_broken(r.t, r.magnitude), color=colours(i % 8), lw=1.3,
                    label=f'{name} ({where})')
        ax.set_ylabel('|F| [N]')
        ax.set_title('Reaction force magnitude per constraint', loc='left', fontsize=10)
        ax.legend(loc='upper left', bbox_to_anchor=(1.005, 1.0), fontsize=9, frameon=False,
                  title='constraint', title_fontsize=9)

    axes[-1].set_xlabel('simulation time [s] (header stamps)')
    axes[-1].set_xlim(float(np.nanmin(series.t)), t_end)
    shown = (f'{len(series.bodies)} of {len(series.all_bodies)} bodies'
             if len(series.bodies) < len(series.all_bodies) else
             f'{len(series.bodies)} bodies')
    title = (f'{series.bag.name}: {series.node}, {shown}, '
             f'{np.nanmin(series.t):.3g} to {t_end:.3g} s')
    fig.suptitle(title + ('\n' + '; '.join(notes) if notes else ''), fontsize=12)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    return [name for name, _ in panels]


def default_output(bag: Path) -> Path:
    """Return ``BAG.png`` next to the bag folder (or the bag file, its suffix replaced)."""
    bag = Path(bag)
    return bag.with_suffix('.png') if bag.is_file() else bag.parent / (bag.name + '.png')


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
    print(f'plot: {out}: {series.node}{extra}, {len(series.t)} states '
          f'{np.nanmin(series.t):.6g}..{np.nanmax(series.t):.6g} s, '
          f'bodies {", ".join(series.bodies)}; panels: {", ".join(panels)}'
          + (f' ({", ".join(series.reactions)})' if series.reactions else '')
          + (f'; {n_inputs} wrench inputs' if n_inputs else ''), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
