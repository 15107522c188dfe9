# The fixtures (ros_master, procs, rospy_client, ...) come from temoto_testing.pytest_plugin, which pytest
# loads through its pytest11 entry point (setup.py) in every environment where TeMoto is installed.

import pytest

from temoto_action_engine.grounding import Grounder
from temoto_action_engine.indexer import ActionIndex
from temoto_robot_manager.interface import RobotManagerInterface
from temoto_testing import made_interfaces
from temoto_testing.sensor_manager import managers_idle

ROBOT_STACK = ('temoto_robot_manager', 'temoto_sensor_manager', 'temoto_er_manager')


@pytest.fixture
def rmi(stack):
    """Robot Manager interfaces, over the module's own ``stack`` fixture (the sim and the three managers); after
    the test, every registrar of the stack is idle again."""
    with made_interfaces(RobotManagerInterface) as make:
        yield make
    managers_idle(ROBOT_STACK, timeout=30)


@pytest.fixture(scope='module')
def index():
    """The bundled actions, indexed without a problem."""
    idx = ActionIndex([]).reindex()
    assert idx.problems == []
    return idx


@pytest.fixture(scope='module')
def grounder(index):
    """A grounder of the bundled actions."""
    return Grounder(index.descriptors())
