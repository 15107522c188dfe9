"""Which displays exist: the abstract TeMoto display types and the RViz classes.

RViz itself accepts any class name and silently creates a placeholder display
for an unknown one, so every name is validated here first.
"""
from __future__ import annotations

import re
from typing import Any, Dict, FrozenSet, Optional

#: The original's type table plus `point cloud`, `tf` and the types that the bundled actions and trackers
#: produce (poses, marker arrays, odometry).
#: Types whose RViz plugins are not packaged for Debian (camera sphere, MoveIt) are left out.
ABSTRACT_TYPES: Dict[str, str] = {
    'point cloud': 'rviz/PointCloud2',
    'depth image': 'rviz/PointCloud2',
    'laser scan': 'rviz/LaserScan',
    'image': 'rviz/Image',
    'robot_model': 'rviz/RobotModel',
    'marker': 'rviz/Marker',
    'marker array': 'rviz/MarkerArray',
    'path': 'rviz/Path',
    'pose': 'rviz/Pose',
    'pose stamped': 'rviz/Pose',
    'pose array': 'rviz/PoseArray',
    'point stamped': 'rviz/PointStamped',
    'odometry': 'rviz/Odometry',
    'tf': 'rviz/TF',
}

#: Properties the Output Manager sets unless a request's config says otherwise. RViz draws a PointCloud2 as
#: "Flat Squares" by default, a camera-facing quad per point: with Mesa's llvmpipe that took a whole core for
#: a 424x240 cloud at 30 Hz; as 3-pixel points it takes about 55 % (bench/bench_output.py).
DEFAULT_CONFIG: Dict[str, Dict[str, Any]] = {
    'rviz/PointCloud2': {'Style': 'Points', 'Size (Pixels)': 3},
}

#: The display classes declared by Debian's rviz 1.14 (/usr/share/rviz/plugin_description.xml).
DEFAULT_RVIZ_CLASSES: FrozenSet[str] = frozenset(
    'rviz/' + n for n in (
        'Axes DepthCloud Effort FluidPressure Grid GridCells Illuminance Image InteractiveMarkers LaserScan Map '
        'Marker MarkerArray Odometry Path PointStamped PointCloud PointCloud2 Polygon Pose PoseArray '
        'PoseWithCovariance Range RelativeHumidity RobotModel Camera Temperature TF AccelStamped TwistStamped '
        'WrenchStamped').split())

PLUGIN_DESCRIPTION = '/usr/share/rviz/plugin_description.xml'

#: The property that holds a class's input topic (the GUI label). Classes that
#: are not listed use 'Topic'; None means the class takes no topic.
TOPIC_PROPERTY: Dict[str, Optional[str]] = {
    'rviz/Image': 'Image Topic',
    'rviz/Camera': 'Image Topic',
    'rviz/DepthCloud': 'Depth Map Topic',
    'rviz/Marker': 'Marker Topic',
    'rviz/MarkerArray': 'Marker Topic',
    'rviz/InteractiveMarkers': 'Update Topic',
    'rviz/RobotModel': None,
    'rviz/TF': None,
    'rviz/Grid': None,
    'rviz/Axes': None,
}

#: Message type each topic-taking class subscribes to; used to refuse a topic
#: that carries another type (RViz would subscribe and show nothing).
MESSAGE_TYPE: Dict[str, str] = {
    'rviz/PointCloud2': 'sensor_msgs/PointCloud2',
    'rviz/PointCloud': 'sensor_msgs/PointCloud',
    'rviz/LaserScan': 'sensor_msgs/LaserScan',
    'rviz/Image': 'sensor_msgs/Image',
    'rviz/Camera': 'sensor_msgs/Image',
    'rviz/DepthCloud': 'sensor_msgs/Image',
    'rviz/Marker': 'visualization_msgs/Marker',
    'rviz/MarkerArray': 'visualization_msgs/MarkerArray',
    'rviz/Path': 'nav_msgs/Path',
    'rviz/Odometry': 'nav_msgs/Odometry',
    'rviz/Map': 'nav_msgs/OccupancyGrid',
    'rviz/GridCells': 'nav_msgs/GridCells',
    'rviz/Pose': 'geometry_msgs/PoseStamped',
    'rviz/PoseArray': 'geometry_msgs/PoseArray',
    'rviz/PoseWithCovariance': 'geometry_msgs/PoseWithCovarianceStamped',
    'rviz/PointStamped': 'geometry_msgs/PointStamped',
    'rviz/Polygon': 'geometry_msgs/PolygonStamped',
    'rviz/Range': 'sensor_msgs/Range',
}


#: Classes whose status line carries no message count: "first frame drawn" uses a probe subscriber.
PROBED_CLASSES: FrozenSet[str] = frozenset({'rviz/Marker', 'rviz/MarkerArray', 'rviz/DepthCloud',
                                            'rviz/InteractiveMarkers'})


class UnknownDisplayType(ValueError):
    """An abstract type or RViz class name that is not known."""


def installed_rviz_classes(path: str = PLUGIN_DESCRIPTION) -> FrozenSet[str]:
    """Display classes declared by the installed rviz; the built-in list when unreadable."""
    try:
        with open(path, encoding='utf-8') as f:
            text = f.read()
    except OSError:
        return DEFAULT_RVIZ_CLASSES
    found = re.findall(r'<class\s+name="([^"]+)"[^>]*base_class_type="rviz::Display"', text)
    return frozenset(found) or DEFAULT_RVIZ_CLASSES


def rviz_class_for(display_type: str) -> str:
    """Map an abstract TeMoto display type to its RViz class, or raise with the known types."""
    key = display_type.strip().lower().replace('_', ' ')
    for name, cls in ABSTRACT_TYPES.items():
        if name.replace('_', ' ') == key:
            return cls
    raise UnknownDisplayType("unknown display type '%s'; known types: %s"
                             % (display_type, ', '.join(sorted(ABSTRACT_TYPES))))


def check_rviz_class(cls: str, known: FrozenSet[str]) -> str:
    if cls not in known:
        raise UnknownDisplayType("unknown RViz display class '%s'; known classes: %s"
                                 % (cls, ', '.join(sorted(known))))
    return cls


def topic_property(cls: str) -> Optional[str]:
    return TOPIC_PROPERTY.get(cls, 'Topic')


def needs_topic(cls: str) -> bool:
    return topic_property(cls) is not None


def check_topic_name(topic: str) -> str:
    """A ROS graph resource name, as RViz needs it (no spaces, no '~')."""
    if not re.fullmatch(r'/?[A-Za-z][A-Za-z0-9_/]*', topic) or '//' in topic:
        raise ValueError("invalid topic name '%s'" % topic)
    return topic
