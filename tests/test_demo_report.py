"""The demo report, computed from a real bag file written here with rosbag's Python API.

The bag is a scripted failover run with known times, so every latency in the report can be checked
to the millisecond; it is read back with ``rosbags`` exactly as a bag from a live run.
"""
import io
import json
import os
import subprocess
import sys

import pytest

T0 = 1_700_000_000.0


def _png(color, marks=True):
    from PIL import Image, ImageDraw
    img = Image.new('RGB', (160, 100), (48, 48, 48))
    if marks:
        d = ImageDraw.Draw(img)
        for i in range(0, 160, 7):
            d.rectangle([i, 30 + (i % 30), i + 4, 70], fill=color)
    buf = io.BytesIO()
    img.save(buf, 'PNG')
    return buf.getvalue()


def write_synthetic_bag(path, with_screenshots=True):
    """Scripted run: D435 shown at +3 s, unplugged (crash) at +10 s, Hokuyo cloud at +11.4 s,
    Hokuyo unplugged (stall) at +20 s (and a fail-back attempt of the D435 fails at +20.5 s), SICK scan at
    +21.5 s."""
    import rosbag
    import rospy
    from sensor_msgs.msg import CompressedImage
    from std_msgs.msg import Header, String
    from temoto_core.msg import ResourceStatus
    from temoto_output_manager.msg import DisplayEvent
    from vaultbot_sim.msg import DeviceState, DeviceStates
    from temoto_demo import topics as T

    def ts(t):
        return rospy.Time.from_sec(T0 + t)

    def action(bag, t, **ev):
        ev.update(stamp=T0 + t, graph='g1', action='show_environment', instance_id=0)
        bag.write(T.action_events(), String(data=json.dumps(ev)), ts(t + 0.001))

    def display(bag, t, event, topic, name):
        m = DisplayEvent(event=event, display_name=name, topic=topic, display_class='rviz/PointCloud2')
        m.header.stamp = ts(t)
        bag.write(T.display_events(), m, ts(t + 0.002))

    def devices(bag, t, d435=True, hokuyo=True, sick=True, modes=('crash', 'crash', 'crash')):
        m = DeviceStates(devices=[DeviceState(name=n, plugged=p, mode=mo) for n, p, mo in
                                  zip(('d435', 'hokuyo', 'sick'), (d435, hokuyo, sick), modes)])
        m.header.stamp = ts(t)
        bag.write(T.DEVICE_STATES, m, ts(t + 0.001))

    def status(bag, t, topic, manager, rid, message='dead'):
        m = ResourceStatus(manager_name=manager, server_name='x', resource_id=rid, status_code=1, message=message)
        m.header.stamp = ts(t)
        bag.write(topic, m, ts(t + 0.001))

    def ticks(bag, topic, start, stop, rate):
        n = int((stop - start) * rate)
        for i in range(n + 1):
            t = start + i / rate
            if t > stop:
                break
            h = Header(frame_id=topic)
            h.stamp = ts(t)
            bag.write(T.TICKS, h, ts(t + 0.0005))

    d435, cloud, sick = '/d435/depth_registered/points', '/laser_stitcher/cloud', '/sick/scan'
    with rosbag.Bag(path, 'w') as bag:
        devices(bag, 0.0)
        bag.write(T.chatter(), String(data='show the environment'), ts(0.5))
        action(bag, 2.0, event='sensor_active', priority_index=0, label='RGB-D camera cloud',
               sensor_name='realsense_d435', topic=d435)
        display(bag, 2.1, 'added', d435, 'rgbd')
        ticks(bag, d435, 2.5, 9.99, 30)           # last D435 frame at 9.9667 s
        display(bag, 3.0, 'first_frame', d435, 'rgbd')
        devices(bag, 10.0, d435=False)
        status(bag, 10.005, '/temoto/temoto_sensor_manager/status', 'temoto_er_manager', 7)
        status(bag, 10.009, '/temoto/sensor_manager_interface_1_0/status', 'temoto_sensor_manager', 3)
        action(bag, 10.012, event='sensor_failed', sensor_name='realsense_d435', priority_index=0)
        display(bag, 10.02, 'removed', d435, 'rgbd')
        action(bag, 10.9, event='sensor_active', priority_index=1, label='arm LIDAR stitched cloud',
               sensor_name='hokuyo_utm30lx', topic=cloud)
        display(bag, 10.95, 'added', cloud, 'arm')
        ticks(bag, cloud, 11.3, 19.5, 0.5)        # 11.3, 13.3, ... 19.3
        display(bag, 11.4, 'first_frame', cloud, 'arm')
        devices(bag, 20.0, d435=False, hokuyo=False, modes=('crash', 'stall', 'crash'))
        # a fail-back attempt of the unplugged D435 fails meanwhile: a FAILED that is not the Hokuyo's
        status(bag, 20.5, '/temoto/temoto_sensor_manager/status', 'temoto_er_manager', 8,
               'vaultbot_sim/d435_driver: process 9 exited with code 1')
        stalled = 'sensor hokuyo_utm30lx stalled: no message on /hokuyo/scan for 0.300 s (limit 0.300 s)'
        status(bag, 21.0, '/temoto/sensor_manager_interface_1_0/status', 'temoto_sensor_manager', 4, stalled)
        action(bag, 21.004, event='sensor_failed', sensor_name='hokuyo_utm30lx', priority_index=1, message=stalled)
        display(bag, 21.01, 'removed', cloud, 'arm')
        action(bag, 21.2, event='sensor_active', priority_index=2, label='base LIDAR scan',
               sensor_name='sick_lms511', topic=sick)
        display(bag, 21.25, 'added', sick, 'base')
        ticks(bag, sick, 21.4, 24.0, 25)
        display(bag, 21.5, 'first_frame', sick, 'base')
        if with_screenshots:
            for i, (t, stage, color) in enumerate(((3.2, 'rgbd_cloud', (200, 80, 80)), (11.6, 'arm_cloud', (80, 200, 80)),
                                                    (21.7, 'base_scan', (80, 80, 200)))):
                m = CompressedImage(format='png', data=_png(color))
                m.header.stamp = ts(t)
                m.header.frame_id = stage
                bag.write(T.SCREENSHOTS, m, ts(t))
    return path


def test_report_figures_from_a_synthetic_bag(tmp_path):
    from temoto_demo.report import write_report
    bag = write_synthetic_bag(str(tmp_path / 'failover.bag'))
    rep = write_report(bag)
    an = rep.analysis
    assert [s.index for s in an.stages] == [0, 1, 2]
    assert all(s.first_frame_t is not None for s in an.stages)
    f1, f2 = an.failures
    assert (f1.device, f1.mode, f2.device, f2.mode) == ('d435', 'crash', 'hokuyo', 'stall')
    assert f1.detection == pytest.approx(0.005, abs=1e-4)
    assert 'temoto_er_manager' in f1.failed_by
    assert f1.propagation == pytest.approx(0.007, abs=1e-4)
    assert f1.display_gap == pytest.approx(11.4 - (2.5 + 224 / 30), abs=1e-4)
    assert f1.switch == pytest.approx(1.4, abs=1e-4)
    assert f1.substitute_topic == '/laser_stitcher/cloud'
    assert f2.detection == pytest.approx(1.0, abs=1e-4)
    assert 'temoto_sensor_manager' in f2.failed_by
    assert f2.display_gap == pytest.approx(21.5 - 19.3, abs=1e-4)
    assert f2.substitute_topic == '/sick/scan'
    text = open(rep.path).read()
    assert 'timeline.png' in text and text.count('![') == 4
    assert '| display gap | 2.200 s |' in text
    for shot in rep.screenshots:
        assert os.path.getsize(shot) > 0
    from temoto_demo.report import non_background_fraction
    assert all(non_background_fraction(open(s, 'rb').read()) > 0.05 for s in rep.screenshots)
    assert non_background_fraction(_png((0, 0, 0), marks=False)) == 0.0
    from PIL import Image
    w, h = Image.open(rep.timeline).size
    assert w > 600 and h > 200
    summary = json.load(open(os.path.join(tmp_path, 'report.json')))
    assert summary['failures'][1]['display_gap_s'] == pytest.approx(2.2, abs=1e-4)


def test_report_cli_on_a_bag_without_screenshots_uses_pngs_beside_it(tmp_path):
    bag = write_synthetic_bag(str(tmp_path / 'run.bag'), with_screenshots=False)
    (tmp_path / 'screenshot_1_rgbd.png').write_bytes(_png((255, 0, 0)))
    out = tmp_path / 'out'
    env = dict(os.environ)
    proc = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'report', bag, '--out', str(out)], env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert (out / 'report.md').exists() and (out / 'timeline.png').exists()
    assert (out / 'screenshot_1_rgbd.png').exists()
    assert 'display gap' in proc.stdout


def test_report_cli_names_a_missing_bag(tmp_path):
    proc = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'report', str(tmp_path / 'nope.bag')],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0
    assert 'nope.bag' in proc.stderr


def test_the_default_run_folder_is_hidden_from_rospack(tmp_path, monkeypatch):
    """runs/ sits in the repository, on ROS_PACKAGE_PATH: rospack must not walk every old run."""
    import rospkg
    from temoto_demo.cli import default_run_dir
    monkeypatch.chdir(tmp_path)
    run = tmp_path / default_run_dir()
    (run / 'ros' / 'log' / 'decoy').mkdir(parents=True)
    (run / 'ros' / 'log' / 'decoy' / 'package.xml').write_text(
        '<package format="2"><name>decoy_in_a_run</name><version>0.0.0</version><description>d</description>'
        '<maintainer email="a@b.c">a</maintainer><license>BSD</license></package>')
    assert (tmp_path / 'runs' / 'CATKIN_IGNORE').is_file()
    assert rospkg.rospack.list_by_path('package.xml', str(tmp_path), {}) == []
