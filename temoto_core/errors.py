"""TeMoto errors: one exception type that carries an error stack across processes.

A load or unload callback signals failure by raising :class:`TemotoError`. The
registrar sends its stack back in the response (``trr.error_stack``), and the
client side raises it again with one more frame, so the action at the top of a
dependency chain sees where the failure started and every hop it took.
"""
import enum
import time
from typing import Iterable, List, Optional, Sequence

import rospy

from temoto_core.msg import Error


class ErrorCode(enum.IntEnum):
    UNSPECIFIED = 0
    RR_FAIL = 1                 # the registrar itself could not do what was asked
    SERVICE_REQ_FAIL = 2        # a service call failed: no such server, or it died
    RESOURCE_NOT_FOUND = 3      # unknown or already-unloaded resource id
    RESOURCE_UNLOAD_FAIL = 4
    RESOURCE_FAILED = 5         # a resource failed while loading or while held
    BAD_REQUEST = 6             # a field of a request is malformed or not allowed
    UNKNOWN_SERVER = 7
    NESTED_CALL = 8             # a registrar asked itself for a resource
    LOAD_CALLBACK = 9           # a load callback raised something other than TemotoError
    PROCESS_STOPPED = 10
    PACKAGE_NOT_FOUND = 11
    EXECUTABLE_NOT_FOUND = 12
    NOT_ALLOWED = 13            # refused by an allowlist
    SENSOR_NOT_FOUND = 14
    NO_TRACKERS_FOUND = 15
    TIMEOUT = 16
    DISPLAY_FAIL = 17
    ACTION_FAIL = 18
    SHUTDOWN = 19
    NAME_TAKEN = 20             # a node name that a live node (or another managed process) already has
    RECOVERING = 21             # a registrar still taking its registry back after a restart: ask again
    ROBOT_NOT_FOUND = 22        # no described robot has what was asked


class Subsystem(enum.IntEnum):
    CORE = 0
    ER_MANAGER = 1
    SENSOR_MANAGER = 2
    OUTPUT_MANAGER = 3
    CONTEXT_MANAGER = 4
    ACTION_ENGINE = 5
    SIMULATION = 6
    ROBOT_MANAGER = 7


class ErrorFrame:
    """One frame of a stack; converts to and from ``temoto_core/Error``."""
    __slots__ = ('code', 'subsystem', 'urgency', 'prefix', 'message', 'stamp')

    def __init__(self, code: int, subsystem: int, message: str, prefix: str = '', urgency: int = 0,
                 stamp: Optional[float] = None) -> None:
        self.code = int(code)
        self.subsystem = int(subsystem)
        self.urgency = int(urgency)
        self.prefix = prefix
        self.message = message
        self.stamp = stamp if stamp is not None else _now()

    def to_msg(self):
        return Error(code=self.code, subsystem=self.subsystem, urgency=self.urgency, prefix=self.prefix,
                     message=self.message, stamp=rospy.Time.from_sec(self.stamp))

    @classmethod
    def from_msg(cls, msg) -> 'ErrorFrame':
        return cls(msg.code, msg.subsystem, msg.message, msg.prefix, msg.urgency, msg.stamp.to_sec())

    def __repr__(self) -> str:
        return 'ErrorFrame(%s, %s, %r)' % (_name(ErrorCode, self.code), _name(Subsystem, self.subsystem), self.message)


class TemotoError(Exception):
    """An error with a code, a subsystem, a message and the stack it travelled."""

    def __init__(self, code: int, subsystem: int, message: str, stack: Sequence[ErrorFrame] = (),
                 prefix: str = '') -> None:
        super().__init__(message)
        self.code = int(code)
        self.subsystem = int(subsystem)
        self.message = message
        # the newest frame is last; the first frame is where the failure started
        self.stack: List[ErrorFrame] = list(stack) or [ErrorFrame(code, subsystem, message, prefix)]

    def extended(self, code: int, subsystem: int, message: str, prefix: str = '') -> 'TemotoError':
        """A new error for the next hop up, keeping this stack beneath it."""
        return TemotoError(code, subsystem, message, self.stack + [ErrorFrame(code, subsystem, message, prefix)])

    def to_msgs(self) -> list:
        return [f.to_msg() for f in self.stack]

    @classmethod
    def from_msgs(cls, msgs: Iterable, fallback_message: str = '', code: int = ErrorCode.UNSPECIFIED,
                  subsystem: int = Subsystem.CORE) -> 'TemotoError':
        frames = [ErrorFrame.from_msg(m) for m in msgs]
        if not frames:
            return cls(code, subsystem, fallback_message or 'failed without an error stack')
        top = frames[-1]
        return cls(top.code, top.subsystem, fallback_message or top.message, frames)

    @property
    def origin(self) -> ErrorFrame:
        return self.stack[0]

    def __str__(self) -> str:
        """What failed here, then where it started, once; then the hops in between, newest first."""
        if len(self.stack) <= 1:
            return self.message
        text = '%s: %s' % (self.message, self.stack[0].message)
        middle = [f.message for f in reversed(self.stack[1:-1]) if f.message != self.message]
        if middle:
            text += ' (through: %s)' % ' <- '.join(middle)
        return text

    def __repr__(self) -> str:
        return 'TemotoError(%s, %s, %r, %d frames)' % (_name(ErrorCode, self.code), _name(Subsystem, self.subsystem),
                                                       self.message, len(self.stack))


def _name(enum_cls, value: int) -> str:
    try:
        return enum_cls(value).name
    except ValueError:
        return str(value)


def _now() -> float:
    return time.time()
