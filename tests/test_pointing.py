"""The pointed goal, without ROS: what RViz's tools may point, and how long a goal stays."""
import math

import pytest

from temoto_operator.pointing import NO_HEADING, BadPointing, PointedGoal, checked


def test_a_nav_goal_keeps_its_heading_and_a_point_has_none():
    yaw = 0.7
    goal = checked('world', (1.0, 2.0, 0.0), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)), 'nav_goal', 1.0)
    assert goal.has_heading and goal.yaw() == pytest.approx(yaw)
    point = checked('world', (1.0, 2.0, 0.3), None, 'clicked_point', 1.0)
    assert not point.has_heading and point.yaw() is None and point.quaternion == NO_HEADING
    assert point.describe() == '(1.00, 2.00, no heading) in world'


@pytest.mark.parametrize('frame, position, quaternion, words', [
    ('', (0, 0, 0), None, 'header.frame_id is empty'),
    ('world', (math.nan, 0, 0), None, 'position.x is nan'),
    ('world', (0, math.inf, 0), None, 'position.y is inf'),
    ('world', (0, 0, 0), (0, 0, 0, 0), 'norm 0.000, not a unit quaternion'),
    ('world', (0, 0, 0), (0, 0, 0, math.nan), 'not finite'),
    ('world', (0, 0, 0), (0.7071, 0, 0, 0.7071), 'tilts'),
])
def test_a_goal_that_cannot_be_one_is_refused_naming_the_field(frame, position, quaternion, words):
    with pytest.raises(BadPointing, match=words):
        checked(frame, position, quaternion, 'nav_goal', 0.0)


def test_a_goal_stays_until_used_or_replaced():
    pointed = PointedGoal()
    assert pointed.use('navigate') is None and pointed.used_by == ''      # nothing pointed: nothing used
    first = checked('world', (1, 0, 0), None, 'clicked_point', 1.0)
    second = checked('world', (2, 0, 0), None, 'clicked_point', 2.0)
    pointed.point(first)
    pointed.point(second)                                   # replaced
    assert pointed.current is second
    assert pointed.use('navigate') is second and pointed.used_by == 'navigate'
    assert pointed.current is None and pointed.use('navigate') is None
