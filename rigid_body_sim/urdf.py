"""
URDF and xacro files -> :class:`rigid_body_sim.core.robots.RobotSpec` (the XML edge).

Parsed by ROS's own parser, ``urdf_parser_py`` (urdfdom-py), after ``xacro`` for
``.xacro`` files. Errors name the file, and the line and element where the
XML says; elements the simulator does not use (``collision`` until contact
exists, ``transmission``, ``gazebo``, ``ros2_control``, ``safety_controller``,
``calibration``, unknown tags) are named in one warning, never dropped
silently.

URIs (``package://pkg/path``, ``file:///path``) resolve through ``ament_index``
when the package is installed, else relative to the folder of the nearest
``package.xml`` above the URDF whose name is ``pkg`` (a source checkout), else
they are left as they are.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import re
from typing import Any, Optional

import numpy as np

from .core.errors import SpecError
from .core.robots import JointSpec, LinkSpec, rpy_matrix

#: Elements of a URDF that are read but not simulated (named in the load warning).
NOT_SIMULATED = ('collision', 'transmission', 'gazebo', 'ros2_control', 'safety_controller',
                 'calibration')


class UrdfError(ValueError):
    """A URDF or xacro file that cannot be loaded: ``"<file>[:line]: <problem>"``."""


@dataclass
class Visual:
    """A link's visual: shape ``box|cylinder|sphere|mesh``, its size, pose in the link."""

    link: str
    shape: str
    size: tuple            # box (lx, ly, lz); cylinder (r, length); sphere (r,); mesh scale
    xyz: np.ndarray
    rpy: np.ndarray
    uri: str = ''          # mesh: as written
    path: str = ''         # mesh: resolved file, '' if not found
    rgba: Optional[tuple] = None


@dataclass
class Collision:
    """A link's collision geometry: ``box|cylinder|sphere|mesh``, its size, pose in the link."""

    link: str
    shape: str
    size: tuple            # box (lx, ly, lz); cylinder (r, length); sphere (r,); mesh scale
    xyz: np.ndarray
    rpy: np.ndarray
    uri: str = ''          # mesh: as written
    path: str = ''         # mesh: resolved file, '' if not found


@dataclass
class ParsedUrdf:
    """What a URDF holds for the simulator."""

    name: str
    xml: str
    links: list
    joints: list
    visuals: list = field(default_factory=list)
    ignored: list = field(default_factory=list)   # elements not simulated, as 'tag (where)'
    source: str = ''
    #: The links' <collision> geometry (shapes for contact when a scene asks for them).
    collisions: list = field(default_factory=list)


def read_robot_xml(path: Any, xacro_args: Optional[dict] = None) -> str:
    """
    Return the URDF text of a ``.urdf`` file, or of a ``.xacro`` expanded with its args.

    Raises
    ------
    UrdfError
        Naming the file and the problem (a missing file, a xacro error).

    """
    path = Path(path)
    if not path.is_file():
        raise UrdfError(f'{path}: no such file')
    args = {} if xacro_args is None else xacro_args
    if not isinstance(args, dict):
        raise UrdfError(f'{path}: xacro_args: expected a mapping name -> value, got {args!r}')
    if path.suffix == '.xacro':
        import xacro
        try:
            doc = xacro.process_file(str(path), mappings={str(k): str(v)
                                                          for k, v in args.items()})
        except Exception as exc:  # noqa: B902 - xacro raises many types; all are bad input
            raise UrdfError(f'{path}: xacro failed: {type(exc).__name__}: {exc}') from None
        return doc.toprettyxml(indent='  ')
    if args:
        raise UrdfError(f'{path}: xacro_args given, but the file is not a .xacro file')
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise UrdfError(f'{path}: cannot read: {exc}') from None


def parse_urdf(xml: str, source: str = '<urdf>') -> ParsedUrdf:
    """
    Parse URDF text into link and joint specs.

    Raises
    ------
    UrdfError
        ``"<source>:<line>: <element>: <problem>"`` where the line is known.

    """
    from lxml import etree
    from urdf_parser_py import urdf as up
    from urdf_parser_py.xml_reflection import core as xml_core

    try:
        root = etree.fromstring(xml.encode() if isinstance(xml, str) else xml)
    except etree.XMLSyntaxError as exc:
        raise UrdfError(f'{source}:{exc.lineno}: not well-formed XML: {exc.msg}') from None
    if root.tag != 'robot':
        raise UrdfError(f'{source}:{root.sourceline}: the root element is <{root.tag}>, '
                        f'not <robot>')

    def line_of(tag: str, name: str) -> str:
        for el in root.iter(tag):
            if el.get('name') == name:
                return f'{source}:{el.sourceline}'
        return source

    ignored = []
    for tag in NOT_SIMULATED:
        count = sum(1 for _ in root.iter(tag))
        if count:
            ignored.append(f'<{tag}> x{count}')
    # What the simulator does not read is not parsed either (a transmission written for
    # another tool must not stop a load); the rest goes to urdf_parser_py.
    parse_tree = etree.fromstring(etree.tostring(root))
    for tag in ('transmission', 'gazebo', 'ros2_control'):
        for el in list(parse_tree.iter(tag)):
            el.getparent().remove(el)
    # Everything urdf_parser_py would only print, collected for one warning.
    complaints: list = []
    saved = xml_core.on_error
    xml_core.on_error = complaints.append
    try:
        robot = up.URDF.from_xml_string(etree.tostring(parse_tree))
    except Exception as exc:  # noqa: B902 - urdf_parser_py raises bare Exceptions
        flat = ' '.join(str(exc).split())
        raise UrdfError(f'{_where(parse_tree, flat, source)}: {flat}') from None
    finally:
        xml_core.on_error = saved
    # urdf_parser_py names an unknown attribute once per element: count them instead.
    unknown = {}
    for c in complaints:
        m = re.match(r'Unknown (attribute|tag) "([^"]+)" in (.*)$', c)
        key = c if m is None else f'unknown {m.group(1)} "{m.group(2)}" in '\
            f'<{m.group(3).rsplit("/", 1)[-1].split("[")[0]}>'
        unknown[key] = unknown.get(key, 0) + 1
    ignored += [k if n == 1 else f'{k} x{n}' for k, n in unknown.items()]

    # Colours by material name: the top-level <material>s and those defined inline in a
    # visual, for visuals that name a material without a colour (as xacro output does).
    colours = {}
    for material in list(robot.materials) + [v.material for link in robot.links
                                             for v in link.visuals
                                             if getattr(v, 'material', None) is not None]:
        if material.name and getattr(material, 'color', None) is not None \
                and material.name not in colours:
            colours[material.name] = tuple(float(c) for c in material.color.rgba)
    links, visuals, collisions = [], [], []
    for link in robot.links:
        where = f'{line_of("link", link.name)}: link {link.name!r}'
        inertial = link.inertial
        if inertial is None:
            links.append(LinkSpec(link.name))
        else:
            xyz, rpy = _origin(inertial.origin)
            mass = 0.0 if inertial.mass is None else float(inertial.mass)
            if mass < 0.0 or not np.isfinite(mass):
                raise UrdfError(f'{where}: inertial.mass must be >= 0, got {mass!r}')
            i = inertial.inertia
            if i is None:
                raise UrdfError(f'{where}: inertial has a mass but no <inertia>')
            tensor = np.array([[i.ixx, i.ixy, i.ixz], [i.ixy, i.iyy, i.iyz],
                               [i.ixz, i.iyz, i.izz]], dtype=float)
            R = rpy_matrix(rpy)
            try:
                links.append(LinkSpec(link.name, mass, xyz, R @ tensor @ R.T))
            except SpecError as exc:
                raise UrdfError(f'{where}: inertial.{exc}') from None
        for visual in link.visuals:
            v = _visual(link.name, visual, source, colours)
            if v is not None:
                visuals.append(v)
        for geometry in getattr(link, 'collisions', None) or []:
            c = _collision(link.name, geometry, source)
            if c is not None:
                collisions.append(c)
    joints = []
    for joint in robot.joints:
        where = f'{line_of("joint", joint.name)}: joint {joint.name!r}'
        xyz, rpy = _origin(joint.origin)
        limit, dynamics, mimic = joint.limit, joint.dynamics, joint.mimic
        kwargs = {'name': joint.name, 'kind': joint.type, 'parent': joint.parent,
                  'child': joint.child, 'origin_xyz': xyz, 'origin_rpy': rpy,
                  'axis': (1.0, 0.0, 0.0) if joint.axis is None else joint.axis}
        if joint.type in ('revolute', 'prismatic') and limit is None:
            raise UrdfError(f'{where}: a {joint.type} joint needs a <limit> (URDF requires '
                            f'effort and velocity)')
        if limit is not None:
            kwargs.update(effort=limit.effort, velocity=limit.velocity)
            if joint.type != 'continuous':
                kwargs.update(lower=limit.lower, upper=limit.upper)
        if dynamics is not None:
            kwargs.update(damping=dynamics.damping or 0.0, friction=dynamics.friction or 0.0)
        if mimic is not None:
            kwargs['mimic'] = (mimic.joint, 1.0 if mimic.multiplier is None
                               else mimic.multiplier, mimic.offset or 0.0)
        try:
            joints.append(JointSpec(**kwargs))
        except SpecError as exc:
            raise UrdfError(f'{where}: {exc}') from None
    names = {j.name for j in joints}
    for j in joints:
        if j.mimic is not None and j.mimic[0] not in names:
            raise UrdfError(f'{line_of("joint", j.name)}: joint {j.name!r}: mimic.joint: '
                            f'unknown joint {j.mimic[0]!r}')
    return ParsedUrdf(robot.name, xml if isinstance(xml, str) else xml.decode(), links,
                      joints, visuals, ignored, source, collisions)


def prefixed_xml(xml: str, prefix: str) -> str:
    """
    Return the URDF with ``prefix`` before every link and joint name, as the simulation has them.

    Renames ``<link name>``, ``<joint name>``, its ``<parent link>``, ``<child link>`` and
    ``<mimic joint>``, ``<transmission>``'s ``<joint name>`` and ``<gazebo reference>``;
    a link named ``world`` is the world and keeps its name. So ``robot_description``
    names what ``joint_states`` and ``/tf`` name (RViz's RobotModel, robot_state_publisher).
    """
    if not prefix:
        return xml
    from lxml import etree
    root = etree.fromstring(xml.encode())
    links = {el.get('name') for el in root.iter('link')}
    joints = {el.get('name') for el in root.iter('joint') if el.getparent() is root}

    def link(name: Optional[str]) -> Optional[str]:
        return name if name is None or name == 'world' else prefix + name

    for el in root.iter('link'):
        el.set('name', link(el.get('name')))
    for el in root.iter('joint'):
        if el.get('name') is not None:
            el.set('name', prefix + el.get('name'))
        for tag in ('parent', 'child'):
            for end in el.findall(tag):
                end.set('link', link(end.get('link')))
        for mimic in el.findall('mimic'):
            mimic.set('joint', prefix + mimic.get('joint', ''))
    for el in root.iter('gazebo'):
        ref = el.get('reference')
        if ref in links:
            el.set('reference', link(ref))
        elif ref in joints:
            el.set('reference', prefix + ref)
    return etree.tostring(root, encoding='unicode')


_PATH = re.compile(r'ParseError in (/\S+?):?\s')


def _where(tree: Any, message: str, source: str) -> str:
    """``source:line`` of the element a urdf_parser_py message names by its path."""
    m = _PATH.search(message + ' ')
    if m is not None:
        try:
            found = tree.getroottree().xpath(m.group(1))
        except Exception:  # noqa: B902 - lxml's XPath errors: the path is only a hint
            found = []
        if found:
            return f'{source}:{found[0].sourceline}'
    return source


def _origin(origin: Any) -> tuple:
    if origin is None:
        return np.zeros(3), np.zeros(3)
    xyz = np.zeros(3) if origin.xyz is None else np.asarray(origin.xyz, dtype=float)
    rpy = np.zeros(3) if origin.rpy is None else np.asarray(origin.rpy, dtype=float)
    return xyz, rpy


def _visual(link: str, visual: Any, source: str, colours: dict) -> Optional[Visual]:
    from urdf_parser_py import urdf as up
    xyz, rpy = _origin(visual.origin)
    g = visual.geometry
    rgba = None
    material = getattr(visual, 'material', None)
    if material is not None and getattr(material, 'color', None) is not None:
        rgba = tuple(float(c) for c in material.color.rgba)
    elif material is not None:
        rgba = colours.get(material.name)   # a material named only: its definition
    if isinstance(g, up.Box):
        return Visual(link, 'box', tuple(g.size), xyz, rpy, rgba=rgba)
    if isinstance(g, up.Cylinder):
        return Visual(link, 'cylinder', (g.radius, g.length), xyz, rpy, rgba=rgba)
    if isinstance(g, up.Sphere):
        return Visual(link, 'sphere', (g.radius,), xyz, rpy, rgba=rgba)
    if isinstance(g, up.Mesh):
        scale = (1.0, 1.0, 1.0) if g.scale is None else tuple(g.scale)
        return Visual(link, 'mesh', scale, xyz, rpy, uri=g.filename,
                      path=resolve_uri(g.filename, source), rgba=rgba)
    return None


def _collision(link: str, collision: Any, source: str) -> Optional[Collision]:
    from urdf_parser_py import urdf as up
    xyz, rpy = _origin(collision.origin)
    g = collision.geometry
    if isinstance(g, up.Box):
        return Collision(link, 'box', tuple(g.size), xyz, rpy)
    if isinstance(g, up.Cylinder):
        return Collision(link, 'cylinder', (g.radius, g.length), xyz, rpy)
    if isinstance(g, up.Sphere):
        return Collision(link, 'sphere', (g.radius,), xyz, rpy)
    if isinstance(g, up.Mesh):
        scale = (1.0, 1.0, 1.0) if g.scale is None else tuple(g.scale)
        return Collision(link, 'mesh', scale, xyz, rpy, uri=g.filename,
                         path=resolve_uri(g.filename, source))
    return None


_PACKAGE = re.compile(r'^package://([^/]+)/(.*)$')


def resolve_uri(uri: str, source: str = '') -> str:
    """
    Return the file a ``package://`` or ``file://`` URI names, or '' if none is found.

    ``package://pkg/rest`` resolves through ``ament_index`` when ``pkg`` is
    installed, else to ``rest`` under the nearest folder above ``source``
    whose ``package.xml`` names ``pkg`` (or which is called ``pkg``).
    """
    if uri.startswith('file://'):
        path = Path(uri[len('file://'):])
        return str(path) if path.is_file() else ''
    m = _PACKAGE.match(uri)
    if m is None:
        path = Path(source).parent / uri if source else Path(uri)
        return str(path) if path.is_file() else ''
    package, rest = m.groups()
    try:
        from ament_index_python.packages import get_package_share_directory
        candidate = Path(get_package_share_directory(package)) / rest
        if candidate.is_file():
            return str(candidate)
    except Exception:  # noqa: B902 - not installed (PackageNotFoundError), or no ament_index
        pass
    if source:
        for folder in Path(source).resolve().parents:
            manifest = folder / 'package.xml'
            named = manifest.is_file() and f'<name>{package}</name>' in manifest.read_text()
            if named or folder.name == package:
                candidate = folder / rest
                return str(candidate) if candidate.is_file() else ''
    return ''
