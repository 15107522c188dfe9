"""What a status callback receives."""
import dataclasses
from typing import List

from temoto_core.errors import ErrorFrame


@dataclasses.dataclass(frozen=True)
class StatusEvent:
    """A status for one resource, addressed by the receiver's own local id."""
    resource_id: int              # the receiving registrar's local id
    code: int                     # ResourceStatus.FAILED / UPDATE
    message: str
    error_stack: List[ErrorFrame]
    rr_name: str                  # the registrar that sent it (the resource's owner)
    server_name: str
    namespace: str
    stamp: float                  # when the owner sent it (ROS time, seconds)

    @property
    def failed(self) -> bool:
        return self.code == 1
