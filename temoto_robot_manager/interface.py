"""RobotManagerInterface: load a described robot with the features an action needs.

Default failure policy (``ManagerInterface``): unload the failed robot and ask again with the same
request; the ranking then prefers another robot or another obstacle source. A motion action states
its own policy instead (``on_status=``): a robot that failed must stop what it moves, not reload
silently under it.
"""
import dataclasses
from typing import Callable, Dict, Optional, Sequence

from temoto_core.errors import Subsystem
from temoto_core.interface import ManagerInterface
from temoto_core.rr import StatusEvent
from temoto_robot_manager.contract import LOAD_ROBOT, LOAD_ROBOT_TYPE, RR_NAME


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
