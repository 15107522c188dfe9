"""The RViz host on its own: real librviz under the host's private Xvfb.

One host serves the module (it takes ~1.5 s to start and renders on the shared
2 cores); the crash test starts its own.
"""
import io
import os
import signal
import time
import xmlrpc.client

import numpy as np
import psutil
import pytest
from PIL import Image as PILImage

from temoto_testing import wait_for, wait_receiving
from temoto_output_manager import sample_data as sd
from temoto_output_manager.host_client import RvizHostClient, RvizHostError
from temoto_output_manager.msg import DisplayEvent
from temoto_output_manager.xvfb import runtime_dir

NS = 'temoto'


@pytest.fixture(scope='module')
def host(module_procs, rospy_client):
    proc = module_procs.node('temoto_output_manager', 'rviz_host', name='rviz_host', namespace=NS,
                             params={'show_robot': 'false'})
    client = RvizHostClient('/%s/rviz_host' % NS)
    client.wait_ready(20, failed=exit_reason(proc))
    return proc, client


def exit_reason(proc):
    """For wait_ready: why the host process is gone (with its log), or None while it runs."""
    return lambda: None if proc.alive() else 'exited (rc %s); log:\n%s' % (proc.returncode, proc.log(40))


@pytest.fixture(scope='module')
def events(host, rospy_client):
    got = []
    sub = rospy_client.Subscriber('/%s/temoto_output_manager/display_events' % NS, DisplayEvent, got.append)
    wait_receiving(sub, 10, 'the display events connected')
    yield got
    sub.unregister()


def png_pixels(resp):
    return np.asarray(PILImage.open(io.BytesIO(bytes(resp.png))).convert('RGB'))


def colour_fraction(pixels, rgb, tol=40):
    diff = np.abs(pixels.astype(int) - np.array(rgb)).max(axis=2)
    return float((diff <= tol).mean())


def master_subscriptions(topic):
    import rosgraph
    master = rosgraph.Master('/pytest')
    for name, nodes in master.getSystemState()[1]:
        if name == topic:
            return nodes
    return []


def first_frame(events, name):
    for e in events:
        if e.event == DisplayEvent.FIRST_FRAME and e.display_name == name:
            return e
    return None


def test_point_cloud_is_drawn_in_its_colours_and_unsubscribes_on_remove(host, events, rospy_client):
    _, client = host
    pub = sd.RepeatingPublisher('/om_test/cloud', sd.cloud_msg(rgb=(255, 0, 255)), 15).start()
    try:
        before = client.screenshot('view')
        assert colour_fraction(png_pixels(before), (255, 0, 255)) < 0.001
        name = client.add_display('rviz/PointCloud2', '/om_test/cloud', name='cloud',
                                  config='{Size (Pixels): 3, Color Transformer: RGB8}')
        assert name == 'cloud'
        ev = wait_for(lambda: first_frame(events, 'cloud'), 15, 'first frame of the cloud display')
        added = next(e for e in events if e.event == DisplayEvent.ADDED and e.display_name == 'cloud')
        assert ev.frame_count > added.frame_count and 0 < ev.seconds_since_added < 15
        shot = client.screenshot('view')
        assert shot.width > 300 and shot.height > 300
        assert colour_fraction(png_pixels(shot), (255, 0, 255)) > 0.01, 'the magenta cloud is not on screen'
        assert [d for d in client.list_displays().displays if d.name == 'cloud'][0].drawn
        wait_for(lambda: master_subscriptions('/om_test/cloud'), 5, 'RViz subscription to the cloud')
        client.remove_display('cloud')
        wait_for(lambda: not master_subscriptions('/om_test/cloud'), 10, 'subscription gone at the master')
        assert 'cloud' not in client.display_names()
        wait_for(lambda: any(e.event == DisplayEvent.REMOVED and e.display_name == 'cloud' for e in events), 10,
                 'the removed event')
    finally:
        pub.stop()


def test_laser_scan_and_image_displays(host, events, rospy_client):
    _, client = host
    scan = sd.RepeatingPublisher('/om_test/scan', sd.scan_msg(), 15).start()
    image = sd.RepeatingPublisher('/om_test/image', sd.image_msg(rgb=(0, 255, 0)), 15).start()
    try:
        client.add_display('rviz/LaserScan', '/om_test/scan', name='scan',
                           config='{Color Transformer: FlatColor, Color: [255, 255, 0], Size (m): 0.05}')
        client.add_display('rviz/Image', '/om_test/image', name='image')
        wait_for(lambda: first_frame(events, 'scan') and first_frame(events, 'image'), 15, 'scan and image drawn')
        window = png_pixels(client.screenshot('window'))
        view = png_pixels(client.screenshot('view'))
        assert colour_fraction(window, (0, 255, 0)) > 0.02, 'the green image pane is missing'
        assert colour_fraction(view, (0, 255, 0)) < 0.001, 'the 3D view must not contain the image pane'
        assert colour_fraction(view, (255, 255, 0)) > 0.0005, 'the yellow scan is not drawn'
        client.remove_display('scan')
        client.remove_display('image')
        wait_for(lambda: not master_subscriptions('/om_test/image'), 10, 'image subscription gone')
    finally:
        scan.stop()
        image.stop()


def test_a_hidden_display_stays_subscribed_and_shows_the_data_it_holds_at_once(host, events, rospy_client):
    """Hot standby's display: hidden, it receives but draws nothing; shown, its last message is on screen at the
    next frame. The publisher stops before the reveal, so the picture can only come from what it held."""
    _, client = host
    pub = sd.RepeatingPublisher('/om_test/standby', sd.cloud_msg(rgb=(255, 0, 255)), 15).start()
    try:
        client.add_display('rviz/PointCloud2', '/om_test/standby', name='standby',
                           config='{Size (Pixels): 3, Color Transformer: RGB8, Visible: false}')
        wait_for(lambda: pub.pub.get_num_connections() > 0, 10, 'the hidden display to subscribe')
        wait_for(lambda: 'Points' in next(d for d in client.list_displays().displays if d.name == 'standby').status,
                 15, 'the hidden display to receive clouds')
        info = next(d for d in client.list_displays().displays if d.name == 'standby')
        assert not info.visible and not info.drawn and info.enabled
        assert colour_fraction(png_pixels(client.screenshot('view')), (255, 0, 255)) < 0.001, 'hidden, yet drawn'
        assert first_frame(events, 'standby') is None, 'a hidden display reported a frame on screen'
    finally:
        pub.stop()
    client.set_visible('standby', True)
    ev = wait_for(lambda: first_frame(events, 'standby'), 10, 'the first frame once shown')
    shown = next(e for e in events if e.event == DisplayEvent.SHOWN and e.display_name == 'standby')
    assert ev.frame_count > shown.frame_count
    assert colour_fraction(png_pixels(client.screenshot('view')), (255, 0, 255)) > 0.01, 'shown, yet not drawn'
    info = next(d for d in client.list_displays().displays if d.name == 'standby')
    assert info.visible and info.drawn
    client.set_visible('standby', False)
    wait_for(lambda: any(e.event == DisplayEvent.HIDDEN and e.display_name == 'standby' for e in events), 10,
             'the hidden event')          # events arrive on a topic: after the call returns, not with it
    wait_for(lambda: colour_fraction(png_pixels(client.screenshot('view')), (255, 0, 255)) < 0.001, 10,
             'the cloud to leave the screen once hidden again')
    client.remove_display('standby')


def test_hiding_is_refused_clearly_where_it_cannot_work(host):
    _, client = host
    before = client.display_names()
    with pytest.raises(RvizHostError, match='rviz/Image has no Alpha property'):
        client.add_display('rviz/Image', '/om_test/hidden_image', name='hidden image', config='{Visible: false}')
    with pytest.raises(RvizHostError, match="'Visible' expects true or false"):
        client.add_display('rviz/PointCloud2', '/om_test/c', name='bad flag', config='{Visible: maybe}')
    assert client.display_names() == before
    with pytest.raises(RvizHostError, match="no display named 'ghost'"):
        client.set_visible('ghost', True)


def test_bad_requests_get_clear_errors_and_change_nothing(host):
    _, client = host
    before = client.display_names()
    cases = [
        (dict(display_class='rviz/NoSuchDisplay', topic='/x'), 'unknown RViz display class'),
        (dict(display_class='rviz/PointCloud2', topic=''), 'needs a topic'),
        (dict(display_class='rviz/PointCloud2', topic='/c', config='{Size (Pixels): [1,'), 'not valid YAML'),
        (dict(display_class='rviz/PointCloud2', topic='/c', config='{Colour: [1, 2, 3]}'), "unknown property 'Colour'"),
        (dict(display_class='rviz/PointCloud2', topic='/c', config='{Size (Pixels): big}'), 'expects a number'),
        (dict(display_class='rviz/PointCloud2', topic='/c', config='[1, 2]'), 'YAML mapping'),
        (dict(display_class='rviz/Image', topic='/c', config='{Nope: 1}'), "unknown property 'Nope'"),
    ]
    for kwargs, expected in cases:
        with pytest.raises(RvizHostError) as err:
            client.add_display(**kwargs)
        assert expected in str(err.value), (kwargs, str(err.value))
        assert client.display_names() == before
    with pytest.raises(RvizHostError, match="no display named 'ghost'"):
        client.remove_display('ghost')
    with pytest.raises(RvizHostError, match="unknown property 'Zoom'"):
        client.set_view('{Zoom: 3}')
    client.set_view('{Distance: 5.0, Focal Point: [1, 0, 0.5]}', frame_robot=True)


def test_add_remove_cycles_keep_memory_flat(host, rospy_client):
    proc, client = host
    rss = lambda: psutil.Process(proc.pid).memory_info().rss / 1e6
    for cls, topic in (('rviz/PointCloud2', '/om_test/c'), ('rviz/Image', '/om_test/i')):   # warm up both kinds
        client.remove_display(client.add_display(cls, topic, name='warm'))
    start = rss()
    for i in range(50):
        cls, topic = (('rviz/Image', '/om_test/i%d' % i) if i % 2 else ('rviz/PointCloud2', '/om_test/c%d' % i))
        client.remove_display(client.add_display(cls, topic, name='cycle'))
    grown = rss() - start
    assert grown < 30, 'host RSS grew by %.1f MB over 50 add/remove cycles' % grown


def test_killed_host_takes_its_xvfb_along(procs, rospy_client):
    proc = procs.node('temoto_output_manager', 'rviz_host', name='rviz_host_crash', namespace=NS,
                      params={'show_robot': 'false', 'show_grid': 'false'})
    client = RvizHostClient('/%s/rviz_host_crash' % NS)
    client.wait_ready(20, failed=exit_reason(proc))
    children = psutil.Process(proc.pid).children()
    xvfb = [c for c in children if c.name() == 'Xvfb']
    assert len(xvfb) == 1, 'headless host must run its own Xvfb: %s' % children
    assert '-nolisten' in xvfb[0].cmdline() and 'tcp' in xvfb[0].cmdline()
    # a killed host cleans nothing up: its Qt runtime folder (its Xvfb was started with it) is the user's
    # one, not one more left in /tmp
    assert xvfb[0].environ()['XDG_RUNTIME_DIR'] == runtime_dir()
    os.kill(proc.pid, signal.SIGKILL)
    proc.proc.wait(timeout=10)
    wait_for(lambda: not xvfb[0].is_running() or xvfb[0].status() == psutil.STATUS_ZOMBIE, 10,
             'Xvfb to stop after its host was killed')
    # The dead host's services are still registered at the master: that is not "ready" ...
    with pytest.raises(RvizHostError, match='did not come up within'):
        client.wait_ready(0.5)
    # ... and a wait that knows the host is gone ends at once, with the reason.
    t0 = time.monotonic()
    with pytest.raises(RvizHostError, match=r'failed while starting: exited \(rc -9\)'):
        client.wait_ready(20, failed=exit_reason(proc))
    assert time.monotonic() - t0 < 2.0


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_host_stops_cleanly_on_a_signal(procs, rospy_client, sig):
    """librviz's roscpp installs its own SIGINT handler; the host must still quit Qt on SIGINT and SIGTERM.

    With a display reconfigured first: RViz then counts its config as modified and, on close, asks
    "save changes?" in a modal dialog that nobody headless answers (the host sat in it until its
    supervisor's next signal)."""
    name = 'rviz_host_sig%d' % sig
    proc = procs.node('temoto_output_manager', 'rviz_host', name=name, namespace=NS,
                      params={'show_robot': 'false', 'show_grid': 'false'})
    client = RvizHostClient('/%s/%s' % (NS, name))
    client.wait_ready(20, failed=exit_reason(proc))
    drawn = []
    sub = rospy_client.Subscriber('/%s/temoto_output_manager/display_events' % NS, DisplayEvent,
                                  lambda e: drawn.append(e) if e.event == DisplayEvent.FIRST_FRAME else None)
    pub = sd.RepeatingPublisher('/om_test/sig_cloud', sd.cloud_msg(rgb=(255, 0, 255)), 15).start()
    try:
        client.add_display('rviz/PointCloud2', '/om_test/sig_cloud', name='changes the config')
        wait_for(lambda: any(e.display_name == 'changes the config' for e in drawn), 15, 'the cloud drawn')
        sent = pub.count       # a change made only after the display has drawn a while marks the config modified
        wait_for(lambda: pub.count >= sent + 25, 15, 'the cloud to be drawn a while')
        client.configure_display('changes the config', config='{Size (m): 0.05}')
        client.remove_display('changes the config')
    finally:
        pub.stop()
        sub.unregister()
    xvfb = [c for c in psutil.Process(proc.pid).children() if c.name() == 'Xvfb']
    os.kill(proc.pid, sig)                          # one signal, and nothing after it
    assert proc.proc.wait(timeout=10) == 0          # a hang here used to end only in SIGKILL
    wait_for(lambda: all(not x.is_running() or x.status() == psutil.STATUS_ZOMBIE for x in xvfb), 10,
             'its Xvfb to stop')


def test_cli_screenshot_and_displays(host, tmp_path, capsys):
    from temoto_output_manager.cli import displays_main, screenshot_main
    out = tmp_path / 'shot.png'
    assert screenshot_main([str(out), '--window']) == 0
    img = PILImage.open(out)
    assert img.size[0] >= 900 and img.format == 'PNG'
    assert displays_main([]) == 0
    text = capsys.readouterr().out
    assert 'shot.png' in text and 'Grid' in text and 'rviz/Grid' in text and 'fixed frame base_link' in text
    assert displays_main(['--namespace', 'nowhere', '--timeout', '0.5']) == 1
    err = capsys.readouterr().err     # no host there is the normal state with nothing shown, not a failure
    assert "no RViz host is running in namespace 'nowhere'" in err and 'stops with the last' in err, err
    assert 'did not come up' not in err, err


def test_several_robots_are_drawn_each_with_its_own_model_and_frame_prefix(procs, rospy_client):
    """One station, two robots sharing the TF tree: one robot model per robot, from its own description,
    under its own frame prefix (robot.launch robot:=NAME frame_prefix:=NAME/)."""
    with open(os.path.join(os.environ['TEMOTO_ROOT'], 'vaultbot_sim', 'urdf', 'vaultbot.urdf')) as f:
        urdf = f.read()
    for robot in ('om_r1', 'om_r2'):
        rospy_client.set_param('/%s/robot_description' % robot, urdf)
    try:
        _check_two_robot_models(procs, rospy_client)
    finally:
        for robot in ('om_r1', 'om_r2'):
            rospy_client.delete_param('/%s/robot_description' % robot)


def _check_two_robot_models(procs, rospy_client):
    proc = procs.node('temoto_output_manager', 'rviz_host', name='rviz_host_robots', namespace=NS,
                      params={'robots': 'om_r1,om_r2', 'show_grid': 'false', 'fixed_frame': 'world'})
    client = RvizHostClient('/%s/rviz_host_robots' % NS)
    client.wait_ready(20, failed=exit_reason(proc))

    def models():
        return {d.name: d.status for d in client.list_displays().displays if d.display_class == 'rviz/RobotModel'}
    assert sorted(models()) == ['RobotModel om_r1', 'RobotModel om_r2']
    for robot, other in (('om_r1', 'om_r2'), ('om_r2', 'om_r1')):
        # each parsed its own URDF (its links are listed), and looks them up under its own prefix (no TF here)
        wait_for(lambda robot=robot: '[%s/sick_link]' % robot in models()['RobotModel %s' % robot], 15,
                 "%s's model looking up its prefixed links" % robot)
        status = models()['RobotModel %s' % robot]
        assert '[%s/base_link]' % robot in status and other + '/' not in status, status


def test_a_bad_robot_name_stops_the_host_naming_it(procs, rospy_client):
    proc = procs.node('temoto_output_manager', 'rviz_host', name='rviz_host_bad_robot', namespace=NS,
                      params={'robots': 'om_r1,2bot', 'show_grid': 'false'}, wait=False)
    wait_for(lambda: not proc.alive(), 20, 'the host to refuse its robots')
    assert proc.returncode != 0 and "~robots: robot name '2bot'" in proc.log(40), proc.log(40)


def test_the_motion_scene_s_markers_are_drawn(host, events, rospy_client):
    """The footprint, the stop zone (temoto_robot_manager/navigation/scene_markers.py) and the hand with its target,
    as the navigator and follow_hand publish them, drawn by real RViz (the host's fixed frame is base_link)."""
    from visualization_msgs.msg import MarkerArray
    from temoto_robot_manager.navigation.costmap import Footprint
    from temoto_robot_manager.navigation.scene_markers import (FOOTPRINT_COLOUR, HAND_COLOUR, STOP_ZONE_COLOUR,
                                                               TARGET_COLOUR, TEXT_COLOUR, base_scene, hand_scene)
    _, client = host
    base = rospy_client.Publisher('/om_test/base_scene', MarkerArray, queue_size=1, latch=True)
    hand = rospy_client.Publisher('/om_test/hand_scene', MarkerArray, queue_size=1, latch=True)
    base.publish(base_scene(Footprint.of([1.2, 1.4]), 'base_link', 0.8, 0.0, rospy_client.Time.now()))
    hand.publish(hand_scene('base_link', rospy_client.Time.now(), (0.0, -0.3, 0.5), (0.0, 0.3, 0.5),
                            gripper='gripper: holding (50 mm)', tool=(0.0, 0.3, 0.5)))
    try:
        client.add_display('rviz/MarkerArray', '/om_test/base_scene', name='base scene')
        client.add_display('rviz/MarkerArray', '/om_test/hand_scene', name='hand scene')
        wait_for(lambda: first_frame(events, 'base scene') and first_frame(events, 'hand scene'), 15,
                 'the scene drawn')
        first = client.screenshot('view').frame_count
        wait_for(lambda: client.screenshot('view').frame_count >= first + 5, 15, 'RViz to draw on')
        view = png_pixels(client.screenshot('view'))
        for what, rgba in (('footprint', FOOTPRINT_COLOUR), ('stop zone', STOP_ZONE_COLOUR), ('hand', HAND_COLOUR),
                           ('target', TARGET_COLOUR), ("gripper's state", TEXT_COLOUR)):
            rgb = tuple(int(255 * c) for c in rgba[:3])
            assert colour_fraction(view, rgb, tol=60) > 1e-5, 'the %s is not drawn' % what
        client.remove_display('base scene')
        client.remove_display('hand scene')
    finally:
        base.unregister()
        hand.unregister()
