"""A master's "new node registered with same name" shutdown reaches whoever holds the dead node's port now;
a TeMoto node refuses it when it names another node, and still obeys one that names it
(temoto_core/rospy_internals.py, the shutdown guard). Against a real master and a real node process.

A clean-clone suite lost a Sensor Manager so: another test's master, replacing a dead
``/temoto_action_engine``, told the engine's old port to shut down, and the Sensor Manager held that port.
"""
import xmlrpc.client

import rosgraph

from temoto_core import rospy_internals
from temoto_core.wait import wait_for
from rr_helpers import RegistrarNode

HANG = 20.0                   # generous: catches a shutdown that never comes, or a node that never answers
NOWHERE = 'http://127.0.0.1:9/'   # the new incarnation's URI: nothing listens there, and nothing need


def _register(master, name: str, uri: str) -> None:
    code, msg, _ = master.registerSubscriber(name, '/shutdown_guard_topic', 'std_msgs/String', uri)
    assert code == 1, msg


def test_bumped_node_reads_only_the_masters_words():
    assert rospy_internals.bumped_node('[/temoto_action_engine] Reason: new node registered with same name') \
        == '/temoto_action_engine'
    assert rospy_internals.bumped_node('') is None
    assert rospy_internals.bumped_node('external shutdown') is None
    assert rospy_internals.bumped_node('[/a] Reason: something else') is None


def test_a_masters_shutdown_meant_for_a_dead_node_on_this_port_is_refused(rospy_client, procs):
    node = RegistrarNode(procs, 'rr_port_heir')
    master = xmlrpc.client.ServerProxy(rosgraph.get_master_uri())
    code, _msg, uri = master.lookupNode('/test_shutdown_guard', '/rr_port_heir')
    assert code == 1
    # a node '/ghost' died, and its port is now the heir's: the master still has '/ghost' at that URI
    _register(master, '/ghost', uri)
    try:
        # a new '/ghost' registers elsewhere: the master tells the old URI, the heir's, to shut down
        _register(master, '/ghost', NOWHERE)
        wait_for(lambda: 'refused a shutdown from /master meant for /ghost' in node.process.log(200), HANG,
                 'the heir to refuse the shutdown meant for /ghost')
        assert node.process.alive()
        assert 'unloads' in node.command(op='counts'), 'the heir still serves'
    finally:
        master.unregisterSubscriber('/ghost', '/shutdown_guard_topic', NOWHERE)
    # a shutdown that names the heir itself is obeyed: the master's own rule for a name registered twice
    _register(master, '/rr_port_heir', NOWHERE)
    try:
        wait_for(lambda: not node.process.alive(), HANG, 'the heir to obey a shutdown naming it')
    finally:
        master.unregisterSubscriber('/rr_port_heir', '/shutdown_guard_topic', NOWHERE)
