"""What the operator's scene draws of the robot's motion, as RViz markers: the base's footprint with its stop
zone, and the hand with the target it gives.

The stop zone is drawn as the collision monitor checks it (``collision_monitor.py``): the footprint grown by
the stop margin, at the pose the robot would reach on the current command before it could stop (the command's
latency plus its braking time). At rest it is the footprint plus the margin; driving, it reaches ahead, so the
operator sees what an obstacle must stay out of. The markers are plain messages; the nodes and actions that
know the state publish them.
"""
from __future__ import annotations

import math
from typing import Iterable, List, Optional, Sequence, Tuple

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from temoto_robot_manager.navigation.collision_monitor import MonitorSettings
from temoto_robot_manager.navigation.costmap import Footprint

FOOTPRINT_COLOUR = (0.1, 0.8, 0.2, 0.9)
STOP_ZONE_COLOUR = (0.9, 0.1, 0.1, 0.9)
HAND_COLOUR = (1.0, 0.6, 0.1, 0.9)
TARGET_COLOUR = (0.2, 0.4, 1.0, 0.9)
LINE_WIDTH = 0.02
HAND_SIZE = 0.06
TEXT_COLOUR = (1.0, 1.0, 1.0, 0.95)
TEXT_HEIGHT = 0.08


def _colour(rgba: Tuple[float, float, float, float]) -> ColorRGBA:
    return ColorRGBA(*rgba)


def _outline(boxes: Iterable[Tuple[float, float, float, float]], pose=(0.0, 0.0, 0.0)) -> List[Point]:
    """The boxes' sides as a LINE_LIST's point pairs, each box moved to ``pose`` (x, y, yaw) in the base frame."""
    x0, y0, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    points = []
    for bx0, bx1, by0, by1 in boxes:
        corners = [(bx0, by0), (bx1, by0), (bx1, by1), (bx0, by1)]
        moved = [Point(x0 + c * x - s * y, y0 + s * x + c * y, 0.02) for x, y in corners]
        for k in range(4):
            points += [moved[k], moved[(k + 1) % 4]]
    return points


def stop_pose(linear: float, angular: float, settings: MonitorSettings) -> Tuple[float, float, float]:
    """Where the base would be, from here, before a stop on (``linear``, ``angular``) takes hold: the latency at
    speed, then braking at the base's limits (constant deceleration)."""
    braking = max(abs(linear) / settings.decel, abs(angular) / settings.turn_decel)
    # the distance and turn covered: full speed over the latency, half of it (on average) over the braking
    dist = linear * (settings.latency + braking / 2)
    turn = angular * (settings.latency + braking / 2)
    if abs(turn) < 1e-6:
        return dist, 0.0, 0.0
    radius = dist / turn
    return radius * math.sin(turn), radius * (1 - math.cos(turn)), turn


def base_scene(footprint: Footprint, frame: str, linear: float, angular: float, stamp,
               settings: MonitorSettings = MonitorSettings(), ns: str = 'base') -> MarkerArray:
    """The footprint (green) and the stop zone on the current command (red), in the base's ``frame``."""
    grown = [(x0 - settings.stop_margin, x1 + settings.stop_margin, y0 - settings.stop_margin,
              y1 + settings.stop_margin) for x0, x1, y0, y1 in footprint.boxes]
    markers = []
    for mid, (what, points, colour) in enumerate((
            ('footprint', _outline(footprint.boxes), FOOTPRINT_COLOUR),
            ('stop zone', _outline(grown) + _outline(grown, stop_pose(linear, angular, settings)),
             STOP_ZONE_COLOUR))):
        m = Marker(type=Marker.LINE_LIST, action=Marker.ADD, ns='%s/%s' % (ns, what), id=mid)
        m.header.frame_id, m.header.stamp = frame, stamp
        m.pose.orientation.w = 1.0
        m.scale.x = LINE_WIDTH
        m.color = _colour(colour)
        m.points = points
        markers.append(m)
    return MarkerArray(markers=markers)


def gripper_text(gap: Optional[float], stalled: bool, reached: bool) -> str:
    """What the scene says of the gripper, from its controller's GripperCommand feedback or result."""
    if gap is None:
        return 'gripper: not heard from yet'
    if stalled and not reached:
        return 'gripper: holding (%.0f mm)' % (1e3 * gap)
    return 'gripper: %s %.0f mm' % ('open' if gap > 0.01 else 'closed', 1e3 * gap)


def hand_scene(frame: str, stamp, hand: Optional[Sequence[float]], target: Optional[Sequence[float]],
               ns: str = 'hand', gripper: str = '', tool: Optional[Sequence[float]] = None) -> MarkerArray:
    """The hand (orange: where the hand has moved since the grab, from the tool's anchor, unscaled) and the target
    it gives (blue: scaled by the dial), in the arm base's ``frame``; a point that is None is deleted (nothing
    is engaged)."""
    markers = []
    for mid, (what, at, colour) in enumerate((('hand', hand, HAND_COLOUR), ('target', target, TARGET_COLOUR))):
        m = Marker(type=Marker.SPHERE, ns='%s/%s' % (ns, what), id=mid)
        m.header.frame_id, m.header.stamp = frame, stamp
        if at is None or not np.all(np.isfinite(at)):
            m.action = Marker.DELETE
        else:
            m.action = Marker.ADD
            m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(v) for v in at[:3])
            m.pose.orientation.w = 1.0
            m.scale.x = m.scale.y = m.scale.z = HAND_SIZE
            m.color = _colour(colour)
        markers.append(m)
    if gripper:                            # the gripper's state, written above the tool
        m = Marker(type=Marker.TEXT_VIEW_FACING, action=Marker.ADD, ns='%s/gripper' % ns, id=2, text=gripper)
        m.header.frame_id, m.header.stamp = frame, stamp
        at = tool if tool is not None and np.all(np.isfinite(tool)) else (0.0, 0.0, 0.0)
        m.pose.position.x, m.pose.position.y, m.pose.position.z = float(at[0]), float(at[1]), float(at[2]) + 0.15
        m.pose.orientation.w = 1.0
        m.scale.z = TEXT_HEIGHT
        m.color = _colour(TEXT_COLOUR)
        markers.append(m)
    return MarkerArray(markers=markers)
