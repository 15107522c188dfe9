"""`pip install .` into a fresh venv gives a working `temoto` outside the checkout.

The venv is made as the README says (Debian's python3, ``--system-site-packages``, for rospy). The pinned
third-party packages come from the project's own venv through a path file (a test must not reach a package
registry), and the project itself from a copy of the checkout with its generated messages: nothing of the
checkout is on any path afterwards. Then, from another folder, the installed ``temoto`` checks a catalogue,
says where its packages are, and an ER Manager started by rosrun from the installed copy answers
``temoto ps`` over a private master.
"""
import os
import shutil
import subprocess
import sysconfig

import pytest

from temoto_testing import wait_for

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INSTALL_BOUND_S = 600     # generous: a copy, a wheel built offline and installed, on a loaded machine


@pytest.fixture(scope='module')
def installed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('install')
    src, venv = tmp / 'src', tmp / 'venv'
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns('.venv', '.git', 'build', 'runs', '__pycache__',
                                                             '*.egg-info', '.pytest_cache'))
    subprocess.run(['/usr/bin/python3', '-m', 'venv', '--system-site-packages', str(venv)], check=True,
                   timeout=INSTALL_BOUND_S)
    site = subprocess.run([str(venv / 'bin' / 'python'), '-c', 'import sysconfig; print(sysconfig.get_path("purelib"))'],
                          capture_output=True, text=True, check=True).stdout.strip()
    # the pinned packages (numpy, pybullet, ...) of the project's venv, without its editable install of the
    # checkout: a path line adds the folder, and the .pth files inside it are not read
    (tmp / 'venv' / os.path.relpath(site, str(venv)) / 'pinned.pth').write_text(sysconfig.get_path('purelib') + '\n')
    out = subprocess.run([str(venv / 'bin' / 'pip'), 'install', '--no-deps', '--no-build-isolation', '--no-index',
                          '--disable-pip-version-check', str(src)], capture_output=True, text=True,
                         timeout=INSTALL_BOUND_S, cwd=str(tmp))
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    shutil.rmtree(src)          # nothing may come from the copy either
    env = {'HOME': str(tmp), 'PATH': '%s:/usr/bin:/bin' % (venv / 'bin'), 'LANG': 'C.UTF-8'}
    return tmp, venv, site, env


def run(installed, *argv, env=None, timeout=120):
    tmp, venv, _, base = installed
    return subprocess.run(list(argv), cwd=str(tmp), env=dict(base, **(env or {})), capture_output=True, text=True,
                          timeout=timeout)


def test_the_installed_packages_come_from_site_packages_with_their_ros_files(installed):
    tmp, venv, site, _ = installed
    out = run(installed, str(venv / 'bin' / 'python'), '-c',
              'import temoto_core, temoto_bringup, vaultbot_sim.kinematics as k; '
              'print(temoto_core.__file__); print(k.ROBOT_URDF); print(k.WORLDS["lab"])')
    assert out.returncode == 0, out.stderr
    core, urdf, world = out.stdout.split()
    assert core.startswith(site) and urdf.startswith(site) and world.startswith(site), out.stdout
    for path in (urdf, world, os.path.join(site, 'temoto_bringup', 'launch', 'demo.launch'),
                 os.path.join(site, 'temoto_er_manager', 'nodes', 'temoto_er_manager'),
                 os.path.join(site, 'temoto_core', 'msg', '_ResourceStatus.py'),
                 os.path.join(site, 'temoto_action_engine', 'actions', 'show_environment', 'show_environment.umrf.json')):
        assert os.path.exists(path), path


def test_the_installed_temoto_checks_a_catalogue_and_finds_its_packages(installed):
    tmp, venv, site, _ = installed
    temoto = str(venv / 'bin' / 'temoto')
    out = run(installed, temoto, 'sensors', 'check', os.path.join(site, 'temoto_sensor_manager', 'config',
                                                                   'vaultbot.yaml'))
    assert out.returncode == 0 and 'realsense_d435' in out.stdout, out.stdout + out.stderr
    out = run(installed, temoto, 'env')
    assert out.returncode == 0 and out.stdout.startswith('export ROS_PACKAGE_PATH=' + site), out.stdout


def test_an_installed_manager_started_by_rosrun_answers_the_installed_temoto(installed, ros_master):
    tmp, venv, site, _ = installed
    ros = {'ROS_MASTER_URI': ros_master.uri, 'ROS_HOSTNAME': '127.0.0.1', 'ROS_PACKAGE_PATH': site,
           'ROS_LOG_DIR': str(tmp / 'log'), 'TEMOTO_TEST_SESSION': os.environ.get('TEMOTO_TEST_SESSION', '')}
    _, _, _, base = installed
    manager = subprocess.Popen(['rosrun', 'temoto_er_manager', 'temoto_er_manager', '__ns:=/installed',
                                '_temoto_namespace:=installed'], cwd=str(tmp), env=dict(base, **ros),
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        def answers():
            return run(installed, str(venv / 'bin' / 'temoto'), 'ps', '--namespace', 'installed', env=ros,
                       timeout=60).returncode == 0
        wait_for(answers, 60, 'the installed ER Manager to answer `temoto ps`')
        with open('/proc/%d/cmdline' % manager.pid, 'rb') as f:       # rosrun execs the node's script
            argv = f.read().split(b'\0')
        assert any(a.decode().startswith(site) for a in argv), argv
    finally:
        os.killpg(manager.pid, 2)
        try:
            manager.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(manager.pid, 9)
            manager.wait(30)
    assert manager.returncode == 0, manager.stderr.read()[-2000:] if manager.stderr else ''

