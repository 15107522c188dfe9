"""Pieces of the chaos runner against real processes (the whole runner: test_chaos.py)."""
import os
import shlex
import subprocess
import sys
import threading
import types

from temoto_chaos.cli import chaos_options
from temoto_chaos.runner import Chaos, ChaosOptions, ClientHandle, replay_command
from temoto_core.master import RosMaster, free_port
from temoto_core.processes import ProcessGroupLauncher, leftover_processes
from temoto_testing import wait_for


def test_a_client_whose_master_is_out_of_reach_is_started_again_once_it_can_be(tmp_path):
    """Chaos seed 17, two hosts: a client killed just before the link was cut could not register, its
    restart raised, and nobody read the exception; the client stayed dead for the next 6,000 steps with no
    violation. The restart now tries again within its bound, and a start that fails leaves no process."""
    token = 'test_chaos_runner_' + os.urandom(6).hex()
    os.makedirs(tmp_path / 'ros')
    master = RosMaster(str(tmp_path / 'ros'), session_token=token, port=free_port())   # out of reach for now
    chaos = Chaos(ChaosOptions(seed=1, steps=1, out_dir=str(tmp_path)))
    chaos.launcher = ProcessGroupLauncher(master.env, str(tmp_path))
    old = ClientHandle.__new__(ClientHandle)          # a killed incarnation: its process, already gone
    old.proc = chaos.launcher.command(['true'], 'killed_client')
    reachable = threading.Thread(target=lambda: wait_for(lambda: chaos.generations[0] >= 2, 60,
                                                         'a second attempt') and master.start(), daemon=True)
    reachable.start()
    try:
        chaos._restart_client(0, old)
        reachable.join(60)
        assert chaos.call_violations == []
        assert chaos.clients[0].ask(op='state')['node'].endswith(chaos.clients[0].name)
        # the failed attempts left nothing: one client process runs, the one that answered
        clients = [cmd for _, cmd in leftover_processes(token) if 'chaos_client' in cmd]
        assert len(clients) == 1 and chaos.clients[0].name in clients[0], clients
    finally:
        chaos.launcher.stop_all()
        master.stop()
    assert leftover_processes(token) == []


def test_a_failures_replay_command_replays_every_step_up_to_it():
    """Chaos seed 17, two hosts: the violation at step 6429 printed ``--until 6430``, which ran 300 steps
    (the default length) and stopped long before it. The printed command alone now replays up to the step."""
    run = ChaosOptions(seed=17, steps=10000, out_dir='', hosts=2)
    replay = chaos_options(shlex.split(replay_command(run, 6430))[2:])
    assert (replay.seed, replay.steps, replay.until, replay.hosts, replay.clients, replay.version) == \
        (17, 6430, 6430, 2, run.clients, run.version)
    assert chaos_options(['--seed', '3']).steps == 300
    assert chaos_options(['--seed', '3', '--steps', '50', '--until', '6430']).steps == 50


def test_a_run_that_found_a_violation_asks_the_stacks_nodes_for_their_stacks(tmp_path):
    """The nodes of a stack that catch SIGUSR1 write every thread's stack to their logs (the first version
    raised NameError there, at the end of a 10,000-step run that had found a violation)."""
    log_path = tmp_path / 'node.log'
    with open(log_path, 'wb') as log:
        node = subprocess.Popen([sys.executable, '-c', NODE_WAITING_IN_HERE], stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
    try:
        wait_for(lambda: b'ready' in log_path.read_bytes(), 20, 'the node to start')
        chaos = Chaos(ChaosOptions(seed=1, steps=1, out_dir=str(tmp_path)))
        chaos.stack = types.SimpleNamespace(pids=[node.pid])       # what the runner reads of a demo Stack
        assert chaos.dump_stacks() == [node.pid]
        wait_for(lambda: 'in waiting_in_here' in log_path.read_text(errors='replace'), 20, 'the node\'s stack')
    finally:
        node.kill()
        node.wait(10)


NODE_WAITING_IN_HERE = '''
import faulthandler, signal, threading
faulthandler.register(signal.SIGUSR1, all_threads=True)
def waiting_in_here():
    print('ready', flush=True)
    threading.Event().wait(60)
waiting_in_here()
'''
