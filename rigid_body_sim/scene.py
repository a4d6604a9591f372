"""
Scene files (YAML) -> core specs. Every error names the file, the key path and the problem.

A scene file::

    integrator: lie_poisson2        # a name from rigid_body_sim.core.INTEGRATORS
    dt: 0.001                       # s
    duration: 10.0                  # s, how long the command-line run lasts
    effects:                        # only the effects listed are simulated
      gravity: {g_world: [0, 0, -9.81]}
      damping: {linear: 0.1, angular: 0.01, bodies: [box]}
      wrenches:
        - {body: box, force: [1, 0, 0], frame: world, point_body: [0, 0, 0.1],
           start: 0.0, duration: 0.5}
    bodies:
      - name: box
        mass: 2.0                                 # kg
        inertia: {box: [0.3, 0.2, 0.1]}           # or [Ixx, Iyy, Izz], a 3x3 list,
                                                  # or {ixx:, iyy:, izz:, ixy:, ixz:, iyz:}
        com_body: [0, 0, 0]                       # m, centre of mass in the body frame
        position_world: [0, 0, 1]                 # m, body origin
        orientation_xyzw: [0, 0, 0, 1]            # or orientation_rpy: [r, p, y] (rad, URDF)
        linear_velocity_world: [0, 0, 0]          # m/s, of the body origin
        angular_velocity_body: [0, 1, 0]          # rad/s
        shapes:                                   # collision shapes (core.shapes), body frame
          - {kind: box, size: [0.3, 0.2, 0.1], friction: 0.5, restitution: 0.2}
          - {kind: sphere, radius: 0.05, position_body: [0, 0, 0.1]}   # also capsule,
                                                  # cylinder: {radius:, length:} along z;
                                                  # mesh: {mesh: part.stl (or vertices),
                                                  # scale: [1, 1, 1]}, its convex hull;
                                                  # collide: false; group:, mask: (bits)
    ground: {height: 0.0, normal: [0, 0, 1], friction: 0.8, restitution: 0.0}
                                    # a plane (solid below); pair coefficients:
                                    # mu = sqrt(mu_a mu_b), e = max(e_a, e_b)

    constraints:                    # joints (see rigid_body_sim.core.constraints)
      - {name: pivot, type: ball, body_a: box, body_b: world, anchor_world: [0, 0, 1.2]}
      - {name: axle, type: hinge, body_a: wheel, body_b: box, anchor_world: [0, 0, 1],
         axis_world: [0, 1, 0]}
      - {name: lid, type: hinge, body_a: lid, body_b: box, anchor_world: [0, 0.2, 1.1],
         axis_world: [1, 0, 0], lower: -0.1, upper: 1.5,   # hinges and sliders: limits
         restitution: 0.0, friction: 0.2}   # (rad or m from the start), e, Coulomb F
    constraint_time_constant: 0.05  # s, decay time of a violated constraint
    tolerance: 1.0e-6               # optional: local error per unit time (the accuracy
                                    # knob, see rigid_body_sim.core.accuracy)

    robots:                         # URDF or xacro robots (see rigid_body_sim.core.robots)
      - name: arm                   # default: the URDF's robot name
        urdf: arm.urdf.xacro        # relative to this file; .urdf, .urdf.xacro or .xacro
        xacro_args: {prefix: ''}    # xacro arguments (strings)
        prefix: ''                  # prepended to link and joint names (several robots)
        base_pose: {xyz: [0, 0, 0], rpy: [0, 0, 0]}   # or quat_xyzw: [x, y, z, w]
        fixed_base: true            # weld the root link to the world (also: a 'world' link)
        initial_positions: {joint1: 0.5}    # rad or m; others 0
        initial_velocities: {joint1: 0.0}   # rad/s or m/s
        keep_fixed: [ft_sensor_joint]       # fixed joints kept as welds (reaction published)
        limits: true                        # hold joints within their URDF <limit lower upper>
        limit_restitution: 0.0              # Newton's e at the bounds, or {joint: e}
        friction: true                      # Coulomb friction of <dynamics friction>
        effort_limits: true                 # exact drives bounded by <limit effort>
        collisions: false                   # the links' <collision> boxes, cylinders,
                                            # spheres and meshes (STL, OBJ: their convex
                                            # hulls) as contact shapes (other meshes:
                                            # named, not simulated); or a mapping (true):
                                            # {friction: 1.0, restitution: 0.0, group: 1,
                                            #  mask: ..., links: {foot: {friction: 0.9}}}
        self_collide: false                 # true: its links meet each other too (false:
                                            # Gazebo's default)
    command_groups:                 # joints commanded together (others take efforts)
      - {name: arm_controller, joints: [joint1, joint2], interface: position,
         mode: servo, kp: 100.0, kd: 5.0}   # effort | position | velocity; N m/rad, N m s/rad
      - {name: wrist, joints: [joint3], interface: position, mode: exact}
                                    # exact: a driving constraint q = q* (no gains); its
                                    # multiplier is the joint's effort; on the velocity
                                    # interface its target moves: q̇ = v* exactly

A URDF or xacro file is a scene by itself: its robot, with gravity, ``dt``
0.001 s, ``duration`` 10 s, floating unless it has a ``world`` link.

Shapes for ``inertia`` (uniform density, about the centre of mass):
``{box: [lx, ly, lz]}``, ``{sphere: r}``, ``{cylinder: [r, length]}`` (axis z).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
import re
from typing import Any, Optional, Union

import numpy as np
from scipy.spatial.transform import Rotation
import yaml

from .core import Constraint, Damping, Gravity, RigidBody, Simulation, SpecError
from .core.effects import AppliedWrenches
from .core.hulls import FORMATS as MESH_FORMATS
from .core.integrators import INTEGRATORS
from .core.limits import SceneJoint
from .core.robots import CommandGroup, RobotSpec
from .core.shapes import ALL_BITS, CollisionShape
from .core.validate import finite_array, positive_scalar
from .urdf import parse_urdf, read_robot_xml, UrdfError

TOP_KEYS = ('name', 'integrator', 'dt', 'duration', 'effects', 'bodies', 'constraints',
            'constraint_time_constant', 'tolerance', 'robots', 'command_groups', 'ground')
#: The ground: a plane through ``height`` along its unit ``normal`` (solid below).
GROUND_KEYS = ('height', 'normal', 'friction', 'restitution')
#: A body's collision shape (:class:`.core.shapes.CollisionShape`, its body implied).
SHAPE_KEYS = ('kind', 'radius', 'length', 'size', 'mesh', 'scale', 'position_body',
              'orientation_xyzw', 'friction', 'restitution', 'collide', 'group', 'mask',
              'name')
GROUP_KEYS = ('name', 'joints', 'interface', 'mode', 'kp', 'kd')
ROBOT_KEYS = ('name', 'urdf', 'xacro_args', 'prefix', 'base_pose', 'fixed_base',
              'initial_positions', 'initial_velocities', 'keep_fixed', 'limits',
              'limit_restitution', 'friction', 'effort_limits', 'collisions', 'self_collide')
ROBOT_SUFFIXES = ('.urdf', '.xacro')
CONSTRAINT_KEYS = ('name', 'type', 'body_a', 'body_b', 'anchor_world', 'anchor_a_body',
                   'anchor_b_body', 'axis_world', 'length')
#: A hinge's or slider's limits and friction (:class:`.core.limits.SceneJoint`).
SCENE_JOINT_KEYS = ('lower', 'upper', 'restitution', 'friction')
BODY_KEYS = ('name', 'mass', 'inertia', 'com_body', 'position_world', 'orientation_xyzw',
             'orientation_rpy', 'linear_velocity_world', 'angular_velocity_body', 'shapes')
EFFECT_KEYS = {'gravity': ('g_world',), 'damping': ('linear', 'angular', 'bodies'),
               'wrenches': None}
WRENCH_KEYS = ('body', 'force', 'torque', 'frame', 'point_body', 'start', 'duration')
URDF_INERTIA_KEYS = ('ixx', 'iyy', 'izz', 'ixy', 'ixz', 'iyz')


class SceneError(ValueError):
    """A scene that cannot be loaded: ``"<file>: <key path>: <problem>"``."""


@dataclass
class Scene:
    """A loaded scene: the simulation it describes and its run settings."""

    name: str
    simulation: Simulation
    duration: float
    source: str
    #: body name -> (shape, dimensions) for bodies whose inertia is given as a shape:
    #: ('box', [lx, ly, lz]), ('sphere', [r]) or ('cylinder', [r, length]), m, centred
    #: on the centre of mass, in the body's axes.
    shapes: dict = field(default_factory=dict)
    #: The robots, in the order of ``simulation.robots``: (prefix, ParsedUrdf).
    robots: list = field(default_factory=list)
    #: What a user should read once, one line per robot: elements not simulated,
    #: limits not enforced.
    warnings: list = field(default_factory=list)


def load_scene(path: Union[str, Path]) -> Scene:
    """
    Load a scene file and build its :class:`Simulation`.

    Raises
    ------
    SceneError
        Naming the file, the key path and the problem.

    """
    path = Path(path)
    if path.suffix in ROBOT_SUFFIXES:
        return scene_from_dict({'dt': 0.001, 'effects': {'gravity': {}},
                                'robots': [{'urdf': str(path.resolve())}]}, str(path),
                               name=path.name.split('.')[0])
    try:
        text = path.read_text()
    except OSError as exc:
        raise SceneError(f'{path}: cannot read: {exc.strerror}') from None
    try:
        data = yaml.load(text, Loader=YamlLoader)
    except yaml.YAMLError as exc:
        raise SceneError(f'{path}: not valid YAML: {exc}') from None
    return scene_from_dict(data, str(path))


class YamlLoader(yaml.SafeLoader):
    """
    PyYAML's safe loader with YAML 1.2 floats.

    PyYAML implements YAML 1.1, where ``1e-3`` (no dot) is a string; scene files
    are written by people who mean a number, as YAML 1.2 and ROS parameter files
    (read by a YAML 1.2 parser) agree.
    """


YamlLoader.yaml_implicit_resolvers = {k: list(v) for k, v in
                                      yaml.SafeLoader.yaml_implicit_resolvers.items()}
YamlLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$'),
    list('-+0123456789'))


def scene_from_dict(data: Any, source: str = '<scene>', name: Optional[str] = None) -> Scene:
    """Build a :class:`Scene` from parsed YAML; ``source`` names it in errors."""
    try:
        scene = _build(data, source)
    except SpecError as exc:
        raise SceneError(f'{source}: {exc}') from None
    except UrdfError as exc:
        raise SceneError(f'{source}: {exc}') from None
    if name is not None:
        scene.name = name
    return scene


def _mapping(value: Any, field: str, allowed: tuple) -> dict:
    if not isinstance(value, dict):
        raise SpecError(field, f'expected a mapping, got {value!r}')
    unknown = [k for k in value if k not in allowed]
    if unknown:
        raise SpecError(f'{field}.{unknown[0]}' if field else str(unknown[0]),
                        f'unknown key; expected one of {list(allowed)}')
    return value


def _build(data: Any, source: str) -> Scene:
    data = _mapping(data, '', TOP_KEYS)
    if 'dt' not in data:
        raise SpecError('dt', 'missing (required)')
    if 'bodies' not in data and not data.get('robots'):
        raise SpecError('bodies', 'missing (required unless the scene has robots)')
    integrator = data.get('integrator', 'lie_poisson2')
    if not isinstance(integrator, str) or integrator not in INTEGRATORS:
        raise SpecError('integrator', f'unknown integrator {integrator!r}; known: '
                                      f'{sorted(INTEGRATORS)}')
    dt = positive_scalar(data['dt'], 'dt')
    duration = positive_scalar(data.get('duration', 10.0), 'duration')
    bodies_data = data.get('bodies', [])
    if not isinstance(bodies_data, list) or not (bodies_data or data.get('robots')):
        raise SpecError('bodies', f'expected a non-empty list of bodies, got {bodies_data!r}')
    robots = _robots(data.get('robots') or [], source)
    bodies = [_body(b, f'bodies[{i}]') for i, b in enumerate(bodies_data)]
    effects = _effects(data.get('effects') or {})
    constraints, scene_joints = _constraints(data.get('constraints') or [])
    time_constant = positive_scalar(data.get('constraint_time_constant', 0.05),
                                    'constraint_time_constant')
    try:
        sim = Simulation(bodies, [e for _, e in effects], integrator, dt, constraints,
                         time_constant, tolerance=data.get('tolerance'),
                         robots=[spec for spec, _ in robots],
                         command_groups=_groups(data.get('command_groups') or []),
                         scene_joints=scene_joints,
                         shapes=_collision_shapes(
                             ({} if data['ground'] is None else data['ground'])
                             if 'ground' in data else None, bodies_data,
                             Path(source).parent))
    except SpecError as exc:
        # Map 'effects[i]...' from the core back to the scene's effect key.
        if exc.field.startswith('effects['):
            i = int(exc.field[len('effects['):exc.field.index(']')])
            rest = exc.field[exc.field.index(']') + 1:]
            raise SpecError(f'effects.{effects[i][0]}{rest}', exc.problem) from None
        raise
    shapes = {}
    for body in bodies_data:
        inertia = body['inertia']
        if isinstance(inertia, dict) and len(inertia) == 1 and \
                next(iter(inertia)) in ('box', 'sphere', 'cylinder'):
            kind, dims = next(iter(inertia.items()))
            shapes[body['name']] = (kind, [float(d) for d in np.atleast_1d(dims)])
    warnings = []   # one line per robot
    for (spec, parsed), model in zip(robots, sim.robots):
        parts = (['not simulated: ' + ', '.join(parsed.ignored)] if parsed.ignored else []) \
            + list(model.notes)
        if parts:
            warnings.append(f'robot {spec.name!r} ({parsed.source}): ' + '; '.join(parts))
    return Scene(name=str(data.get('name', Path(source).stem)), simulation=sim,
                 duration=duration, source=source, shapes=shapes,
                 robots=[(spec.prefix, parsed) for spec, parsed in robots], warnings=warnings)


def _entries(data: Any, key: str, allowed: tuple, required: tuple) -> list:
    """Return ``(field, entry)`` of a list of mappings, each key checked; SpecError naming it."""
    if not isinstance(data, list):
        raise SpecError(key, f'expected a list, got {data!r}')
    out = []
    for i, entry in enumerate(data):
        field = f'{key}[{i}]'
        entry = _mapping(entry, field, allowed)
        for name in required:
            if name not in entry:
                raise SpecError(f'{field}.{name}', 'missing (required)')
        out.append((field, entry))
    return out


def _groups(data: Any) -> list:
    """Return the scene's joint command groups."""
    out = []
    for where, entry in _entries(data, 'command_groups', GROUP_KEYS, ('name', 'joints')):
        try:
            out.append(CommandGroup(**entry))
        except SpecError as exc:
            raise exc.within(where) from None
    return out


def _robots(data: Any, source: str) -> list:
    """Return the scene's robots as (RobotSpec, ParsedUrdf) pairs."""
    if not isinstance(data, list):
        raise SpecError('robots', f'expected a list of robots, got {data!r}')
    folder = Path(source).parent
    return [_robot(entry, f'robots[{i}]', folder) for i, entry in enumerate(data)]


def robot_from_dict(data: Any, folder: Union[str, Path] = '.', field: str = 'robot',
                    text: Optional[str] = None) -> tuple:
    """
    Return ``(RobotSpec, ParsedUrdf, [CommandGroup])`` of one robot entry (a spawn).

    ``data``: a scene's ``robots:`` entry (files relative to ``folder``), with its own
    ``command_groups`` (joint names as given: the caller prefixes them); ``text``:
    the URDF itself (then ``urdf`` names it only). Errors name the field under ``field``.
    """
    data = dict(_mapping(data, field, ROBOT_KEYS + ('command_groups',)))
    groups = _groups(data.pop('command_groups', None) or [])
    spec, parsed = _robot(data, field, Path(folder), text)
    return spec, parsed, groups


def _robot(entry: Any, field: str, folder: Path, text: Optional[str] = None) -> tuple:
    """Return one robot entry as ``(RobotSpec, ParsedUrdf)`` (``text``: its URDF, given)."""
    entry = _mapping(entry, field, ROBOT_KEYS)
    if text is None:
        if 'urdf' not in entry:
            raise SpecError(f'{field}.urdf', 'missing (required): a .urdf or .xacro file')
        if not isinstance(entry['urdf'], str):
            raise SpecError(f'{field}.urdf', f'expected a file name, got {entry["urdf"]!r}')
        path = Path(entry['urdf'])
        path = path if path.is_absolute() else folder / path
    else:
        path = Path(entry.get('urdf') or '<urdf>')
    try:
        parsed = parse_urdf(read_robot_xml(path, entry.get('xacro_args')) if text is None
                            else text, str(path))
    except UrdfError as exc:
        raise SpecError(f'{field}.urdf', str(exc)) from None
    base = _mapping(entry.get('base_pose') or {}, f'{field}.base_pose',
                    ('xyz', 'rpy', 'quat_xyzw'))
    if 'rpy' in base and 'quat_xyzw' in base:
        raise SpecError(f'{field}.base_pose', 'give rpy or quat_xyzw, not both')
    xyz = finite_array(base.get('xyz', [0.0, 0.0, 0.0]), f'{field}.base_pose.xyz', (3,))
    if 'rpy' in base:
        rpy = finite_array(base['rpy'], f'{field}.base_pose.rpy', (3,))
        quat = Rotation.from_euler('xyz', rpy).as_quat()
    else:
        quat = finite_array(base.get('quat_xyzw', [0.0, 0.0, 0.0, 1.0]),
                            f'{field}.base_pose.quat_xyzw', (4,))
        if not np.linalg.norm(quat) > 0.0:
            raise SpecError(f'{field}.base_pose.quat_xyzw', 'a zero quaternion')
    fixed = entry.get('fixed_base', False)
    if not isinstance(fixed, bool):
        raise SpecError(f'{field}.fixed_base', f'expected true or false, got {fixed!r}')
    prefix = entry.get('prefix', '')
    if not isinstance(prefix, str):
        raise SpecError(f'{field}.prefix', f'expected a string, got {prefix!r}')
    keep = entry.get('keep_fixed') or []
    if not isinstance(keep, list) or not all(isinstance(k, str) for k in keep):
        raise SpecError(f'{field}.keep_fixed', f'expected a list of joint names, '
                                               f'got {keep!r}')
    limits = entry.get('limits', True)
    if not isinstance(limits, bool):
        raise SpecError(f'{field}.limits', f'expected true or false, got {limits!r}')
    friction = entry.get('friction', True)
    if not isinstance(friction, bool):
        raise SpecError(f'{field}.friction', f'expected true or false, got {friction!r}')
    efforts = entry.get('effort_limits', True)
    if not isinstance(efforts, bool):
        raise SpecError(f'{field}.effort_limits', f'expected true or false, got {efforts!r}')
    collide = entry.get('collisions', False)
    options: dict = {}
    if isinstance(collide, dict):
        options = _collision_options(collide, f'{field}.collisions',
                                     {link.name for link in parsed.links})
        collide = True
        group, mask = options.get('group', 0), options.get('mask', ALL_BITS)
        if not entry.get('self_collide', False) and group & mask:
            raise SpecError(f'{field}.collisions.mask',
                            f'shares bits {group & mask} with the group {group}: the '
                            f"robot's links would meet each other, and self_collide is "
                            f"false; give a mask without the group's bits")
    elif not isinstance(collide, bool):
        raise SpecError(f'{field}.collisions', f'expected true, false or a mapping '
                                               f'{{friction, restitution, group, mask, '
                                               f'links}}, got {collide!r}')
    self_collide = entry.get('self_collide', False)
    if not isinstance(self_collide, bool):
        raise SpecError(f'{field}.self_collide', f'expected true or false, got '
                                                 f'{self_collide!r}')
    collisions = []
    if collide:
        # Each <collision> a shape on its link's body, a mesh as its convex hull; a
        # mesh whose file is not found or not read (not STL or OBJ) is named in the
        # robot's warning, never dropped silently.
        parsed.ignored = [x for x in parsed.ignored if not x.startswith('<collision>')]
        for c in parsed.collisions:
            if c.shape != 'mesh':
                collisions.append((c.link, c.shape, c.size, c.xyz, c.rpy))
            elif not c.path:
                parsed.ignored.append(f'mesh <collision> of link {c.link!r} ({c.uri}: '
                                      f'file not found)')
            elif Path(c.path).suffix.lower() not in MESH_FORMATS:
                parsed.ignored.append(f'mesh <collision> of link {c.link!r} ({c.uri}: '
                                      f'format not read; STL and OBJ are)')
            else:
                collisions.append((c.link, 'mesh', (c.path, tuple(c.size)), c.xyz,
                                   c.rpy))
    name = entry.get('name', parsed.name)
    if not isinstance(name, str) or not name:
        raise SpecError(f'{field}.name', f'expected a non-empty string, got {name!r}')
    spec = RobotSpec(name=name, links=parsed.links, joints=parsed.joints, base_xyz=xyz,
                     base_quat_xyzw=quat, fixed_base=fixed,
                     initial_positions=entry.get('initial_positions') or {},
                     initial_velocities=entry.get('initial_velocities') or {},
                     keep_fixed=tuple(keep), prefix=prefix, source=str(path),
                     enforce_limits=limits,
                     limit_restitution=entry.get('limit_restitution', 0.0),
                     enforce_friction=friction, enforce_efforts=efforts,
                     collisions=tuple(collisions), self_collide=self_collide,
                     collision_options=options)
    return spec, parsed


#: What a robot's ``collisions:`` mapping may set, for all its shapes or a link's.
COLLISION_KEYS = ('friction', 'restitution', 'group', 'mask', 'links')
LINK_COLLISION_KEYS = ('friction', 'restitution')


def _collision_options(data: dict, field: str, links: set) -> dict:
    """
    Return a robot's ``collisions:`` mapping, checked: its shapes' surface and filters.

    ``{friction, restitution, group, mask}`` for all the robot's shapes (as a body's
    ``shapes:`` entries), ``links: {link: {friction, restitution}}`` per link over them.
    Errors name the key (``robots[0].collisions.links.foot.friction``).
    """
    for key in data:
        if key not in COLLISION_KEYS:
            raise SpecError(f'{field}.{key}', f'unknown key; known: {list(COLLISION_KEYS)}')
    out = {k: data[k] for k in COLLISION_KEYS[:4] if k in data}
    _check_surface(out, field)
    per = data.get('links', {}) or {}
    if not isinstance(per, dict):
        raise SpecError(f'{field}.links', f'expected a mapping {{link: {{friction, '
                                          f'restitution}}}}, got {per!r}')
    out['links'] = {}
    for link, values in per.items():
        where = f'{field}.links.{link}'
        if link not in links:
            raise SpecError(where, f'unknown link; the robot has {sorted(links)}')
        if not isinstance(values, dict):
            raise SpecError(where, f'expected a mapping {{friction, restitution}}, got '
                                   f'{values!r}')
        for key in values:
            if key not in LINK_COLLISION_KEYS:
                raise SpecError(f'{where}.{key}', f'unknown key; known: '
                                                  f'{list(LINK_COLLISION_KEYS)}')
        _check_surface(values, where)
        out['links'][link] = dict(values)
    return out


def _check_surface(values: dict, field: str) -> None:
    """Check friction, restitution, group and mask as a shape would, naming ``field``'s key."""
    try:
        CollisionShape('sphere', 'check', radius=1.0, **values)
    except SpecError as exc:
        raise exc.within(field) from None


def body_from_dict(data: Any, folder: Union[str, Path] = '.', field: str = 'body') -> tuple:
    """
    Return ``(RigidBody, shapes, marker)`` of one body in the scene format (``bodies:``).

    Its ``shapes`` (mesh files relative to ``folder``) and its marker shape (the
    ``inertia: {box|sphere|cylinder: ...}`` it gives, or None), as a scene builds them:
    what a spawn in that format adds. Errors name ``field``.
    """
    body = _body(data, field)
    try:
        shapes = _collision_shapes(None, [data], Path(folder))
    except SpecError as exc:
        raise SpecError(exc.field.replace('bodies[0]', field, 1), exc.problem) from None
    inertia, marker = data['inertia'], None
    if isinstance(inertia, dict) and len(inertia) == 1 and \
            next(iter(inertia)) in ('box', 'sphere', 'cylinder'):
        kind, dims = next(iter(inertia.items()))
        marker = (kind, [float(d) for d in np.atleast_1d(dims)])
    return body, shapes, marker


def _body(data: Any, field: str) -> RigidBody:
    data = _mapping(data, field, BODY_KEYS)
    for key in ('name', 'mass', 'inertia'):
        if key not in data:
            raise SpecError(f'{field}.{key}', 'missing (required)')
    kwargs = {k: v for k, v in data.items()
              if k not in ('orientation_rpy', 'inertia', 'shapes')}
    try:
        mass = positive_scalar(data['mass'], 'mass')
        kwargs['inertia'] = _inertia(data['inertia'], mass)
        if 'orientation_rpy' in data:
            if 'orientation_xyzw' in data:
                raise SpecError('orientation_rpy', 'give orientation_xyzw or orientation_rpy, '
                                                   'not both')
            rpy = finite_array(data['orientation_rpy'], 'orientation_rpy', (3,))
            # URDF convention: fixed axes x, y, z (roll, then pitch, then yaw).
            kwargs['orientation_xyzw'] = Rotation.from_euler('xyz', rpy).as_quat()
        return RigidBody(**kwargs)
    except SpecError as exc:
        raise exc.within(field) from None


def _collision_shapes(ground: Any, bodies_data: list, folder: Path) -> list:
    """
    Return the scene's collision shapes: its ``ground`` and each body's ``shapes``.

    A mesh's file name is taken from ``folder`` (the scene file's) unless absolute.
    """
    out = []
    if ground is not None:
        g = _mapping(ground, 'ground', GROUND_KEYS)
        normal = finite_array(g.get('normal', (0.0, 0.0, 1.0)), 'ground.normal', (3,))
        length = float(np.linalg.norm(normal))
        if not length > 0.0:
            raise SpecError('ground.normal', f'must be a non-zero vector, got {normal!r}')
        normal = normal / length
        height = float(finite_array(g.get('height', 0.0), 'ground.height', ()))
        # The plane's z axis is its normal: the shortest rotation from z to it.
        axis = np.cross((0.0, 0.0, 1.0), normal)
        angle = math.atan2(float(np.linalg.norm(axis)), float(normal[2]))
        rotvec = np.zeros(3) if not np.any(axis) else axis / np.linalg.norm(axis) * angle
        if not np.any(axis) and normal[2] < 0.0:
            rotvec = np.array([math.pi, 0.0, 0.0])
        try:
            out.append(CollisionShape('plane', None, position_body=height * normal,
                                      orientation_xyzw=Rotation.from_rotvec(rotvec).as_quat(),
                                      friction=g.get('friction', 1.0),
                                      restitution=g.get('restitution', 0.0), name='ground'))
        except SpecError as exc:
            raise exc.within('ground') from None
    for i, body in enumerate(bodies_data):
        entries = body.get('shapes') if isinstance(body, dict) else None
        if entries is None:
            continue
        field = f'bodies[{i}].shapes'
        if not isinstance(entries, list):
            raise SpecError(field, f'expected a list of shapes, got {entries!r}')
        for k, entry in enumerate(entries):
            entry = _mapping(entry, f'{field}[{k}]', SHAPE_KEYS)
            if 'kind' not in entry:
                raise SpecError(f'{field}[{k}].kind', 'missing (required): sphere, box, '
                                                      'capsule, cylinder or mesh')
            if isinstance(entry.get('mesh'), str) and not Path(entry['mesh']).is_absolute():
                entry = {**entry, 'mesh': str(folder / entry['mesh'])}
            try:
                out.append(CollisionShape(body=body['name'], **entry))
            except SpecError as exc:
                raise exc.within(f'{field}[{k}]') from None
    return out


def _inertia(value: Any, mass: float) -> Any:
    """Inertia as given, or from URDF-style components or a uniform-density shape."""
    if not isinstance(value, dict):
        return value
    if len(value) == 1 and next(iter(value)) in ('box', 'sphere', 'cylinder'):
        shape, dims = next(iter(value.items()))
        if shape == 'box':
            lx, ly, lz = finite_array(dims, 'inertia.box', (3,))
            for n, d in zip('xyz', (lx, ly, lz)):
                if not d > 0.0:
                    raise SpecError('inertia.box', f'side l{n} must be positive, got {d:.9g}')
            return mass / 12.0 * np.array([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
        if shape == 'sphere':
            r = positive_scalar(dims, 'inertia.sphere')
            return np.full(3, 0.4 * mass * r**2)
        r, length = finite_array(dims, 'inertia.cylinder', (2,))
        if not (r > 0.0 and length > 0.0):
            raise SpecError('inertia.cylinder',
                            f'radius and length must be positive, got {dims!r}')
        side = mass * (3.0 * r**2 + length**2) / 12.0
        return np.array([side, side, 0.5 * mass * r**2])
    comp = _mapping(value, 'inertia', URDF_INERTIA_KEYS)
    for key in ('ixx', 'iyy', 'izz'):
        if key not in comp:
            raise SpecError(f'inertia.{key}', 'missing (required)')
    c = {k: float(finite_array(comp.get(k, 0.0), f'inertia.{k}', ())) for k in URDF_INERTIA_KEYS}
    return [[c['ixx'], c['ixy'], c['ixz']], [c['ixy'], c['iyy'], c['iyz']],
            [c['ixz'], c['iyz'], c['izz']]]


def _constraints(data: Any) -> tuple:
    """
    Constraints listed in the scene (generic ones need Python: not in files).

    Returns the constraints and the hinges' and sliders' limits and friction
    (:class:`.core.limits.SceneJoint`).
    """
    out, joints = [], []
    for where, c in _entries(data, 'constraints', CONSTRAINT_KEYS + SCENE_JOINT_KEYS,
                             ('name', 'type', 'body_a')):
        if c['type'] == 'generic':
            raise SpecError(f'{where}.type', 'generic constraints need a Python function: add '
                                             'them with Simulation.add_constraint')
        c = dict(c)
        extra = {key: c.pop(key) for key in SCENE_JOINT_KEYS if key in c}
        try:
            out.append(Constraint(**c))
        except SpecError as exc:
            raise exc.within(where) from None
        if extra:
            if out[-1].type.value not in ('hinge', 'slider'):
                key = next(iter(extra))
                raise SpecError(f'{where}.{key}', f'limits and friction are for hinge and '
                                                  f'slider constraints, not '
                                                  f'{out[-1].type.value!r}')
            try:
                joints.append(SceneJoint(out[-1].name, **extra))
            except SpecError as exc:
                raise exc.within(where) from None
    return out, joints


def _effects(data: Any) -> list:
    """Effects listed in the scene, as (key, Effect) pairs."""
    data = _mapping(data, 'effects', tuple(EFFECT_KEYS))
    out = []
    for key, params in data.items():
        field = f'effects.{key}'
        if key == 'wrenches':
            if not isinstance(params, list):
                raise SpecError(field, f'expected a list of wrenches, got {params!r}')
            for i, w in enumerate(params):
                _mapping(w, f'{field}[{i}]', WRENCH_KEYS)
            out.append((key, AppliedWrenches(params)))
            continue
        params = _mapping(params if params is not None else {}, field, EFFECT_KEYS[key])
        try:
            out.append((key, {'gravity': Gravity, 'damping': Damping}[key](**params)))
        except SpecError as exc:
            raise exc.within(field) from None
    return out
