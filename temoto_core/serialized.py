"""Fields of a serialised ROS message, read without deserialising it.

A megabyte cloud costs milliseconds to deserialise; a consumer that only needs to know when it was taken (a
freshness rule, a watch) reads its header's stamp from the bytes rospy received (``rospy.AnyMsg._buff``).
"""
from __future__ import annotations

import struct
from typing import Optional

# a message that begins with a std_msgs/Header (a LaserScan, a PointCloud2), serialised: seq, then the stamp
_HEADER_STAMP = struct.Struct('<II')


def header_stamp(buff: Optional[bytes]) -> Optional[float]:
    """The header stamp (s) of a serialised message that begins with a ``std_msgs/Header``, read without
    deserialising the rest; None when there is none (too short, or zero)."""
    if buff is None or len(buff) < 4 + _HEADER_STAMP.size:
        return None
    secs, nsecs = _HEADER_STAMP.unpack_from(buff, 4)
    return secs + nsecs * 1e-9 if secs or nsecs else None
