"""The demo's launcher (``temoto_demo/stack.py``): a node it respawns after the master started
again gets the parameters of its launch file, which a new master does not have. Real roscore, real nodes."""
import os
import signal

from temoto_demo.stack import Stack
from temoto_core import master_lookup
from temoto_core.master import RosMaster, free_port
from temoto_testing import wait_for

LAUNCH = '''<launch>
  <node pkg="temoto_test_nodes" type="respawn_probe" name="stack_probe" respawn="true">
    <param name="greeting" value="hello"/>
    <param name="echo_to" value="%s"/>
  </node>
</launch>
'''


def test_a_node_respawned_after_the_master_started_again_has_its_launch_parameters(tmp_path):
    echo = tmp_path / 'greeting.txt'
    launch = tmp_path / 'probe.launch'
    launch.write_text(LAUNCH % echo)
    (tmp_path / 'ros').mkdir()
    master = RosMaster(str(tmp_path / 'ros'), port=free_port()).start()
    stack = Stack(str(launch), master.env, str(tmp_path / 'logs'))
    try:
        stack.start(30)
        # open(..., 'w') makes the file before it writes to it
        wait_for(lambda: echo.exists() and echo.read_text(), 20, 'the node to write what it read')
        assert echo.read_text() == 'hello'
        echo.unlink()
        master.stop()
        master.start()                       # the same address, no parameters
        os.kill(stack.pids[0], signal.SIGKILL)
        wait_for(echo.exists, 20, 'the respawned node to write what it read (without its parameters it writes '
                 'nothing)')
        wait_for(lambda: echo.read_text(), 5, 'the file to be written')
        assert echo.read_text() == 'hello'
        assert master_lookup.lookup_node(master.uri, '/stack_probe')
    finally:
        stack.stop()
        master.stop()
