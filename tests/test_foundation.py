"""The workspace itself: generated messages seen by Debian's own CLI tools, and
the test harness (private master, registered nodes, bags, no leaked process)."""
import os
import subprocess
import sys
import textwrap
import uuid

from temoto_testing import leftover_processes, wait_for
from temoto_core.master import connected
from temoto_testing.pytest_plugin import FORCED_TOKEN_ENV

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run_cli(argv, env, timeout=30):
    """Run a Debian ROS command-line tool under Debian's interpreter, as a user would."""
    return subprocess.run(argv, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout)


def test_generated_messages_import_with_the_md5_of_their_definition():
    from temoto_core.msg import ResourceStatus
    from temoto_core.srv import UnloadResource
    import genpy.dynamic
    with open(os.path.join(ROOT, 'temoto_core', 'msg', 'ResourceStatus.msg')) as f:
        assert 'int8 FAILED=1' in f.read()
    assert ResourceStatus.FAILED == 1 and ResourceStatus._type == 'temoto_core/ResourceStatus'
    assert UnloadResource._request_class._type == 'temoto_core/UnloadResourceRequest'
    # the md5 genpy computes from the full text matches the generated class's
    dynamic = genpy.dynamic.generate_dynamic('temoto_core/ResourceStatus', ResourceStatus._full_text)
    assert dynamic['temoto_core/ResourceStatus']._md5sum == ResourceStatus._md5sum


def test_rosmsg_and_rossrv_show_project_types(ros_master):
    out = run_cli(['rosmsg', 'show', 'temoto_core/ResourceStatus'], ros_master.env)
    assert out.returncode == 0, out.stderr
    assert 'int8 FAILED=1' in out.stdout and 'temoto_core/Error[] error_stack' in out.stdout
    out = run_cli(['rossrv', 'show', 'temoto_core/UnloadResource'], ros_master.env)
    assert out.returncode == 0, out.stderr
    assert 'int64 resource_id' in out.stdout and '---' in out.stdout


def test_rosrun_and_rostopic_echo_a_custom_type(ros_master, procs):
    # rosrun (Debian's bash script) resolves the node through ROS_PACKAGE_PATH
    proc = procs.command(['rosrun', 'temoto_test_nodes', 'talker', '__name:=rosrun_talker'], 'rosrun_talker')
    procs.wait_registered(proc, ['/rosrun_talker'], 20)
    out = run_cli(['/usr/bin/python3', '/usr/bin/rostopic', 'echo', '-n', '1', '/status_out'], ros_master.env)
    assert out.returncode == 0, out.stderr
    assert 'manager_name: "talker"' in out.stdout and 'status_code: 2' in out.stdout
    out = run_cli(['rostopic', 'type', '/status_out'], ros_master.env)
    assert out.stdout.strip() == 'temoto_core/ResourceStatus'


def test_roslaunch_file_nodes_are_registered_before_the_test_goes_on(ros_master, procs):
    import rosnode
    procs.launch('temoto_test_nodes', 'two_talkers.launch', ['prefix:=lt'])
    nodes = rosnode.get_node_names()
    assert '/lt_one' in nodes and '/second/lt_two' in nodes


def test_bag_recorded_during_a_test_reads_back_with_rosbags(ros_master, rospy_client, procs, bag_recorder):
    from temoto_core.msg import ResourceStatus
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    from pathlib import Path
    procs.node('temoto_test_nodes', 'talker', name='bag_talker')
    recorder = bag_recorder(['/status_out'], 'talker.bag')
    wait_for(lambda: connected(ros_master.uri, '/bag_talker', recorder.node_name, '/status_out'), 20,
             'the recorder to connect to the talker')
    first = rospy_client.wait_for_message('/status_out', ResourceStatus, timeout=10).resource_id
    wait_for(lambda: rospy_client.wait_for_message('/status_out', ResourceStatus, timeout=10).resource_id > first + 3,
             20, 'four more messages after the connection')
    path = recorder.stop()
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        conns = [c for c in reader.connections if c.topic == '/status_out']
        assert conns and conns[0].msgtype == 'temoto_core/msg/ResourceStatus'
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]
    assert len(msgs) >= 2
    assert all(m.manager_name == 'talker' for m in msgs)
    assert [m.resource_id for m in msgs] == sorted(m.resource_id for m in msgs)


def test_each_session_has_its_own_master_on_loopback(ros_master):
    import rosgraph
    assert ros_master.uri.startswith('http://127.0.0.1:') and ros_master.port != 11311
    assert rosgraph.get_master_uri() == ros_master.uri
    assert ros_master.is_registered('/rosout')


def test_teardown_leaves_no_process_behind_even_when_a_test_fails(tmp_path, ros_master):
    """An inner pytest session starts a node and a launch file, then fails.

    Its fixtures must still stop everything; the inner session's token lets us
    look for survivors at any depth.
    """
    inner = tmp_path / 'inner'
    inner.mkdir()
    # no conftest: the fixtures come from the installed plugin (temoto_testing's pytest11 entry point)
    (inner / 'test_fails.py').write_text(textwrap.dedent('''
        def test_starts_processes_then_fails(procs):
            procs.node('temoto_test_nodes', 'talker', name='doomed')
            procs.launch('temoto_test_nodes', 'two_talkers.launch', ['prefix:=doomed'])
            procs.command(['sleep', '600'], 'sleeper')
            assert False, 'this test fails on purpose'
    '''))
    token = uuid.uuid4().hex
    env = dict(os.environ)
    env[FORCED_TOKEN_ENV] = token
    out = subprocess.run([sys.executable, '-m', 'pytest', '-p', 'no:cacheprovider', '-n', '0', '-q',
                          '-c', os.devnull, '--rootdir', str(inner), str(inner)],
                         env=env, cwd=str(inner), capture_output=True, text=True, timeout=180)
    assert out.returncode == 1, out.stdout + out.stderr
    assert 'this test fails on purpose' in out.stdout
    assert '1 failed' in out.stdout
    assert leftover_processes(token) == []


def test_setup_without_root_says_so_in_one_line_when_packages_are_missing(tmp_path):
    import tempfile
    shared = tempfile.mkdtemp(prefix='temoto_apt_')     # readable by the unprivileged user
    os.chmod(shared, 0o755)
    listing = os.path.join(shared, 'apt.txt')
    with open(listing, 'w') as f:
        f.write('python3-rospy\ntemoto-no-such-package\n')
    os.chmod(listing, 0o644)
    try:
        out = subprocess.run(['setpriv', '--reuid=65534', '--regid=65534', '--clear-groups',
                              'bash', os.path.join(ROOT, 'tools', 'setup.sh')],
                             env=dict(os.environ, TEMOTO_APT_LIST=listing), capture_output=True, text=True,
                             timeout=60, cwd='/')
    finally:
        import shutil
        shutil.rmtree(shared)
    assert out.returncode == 1
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, out.stderr
    assert 'needs root' in lines[0] and 'temoto-no-such-package' in lines[0]
    assert 'python3-rospy' not in lines[0]            # only what is missing is named


def test_warm_setup_only_checks(tmp_path):
    out = subprocess.run(['bash', os.path.join(ROOT, 'tools', 'setup.sh')], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1].startswith('setup: ready in')
    assert 'installing' not in out.stdout and 'creating' not in out.stdout


def test_env_sh_names_the_logging_config_rospy_would_find_so_it_skips_its_crawl(tmp_path):
    """rospy crawls ROS_PACKAGE_PATH on every node start only to locate python_logging.conf."""
    def sourced(**env):
        base = {k: v for k, v in os.environ.items() if k not in ('ROS_PYTHON_LOG_CONFIG_FILE', 'ROS_HOME')}
        out = subprocess.run(['bash', '-c', 'source "$1" && printf %s "$ROS_PYTHON_LOG_CONFIG_FILE"', '-',
                              os.path.join(ROOT, 'env.sh')], env=dict(base, HOME=str(tmp_path), **env),
                             capture_output=True, text=True, timeout=30)
        assert out.returncode == 0, out.stderr
        return out.stdout
    assert sourced() == '/etc/ros/python_logging.conf'          # Debian's, as rospy finds it
    own = tmp_path / 'ros_home' / 'config' / 'python_logging.conf'
    own.parent.mkdir(parents=True)
    own.write_text('[loggers]\n')
    assert sourced(ROS_HOME=str(tmp_path / 'ros_home')) == str(own)      # ROS_HOME's comes first, as in rospy
    assert sourced(ROS_PYTHON_LOG_CONFIG_FILE='/somewhere/mine.conf') == '/somewhere/mine.conf'


def test_the_launcher_removes_the_private_parameters_it_set(ros_master, rospy_client, tmp_path):
    """Private parameters outlive a node on the master: a later test's node of the same name inherited a
    ``~journal`` and ran with a journal it was never given. The launcher removes what it set."""
    from temoto_testing import ProcessGroupLauncher
    launcher = ProcessGroupLauncher(ros_master.env, str(tmp_path))
    launcher.node('temoto_test_nodes', 'talker', name='param_probe', params={'journal': '/nowhere.sqlite'})
    assert rospy_client.get_param('/param_probe/journal') == '/nowhere.sqlite'
    launcher.stop_all()
    assert not rospy_client.has_param('/param_probe/journal')
