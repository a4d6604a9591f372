"""
launch/sim.launch.py starts the real node with real parameters (read, not run).

launch_ros is not among the PyPI wheels, so the launch file cannot run here. These
tests read it with ``ast`` and check what it passes against the sources it must agree
with: the console script in setup.py, the node's name, the parameters settings.py
declares, the installed config files.
"""

import ast
from pathlib import Path

from rigid_body_sim.ros import settings
import yaml

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / 'launch' / 'sim.launch.py'


def _tree() -> ast.Module:
    source = LAUNCH.read_text()
    compile(source, str(LAUNCH), 'exec')
    return ast.parse(source, str(LAUNCH))


def _calls(tree: ast.AST, name: str) -> list:
    """Return the calls of ``name(...)`` in ``tree``."""
    return [n for n in ast.walk(tree)
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == name]


def _value(node: ast.AST):
    """Return a literal as Python; ``LaunchConfiguration('x')`` as ``('$', 'x')``."""
    if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'LaunchConfiguration':
        return ('$', ast.literal_eval(node.args[0]))
    if isinstance(node, ast.List):
        return [_value(e) for e in node.elts]
    if isinstance(node, ast.Dict):
        return {ast.literal_eval(k): _value(v) for k, v in zip(node.keys, node.values)}
    try:
        return ast.literal_eval(node)
    except ValueError:
        return ast.unparse(node)


def _keywords(call: ast.Call) -> dict:
    return {k.arg: _value(k.value) for k in call.keywords}


def _node() -> dict:
    nodes = _calls(_tree(), 'Node')
    assert len(nodes) == 1, 'the launch file starts one node'
    return _keywords(nodes[0])


def _declared() -> dict:
    """Return the launch arguments: name -> the call's keywords (default_value as source)."""
    out = {}
    for call in _calls(_tree(), 'DeclareLaunchArgument'):
        keywords = {k.arg: k.value for k in call.keywords}
        out[ast.literal_eval(call.args[0])] = keywords
    return out


def _console_scripts() -> set:
    """Return the names of setup.py's console scripts."""
    setup = _calls(ast.parse((ROOT / 'setup.py').read_text()), 'setup')[0]
    entry_points = next(k.value for k in setup.keywords if k.arg == 'entry_points')
    scripts = ast.literal_eval(entry_points)['console_scripts']
    return {entry.split('=')[0].strip() for entry in scripts}


def _default_node_name() -> str:
    """Return the default of the node class's ``node_name`` argument (ros/node.py)."""
    tree = ast.parse((ROOT / 'rigid_body_sim' / 'ros' / 'node.py').read_text())
    for n in ast.walk(tree):
        if isinstance(n, ast.FunctionDef) and n.name == '__init__':
            names = [a.arg for a in n.args.args]
            if 'node_name' in names:
                first_default = len(names) - len(n.args.defaults)
                return ast.literal_eval(n.args.defaults[names.index('node_name') - first_default])
    raise AssertionError('ros/node.py: no __init__ with a node_name argument')


def test_launch_file_compiles_and_importing_it_only_imports():
    tree = _tree()
    for statement in tree.body:
        assert isinstance(statement, (ast.Import, ast.ImportFrom, ast.FunctionDef)) or (
            isinstance(statement, ast.Expr) and isinstance(statement.value, ast.Constant)), \
            f'line {statement.lineno}: a module-level statement that does something'
    functions = {s.name: s for s in tree.body if isinstance(s, ast.FunctionDef)}
    generate = functions.get('generate_launch_description')
    assert generate is not None, 'ros2 launch calls generate_launch_description()'
    assert not generate.args.args, 'ros2 launch calls it without arguments'


def test_node_is_the_installed_sim_node_under_its_own_name():
    node = _node()
    assert node['package'] == 'rigid_body_sim'
    assert node['executable'] == 'sim_node' and 'sim_node' in _console_scripts()
    assert node['name'] == _default_node_name() == 'rigid_body_sim'
    assert node['output'] == 'screen'


def test_parameters_are_the_params_file_then_declared_parameters():
    parameters = _node()['parameters']
    assert parameters[0] == ('$', 'params_file')
    # Later entries override earlier ones: the scene argument wins over the file's scene.
    overrides = parameters[-1]
    assert overrides == {'scene': ('$', 'scene')}
    for entry in parameters:
        if isinstance(entry, dict):
            assert set(entry) <= set(settings.BY_NAME), 'a parameter settings.py declares'


def test_launch_arguments_are_declared_with_installed_defaults():
    declared = _declared()
    used = {ast.literal_eval(c.args[0]) for c in _calls(_tree(), 'LaunchConfiguration')}
    assert set(declared) == {'scene', 'params_file'} == used
    for name, expected in (('scene', 'default_scene.yaml'),
                           ('params_file', 'sim_node_params.yaml')):
        default = declared[name]['default_value']
        assert isinstance(default, ast.Call) and ast.unparse(default.func) == 'os.path.join'
        assert ast.literal_eval(default.args[-1]) == expected
        assert (ROOT / 'config' / expected).is_file()
        assert 'description' in declared[name]
    share = _calls(_tree(), 'get_package_share_directory')
    assert [ast.literal_eval(c.args[0]) for c in share] == ['rigid_body_sim']


def test_default_params_file_sets_only_declared_parameters():
    params = yaml.safe_load((ROOT / 'config' / 'sim_node_params.yaml').read_text())
    values = params['/**']['ros__parameters']
    assert set(values) <= set(settings.BY_NAME)
    for name, value in values.items():
        assert settings.BY_NAME[name].check(name, value) == value, name
