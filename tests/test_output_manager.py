"""The Output Manager end to end: ER Manager + Output Manager nodes, a real RViz host started through
load_process, consumers as OutputManagerInterfaces in this test process."""
import io
import os
import signal
import threading
import time

import numpy as np
import pytest
from PIL import Image as PILImage

from temoto_core.errors import TemotoError
from temoto_core.msg import ResourceStatus
from temoto_testing import signals, wait_for
from temoto_core import master_lookup as er_master
from temoto_output_manager import sample_data as sd
from temoto_output_manager.host_client import RvizHostClient
from temoto_output_manager.msg import DisplayEvent

NS = 'temoto'
HOST = '/%s/rviz_host' % NS


@pytest.fixture(scope='module')
def managers(module_procs, tmp_path_factory):
    logs = tmp_path_factory.mktemp('er_logs')
    module_procs.node('temoto_er_manager', 'temoto_er_manager', name='temoto_er_manager',
                      params={'registration_timeout': 20.0, 'sigint_grace': 3.0, 'sigterm_grace': 1.0,
                              'log_dir': str(logs)})
    module_procs.node('temoto_output_manager', 'temoto_output_manager', name='temoto_output_manager',
                      params={'host_ready_timeout': 20.0})
    return logs


@pytest.fixture
def om(managers, rospy_client):
    from temoto_output_manager.interface import OutputManagerInterface
    made = []

    def make():
        i = OutputManagerInterface(namespace=NS)
        i.statuses = []
        i.register_update_callback(i.statuses.append)    # record instead of the default re-request
        made.append(i)
        return i
    yield make
    for i in made:
        i.shutdown()
    wait_for(lambda: host_pid() is None, 15, 'the RViz host to stop after the test')


@pytest.fixture
def events(managers, rospy_client):
    got = []
    sub = rospy_client.Subscriber('/%s/temoto_output_manager/display_events' % NS, DisplayEvent, got.append)
    yield got
    sub.unregister()


def host_pid():
    """The RViz host's pid, or None while no live host is registered."""
    uri = er_master.lookup_node(os.environ['ROS_MASTER_URI'], HOST)
    return er_master.node_pid(uri) if uri else None


def service_registered(name):
    import rosgraph
    try:
        rosgraph.Master('/pytest').lookupService(name)
        return True
    except rosgraph.MasterError:
        return False


def subscribers(topic):
    import rosgraph
    return next((nodes for name, nodes in rosgraph.Master('/pytest').getSystemState()[1] if name == topic), [])


def magenta_fraction(resp):
    px = np.asarray(PILImage.open(io.BytesIO(bytes(resp.png))).convert('RGB')).astype(int)
    return float((np.abs(px - (255, 0, 255)).max(axis=2) <= 40).mean())


def test_shared_cloud_display_is_drawn_and_rviz_stops_with_the_last_consumer(om, events, rospy_client):
    pub = sd.RepeatingPublisher('/om_mgr/cloud', sd.cloud_msg(rgb=(255, 0, 255)), 15).start()
    try:
        a, b = om(), om()
        ra = a.show('point cloud', '/om_mgr/cloud', config='{Size (Pixels): 3, Color Transformer: RGB8}')
        pid = host_pid()
        assert pid, 'the RViz host runs'
        rb = b.show('point cloud', '/om_mgr/cloud', config='{Size (Pixels): 3, Color Transformer: RGB8}')
        assert ra.display_name == rb.display_name == 'point cloud /om_mgr/cloud'
        assert host_pid() == pid
        host = RvizHostClient(HOST)
        shown = [d for d in host.display_names() if d == ra.display_name]
        assert len(shown) == 1, 'two consumers share one display'
        wait_for(lambda: any(e.event == 'first_frame' and e.display_name == ra.display_name for e in events),
                 15, 'first frame of the shared cloud')
        assert magenta_fraction(host.screenshot('view')) > 0.01
        a.hide(ra.trr.resource_id)
        assert ra.display_name in host.display_names(), 'still held by the second consumer'
        b.hide(rb.trr.resource_id)
        wait_for(lambda: host_pid() is None, 15, 'RViz host to stop after the last display was unloaded')
        wait_for(lambda: not subscribers('/om_mgr/cloud'), 10, 'no subscriber left on the cloud topic')
        wait_for(lambda: not os.path.exists('/proc/%d' % pid), 10, 'host process reaped')
    finally:
        pub.stop()


def test_host_crash_is_failed_for_every_holder_and_a_new_request_starts_a_new_host(om, rospy_client):
    a, b = om(), om()
    ra = a.show('laser scan', '/om_mgr/scan')
    rb = b.show('image', '/om_mgr/image')
    pid = host_pid()
    os.kill(pid, signal.SIGKILL)
    wait_for(lambda: any(s.code == ResourceStatus.FAILED for s in a.statuses), 20, 'FAILED at the scan holder')
    wait_for(lambda: any(s.code == ResourceStatus.FAILED for s in b.statuses), 20, 'FAILED at the image holder')
    assert a.statuses[0].resource_id == ra.trr.resource_id and b.statuses[0].resource_id == rb.trr.resource_id
    a.hide(ra.trr.resource_id)
    b.hide(rb.trr.resource_id)
    again = a.show('laser scan', '/om_mgr/scan')
    new_pid = host_pid()
    assert new_pid and new_pid != pid
    assert again.display_name in RvizHostClient(HOST).display_names()


def kill_host_while_starting(previous_pid=None):
    """SIGKILL the RViz host the ER Manager just started, before it offers its services; its pid."""
    from temoto_core.registry_cli import fetch

    def started():      # the ER Manager answered load_process: the Output Manager now waits for the services
        pid = host_pid()
        return pid if pid and pid != previous_pid and any(
            q.target.endswith('/load_process') and q.state == 'active'
            for q in fetch(NS, 'temoto_output_manager').client_queries) else None
    pid = wait_for(started, 20, 'the ER Manager to start an RViz host', interval=0.01)
    signals.stop(pid)
    try:
        assert not service_registered(HOST + '/list_displays'), 'the host was ready before it could be stopped'
    finally:
        os.kill(pid, signal.SIGKILL)
    return pid


def show_in_thread(consumer, *args):
    outcome = {}

    def show():
        try:
            outcome['response'] = consumer.show(*args)
        except TemotoError as e:
            outcome['error'] = e
    thread = threading.Thread(target=show, daemon=True)
    thread.start()
    return thread, outcome


def test_a_host_that_dies_while_starting_is_started_once_more(om, rospy_client):
    thread, outcome = show_in_thread(om(), 'laser scan', '/om_mgr/scan_after_a_restart')
    first = kill_host_while_starting()
    thread.join(30)
    assert not thread.is_alive() and 'response' in outcome, outcome
    assert host_pid() not in (None, first)
    assert outcome['response'].display_name in RvizHostClient(HOST).display_names()


def test_a_host_that_keeps_dying_while_starting_fails_at_once_with_the_reason(om, rospy_client):
    """Not after host_ready_timeout (20 s): the ER Manager's FAILED, with the host's log tail, ends the wait."""
    thread, outcome = show_in_thread(om(), 'laser scan', '/om_mgr/scan_of_a_dying_host')
    first = kill_host_while_starting()
    kill_host_while_starting(previous_pid=first)
    t0 = time.monotonic()
    thread.join(15)
    assert not thread.is_alive()
    assert time.monotonic() - t0 < 5.0, 'the request waited out the timeout instead of failing at once'
    message = str(outcome['error'])
    assert 'failed while starting' in message and 'SIGKILL' in message, message


@pytest.mark.parametrize('kwargs,words', [
    (dict(type='hologram', topic='/x'), ['unknown display type', 'point cloud', 'laser scan']),
    (dict(type='point cloud', topic=''), ['needs a topic']),
    (dict(type='point cloud', topic='/x', config='{a: [1,'), ['not valid YAML']),
    (dict(type='point cloud', topic='/x', config='{Colour: [1, 2, 3]}'), ["unknown property 'Colour'"]),
])
def test_bad_requests_fail_clearly_and_leave_no_host(om, kwargs, words):
    with pytest.raises(TemotoError) as err:
        om().show(**kwargs)
    for w in words:
        assert w in str(err.value), str(err.value)
    wait_for(lambda: host_pid() is None, 15, 'no RViz host left after a refused display')


def test_a_hidden_display_is_its_own_resource_and_its_holder_shows_it(om, events, rospy_client):
    """A hot standby's display: requested hidden, never shared with the visible display of the same topic,
    and shown by the interface that holds it, in one call to the host."""
    pub = sd.RepeatingPublisher('/om_mgr/standby', sd.cloud_msg(rgb=(255, 0, 255)), 15).start()
    try:
        a, b = om(), om()
        config = '{Size (Pixels): 3, Color Transformer: RGB8}'
        hidden = a.show('point cloud', '/om_mgr/standby', config=config, hidden=True)
        visible = b.show('point cloud', '/om_mgr/standby', config=config)
        assert hidden.display_name != visible.display_name, 'a hidden request must not share a visible display'
        host = RvizHostClient(HOST)
        by_name = {d.name: d for d in host.list_displays().displays}
        assert not by_name[hidden.display_name].visible and by_name[visible.display_name].visible
        with pytest.raises(TemotoError, match='holds no display'):
            b.set_visible(hidden.trr.resource_id, True)
        b.hide(visible.trr.resource_id)
        wait_for(lambda: magenta_fraction(host.screenshot('view')) < 0.001, 10, 'the visible display gone')
        a.set_visible(hidden.trr.resource_id, True)
        wait_for(lambda: any(e.event == 'first_frame' and e.display_name == hidden.display_name for e in events),
                 10, 'the first frame of the shown display')
        assert magenta_fraction(host.screenshot('view')) > 0.01
        a.hide(hidden.trr.resource_id)
        with pytest.raises(TemotoError, match='holds no display'):
            a.set_visible(hidden.trr.resource_id, False)
    finally:
        pub.stop()
