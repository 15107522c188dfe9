"""Frame the robot: an orbit view that shows the whole URDF at its zero pose.

The host has no TF listener of its own in Python, so it estimates the robot's
extent from the URDF alone: forward kinematics of the joint origins at zero
joint values, padded by each link's primitive geometry. Good enough to aim a
camera; RViz draws the real model.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

import numpy as np


@dataclass
class OrbitView:
    focal_point: Tuple[float, float, float] = (0.0, 0.0, 0.5)
    distance: float = 6.0
    yaw: float = 0.785      # looking from front-left
    pitch: float = 0.45


def _origin(elem) -> np.ndarray:
    T = np.eye(4)
    o = elem.find('origin') if elem is not None else None
    if o is None:
        return T
    xyz = [float(v) for v in o.get('xyz', '0 0 0').split()]
    r, p, y = [float(v) for v in o.get('rpy', '0 0 0').split()]
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    T[:3, :3] = [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                 [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                 [-sp, cp * sr, cp * cr]]
    T[:3, 3] = xyz
    return T


def _geometry_radius(link) -> float:
    r = 0.0
    for vis in link.findall('visual'):
        g = vis.find('geometry')
        if g is None:
            continue
        off = float(np.linalg.norm(_origin(vis)[:3, 3]))
        box, cyl, sph = g.find('box'), g.find('cylinder'), g.find('sphere')
        if box is not None:
            size = [float(v) for v in box.get('size', '0 0 0').split()]
            r = max(r, off + 0.5 * math.sqrt(sum(s * s for s in size)))
        elif cyl is not None:
            rad, length = float(cyl.get('radius', 0)), float(cyl.get('length', 0))
            r = max(r, off + math.hypot(rad, length / 2))
        elif sph is not None:
            r = max(r, off + float(sph.get('radius', 0)))
        else:
            r = max(r, off + 0.1)
    return r


def robot_view(urdf_xml: Optional[str], fixed_frame: str = 'base_link') -> OrbitView:
    """An orbit view centred on the robot, far enough to show all of it."""
    if not urdf_xml:
        return OrbitView()
    try:
        robot = ET.fromstring(urdf_xml)
    except ET.ParseError:
        return OrbitView()
    links = {l.get('name'): l for l in robot.findall('link')}
    children: Dict[str, List] = {}
    child_links = set()
    for j in robot.findall('joint'):
        p, c = j.find('parent'), j.find('child')
        if p is None or c is None:
            continue
        children.setdefault(p.get('link'), []).append((j, c.get('link')))
        child_links.add(c.get('link'))
    roots = [n for n in links if n not in child_links]
    start = fixed_frame if fixed_frame in links else (roots[0] if roots else None)
    if start is None:
        return OrbitView()
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    stack = [(start, np.eye(4))]
    seen = set()
    while stack:                      # bounded: each link visited once
        name, T = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        pos, rad = T[:3, 3], _geometry_radius(links.get(name, ET.Element('link')))
        lo, hi = np.minimum(lo, pos - rad), np.maximum(hi, pos + rad)
        for joint, child_name in children.get(name, []):
            stack.append((child_name, T @ _origin(joint)))
    center = (lo + hi) / 2
    size = float(np.linalg.norm(hi - lo))
    return OrbitView(focal_point=tuple(round(float(v), 3) for v in center),
                     distance=round(max(2.0, 1.6 * size), 3))


#: The operator's view of the VaultBot's surroundings: from behind and above the robot, looking ahead at
#: the data its sensors see (what the demo and `temoto replay` show, and what a host starts with by default).
OPERATOR_VIEW = {'Distance': 7.5, 'Yaw': 3.14159, 'Pitch': 0.6, 'Focal Point': [2.2, 0.0, 0.4]}
