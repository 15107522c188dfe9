"""What a status callback receives: one typed event per status, never a bare wire integer."""
import dataclasses
import enum
from typing import List

from temoto_core.errors import ErrorFrame
from temoto_core.msg import ResourceStatus


class Status(enum.IntEnum):
    """A resource's state as its owner reports it (the wire's ``ResourceStatus`` constants, named).

    An IntEnum, so code that compares with ``ResourceStatus.FAILED`` keeps working.
    """
    OK = ResourceStatus.OK
    FAILED = ResourceStatus.FAILED
    UPDATE = ResourceStatus.UPDATE


@dataclasses.dataclass(frozen=True)
class StatusEvent:
    """A status for one resource, addressed by the receiver's own local id."""
    resource_id: int              # the receiving registrar's local id
    code: Status
    message: str
    error_stack: List[ErrorFrame]
    rr_name: str                  # the registrar that sent it (the resource's owner)
    server_name: str
    namespace: str
    stamp: float                  # when the owner sent it (ROS time, seconds)

    def __post_init__(self) -> None:
        object.__setattr__(self, 'code', Status(self.code))

    @property
    def failed(self) -> bool:
        return self.code == Status.FAILED

    @property
    def origin(self) -> str:
        """Where the failure started: the first frame of the stack (or this event's own message)."""
        return self.error_stack[0].message if self.error_stack else self.message
