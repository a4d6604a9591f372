"""Scene files: the shipped scenes load, and errors name the file, the key path, the problem."""

import copy
from pathlib import Path

import numpy as np
import pytest
from rigid_body_sim.cli import main
from rigid_body_sim.scene import load_scene, scene_from_dict, SceneError
import yaml

CONFIG = Path(__file__).resolve().parents[1] / 'config'
SCENES = sorted(p for p in CONFIG.glob('*.yaml')   # (not parameter or schedule files)
                if not p.stem.endswith(('_params', '_schedule')))


@pytest.mark.parametrize('path', SCENES, ids=[p.stem for p in SCENES])
def test_shipped_scene_loads_and_steps(path):
    scene = load_scene(path)
    sim = scene.simulation
    e0 = sim.diagnostics().total_energy
    sim.step(20)
    d = sim.diagnostics()
    assert np.isfinite(d.total_energy)
    # bound: order 2, 20 steps x C dt^3: 2.1e-8 J (chain, measured) x50; rounding only ~1e-12 J
    assert abs(d.total_energy - e0) <= 1e-6 * max(1.0, abs(e0))
    # bound: SHAKE stops within 1e-13 of rho Phi, rho = exp(-dt / tau): 1e-13 / (1 - rho) = 5e-12
    assert d.constraint_violation < 1e-11


def test_thrown_bodies_scene_bodies_in_user_frame():
    sim = load_scene(CONFIG / 'thrown_bodies.yaml').simulation
    pos, quat = sim.pose('tumbling_box')
    # bound: to the centre of mass and back, ~4 roundings of |x| <= 1.05 m: 5e-16; x20
    np.testing.assert_allclose(pos, [-0.15, -0.1, 1.05], rtol=0, atol=1e-14)
    # bound: eigh's axes, eps |J| / gap = 2.2e-16 x 0.022 / 0.005 = 1e-15 rad; x10
    np.testing.assert_allclose(quat, [0.0, 0.0, 0.0, 1.0], rtol=0, atol=1e-14)
    _, w_body = sim.twist('tumbling_box', frame='body')
    # bound: the same axes error times |w| = 12 rad/s: 1.2e-14 rad/s; x10
    np.testing.assert_allclose(w_body, [0.05, 12.0, 0.05], rtol=0, atol=1e-13)


def test_shape_inertia_matches_formula():
    data = {'dt': 1e-3, 'bodies': [{'name': 'box', 'mass': 12.0, 'inertia': {'box': [1, 2, 3]}}]}
    sim = scene_from_dict(data).simulation
    moments = np.sort(sim.bodies.moments[0])
    # bound: eigh's eigenvalues, ~3 eps |J| = 3 x 2.2e-16 x 13 = 9e-15 kg m^2; x10
    np.testing.assert_allclose(moments, np.sort([4 + 9, 1 + 9, 1 + 4]), rtol=0, atol=1e-13)


def _default():
    return yaml.safe_load((CONFIG / 'thrown_bodies.yaml').read_text())


@pytest.mark.parametrize('edit, message', [
    (lambda d: d['bodies'][1].update(mass=-1), r'bodies\[1\]\.mass: must be positive'),
    (lambda d: d['bodies'][0].update(inertia=[1, 1, 3]),
     r'bodies\[0\]\.inertia: violates the triangle inequality'),
    (lambda d: d['bodies'][0].update(com_body=[0, '.nan', 0]),
     r'bodies\[0\]\.com_body: expected numbers'),
    (lambda d: d['bodies'][0].update(mas=1), r'bodies\[0\]\.mas: unknown key'),
    (lambda d: d['bodies'][1].update(inertia={'ixx': 1, 'iyy': 1}),
     r'bodies\[1\]\.inertia\.izz: missing'),
    (lambda d: d['effects'].update(wind={}), r'effects\.wind: unknown key'),
    (lambda d: d['effects'].update(damping={'linear': 1, 'bodies': ['nope']}),
     r"effects\.damping\.bodies\[0\]: unknown body 'nope'"),
    (lambda d: d['effects'].update(wrenches=[{'body': 'rugby_ball'}, {'body': 'x'}]),
     r"effects\.wrenches\[1\]\.body: unknown body 'x'"),
    (lambda d: d.update(integrator='rk45'), r"integrator: unknown integrator 'rk45'"),
    (lambda d: d.update(dt=0), r'dt: must be positive'),
    (lambda d: d.pop('bodies'), r'bodies: missing'),
    (lambda d: d.update(constraints=[{'name': 'j', 'type': 'hinge', 'body_a': 'rugby_ball'}]),
     r'constraints\[0\]\.axis_world: required'),
    (lambda d: d.update(constraints=[{'name': 'j', 'type': 'ball', 'body_a': 'nobody'}]),
     r"constraints\[0\]\.body_a: unknown body 'nobody'"),
])
def test_errors_name_file_key_and_problem(edit, message):
    data = copy.deepcopy(_default())
    edit(data)
    with pytest.raises(SceneError, match=r'^my_scene\.yaml: ' + message):
        scene_from_dict(data, 'my_scene.yaml')


def test_invalid_yaml_names_the_file(tmp_path):
    path = tmp_path / 'broken.yaml'
    path.write_text('bodies: [\n')
    with pytest.raises(SceneError, match=r'broken\.yaml: not valid YAML'):
        load_scene(path)


@pytest.mark.parametrize('text, message', [
    # YAML's own NaN and infinity load as floats, not strings.
    ('bodies: [{name: b, mass: 1, inertia: [1, 1, 1], com_body: [0, .nan, 0]}]',
     r'bodies\[0\]\.com_body: must be finite'),
    ('bodies: [{name: b, mass: .inf, inertia: [1, 1, 1]}]', r'bodies\[0\]\.mass: must be finite'),
    ("bodies: [{name: b, mass: '1', inertia: [1, 1, 1]}]",
     r"bodies\[0\]\.mass: expected a number, got '1'"),
    ('integrator: [rkmk4]\nbodies: [{name: b, mass: 1, inertia: [1, 1, 1]}]',
     r"integrator: unknown integrator \['rkmk4'\]"),
    ('bodies: [{name: b, mass: 1, inertia: [1, 1, 1]}]\n'
     'effects: {wrenches: [{body: b, forc: [1, 0, 0]}]}',
     r'effects\.wrenches\[0\]\.forc: unknown key'),
])
def test_yaml_values_are_checked_as_loaded(tmp_path, text, message):
    path = tmp_path / 'odd.yaml'
    path.write_text('dt: 0.001\n' + text + '\n')
    with pytest.raises(SceneError, match=r'odd\.yaml: ' + message):
        load_scene(path)


def test_command_line_run_prints_a_summary(capsys):
    assert main([str(CONFIG / 'default_scene.yaml'), '--duration', '0.1']) == 0
    out = capsys.readouterr().out
    assert 'integrator lie_poisson2 (order 2)' in out
    assert 'done: 100 steps' in out


def test_command_line_reports_bad_scene(tmp_path, capsys):
    path = tmp_path / 'bad.yaml'
    path.write_text('dt: 0.001\nbodies: [{name: b, mass: 0, inertia: [1, 1, 1]}]\n')
    assert main([str(path)]) == 2
    assert 'bad.yaml: bodies[0].mass: must be positive' in capsys.readouterr().err


def test_exponent_notation_is_a_number(tmp_path):
    # YAML 1.1 (PyYAML) reads 1e-3 as a string; scene files follow YAML 1.2.
    path = tmp_path / 'sci.yaml'
    path.write_text('dt: 1e-3\nbodies: [{name: b, mass: 2E+0, inertia: [1e-2, 1e-2, 1e-2]}]\n')
    sim = load_scene(path).simulation
    assert sim.dt == 1e-3
    assert sim.bodies.mass[0] == 2.0
