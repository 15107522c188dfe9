"""Repository rules that a reader relies on: runtime code never imports the test fixtures; launch files and
command lines take what the docs say they take."""
import ast
import os
import subprocess
import sys


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUNTIME = ['temoto_core', 'temoto_er_manager', 'temoto_sensor_manager', 'temoto_output_manager',
           'temoto_context_manager', 'temoto_action_engine', 'vaultbot_sim', 'temoto_chaos']


def runtime_modules():
    for package in RUNTIME:
        for folder, dirs, files in os.walk(os.path.join(ROOT, package)):
            dirs[:] = [d for d in dirs if d not in ('testing', 'msg', 'srv', '__pycache__')]
            for name in files:
                path = os.path.join(folder, name)
                if name.endswith('.py') and name != 'testing.py':
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
    offenders = {os.path.relpath(p, ROOT): m for p in runtime_modules() for m in imported_modules(p)
                 if m.startswith('temoto_core.testing') or m.endswith('.testing')}
    assert offenders == {}


def test_demo_launch_passes_plugin_paths_catalogues_and_first_data_settings():
    import roslaunch.config
    path = os.path.join(ROOT, 'temoto_action_engine', 'launch', 'demo.launch')
    config = roslaunch.config.load_config_default(
        [(path, ['action_paths:=/my/actions', 'extra_catalogues:=/my/sensors.yaml', 'first_data_timeout:=7',
                 'first_data_allowance:=2', 'wake_words:=robot'])], None)
    params = {k: v.value for k, v in config.params.items()}
    assert params['/temoto_action_engine/action_paths'] == '/my/actions'
    assert params['/temoto_action_engine/wake_words'] == 'robot'
    assert params['/temoto_sensor_manager/extra_catalogues'] == '/my/sensors.yaml'
    assert params['/temoto_sensor_manager/first_data_timeout'] == 7
    assert params['/temoto_sensor_manager/first_data_allowance'] == 2


def run_cli(*args, env=None):
    return subprocess.run([sys.executable, '-m', 'temoto_core.cli'] + list(args), capture_output=True, text=True,
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
