"""RobotManagerInterface: load a described robot with the features an action needs.

Default failure policy (``ManagerInterface``): unload the failed robot and ask again with the same
request; the ranking then prefers another robot or another obstacle source. A motion action states
its own policy instead (``on_status=``): a robot that failed must stop what it moves, not reload
silently under it.
"""
import dataclasses
import json
from typing import Callable, Dict, List, Optional, Sequence

import rospy

from temoto_core.errors import Subsystem
from temoto_core.interface import ManagerInterface
from temoto_core.rr import StatusEvent
from temoto_core.rr.deadlines import call_once
from temoto_core.srv import GetRegistry
from temoto_robot_manager.contract import LOAD_ROBOT, LOAD_ROBOT_TYPE, ROBOTS, RR_NAME

INFO_TIMEOUT_S = 5.0


@dataclasses.dataclass(frozen=True)
class LoadedRobot:
    resource_id: int
    robot_name: str
    features: tuple
    parts: Dict[str, str]       # feature.part -> what serves it


class RobotManagerInterface(ManagerInterface):
    MANAGER = RR_NAME
    SUBSYSTEM = Subsystem.ROBOT_MANAGER

    def load_robot(self, features: Sequence[str] = (), robot_name: str = '',
                   on_status: Optional[Callable[[StatusEvent], None]] = None) -> LoadedRobot:
        """Load ``robot_name`` (or the most reliable robot with ``features``); returns once every part runs."""
        resp = self._load(LOAD_ROBOT, LOAD_ROBOT_TYPE._request_class(robot_name=robot_name, features=list(features)),
                          on_status)
        return LoadedRobot(resp.trr.resource_id, resp.robot_name, tuple(resp.features),
                           {kv.key: kv.value for kv in resp.parts})

    def release(self, resource_id: int) -> None:
        """Release a robot loaded through this interface: its parts stop unless someone else holds them."""
        self._unload(resource_id)

    def robots(self, timeout: float = INFO_TIMEOUT_S) -> List[dict]:
        """The described robots as the manager serves them (``temoto robots``): features, places, arms and
        their frames, the gripper, the ROS namespace of their topics. Raises ``ConnectionError`` (an
        ``OSError``) when the manager does not answer in time, ``ValueError`` on a reply that is not JSON.

        rospy's ``ServiceException`` is not a ``ROSException``: raised as it came, a stopped manager escaped
        callers that catch what this said it raises (chaos, history 5: a navigate while it was SIGSTOPped)."""
        namespace = (self.namespace or self.rr.namespace).strip('/')
        service = '/%s/%s/%s' % (namespace, RR_NAME, ROBOTS)
        try:
            reply = call_once(service, GetRegistry, GetRegistry._request_class(), timeout)
        except (rospy.ServiceException, rospy.ROSException) as err:
            raise ConnectionError('the Robot Manager does not answer on %s: %s' % (service, err)) from err
        return list(json.loads(reply.json)['robots'])

    def robot_with(self, feature: str, robot_name: str = '', timeout: float = INFO_TIMEOUT_S) -> dict:
        """The robot ``robot_name`` (or the first) that has ``feature``; ``LookupError`` naming what exists."""
        robots = [r for r in self.robots(timeout) if feature in r['features']]
        found = next((r for r in robots if r['name'] == robot_name or not robot_name), None)
        if found is None:
            raise LookupError('no robot %s with %s (described with it: %s)'
                              % (robot_name or 'at all', feature, ', '.join(r['name'] for r in robots) or 'none'))
        return found
