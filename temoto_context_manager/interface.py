"""ContextManagerInterface: trackers and tracked objects for actions, with the sensor interface's policy hooks.

Default failure policy (``ManagerInterface``): unload the failed resource and ask
again with the same request; the ranking then prefers another tracker or
detection method. ``register_update_callback(cb)`` replaces it.
"""
import dataclasses
from typing import Callable, Dict, Optional, Sequence

from diagnostic_msgs.msg import KeyValue

from temoto_core.errors import Subsystem
from temoto_core.interface import ManagerInterface
from temoto_core.rr import StatusEvent
from temoto_context_manager.contract import (LOAD_TRACKER, LOAD_TRACKER_TYPE, RR_NAME, TRACK_OBJECT,
                                             TRACK_OBJECT_TYPE)


@dataclasses.dataclass(frozen=True)
class TrackerResult:
    resource_id: int
    tracker_name: str
    pipe_id: str
    output_topics: Dict[str, str]


@dataclasses.dataclass(frozen=True)
class TrackedObject:
    resource_id: int
    object_name: str
    topic: str                 # geometry_msgs/PoseStamped
    detection_method: str
    tracker_name: str
    pipe_id: str


class ContextManagerInterface(ManagerInterface):
    MANAGER = RR_NAME
    SUBSYSTEM = Subsystem.CONTEXT_MANAGER

    def load_tracker(self, category: str, output_types: Sequence[str] = (),
                     on_status: Optional[Callable[[StatusEvent], None]] = None) -> TrackerResult:
        """Start the best tracker of ``category``; ``on_status`` is this request's failure policy."""
        resp = self._load(LOAD_TRACKER, LOAD_TRACKER_TYPE._request_class(
            tracker_category=category, output_topics=[KeyValue(t, '') for t in output_types]), on_status)
        return TrackerResult(resp.trr.resource_id, resp.tracker_name, resp.pipe_id,
                             {kv.key: kv.value for kv in resp.output_topics})

    def track_object(self, object_name: str,
                     on_status: Optional[Callable[[StatusEvent], None]] = None) -> TrackedObject:
        """Start tracking a known object; returns once poses flow on ``topic``.

        ``on_status``: this request's failure policy (a failure anywhere below, down to the camera's
        driver, reaches it as FAILED).
        """
        resp = self._load(TRACK_OBJECT, TRACK_OBJECT_TYPE._request_class(object_name=object_name), on_status)
        return TrackedObject(resp.trr.resource_id, resp.object_name, resp.object_topic, resp.detection_method,
                             resp.tracker_name, resp.pipe_id)

    def stop(self, resource_id: int) -> None:
        """Release a tracker or a tracked object loaded through this interface."""
        self._unload(resource_id)

    def holds_ids(self) -> Optional[list]:
        with self._lock:
            return list(self._requests)
