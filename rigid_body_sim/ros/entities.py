"""
The scene's entities as the ROS simulator interface sees them (``simulation_interfaces``).

ROS-free (the node's :mod:`.standard` turns these into messages). An entity is

- each body of the scene that is not a robot's link: category ``OBJECT``, its state
  its body frame's (origin and axes);
- each robot: category ``ROBOT``, its state its base link's (the URDF's root link's
  frame), its bounds those of all its links' shapes about that frame.

States are in the world frame: pose; twist of the frame's origin (linear) and
angular velocity; accelerations of both from the equations of motion now
(:meth:`~rigid_body_sim.core.Simulation.accelerations`). Setting a state moves the
entity as one rigid whole (:meth:`~rigid_body_sim.core.Simulation.place`): a robot
keeps its joint positions and its joints stop; a robot fixed to the world, or a body
held by a constraint to another entity or the world, is refused.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import re
from typing import Optional

import numpy as np

from ..core import rotation as so3
from ..core import Simulation, SpecError
from ..core.hulls import H_NV, H_VERTS

#: The standard's categories (simulation_interfaces/msg/EntityCategory).
OBJECT, ROBOT = 0, 1


class EntityError(Exception):
    """A request about entities refused: ``code`` says why (a Result code), the message how."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Entity:
    """One entity: its name, category, bodies, and its frame (on ``body`` at ``p``, ``R``)."""

    name: str
    category: int
    bodies: tuple          # the bodies it moves as a whole (a robot's links' bodies)
    body: Optional[str]    # the body its frame is fixed to (None: the world)
    position: np.ndarray   # its frame's origin on that body (body frame; world: world)
    rotation: np.ndarray   # its frame's axes on that body
    description: str
    robot: Optional[str] = None   # a robot's name in the simulation (None: a body)


class Entities:
    """The entities of a simulation (see the module docstring)."""

    def __init__(self, sim: Simulation) -> None:
        self.sim = sim
        robot_bodies = {b.name for model in sim.robots for b in model.bodies}
        out = {}
        for name in sim.bodies.names:
            if name not in robot_bodies:
                out[name] = Entity(name, OBJECT, (name,), name, np.zeros(3), np.eye(3),
                                   f'rigid body {name!r}')
        for model in sim.robots:
            spec = model.spec
            children = {j.child for j in spec.joints}
            root = next(link.name for link in spec.links if link.name not in children)
            frame = model.links[root]
            fixed = ' fixed to the world' if frame.body is None else ''
            name = spec.name
            while name in out:   # (a scene body of the robot's name keeps it)
                name += '_robot'
            out[name] = Entity(
                name, ROBOT, tuple(b.name for b in model.bodies), frame.body,
                np.array(frame.position, dtype=float), np.array(frame.rotation, dtype=float),
                f'robot {spec.name!r} ({spec.source or "URDF"}): {len(model.bodies)} bodies, '
                f'{len(model.joints)} joints, base link {spec.prefix + root!r}{fixed}',
                spec.name)
        self.by_name = out

    def entity_of(self, name: str, robot: bool = False) -> str:
        """Return the entity name of body ``name`` (``robot``: of robot ``name``)."""
        for entity_name, e in self.by_name.items():
            if (e.robot == name) if robot else (e.robot is None and e.body == name):
                return entity_name
        raise EntityError('NOT_FOUND', f'no entity of {"robot" if robot else "body"} '
                                       f'{name!r}')

    def names(self) -> list:
        """Return every entity's name, in the scene's order (bodies, then robots)."""
        return list(self.by_name)

    def states(self, names: list) -> list:
        """Return :meth:`state` of each of ``names`` (the accelerations found once)."""
        acc = self.sim.accelerations() if names else None
        return [self.state(name, acc) for name in names]

    def get(self, name: str) -> Entity:
        """Return the entity called ``name``; EntityError NOT_FOUND naming the known ones."""
        try:
            return self.by_name[name]
        except (KeyError, TypeError):
            raise EntityError('NOT_FOUND', f'no entity {name!r}; entities: '
                                           f'{self.names()}') from None

    def select(self, pattern: str, categories: list) -> list:
        """
        Return the names that ``pattern`` and ``categories`` select.

        ``pattern``: a regular expression searched in the name (empty: all);
        ``categories``: the entity's must be one of them (empty: any). Raises
        EntityError OPERATION_FAILED for a pattern that is not a regular expression.
        """
        try:
            rx = re.compile(pattern) if pattern else None
        except re.error as exc:
            raise EntityError('OPERATION_FAILED', f'filters.filter: {pattern!r} is not a '
                                                  f'regular expression ({exc})') from None
        return [name for name, e in self.by_name.items()
                if (rx is None or rx.search(name)) and (not categories
                                                        or e.category in categories)]

    # -- states ---------------------------------------------------------------------------

    def state(self, name: str, accelerations: Optional[tuple] = None) -> tuple:
        """
        Return ``(position, quat_xyzw, velocity, omega, acceleration, alpha)``, world frame.

        Of the entity's frame: its origin's position, velocity and acceleration, its
        orientation, angular velocity and angular acceleration. ``accelerations``:
        :meth:`~rigid_body_sim.core.Simulation.accelerations` now, when known.
        """
        e = self.get(name)
        if e.body is None:   # (a robot fixed to the world: its base link does not move)
            zero = np.zeros(3)
            return (e.position.copy(), so3.matrix_to_quat(e.rotation), zero, zero.copy(),
                    zero.copy(), zero.copy())
        sim = self.sim
        i = sim.bodies.lookup(e.body)
        pos, quat = sim.pose(e.body)
        vel, omega = sim.twist(e.body)
        acc, alpha = sim.accelerations() if accelerations is None else accelerations
        R = so3.quat_to_matrix(quat)
        r = R @ e.position
        return (pos + r, so3.matrix_to_quat(R @ e.rotation), vel + np.cross(omega, r), omega,
                acc[i] + np.cross(alpha[i], r) + np.cross(omega, np.cross(omega, r)),
                alpha[i])

    def reference(self, frame: str) -> tuple:
        """
        Return a frame's origin, axes, origin velocity and angular velocity, world, now.

        ``frame``: an entity's name, a body's, or a robot link's (its name in
        ``joint_states`` and ``/tf``, the prefix included). EntityError OPERATION_FAILED
        for another name.
        """
        sim = self.sim
        if frame in self.by_name:
            e = self.by_name[frame]
            body, p, R = e.body, e.position, e.rotation
        elif frame in sim.bodies.index:
            body, p, R = frame, np.zeros(3), np.eye(3)
        else:
            link = next((f for m in sim.robots for k, f in m.links.items()
                         if m.spec.prefix + k == frame), None)
            if link is None:
                raise EntityError('OPERATION_FAILED', f'state.header.frame_id: {frame!r} is '
                                                      f'not the world, an entity, a body or a '
                                                      f"robot's link")
            body, p, R = link.body, np.asarray(link.position), np.asarray(link.rotation)
        if body is None:   # (fixed to the world)
            return p.copy(), R.copy(), np.zeros(3), np.zeros(3)
        pos, quat = sim.pose(body)
        vel, omega = sim.twist(body)
        R_b = so3.quat_to_matrix(quat)
        r = R_b @ p
        return pos + r, R_b @ R, vel + np.cross(omega, r), omega

    def set_state(self, name: str, position: np.ndarray, quat_xyzw: np.ndarray,
                  velocity: np.ndarray, omega: np.ndarray, frame: str = '') -> None:
        """
        Move the entity rigidly to a pose of its frame and its twist (see the module doc).

        ``frame``: the reference they are given in ('' the world; else :meth:`reference`'s
        names): the pose in its axes about its origin, the twist as observed from it
        (relative velocity and angular velocity, in its axes), as EntityState says.
        Raises EntityError: NOT_FOUND; OPERATION_FAILED for a robot fixed to the world,
        a value that is not finite, a zero quaternion, a frame unknown or moving with the
        entity, or a constraint it would break.
        """
        e = self.get(name)
        if e.body is None:
            raise EntityError('OPERATION_FAILED', f'{name!r} is fixed to the world (its base '
                                                  f'link is welded to it): it cannot be moved')
        q = np.asarray(quat_xyzw, dtype=float)
        norm = float(np.linalg.norm(q))
        if not (math.isfinite(norm) and norm > 1e-6):
            raise EntityError('OPERATION_FAILED', f'state.pose.orientation: not a rotation '
                                                  f'(norm {norm:.3g})')
        R_frame = so3.quat_to_matrix(q / norm)
        if frame:
            if (frame in self.by_name and self.by_name[frame].bodies == e.bodies) \
                    or frame in e.bodies or self._body_of(frame) in e.bodies:
                raise EntityError('OPERATION_FAILED', f'state.header.frame_id: {frame!r} '
                                                      f'moves with {name!r}')
            p_f, R_f, v_f, w_f = self.reference(frame)
            r = R_f @ np.asarray(position, dtype=float)
            position, R_frame = p_f + r, R_f @ R_frame
            velocity = v_f + np.cross(w_f, r) + R_f @ np.asarray(velocity, dtype=float)
            omega = w_f + R_f @ np.asarray(omega, dtype=float)
        # The body's frame from the entity's: R_body = R_frame Rᵀ, origin at p − R_body r.
        R_body = R_frame @ e.rotation.T
        r = R_body @ e.position
        try:
            self.sim.place(e.bodies, e.body, np.asarray(position, dtype=float) - r,
                           so3.matrix_to_quat(R_body),
                           np.asarray(velocity, dtype=float) - np.cross(omega, r), omega)
        except SpecError as exc:
            raise EntityError('OPERATION_FAILED', str(exc)) from None

    def _body_of(self, frame: str) -> Optional[str]:
        """Return the body a robot link's frame is on (None: not a link, or the world)."""
        for m in self.sim.robots:
            for k, f in m.links.items():
                if m.spec.prefix + k == frame:
                    return f.body
        return None

    # -- bounds ---------------------------------------------------------------------------

    def frame(self, name: str) -> tuple:
        """Return the entity frame's origin (3,) and axes (3, 3) in the world now."""
        e = self.get(name)
        if e.body is None:
            return e.position.copy(), e.rotation.copy()
        pos, quat = self.sim.pose(e.body)
        R_b = so3.quat_to_matrix(quat)
        return pos + R_b @ e.position, R_b @ e.rotation

    def overlapping(self, names: list, kind: str, points: np.ndarray) -> list:
        """
        Return those of ``names`` whose bounds overlap a region (touching counts).

        An entity's bounds are its :meth:`bounds` box about its frame, placed where the
        entity is (an oriented box); an entity without shapes is its frame's origin.
        The region: ``kind`` 'sphere' (``points`` the centre, then a point whose x is the
        radius), 'box' (two opposite corners, world axes) or 'hull' (the convex hull of
        three or more points). A sphere is tested in closed form (the box's closest
        point); a box or a hull by whether the two convex hulls share a point (a linear
        program's feasibility, scipy's HiGHS, to its 1e-7 feasibility tolerance).
        Raises EntityError OPERATION_FAILED for a malformed region, naming it.
        """
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        if not np.all(np.isfinite(points)):
            raise EntityError('OPERATION_FAILED', 'filters.bounds.points: not finite')
        need = {'sphere': 2, 'box': 2, 'hull': 3}[kind]
        if len(points) < need or (kind != 'hull' and len(points) != need):
            raise EntityError('OPERATION_FAILED', f'filters.bounds: a {kind} takes '
                                                  f'{"at least " if kind == "hull" else ""}'
                                                  f'{need} points, got {len(points)}')
        if kind == 'sphere' and not points[1][0] >= 0.0:
            raise EntityError('OPERATION_FAILED', f'filters.bounds.points[1].x: the radius '
                                                  f'must be >= 0, got {points[1][0]!r}')
        if kind == 'box':
            lo, hi = points.min(axis=0), points.max(axis=0)
            points = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)])
        out = []
        for name in names:
            p, R = self.frame(name)
            box = self.bounds(name)
            if kind == 'sphere':
                centre, radius = points[0], float(points[1][0])
                local = R.T @ (centre - p)
                nearest = np.zeros(3) if box is None else np.clip(local, box[0], box[1])
                hit = float(np.linalg.norm(local - nearest)) <= radius
            else:
                corners = p[None, :] if box is None else np.array(
                    [p + R @ np.array([(box[0], box[1])[i >> k & 1][k] for k in range(3)])
                     for i in range(8)])
                hit = _hulls_meet(corners, points)
            if hit:
                out.append(name)
        return out

    def bounds(self, name: str) -> Optional[tuple]:
        """
        Return ``(lower, upper)`` (3,) each: the box around the entity's shapes in its frame.

        Axis-aligned in the entity's frame (its base link's for a robot, at the current
        configuration), from each shape's support function (exact for boxes, spheres,
        capsules and cylinders; a mesh by its hull's vertices); None
        when the entity has no shape.
        """
        e = self.get(name)
        sim = self.sim
        shapes = [s for s in sim.shapes if s.body in e.bodies and s.kind != 'plane']
        if not shapes:
            return None
        p_frame, R_frame = self.frame(name)
        lower, upper = np.full(3, np.inf), np.full(3, -np.inf)
        for s in shapes:
            pos, quat = sim.pose(s.body)
            R_b = so3.quat_to_matrix(quat)
            c = pos + R_b @ np.asarray(s.position_body, dtype=float)
            R_s = R_b @ so3.quat_to_matrix(np.asarray(s.orientation_xyzw, dtype=float))
            for k in range(3):
                d = R_frame[:, k]   # the frame's k-th axis, world
                centre = float(d @ (c - p_frame))
                local = R_s.T @ d
                upper[k] = max(upper[k], centre + _support(s, local))
                lower[k] = min(lower[k], centre - _support(s, -local))
        return lower, upper


def _hulls_meet(a: np.ndarray, b: np.ndarray) -> bool:
    """Tell whether the convex hulls of points ``a`` (n, 3) and ``b`` (m, 3) share a point."""
    from scipy.optimize import linprog
    n, m = len(a), len(b)
    # λ ≥ 0, μ ≥ 0, Σλ = Σμ = 1, aᵀλ − bᵀμ = 0: feasible exactly when they meet.
    eq = np.zeros((5, n + m))
    eq[:3, :n], eq[:3, n:] = a.T, -b.T
    eq[3, :n], eq[4, n:] = 1.0, 1.0
    rhs = np.array([0.0, 0.0, 0.0, 1.0, 1.0])
    res = linprog(np.zeros(n + m), A_eq=eq, b_eq=rhs, bounds=(0, None), method='highs')
    return res.status == 0


def _support(shape, d: np.ndarray) -> float:
    """Return how far ``shape`` reaches from its origin along unit ``d`` (its own axes)."""
    kind = shape.kind
    if kind == 'sphere':
        return float(shape.radius)
    if kind == 'box':
        return float(np.abs(d) @ shape.dimensions())
    if kind == 'mesh':   # (its hull's vertices, in the shape's frame)
        rec = shape.hull
        nv = int(rec[H_NV])
        return float(np.max(rec[H_VERTS:H_VERTS + 3 * nv].reshape(nv, 3) @ d))
    half = 0.5 * float(shape.length)
    axial = abs(float(d[2]))
    if kind == 'capsule':
        return half * axial + float(shape.radius)
    # a cylinder: its end disc's rim reaches r √(1 − d_z²) across the axis
    return half * axial + float(shape.radius) * math.sqrt(max(0.0, 1.0 - axial * axial))
