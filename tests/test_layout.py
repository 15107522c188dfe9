"""Repository rules that a reader relies on: imports go down the layers only; runtime code never imports the test
fixtures; launch files and command lines take what the docs say they take."""
import ast
import os
import subprocess
import sys


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# The layers, bottom first (docs/architecture.md). A package imports only packages of lower layers: never one
# above it, nor one beside it in its own layer. The managers are layered among themselves as they use each
# other (the Sensor Manager starts its drivers through the ER Manager; the Context Manager reads sensors).
LAYERS = [
    ['temoto_core', 'control_msgs'],             # control_msgs: upstream's message definitions only
    ['temoto_er_manager', 'vaultbot_sim'],       # the simulated robot needs only the core
    ['temoto_sensor_manager', 'temoto_output_manager'],
    ['temoto_context_manager', 'temoto_robot_manager', 'temoto_operator'],
    ['temoto_action_engine'],
    ['temoto_speech'],
    ['temoto_testing'],                          # fixtures for stacks of the layers below; runtime never imports it
    ['temoto_demo'],                             # leaf packages from here on
    ['temoto_chaos'],                            # starts the demo's stacks
    ['temoto_bringup'],                          # the `temoto` command, which names every subcommand
]
RANK = {package: rank for rank, layer in enumerate(LAYERS) for package in layer}
RUNTIME = [package for layer in LAYERS for package in layer]


def runtime_modules(packages=RUNTIME):
    for package in packages:
        for folder, dirs, files in os.walk(os.path.join(ROOT, package)):
            dirs[:] = [d for d in dirs if d not in ('msg', 'srv', '__pycache__')]
            for name in files:
                path = os.path.join(folder, name)
                if name.endswith('.py'):
                    yield path
                elif os.path.basename(folder) == 'nodes':
                    yield path


def imported_modules(path):
    with open(path, 'rb') as f:
        source = f.read()
    if not source.startswith(b'#!') and not path.endswith('.py'):
        return []
    tree = ast.parse(source)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.append(node.module)
    return out


def test_runtime_code_never_imports_test_fixtures():
    runtime = [package for package in RUNTIME if package != 'temoto_testing']
    offenders = {os.path.relpath(p, ROOT): m for p in runtime_modules(runtime) for m in imported_modules(p)
                 if m.startswith('temoto_testing') or m.endswith('.testing')}
    assert offenders == {}


def test_demo_launch_passes_plugin_paths_catalogues_and_first_data_settings():
    import roslaunch.config
    path = os.path.join(ROOT, 'temoto_bringup', 'launch', 'demo.launch')
    config = roslaunch.config.load_config_default(
        [(path, ['action_paths:=/my/actions', 'extra_catalogues:=/my/sensors.yaml', 'first_data_timeout:=7',
                 'first_data_allowance:=2', 'wake_words:=robot'])], None)
    params = {k: v.value for k, v in config.params.items()}
    assert params['/temoto_action_engine/action_paths'] == '/my/actions'
    assert params['/temoto_action_engine/wake_words'] == 'robot'
    assert params['/temoto_sensor_manager/extra_catalogues'] == '/my/sensors.yaml'
    assert params['/temoto_sensor_manager/first_data_timeout'] == 7
    assert params['/temoto_sensor_manager/first_data_allowance'] == 2


def test_imports_go_down_the_layers_only():
    """Up or sideways, an import makes a cycle possible and a layer impossible to use alone."""
    found = {os.path.relpath(p, ROOT) for package in RUNTIME for p in runtime_modules([package])}
    assert 'temoto_demo/scenario.py' in found and 'temoto_speech/node.py' in found     # the walk sees them
    offenders = []
    for package in RUNTIME:
        for path in runtime_modules([package]):
            for module in imported_modules(path):
                top = module.split('.')[0]
                if top in RANK and top != package and RANK[top] >= RANK[package]:
                    offenders.append('%s imports %s (%s)' % (os.path.relpath(path, ROOT), module,
                                                             'beside it' if RANK[top] == RANK[package] else 'above it'))
    assert offenders == []


def test_every_top_level_package_has_its_layer():
    packages = {name for name in os.listdir(ROOT) if os.path.exists(os.path.join(ROOT, name, 'package.xml'))}
    assert packages - {'temoto_test_nodes'} == set(RANK)


def run_cli(*args, env=None):
    return subprocess.run([sys.executable, '-m', 'temoto_bringup.cli'] + list(args), capture_output=True, text=True,
                          timeout=60, env=env)


def test_cli_takes_both_namespace_spellings(ros_master):
    catalogue = os.path.join(ROOT, 'temoto_sensor_manager', 'config', 'vaultbot.yaml')
    env = dict(os.environ, **ros_master.env)
    for flag in ('--ns', '--namespace'):
        out = run_cli('sensors', flag, 'elsewhere', 'check', catalogue, env=env)
        assert out.returncode == 0 and 'realsense_d435' in out.stdout, (flag, out.stderr[-1000:])
        out = run_cli('registry', flag, 'elsewhere', '--json', env=env)
        assert 'no registrars in namespace /elsewhere' in out.stderr, (flag, out.stderr[-1000:])
    assert run_cli('registry', '--bogus', 'x', env=env).returncode == 2      # the control: argparse refuses


def test_the_old_launch_names_still_start_the_same_nodes_with_the_same_arguments():
    """The system's launch files moved to temoto_bringup; `roslaunch temoto_action_engine demo.launch ...`
    keeps working for one release."""
    import rospkg
    import roslaunch.config
    engine = rospkg.RosPack().get_path('temoto_action_engine')
    for name, args in [('demo.launch', ['world:=test_wall']), ('robot.launch', ['robot:=r2']),
                       ('operator.launch', ['robot:=r2'])]:
        old, new = (roslaunch.config.load_config_default([(os.path.join(folder, name), args)], None)
                    for folder in (os.path.join(engine, 'launch'), os.path.join(ROOT, 'temoto_bringup', 'launch')))
        assert sorted(n.namespace + n.name for n in old.nodes) == sorted(n.namespace + n.name for n in new.nodes)
        assert {k: v.value for k, v in old.params.items()} == {k: v.value for k, v in new.params.items()}
        assert old.nodes, name


def test_robot_launch_takes_a_catalogue_that_replaces_the_vaultbot_s_and_the_docs_example_checks_clean(tmp_path):
    import re
    import roslaunch.config
    path = os.path.join(ROOT, 'temoto_bringup', 'launch', 'robot.launch')
    config = roslaunch.config.load_config_default([(path, ['robot:=my_robot', 'sim:=false',
                                                           'catalogue:=/robots/mine.yaml'])], None)
    params = {k: v.value for k, v in config.params.items()}
    assert params['/my_robot/temoto_sensor_manager/catalogue'] == '/robots/mine.yaml'
    assert not any('vaultbot_sim' in n.package for n in config.nodes)
    with open(os.path.join(ROOT, 'docs', 'your_robot.md'), encoding='utf-8') as f:
        example = re.search(r'```yaml\n(.*?)```', f.read(), re.S).group(1)
    (tmp_path / 'mine.yaml').write_text(example)
    out = run_cli('sensors', 'check', str(tmp_path / 'mine.yaml'))
    assert out.returncode == 0 and out.stdout.count('ok ') == 2, out.stdout + out.stderr


def test_the_motion_checker_imports_nothing_of_the_robot_manager():
    """A checker never judges with the code it checks: the chaos motion checker (the ground truth, the ledger, the
    watch) works the navigator's contract out on its own, from the sim and the robot's declarations."""
    checker = [os.path.join(ROOT, 'temoto_chaos', name)
               for name in ('motion_truth.py', 'motion_checker.py', 'motion_watch.py')]
    offenders = {os.path.relpath(p, ROOT): m for p in checker for m in imported_modules(p)
                 if m.startswith('temoto_robot_manager')}
    assert offenders == {}
