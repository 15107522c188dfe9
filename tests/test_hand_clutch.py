"""The hand clutch (temoto_operator/hand_clutch.py): a deliberate grab engages, the tool follows the hand's
motion relative to the grab, scaled by the dial; an open hand, a lost hand or a bad sample lets go."""
import math

import numpy as np
import pytest

from temoto_operator.dial import Dial
from temoto_operator.hand_clutch import HandClutch

TOOL = np.eye(4)
TOOL[:3, 3] = (0.6, 0.3, 1.1)


def pose(x, y, z, yaw=0.0):
    m = np.eye(4)
    m[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    m[:3, 3] = x, y, z
    return m


def engaged(clutch, palm=pose(0.1, 0.0, 0.2)):
    assert clutch.sample(palm, 0.0, lambda: TOOL) is None          # an open hand arms it
    return clutch.sample(palm, 1.0, lambda: TOOL)                   # a grab engages: the tool holds


def test_a_fist_held_from_the_start_moves_nothing_until_the_hand_opens_and_grabs():
    clutch = HandClutch(Dial())
    for k in range(5):
        assert clutch.sample(pose(0.1 * k, 0, 0.2), 1.0, lambda: TOOL) is None
    assert not clutch.engaged
    assert np.allclose(engaged(clutch), TOOL)


def test_the_tool_follows_the_hands_motion_from_the_grab_scaled_by_the_dial():
    clutch = HandClutch(Dial(0.1))
    engaged(clutch)
    target = clutch.sample(pose(0.3, -0.1, 0.25, yaw=0.2), 1.0, lambda: TOOL)
    assert np.allclose(target[:3, 3], TOOL[:3, 3] + 0.1 * np.array([0.2, -0.1, 0.05]))
    assert np.allclose(target[:3, :3], pose(0, 0, 0, yaw=0.2)[:3, :3])    # turned as the palm turned


def test_an_open_hand_lets_go_and_a_new_grab_starts_from_where_the_tool_is():
    clutch = HandClutch(Dial(1.0))
    engaged(clutch)
    moved = clutch.sample(pose(0.2, 0, 0.2), 1.0, lambda: TOOL)
    assert clutch.sample(pose(0.2, 0, 0.2), 0.6, lambda: TOOL) is not None    # hysteresis: still held at 0.6
    assert clutch.sample(pose(0.2, 0, 0.2), 0.3, lambda: TOOL) is None and not clutch.engaged
    assert clutch.sample(pose(-0.4, 0, 0.2), 0.0, lambda: moved) is None        # the hand moves back, open
    again = clutch.sample(pose(-0.4, 0, 0.2), 1.0, lambda: moved)
    assert np.allclose(again, moved)                                            # no jump at the new grab


def test_a_lost_hand_needs_an_open_hand_and_a_new_grab_before_anything_moves():
    clutch = HandClutch(Dial())
    engaged(clutch)
    clutch.lost()
    assert clutch.sample(pose(0.5, 0, 0.2), 1.0, lambda: TOOL) is None        # the fist after the failover
    assert np.allclose(engaged(clutch, pose(0.5, 0, 0.2)), TOOL)


@pytest.mark.parametrize('palm, grab', [(pose(math.nan, 0, 0), 1.0), (pose(0, 0, 0), math.nan)])
def test_a_bad_sample_lets_go(palm, grab):
    clutch = HandClutch(Dial())
    engaged(clutch)
    assert clutch.sample(palm, grab, lambda: TOOL) is None and not clutch.engaged and not clutch.armed


def test_turning_the_dial_while_engaged_does_not_make_the_target_jump():
    dial = Dial(1.0)
    clutch = HandClutch(dial)
    engaged(clutch)
    before = clutch.sample(pose(0.3, 0, 0.2), 1.0, lambda: TOOL)
    dial.set(0.1)
    same = clutch.sample(pose(0.3, 0, 0.2), 1.0, lambda: TOOL)
    assert np.allclose(same, before)
    further = clutch.sample(pose(0.4, 0, 0.2), 1.0, lambda: TOOL)
    assert np.allclose(further[:3, 3], before[:3, 3] + [0.01, 0, 0])


def test_the_scene_draws_the_hand_unscaled_from_the_tool_beside_its_scaled_target():
    clutch = HandClutch(Dial(0.1))
    assert clutch.hand_point(pose(0.1, 0.0, 0.2)) is None, 'nothing engaged: no hand drawn'
    engaged(clutch)
    moved = pose(0.1, 0.05, 0.2)
    target = clutch.sample(moved, 1.0, lambda: TOOL)
    assert np.allclose(clutch.hand_point(moved), TOOL[:3, 3] + (0.0, 0.05, 0.0))
    assert np.allclose(target[:3, 3], TOOL[:3, 3] + (0.0, 0.005, 0.0))
    clutch.lost()
    assert clutch.hand_point(moved) is None
