"""A robot's named places checked against a map, before anything drives: a place where the robot's outline does
not fit is a goal that can only fail, found by the operator mid-task. No ROS.

Each place is checked as the navigator checks a goal (:meth:`navigator.Navigator.check`): inside the map, not in
an obstacle, and the whole outline (footprint and protrusions) at the place's heading clear of the map's obstacles
by more than the collision monitor's stop margin.
"""
from __future__ import annotations

import math
from typing import List

from temoto_core.map_file import MapGrid
from temoto_robot_manager.navigation.costmap import Costmap
from temoto_robot_manager.description import Navigation
from temoto_robot_manager.navigation.navigator import BadGoal, described


def places_off_map(navigation: Navigation, grid: MapGrid) -> List[str]:
    """One problem for each place the robot cannot stand on in ``grid``, as ``file:line: place NAME: why``."""
    nav = described(navigation)
    width, height = grid.size
    nav.set_map(Costmap.from_grid(grid.origin, grid.resolution, width, height, grid.cells.ravel(), nav.footprint))
    problems = []
    for name, (x, y, yaw) in sorted(navigation.places.items()):
        try:
            nav.check(x, y, (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)), field='places.%s' % name)
        except BadGoal as err:
            problems.append('%s: place %s: %s' % (navigation.place_sources.get(name, '?'), name, err))
    return problems
