"""A map as ROS's map_server saves and serves it: a YAML file beside an image. No ROS.

The YAML says ``image`` (a path, relative to the YAML's folder), ``resolution`` (m a pixel), ``origin``
(``[x, y, yaw]`` of the image's lower-left pixel), ``negate``, ``occupied_thresh`` and ``free_thresh``. A pixel's
occupancy is ``(255 - value) / 255`` (``value / 255`` when negated): above ``occupied_thresh`` it is occupied,
below ``free_thresh`` free, between unknown (map_server's trinary mode). The image's top row is the map's far edge
(largest y), so it is flipped into a grid whose row 0 is at the origin, as ``nav_msgs/OccupancyGrid`` has it.

A map written here is what ``map_saver`` writes: occupied black (0), free white (254), unknown grey (205).
Images are read and written by Pillow (PGM, PNG, whatever it knows).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Tuple

import numpy as np
import yaml
from PIL import Image

OCCUPIED, FREE, UNKNOWN = 100, 0, -1
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.196        # map_saver's defaults


class MapError(ValueError):
    """A map file that cannot be read: the message names the file and the field."""


@dataclass(frozen=True)
class MapGrid:
    origin: Tuple[float, float]      # the corner of cell (0, 0) (m)
    resolution: float                # m a cell
    cells: np.ndarray                # int8, rows = y from the origin: 100 occupied, 0 free, -1 unknown

    @property
    def size(self) -> Tuple[int, int]:
        """(width, height) in cells."""
        return self.cells.shape[1], self.cells.shape[0]


def read(path: str) -> MapGrid:
    """The map of a map_server YAML file; raises :class:`MapError` naming the file and what is wrong."""
    try:
        with open(path) as f:
            raw = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as err:
        raise MapError('%s: %s' % (path, err)) from None
    if not isinstance(raw, dict):
        raise MapError('%s: a map file is a mapping with image, resolution and origin' % path)
    missing = [k for k in ('image', 'resolution', 'origin') if k not in raw]
    if missing:
        raise MapError('%s: missing %s' % (path, ', '.join(missing)))
    resolution = _number(path, raw, 'resolution')
    if resolution <= 0:
        raise MapError('%s: resolution must be above 0, not %r' % (path, resolution))
    origin = raw['origin']
    if not (isinstance(origin, list) and len(origin) == 3 and all(_finite(v) for v in origin)):
        raise MapError('%s: origin must be [x, y, yaw], three finite numbers, not %r' % (path, origin))
    if origin[2] != 0:
        raise MapError('%s: origin yaw %r: a rotated map is not supported (map_server ignores it too)'
                       % (path, origin[2]))
    occupied = _number(path, raw, 'occupied_thresh', OCCUPIED_THRESH)
    free = _number(path, raw, 'free_thresh', FREE_THRESH)
    if not 0 <= free < occupied <= 1:
        raise MapError('%s: free_thresh %r and occupied_thresh %r must be 0 <= free < occupied <= 1'
                       % (path, free, occupied))
    image = os.path.join(os.path.dirname(os.path.abspath(path)), str(raw['image']))
    try:
        with Image.open(image) as img:
            pixels = np.asarray(img.convert('L'), dtype=float) / 255.0
    except OSError as err:
        raise MapError('%s: image %s: %s' % (path, raw['image'], err)) from None
    p = pixels if raw.get('negate', 0) else 1.0 - pixels
    cells = np.full(p.shape, UNKNOWN, dtype=np.int8)
    cells[p > occupied] = OCCUPIED
    cells[p < free] = FREE
    return MapGrid((float(origin[0]), float(origin[1])), resolution, np.flipud(cells).copy())


def write(path: str, grid: MapGrid) -> str:
    """Write ``grid`` as map_saver does: ``path`` (YAML) and a PGM beside it; returns the image's path."""
    base = os.path.splitext(path)[0]
    image = base + '.pgm'
    pixels = np.full(grid.cells.shape, 205, dtype=np.uint8)
    pixels[grid.cells == FREE] = 254
    pixels[grid.cells >= 50] = 0
    Image.fromarray(np.flipud(pixels)).save(image)
    with open(path, 'w') as f:
        yaml.safe_dump({'image': os.path.basename(image), 'resolution': float(grid.resolution),
                        'origin': [float(grid.origin[0]), float(grid.origin[1]), 0.0], 'negate': 0,
                        'occupied_thresh': OCCUPIED_THRESH, 'free_thresh': FREE_THRESH}, f, sort_keys=False)
    return image


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _number(path: str, raw: dict, key: str, default: float = None) -> float:
    value = raw.get(key, default)
    if not _finite(value):
        raise MapError('%s: %s must be a finite number, not %r' % (path, key, value))
    return float(value)
