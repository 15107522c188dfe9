"""The shipped control_msgs are upstream's, type for type: the md5sums of what tools/gen_msgs.py generated equal
those of the modules catkin generates from control_msgs 1.5.2 (as rosserial's ros_lib records them), so a real
FollowJointTrajectory or GripperCommand client talks to the simulated arms unchanged."""
import pytest

import control_msgs.msg

UPSTREAM_MD5 = {
    'FollowJointTrajectoryAction': 'bc4f9b743838566551c0390c65f1a248',
    'FollowJointTrajectoryActionGoal': 'cff5c1d533bf2f82dd0138d57f4304bb',
    'FollowJointTrajectoryGoal': '69636787b6ecbde4d61d711979bc7ecb',
    'FollowJointTrajectoryResult': '493383b18409bfb604b4e26c676401d2',
    'GripperCommandAction': '950b2a6ebe831f5d4f4ceaba3d8be01e',
    'GripperCommandActionGoal': 'aa581f648a35ed681db2ec0bf7a82bea',
    'JointTrajectoryGoal': '2a0eff76c870e8595636c2a562ca298e',
}


@pytest.mark.parametrize('name', sorted(UPSTREAM_MD5))
def test_the_md5sum_is_upstreams(name):
    cls = getattr(control_msgs.msg, name)
    assert cls._type == 'control_msgs/' + name and cls._md5sum == UPSTREAM_MD5[name]


def test_every_action_has_its_seven_messages():
    for action in ('FollowJointTrajectory', 'GripperCommand', 'JointTrajectory', 'PointHead', 'SingleJointPosition'):
        for suffix in ('Action', 'ActionGoal', 'ActionResult', 'ActionFeedback', 'Goal', 'Result', 'Feedback'):
            assert hasattr(control_msgs.msg, action + suffix), action + suffix
