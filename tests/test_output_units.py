"""Output Manager pieces that need neither ROS nor RViz: config, types, first-frame logic, framing, Xvfb."""
import os

import pytest

from temoto_output_manager import display_config as dc
from temoto_output_manager.display_types import UnknownDisplayType, installed_rviz_classes, rviz_class_for
from temoto_output_manager.first_frame import FirstFrameWatch, received_count
from temoto_output_manager.framing import robot_view
from temoto_output_manager.xvfb import Xvfb, ensure_display, runtime_dir


class FakeProp:
    """The part of rviz.Property that display_config uses."""

    def __init__(self, name, value=None, children=(), accept=lambda v: True):
        self.name, self.value, self.children, self.accept = name, value, list(children), accept

    def numChildren(self):
        return len(self.children)

    def childAt(self, i):
        return self.children[i]

    def getName(self):
        return self.name

    def getValue(self):
        return self.value

    def setValue(self, v):
        if not self.accept(v) or v == self.value:
            return False
        self.value = v
        return True


def display():
    return FakeProp('d', True, [
        FakeProp('Size (Pixels)', 1.0), FakeProp('Style', 'Flat Squares'),
        FakeProp('Color', '255; 255; 255', accept=lambda v: isinstance(v, str) and v.count(';') == 2),
        FakeProp('Autocompute Value Bounds', True, [FakeProp('Max Value', 10.0)]),
        FakeProp('Status: Ok', None)])


def test_config_applies_nested_and_list_values():
    d = display()
    changed = dc.apply_config(d, dc.parse_config(
        '{Size (Pixels): 3, Color: [255, 0, 0], Autocompute Value Bounds: {Value: false, Max Value: 2.5}}'))
    assert changed == ['Size (Pixels)', 'Color', 'Autocompute Value Bounds', 'Autocompute Value Bounds/Max Value']
    assert d.children[0].value == 3 and d.children[2].value == '255;0;0'
    assert d.children[3].value is False and d.children[3].children[0].value == 2.5


@pytest.mark.parametrize('text,message', [
    ('{a: [1,', 'not valid YAML'),
    ('- 1', 'YAML mapping'),
    ('{Colour: [1, 2, 3]}', "unknown property 'Colour'"),
    ('{Autocompute Value Bounds: {Min: 1}}', "unknown property 'Autocompute Value Bounds/Min'"),
    ('{Size (Pixels): big}', 'expects a number'),
    ('{Autocompute Value Bounds: 3}', 'expects true or false'),
    ('{Style: {x: [a]}}', "unknown property 'Style/x'"),
])
def test_bad_config_is_refused_before_anything_changes(text, message):
    d = display()
    with pytest.raises(dc.DisplayConfigError) as err:
        dc.apply_config(d, dc.parse_config(text))
    assert message in str(err.value)
    assert d.children[0].value == 1.0


def test_refused_value_rolls_back_earlier_changes():
    d = display()
    d.children[2].accept = lambda v: False
    with pytest.raises(dc.DisplayConfigError, match="'Color' refused"):
        dc.apply_config(d, {'Size (Pixels)': 4, 'Color': 'zz'})
    assert d.children[0].value == 1.0


def test_float32_echo_is_not_a_refusal():
    assert dc.same_value(0.7850000262, 0.785) and dc.same_value('1; 0; 0.5', '1;0;0.5')
    assert not dc.same_value('255; 255; 255', 'zz')


def test_point_clouds_default_to_cheap_points_and_a_request_s_own_config_wins():
    from temoto_output_manager.display_types import DEFAULT_CONFIG
    defaults = DEFAULT_CONFIG['rviz/PointCloud2']
    assert dc.parse_config(dc.with_defaults(defaults, '')) == {'Style': 'Points', 'Size (Pixels)': 3}
    mine = dc.parse_config(dc.with_defaults(defaults, '{Style: Flat Squares, Size (m): 0.05}'))
    assert mine == {'Style': 'Flat Squares', 'Size (Pixels)': 3, 'Size (m)': 0.05}
    assert dc.with_defaults({}, '') == ''
    with pytest.raises(dc.DisplayConfigError, match='YAML mapping'):
        dc.with_defaults(defaults, '[1, 2]')


def test_abstract_types_and_classes():
    assert rviz_class_for('point cloud') == 'rviz/PointCloud2' == rviz_class_for('depth image')
    assert rviz_class_for('robot_model') == 'rviz/RobotModel' and rviz_class_for('laser scan') == 'rviz/LaserScan'
    with pytest.raises(UnknownDisplayType, match='known types: depth image, image, laser scan'):
        rviz_class_for('hologram')
    classes = installed_rviz_classes()
    assert {'rviz/PointCloud2', 'rviz/Image', 'rviz/LaserScan', 'rviz/TF', 'rviz/Marker'} <= classes


def test_first_frame_never_fires_before_a_frame_after_the_data():
    assert received_count('12 messages received') == 12 and received_count('5 images received') == 5
    assert received_count('OK') is None
    w = FirstFrameWatch(True, frame_count=10)
    assert not w.observe(11, None) and not w.observe(12, 0)
    assert not w.observe(12, 1)                 # data seen at frame 12: not drawn yet
    assert not w.observe(12, 2)
    assert w.observe(13, 3) and w.drawn_frame == 13
    assert not w.observe(14, 4)                 # fires once
    w.restart(20)
    assert not w.drawn and not w.observe(21, None)
    probed = FirstFrameWatch(True, 0, margin=1)
    probed.observe(5, 1)
    assert not probed.observe(6, 1) and probed.observe(7, 1)
    topicless = FirstFrameWatch(False, 3)
    assert not topicless.observe(3, None) and topicless.observe(4, None)
    # a hidden display shown again with the data it holds: on screen at the next frame, whatever its status says
    # then (a reveal once waited 10 s for a status read after it)
    shown = FirstFrameWatch(True, 0)
    shown.restart(30, holding=True)
    assert not shown.observe(30, None) and shown.observe(31, None) and shown.drawn_frame == 31


def test_framing_covers_the_robot():
    urdf = '''<robot name="r">
      <link name="base_link"><visual><geometry><box size="1 0.6 0.4"/></geometry></visual></link>
      <link name="mast"><visual><geometry><cylinder radius="0.05" length="1"/></geometry></visual></link>
      <joint name="j" type="fixed"><parent link="base_link"/><child link="mast"/>
        <origin xyz="0 0 1.5" rpy="0 0 0"/></joint></robot>'''
    view = robot_view(urdf, 'base_link')
    assert 0.5 < view.focal_point[2] < 1.3 and abs(view.focal_point[0]) < 0.2
    assert view.distance > 3.0
    assert robot_view(None).distance == 6.0 and robot_view('<not xml').distance == 6.0


def test_xvfb_picks_a_free_display_and_stops_cleanly():
    a, b = Xvfb(), Xvfb()
    try:
        da, db = a.start(), b.start()
        assert da != db and da.startswith(':')
        assert os.path.exists('/tmp/.X11-unix/X%s' % da[1:])
        assert '-nolisten' in open('/proc/%d/cmdline' % a.pid).read().split('\0')
    finally:
        a.stop()
        b.stop()
    assert not a.running() and not os.path.exists('/tmp/.X11-unix/X%s' % da[1:])


def test_headless_hosts_share_one_private_runtime_folder_per_user(tmp_path):
    first = runtime_dir(str(tmp_path))
    assert first == runtime_dir(str(tmp_path)) == str(tmp_path / ('temoto_xdg_%d' % os.getuid()))
    assert os.stat(first).st_mode & 0o777 == 0o700
    env = {'DISPLAY': ':99'}            # a display given: no Xvfb, only the folder
    assert ensure_display(env) is None and env['XDG_RUNTIME_DIR'] == runtime_dir()


@pytest.mark.parametrize('planted', ['open to others', 'a link'])
def test_a_runtime_folder_planted_in_the_shared_tmp_is_not_used(tmp_path, planted):
    path = tmp_path / ('temoto_xdg_%d' % os.getuid())
    if planted == 'a link':
        (tmp_path / 'elsewhere').mkdir(mode=0o700)
        path.symlink_to(tmp_path / 'elsewhere')
    else:
        path.mkdir(mode=0o700)
        path.chmod(0o777)
    assert runtime_dir(str(tmp_path)) is None


def test_the_host_starts_looking_at_the_data_unless_told_otherwise():
    from temoto_output_manager.framing import OPERATOR_VIEW
    from temoto_output_manager.host_node import _initial_view
    assert _initial_view('operator') == OPERATOR_VIEW and _initial_view('robot') == {}
    assert _initial_view({'Distance': 3.0}) == {'Distance': 3.0}
    with pytest.raises(SystemExit, match="'operator', 'robot'"):
        _initial_view('sideways')


def test_the_robot_model_takes_its_robots_frame_prefix_when_robots_share_the_tf_tree():
    from temoto_output_manager.rviz_host import HostSettings, robot_model_config
    one, = HostSettings().drawn_robots()
    assert robot_model_config(one) == {'Robot Description': 'robot_description'}
    prefixed, = HostSettings(robot_description='/vaultbot_2/robot_description',
                             robot_tf_prefix='vaultbot_2/').drawn_robots()
    assert robot_model_config(prefixed) == \
        {'Robot Description': '/vaultbot_2/robot_description', 'TF Prefix': 'vaultbot_2'}


def test_several_robots_are_drawn_each_from_its_own_description_and_prefix():
    from temoto_output_manager.host_node import _robots
    from temoto_output_manager.rviz_host import (HostSettings, RobotDrawn, robot_model_config, robot_model_name,
                                                 robots_from_names)
    robots = robots_from_names('vaultbot_1, vaultbot_2')
    assert robots == [RobotDrawn('/vaultbot_1/robot_description', 'vaultbot_1/'),
                      RobotDrawn('/vaultbot_2/robot_description', 'vaultbot_2/')]
    assert robots_from_names('vaultbot_1 vaultbot_2') == robots and robots_from_names('') == []
    settings = HostSettings(robot_description='/ignored', robots=robots)
    assert settings.drawn_robots() == robots
    assert [robot_model_config(r)['TF Prefix'] for r in robots] == ['vaultbot_1', 'vaultbot_2']
    assert [robot_model_name(r, True) for r in robots] == ['RobotModel vaultbot_1', 'RobotModel vaultbot_2']
    for bad, named in (('vaultbot_1,2bot', "'2bot'"), ('a/b', "'a/b'"), ('vb,vb', 'named twice')):
        with pytest.raises(ValueError, match=named):
            robots_from_names(bad)
    with pytest.raises(SystemExit, match="~robots: robot name '2bot'"):
        _robots('vaultbot_1,2bot')
    assert _robots(None) == []


def test_the_hosts_params_reach_it_whole_through_the_er_managers_split():
    import shlex
    from temoto_output_manager.manager import host_args
    args = shlex.split(host_args('temoto', {'robots': 'vaultbot_1 vaultbot_2', 'fixed_frame': 'world'}))
    assert args == ['__name:=rviz_host', '_temoto_namespace:=temoto', '_fixed_frame:=world',
                    '_robots:=vaultbot_1 vaultbot_2']
