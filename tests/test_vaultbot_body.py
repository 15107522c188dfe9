"""The simulated robot's moving parts (vaultbot_sim/body.py, arm.py) with a stand-in for pybullet's contact
query: how touches are counted, and how the arms' motors track, stop and protective-stop. The real collision
world and the processes are in test_vaultbot_base.py and test_vaultbot_arms.py."""
import math
import time

import pytest

from vaultbot_sim.arm import ACCEL, SPEED, ArmPlant, JointRange
from vaultbot_sim.base import BasePlant, wheel_speeds
from vaultbot_sim.body import CONTACT_MARGIN, Body
from vaultbot_sim.ticks import Ticks

JOINTS = ['j1', 'j2']
RANGES = {j: JointRange(-2 * math.pi, 2 * math.pi) for j in JOINTS}


class Walls:
    """A wall at x = ``wall`` in front of the base; and, for the arm, a table that j1 touches beyond ``table``."""

    def __init__(self, wall=1.0, table=math.inf):
        self.wall, self.table, self.cfg = wall, table, {}

    def set_robot(self, cfg):
        self.cfg = dict(cfg)

    def contacts(self, margin=0.0):
        out = []
        if self.wall - self.cfg.get('base_x', 0.0) <= margin:
            out.append(('chassis_link', 'wall', self.wall - self.cfg['base_x']))
        if self.table - self.cfg.get('j1', 0.0) <= margin:
            out.append(('forearm_link', 'table', self.table - self.cfg['j1']))
        return out


def body(collider, start=0.0):
    return Body(collider, BasePlant(pose=(start, 0.0, 0.0)),
                {'arm': ArmPlant(JOINTS, {'j1': 0.0, 'j2': 0.0}, RANGES)})


def run(b, seconds, t0, base=None, arm=None, dt=0.02):
    """Step for ``seconds`` from ``t0`` with a fresh command each step; the time reached."""
    t = t0
    for _ in range(int(round(seconds / dt))):
        t += dt
        if base is not None:
            b.command_base(*wheel_speeds(base, 0.0), t)
        if arm is not None:
            b.command_arm('arm', arm, t)
        b.step(t, {'j1': 0.0, 'j2': 0.0})
    return t


def test_a_slow_push_against_a_wall_is_one_contact_and_a_new_approach_another():
    """Slowly, the base comes within the margin before it overlaps: that must not hide the touch."""
    b = body(Walls(wall=1.0), start=1.0 - 5 * CONTACT_MARGIN)
    t = run(b, 3.0, 0.0, base=0.05)
    assert b.contacts == 1 and b.base.pose[0] <= 1.0
    t = run(b, 3.0, t, base=-0.1)
    assert b.base.pose[0] < 1.0 - 2 * CONTACT_MARGIN, 'backed away, clear of the margin'
    run(b, 4.0, t, base=0.1)
    assert b.contacts == 2


def test_a_fast_push_against_a_wall_is_one_contact():
    """At top speed a step covers 2 cm, twice the margin: the base must stop where it touched, not a step short,
    or each push from rest would count a new touch."""
    b = body(Walls(wall=1.0), start=0.0)
    run(b, 4.0, 0.0, base=1.0)
    assert b.contacts == 1 and 1.0 - CONTACT_MARGIN < b.base.pose[0] <= 1.0


def test_an_arm_tracks_its_setpoint_within_its_limits_and_holds_when_the_stream_stops():
    b = body(Walls(wall=100.0))
    t = run(b, 2.0, 0.0, arm={'j1': (1.0, 0.0), 'j2': (-0.5, 0.0)})
    arm = b.arms['arm']
    assert arm.position['j1'] == pytest.approx(1.0, abs=1e-3) and arm.position['j2'] == pytest.approx(-0.5, abs=1e-3)
    arm.velocity['j1'] = SPEED
    b.command_arm('arm', {'j1': (5.0, SPEED), 'j2': (-0.5, 0.0)}, t)
    assert b.drop_stale(t + 0.041) == ['arm'] and arm.setpoint is None
    peak = arm.velocity['j1']
    run(b, 1.0, t + 0.041)
    assert arm.at_rest and peak / ACCEL <= 0.4 + 1e-9, 'braked to a hold at its limit'


def test_a_setpoint_that_stops_a_moving_arm_says_so_for_its_moment_to_be_published():
    b = body(Walls(wall=100.0))
    assert not b.command_arm('arm', {'j1': (0.0, 0.0), 'j2': (0.0, 0.0)}, 0.0)        # not moving: nothing stops
    assert not b.command_arm('arm', {'j1': (1.0, 0.5), 'j2': (0.0, 0.0)}, 0.01)
    assert b.command_arm('arm', {'j1': (0.3, 0.0), 'j2': (0.0, 0.0)}, 0.02)           # the hold's moment
    assert not b.command_arm('arm', {'j1': (0.3, 0.0), 'j2': (0.0, 0.0)}, 0.03)       # held already


def test_an_arm_that_touches_the_world_is_put_back_and_its_setpoint_dropped():
    b = body(Walls(wall=100.0, table=0.5))
    run(b, 2.0, 0.0, arm={'j1': (1.0, 0.0), 'j2': (0.0, 0.0)})
    arm = b.arms['arm']
    assert arm.position['j1'] < 0.5 and arm.at_rest and arm.setpoint is None and b.contacts == 1


def test_a_setpoint_must_name_every_joint_of_the_arm_with_finite_values():
    plant = ArmPlant(JOINTS, {'j1': 0.0, 'j2': 0.0}, RANGES)
    with pytest.raises(ValueError, match='no setpoint for j2'):
        plant.command({'j1': (0.0, 0.0)}, 0.0)
    with pytest.raises(ValueError, match='not joints of this arm: j3'):
        plant.command({'j1': (0.0, 0.0), 'j2': (0.0, 0.0), 'j3': (0.0, 0.0)}, 0.0)
    with pytest.raises(ValueError, match='finite'):
        plant.command({'j1': (math.nan, 0.0), 'j2': (0.0, 0.0)}, 0.0)
    assert plant.setpoint is None and not plant.held, 'a refused command changed nothing'


def test_a_setpoint_sent_before_the_arm_was_given_back_takes_nothing():
    """A controller switched off gives its arm back by a service; a setpoint it stamped before that, still on
    its topic, must not take the arm again (the sweep would stop for good)."""
    plant = ArmPlant(JOINTS, {'j1': 0.0, 'j2': 0.0}, RANGES)
    assert plant.command({'j1': (0.5, 0.1), 'j2': (0.0, 0.0)}, 1.0, sent=100.0) and plant.held
    plant.release(sent=100.5)
    assert not plant.command({'j1': (0.6, 0.1), 'j2': (0.0, 0.0)}, 1.1, sent=100.4)
    assert not plant.held and plant.setpoint is None, 'a stale setpoint took the arm'
    assert plant.command({'j1': (0.6, 0.1), 'j2': (0.0, 0.0)}, 1.2, sent=100.6) and plant.held
    plant.release()                        # a give-back with no moment keeps the last one
    assert plant.released_at == 100.5
    assert plant.command({'j1': (0.6, 0.1), 'j2': (0.0, 0.0)}, 1.3) and plant.held, 'unstamped: taken'


def test_ticks_wake_early_for_a_deadline_and_keep_their_rhythm():
    ticks = Ticks(0.5)                     # long enough that no machine is late by a whole tick here
    t0 = ticks.next
    ticks.wait(wake_by=t0 + 0.01)          # a deadline before the tick: woken for it, the tick still to come
    assert ticks.next == t0 and time.monotonic() >= t0 + 0.01
    ticks.wait()
    assert ticks.next == pytest.approx(t0 + 0.5) and time.monotonic() >= t0 + 0.5
    ticks.next -= 5.0                      # ten ticks late: started again from now, no burst of ticks
    ticks.wait()
    assert 0.0 <= time.monotonic() - ticks.next < 0.5
