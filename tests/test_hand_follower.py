"""From hand samples to servo commands (temoto_operator/hand_follower.py): targets while the grab holds,
one hold the moment the hand goes stale or out of view, and nothing until a new deliberate grab."""
import math

import numpy as np
import pytest

from temoto_operator.dial import Dial
from temoto_robot_manager.navigation.scene_markers import gripper_text
from temoto_operator.hand_drive import GAIN_NAVIGATION, TURN_PER_M, velocity_of
from temoto_operator.hand_follower import HOLD, TARGET, HandFollower

TOOL = np.eye(4)


def palm(x):
    m = np.eye(4)
    m[0, 3] = x
    return m


def following(follower, t=0.0):
    assert follower.sample(t, palm(0), 0.0, True, lambda: TOOL) is None     # an open hand: nothing to stop
    first = follower.sample(t + 0.01, palm(0), 1.0, True, lambda: TOOL)
    assert first.kind == TARGET and np.allclose(first.pose, TOOL)
    return t + 0.01


def test_the_arm_follows_while_the_grab_holds_and_holds_once_when_it_opens():
    follower = HandFollower(Dial(0.1))
    t = following(follower)
    cmd = follower.sample(t + 0.01, palm(0.2), 1.0, True, lambda: TOOL)
    assert cmd.kind == TARGET and cmd.pose[0, 3] == pytest.approx(0.02)
    released = follower.sample(t + 0.02, palm(0.2), 0.0, True, lambda: TOOL)
    assert released.kind == HOLD and 'let go' in released.why
    assert follower.sample(t + 0.03, palm(0.2), 0.0, True, lambda: TOOL) is None     # said once


def test_a_stale_hand_holds_the_arm_at_its_deadline_and_needs_a_new_grab():
    follower = HandFollower(Dial(), period=0.01, missed=2)
    t = following(follower)
    assert follower.deadline() == pytest.approx(t + 0.02)
    assert follower.check(t + 0.019) is None
    held = follower.check(t + 0.02)
    assert held.kind == HOLD and '2 of its periods' in held.why
    assert follower.deadline() is None and follower.check(t + 1.0) is None
    # the source comes back with the fist still closed: nothing moves until the hand opens and grabs again
    assert follower.sample(t + 1.0, palm(0.3), 1.0, True, lambda: TOOL) is None
    following(follower, t + 1.1)


@pytest.mark.parametrize('tracked, x, grab, words', [
    (False, 0.0, 1.0, 'no hand in view'), (True, math.nan, 1.0, 'not finite'), (True, 0.0, math.inf, 'not finite')])
def test_a_hand_out_of_view_or_a_bad_sample_holds_the_arm(tracked, x, grab, words):
    follower = HandFollower(Dial())
    t = following(follower)
    held = follower.sample(t + 0.01, palm(x), grab, tracked, lambda: TOOL)
    assert held.kind == HOLD and words in held.why and not follower.clutch.engaged


def test_nothing_is_held_or_watched_before_the_hand_is_followed():
    follower = HandFollower(Dial())
    assert follower.deadline() is None and follower.lost('the source failed') is None


def test_bad_settings_are_refused():
    with pytest.raises(ValueError):
        HandFollower(Dial(), period=0.0)
    with pytest.raises(ValueError):
        HandFollower(Dial(), missed=0)


# ----------------------------------------------------------------------------------- navigation mode
def test_in_navigation_mode_the_hand_pushed_forward_drives_and_pushed_left_turns_left():
    follower = HandFollower(Dial(1.0), gain=GAIN_NAVIGATION)
    t = following(follower)
    k = GAIN_NAVIGATION
    still = follower.sample(t + 0.01, palm(0.004), 1.0, True, lambda: TOOL)
    assert velocity_of(still.pose[:3, 3], k) == (0.0, 0.0), 'within the dead zone: a trembling hand does not creep'
    forward = follower.sample(t + 0.02, palm(0.055), 1.0, True, lambda: TOOL)
    linear, angular = velocity_of(forward.pose[:3, 3], k)
    assert linear == pytest.approx(k * 0.05) and angular == 0.0
    left = np.eye(4)
    left[1, 3] = 0.055
    linear, angular = velocity_of(follower.sample(t + 0.03, left, 1.0, True, lambda: TOOL).pose[:3, 3], k)
    assert linear == 0.0 and angular == pytest.approx(TURN_PER_M * k * 0.05)


def test_in_navigation_mode_the_dial_scales_the_speed():
    fine = HandFollower(Dial(0.1), gain=GAIN_NAVIGATION)
    t = following(fine)
    offset = fine.sample(t + 0.01, palm(0.055), 1.0, True, lambda: TOOL).pose[:3, 3]
    assert velocity_of(offset, 0.1 * GAIN_NAVIGATION)[0] == pytest.approx(0.1 * GAIN_NAVIGATION * 0.05)


def test_a_drive_velocity_from_a_bad_offset_is_zero_and_a_bad_gain_is_refused():
    assert velocity_of(np.array([math.nan, 0.0, 0.0]), 1.0) == (0.0, 0.0)
    with pytest.raises(ValueError, match='must be above 0'):
        velocity_of(np.zeros(3), 0.0)


def test_the_scene_says_the_gripper_s_state_from_its_controller():
    assert gripper_text(None, False, False) == 'gripper: not heard from yet'
    assert gripper_text(0.085, False, True) == 'gripper: open 85 mm'
    assert gripper_text(0.0, False, True) == 'gripper: closed 0 mm'
    assert gripper_text(0.05, True, False) == 'gripper: holding (50 mm)'
