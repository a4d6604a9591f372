"""Builders of small URDF robots and joint-space readings of a simulation, for the tests."""

import re

import numpy as np
from rigid_body_sim.core import rotation as so3
from rigid_body_sim.scene import scene_from_dict


def inertial(mass, xyz=(0, 0, 0), rpy=(0, 0, 0), ixx=0.1, iyy=0.1, izz=0.1, ixy=0.0,
             ixz=0.0, iyz=0.0):
    """Return an ``<inertial>`` element."""
    return (f'<inertial><origin xyz="{_v(xyz)}" rpy="{_v(rpy)}"/><mass value="{mass}"/>'
            f'<inertia ixx="{ixx!r}" iyy="{iyy!r}" izz="{izz!r}" ixy="{ixy!r}" ixz="{ixz!r}" '
            f'iyz="{iyz!r}"/></inertial>')


def link(name, body=''):
    """Return a ``<link>`` element with ``body`` inside."""
    return f'<link name="{name}">{body}</link>'


def joint(name, kind, parent, child, xyz=(0, 0, 0), rpy=(0, 0, 0), axis=None, extra=''):
    """Return a ``<joint>``; revolute and prismatic joints get a generous ``<limit>``."""
    ax = '' if axis is None else f'<axis xyz="{_v(axis)}"/>'
    if kind in ('revolute', 'prismatic') and '<limit' not in extra:
        extra += '<limit effort="1e6" velocity="1e6" lower="-1e3" upper="1e3"/>'
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="{_v(xyz)}" rpy="{_v(rpy)}"/>{ax}{extra}'
            f'</joint>')


def robot(name, *elements):
    """Return a URDF document."""
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n' + '\n'.join(elements) + '\n</robot>'


def _v(values):
    return ' '.join(repr(float(x)) for x in values)


def without_mimic(text):
    """Return URDF ``text`` with its ``<mimic>`` elements removed (the followers go free)."""
    out = re.sub(r'<mimic[^>]*/>', '', text)
    assert out != text
    return out


def arm7_free_fingers(tmp_path):
    """
    Write arm7 without its fingers' mimic and return the path.

    For tests of other things (drives, damping) that set the fingers apart; the mimic
    has its own tests (test_mimic_joints.py).
    """
    from joint_space_reference import urdf_path
    path = tmp_path / 'arm7_free_fingers.urdf'
    with open(urdf_path('arm7.urdf')) as f:
        path.write_text(without_mimic(f.read()))
    return str(path)


def robot_scene(tmp_path, urdf_text, gravity=None, dt=1e-3, integrator='lie_poisson2',
                file='robot.urdf', **entry):
    """Write ``urdf_text`` and load a scene with that one robot (entry: its scene keys)."""
    path = tmp_path / file
    path.write_text(urdf_text)
    data = {'dt': dt, 'integrator': integrator, 'robots': [dict(urdf=str(path), **entry)]}
    if gravity is not None:
        data['effects'] = {'gravity': {'g_world': list(gravity)}}
    return scene_from_dict(data, str(tmp_path / 'scene.yaml'))


def body_accelerations(sim):
    """
    Accelerations of every body at the current state, from the step's own multipliers.

    Returns
    -------
    acc_com_world, alpha_world : ndarray, shape (n, 3)
        m/s² of each centre of mass and rad/s² (world frame).

    """
    dyn, s = sim.dynamics, sim.state
    pos, quat, vel, om = s.parts
    acc, om_dot = dyn.accelerations(s.time, pos, quat, vel, om)
    if dyn.constrained:
        lam = dyn.solver.multipliers(dyn, s)
        ev = dyn.solver.constraints.evaluate(pos, quat, vel, om)
        f = ev.jacobian.rmatvec(lam)
        acc = acc - dyn.bodies.inv_mass[:, None] * f[:, :3]
        om_dot = om_dot - f[:, 3:] / dyn.bodies.moments
    R = so3.quat_to_matrix(quat)
    return acc, np.einsum('nij,nj->ni', R, om_dot)


def joint_accelerations(sim):
    """
    q̈ of every one-coordinate joint at the current state (from :func:`body_accelerations`).

    Rotary: ``q̈ = k·(α_c − α_p) + (ω_p × k)·(ω_c − ω_p)``; prismatic: ``k_P`` · the
    second derivative of the child origin in the parent body's frame.
    """
    js = sim.joints
    s = sim.state
    acc_com, alpha = body_accelerations(sim)
    p, q, v, w = (np.asarray(x) for x in sim.bodies.outputs(s)[:4])
    R = so3.quat_to_matrix(q)
    rho = p * 0.0 + np.einsum('nij,nj->ni', R, sim.bodies.com_body)   # origin -> com, world
    acc = acc_com - np.cross(alpha, rho) - np.cross(w, np.cross(w, rho))   # of the origins

    def pad(x, eye=False):
        return np.concatenate([x, np.eye(3)[None]]) if eye else np.vstack([x, np.zeros(3)])
    p, v, w, acc, alpha, R = pad(p), pad(v), pad(w), pad(acc), pad(alpha), pad(R, True)
    out = np.zeros(len(js))
    for i in range(len(js)):
        a, b = js.child[i], js.parent[i]
        k_w = R[b] @ js.R_jp[i] @ js.axis[i]
        if js.rotary[i]:
            out[i] = k_w @ (alpha[a] - alpha[b]) + np.cross(w[b], k_w) @ (w[a] - w[b])
        else:
            d, dd = p[a] - p[b], v[a] - v[b]
            ddd = acc[a] - acc[b]
            rel = ddd - np.cross(alpha[b], d) - 2.0 * np.cross(w[b], dd) \
                + np.cross(w[b], np.cross(w[b], d))
            out[i] = k_w @ rel
    return out
