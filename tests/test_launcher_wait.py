"""ProcessGroupLauncher.node returns once *its* node is registered, not a registration the master still
holds under that name from another process (a suite run went on before its /vaultbot_sim was up: the
master's shutdown for the old registration then reached the site LIDAR driver that had taken the dead
node's port)."""
import os
import xmlrpc.client

from temoto_core.master_lookup import ROSPY_PARAM_SUBSCRIPTIONS, cleanup_dead_node, lookup_node, node_pid


def test_a_registration_left_under_the_name_by_another_process_does_not_count_as_started(procs, rospy_client):
    master_uri = os.environ['ROS_MASTER_URI']
    other = procs.node('temoto_test_nodes', 'talker', name='launcher_wait_other')
    other_uri = lookup_node(master_uri, '/launcher_wait_other')
    # the name now points at a live process that publishes what the name published, so it cannot be told
    # from the node's own incarnation and is not cleaned up: only the pid says it is not this start's
    xmlrpc.client.ServerProxy(master_uri).registerPublisher('/launcher_wait_twin', '/status_out',
                                                            'temoto_core/ResourceStatus', other_uri)
    started = procs.node('temoto_test_nodes', 'talker', name='launcher_wait_twin')
    uri = lookup_node(master_uri, '/launcher_wait_twin')
    assert uri != other_uri and node_pid(uri) == started.pid, (uri, other_uri)
    assert other.pid != started.pid


def test_a_dead_node_known_only_by_its_parameter_subscription_is_cleaned_up(rospy_client):
    """rospy unregisters a node's topics and services as it shuts down, and leaves its parameter
    subscription: the master then still answers lookupNode for the name, and a start under it would take
    the old registration for its own."""
    master_uri = os.environ['ROS_MASTER_URI']
    dead = 'http://127.0.0.1:1/'                     # nobody answers there
    master = xmlrpc.client.ServerProxy(master_uri)
    master.subscribeParam('/launcher_wait_ghost', dead, ROSPY_PARAM_SUBSCRIPTIONS[0])
    assert lookup_node(master_uri, '/launcher_wait_ghost') == dead
    cleanup_dead_node(master_uri, '/launcher_wait_ghost')
    assert lookup_node(master_uri, '/launcher_wait_ghost') is None
