"""The Robot Manager's obstacle fail-back, the rule alone (``obstacle_failover.py``): a better source that works
again is taken back after its hold; one that does not start waits longer each time; one that fails within its
hold is let go, and quarantined after flapping. Across processes: ``tests/test_robot_navigation.py``."""
import threading

import pytest

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_robot_manager.description import ObstacleSource
from temoto_robot_manager.obstacle_failover import Failback, ObstacleFailover
from temoto_testing import wait_for

SICK = ObstacleSource('base LIDAR scan', 'lidar', 'lidar_data', 'vaultbot_sim', 'sick_driver')
HOKUYO = ObstacleSource('arm LIDAR stitched cloud', 'lidar', 'cloud_data', '', '')
FAST = Failback(check_s=0.05, max_s=0.2, hold_s=0.3, quarantine_after=2, quarantine_s=60.0, period_s=0.02)


class Devices:
    """Sensors that start or not, as a test says; what was started, released, told and announced."""

    def __init__(self):
        self.lock = threading.Lock()
        self.working = {SICK.label: True, HOKUYO.label: True}
        self.next_id = 1
        self.running = {}                    # local id -> label
        self.released, self.told, self.announced = [], [], []

    def start(self, source):
        with self.lock:
            if not self.working[source.label]:
                raise TemotoError(ErrorCode.TIMEOUT, Subsystem.ROBOT_MANAGER, '%s does not start' % source.label)
            local_id, self.next_id = self.next_id, self.next_id + 1
            self.running[local_id] = source.label
            return local_id, source.label.split()[0], '/%s' % source.output_topic

    def release(self, local_id):
        with self.lock:
            self.released.append(self.running.pop(local_id))

    def id_of(self, label):
        with self.lock:
            return next(i for i, name in self.running.items() if name == label)


@pytest.fixture
def world():
    devices = Devices()
    failover = ObstacleFailover(devices.start, devices.release, lambda load, code, text: devices.told.append(
        (code, text)), lambda load, served: devices.announced.append(served.source.label),
        Subsystem.ROBOT_MANAGER, lambda text: None, FAST)
    yield devices, failover
    failover.close()


def on_the_arm_lidar_with_the_sick_working_again(devices, failover):
    """A load on the SICK, failed over to the arm LIDAR by a stall; then the SICK starts again."""
    failover.take(1, 'vaultbot', (SICK, HOKUYO))
    devices.working[SICK.label] = False
    failover.failed(devices.id_of(SICK.label), 'stalled')
    wait_for(lambda: devices.announced[-1:] == [HOKUYO.label], 5, 'the failover to the arm LIDAR')
    devices.working[SICK.label] = True


def test_a_source_that_works_again_is_taken_back_after_its_hold(world):
    devices, failover = world
    on_the_arm_lidar_with_the_sick_working_again(devices, failover)
    back = wait_for(lambda: next((t for c, t in devices.told if 'again' in t), None), 5, 'the SICK taken back')
    assert back.startswith('obstacles from base LIDAR scan') and devices.announced[-1] == SICK.label
    assert failover.served(1).source == SICK
    wait_for(lambda: HOKUYO.label in devices.released, 5, 'the arm LIDAR let go')
    assert sorted(devices.running.values()) == [SICK.label]


def test_a_source_that_fails_within_its_hold_is_let_go_and_quarantined_after_flapping(world):
    devices, failover = world
    on_the_arm_lidar_with_the_sick_working_again(devices, failover)
    for flap in range(FAST.quarantine_after):
        wait_for(lambda: SICK.label in devices.running.values(), 5, 'the SICK tried again (%d)' % flap)
        failover.failed(devices.id_of(SICK.label), 'stalled again')
    assert failover.served(1).source == HOKUYO and not any('again' in t for _, t in devices.told)
    assert SICK.label not in devices.running.values()
    served = failover.served(1)
    assert served.backoffs[SICK.label].quarantined           # 60 s out: no switch every moment
    assert [c for c, _ in devices.told] == [ResourceStatus.UPDATE, ResourceStatus.UPDATE]


def test_an_unloaded_robot_lets_go_of_a_source_in_its_hold(world):
    devices, failover = world
    on_the_arm_lidar_with_the_sick_working_again(devices, failover)
    wait_for(lambda: SICK.label in devices.running.values(), 5, 'the SICK back, in its hold')
    failover.release(1)
    assert devices.running == {}, 'a source left running for nobody'


def test_a_robot_s_second_load_is_announced_again_when_the_first_lets_go(world):
    """Two loads of one robot share its navigator (one request of the ER Manager); the navigator reads the last
    source announced. When that load lets go, the other's source is announced again, or the navigator would wait on
    a topic that nobody holds."""
    devices, failover = world
    failover.take(1, 'vaultbot', (SICK, HOKUYO))
    failover.take(2, 'vaultbot', (HOKUYO,))
    assert devices.announced == [SICK.label, HOKUYO.label]
    failover.release(2)
    assert devices.announced[-1] == SICK.label
