"""Stitch the Hokuyo's 2D scans over a wrist sweep into a 3D cloud in the base frame.

Each scan is placed with the hokuyo_link pose at its stamp, computed by forward
kinematics from the sim's joint states (JointHistory applies the same
extrapolation rule the driver used when rendering). A sweep covers
`sweep_angle` of wrist turn (pi by default: half a turn of a 270 deg scan plane
that contains the turning axis covers everything around it).

A base that drives while the wrist sweeps carries the scanner along: a scan taken a second ago
placed by the arm alone would put what it saw where the base was, a metre behind. So each scan
is kept in the fixed ``odom`` frame (the base's pose at its stamp, from odometry, given as
``base``), and a cloud is given in the base frame of its newest scan: what the sweep saw, where
it is now. Without odometry (a base that does not drive) the base frame is the fixed one. The
scanner's hits on its own robot move with the base, not with the world: they are dropped scan by
scan (``self_box``, the body in the base frame) before they could be left behind.

Two ways to cut the stream of scans into clouds:
- ``RollingStitcher`` (what the node publishes): the latest sweep's worth of
  scans, the freshest of each direction, published at a steady rate. Data flows
  a few scans after the driver's first one, and a viewer that subscribes late
  waits one publishing period, not one sweep (2 s at the sim's wrist speed).
- ``SweepStitcher``: one cloud per finished sweep (the wrist turned through
  `sweep_angle`, reversed after at least `min_angle`, or `max_window` s passed).
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from vaultbot_sim.kinematics import TreeModel
from vaultbot_sim.rosmsgs import XYZ


def _xyz(pts: np.ndarray) -> np.ndarray:
    out = np.empty(len(pts), dtype=XYZ)
    out['x'], out['y'], out['z'] = pts[:, 0], pts[:, 1], pts[:, 2]
    return out


class ScanProjector:
    """Places one scan in the base frame with the sensor pose of its joint configuration."""

    def __init__(self, model: TreeModel, sweep_joint: str, sensor_frame: str = 'hokuyo_link',
                 base_frame: str = 'base_link', sweep_angle: float = math.pi, max_window: float = 3.0,
                 self_box: tuple | None = None):
        if base_frame != model.root and base_frame not in model.links():
            raise ValueError(f'base frame {base_frame!r} is not a link of {model.path}')
        if not sweep_angle > 0 or not max_window > 0:
            raise ValueError(f'sweep_angle ({sweep_angle}) and max_window ({max_window}) must be > 0')
        self.model, self.sweep_joint = model, sweep_joint
        self.sensor_frame, self.base_frame = sensor_frame, base_frame
        self.sweep_angle, self.max_window = sweep_angle, max_window
        self.self_box = self_box

    def scan_points(self, ranges: np.ndarray, angle_min: float, angle_increment: float,
                    cfg: Mapping[str, float]) -> np.ndarray:
        """One scan as an (n,3) array in the base frame (beams with no return dropped)."""
        r = np.asarray(ranges, dtype=np.float64)
        a = angle_min + np.arange(len(r)) * angle_increment
        ok = np.isfinite(r)
        local = np.stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok]), np.zeros(ok.sum())], axis=1)
        t = self.model.transform(self.sensor_frame, self.base_frame, cfg)
        pts = local @ t[:3, :3].T + t[:3, 3]
        if self.self_box is None:
            return pts
        x0, x1, y0, y1, z0, z1 = self.self_box
        on_self = ((pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)
                   & (pts[:, 2] >= z0) & (pts[:, 2] <= z1))
        return pts[~on_self]


class RollingStitcher(ScanProjector):
    """The freshest scan of every direction the wrist has swept through: a rolling "last sweep".

    Scans are kept by wrist angle, in bins of ``angle_bin`` (default: one scan's turn at
    the sim's 40 Hz and pi/2 rad/s); a new scan replaces the one of its bin. So after a
    whole sweep the window holds one sweep's worth of scans, each direction as last
    seen. A time window could not do that with a wrist that goes back and forth: the
    directions near the end it turned away from were last seen up to a whole period
    ago, while those it just passed twice would be held twice. Scans older than
    ``max_window`` s are dropped (a wrist that stopped leaves only its current plane).
    Until a whole sweep has been seen it holds what was seen so far. ``cloud()`` is
    the window as one cloud; its stamp is the newest scan's (``newest_stamp``).
    """

    def __init__(self, model: TreeModel, sweep_joint: str, sensor_frame: str = 'hokuyo_link',
                 base_frame: str = 'base_link', sweep_angle: float = math.pi, max_window: float = 4.5,
                 angle_bin: float = math.pi / 80, self_box: tuple | None = None):
        super().__init__(model, sweep_joint, sensor_frame, base_frame, sweep_angle, max_window, self_box)
        if not 0 < angle_bin <= sweep_angle:
            raise ValueError(f'angle_bin ({angle_bin}) must be > 0 and at most sweep_angle ({sweep_angle})')
        self.angle_bin = angle_bin
        self.bins: dict[int, tuple[float, float, np.ndarray]] = {}   # bin -> (stamp, angle, points in odom)
        self.newest_stamp: float | None = None
        self.newest_base = np.eye(4)               # odom -> base at the newest scan

    def __len__(self) -> int:
        return len(self.bins)

    def clear(self) -> None:
        """Drop every scan held (the frame they were kept in changed)."""
        self.bins.clear()

    @property
    def complete(self) -> bool:
        """True once the held scans span the whole sweep (the ends to within a bin each)."""
        if not self.bins:
            return False
        angles = [a for _, a, _ in self.bins.values()]
        return max(angles) - min(angles) >= self.sweep_angle - 2.0 * self.angle_bin - 1e-9

    def add(self, stamp: float, ranges, angle_min: float, angle_increment: float,
            cfg: Mapping[str, float], base: np.ndarray | None = None) -> None:
        """Add one scan; ``base``: the base's pose in ``odom`` at ``stamp`` (4 x 4), None for a base at
        rest. A scan older than the newest one means the clock went back (a restarted sim): the
        window starts again from this scan."""
        if self.newest_stamp is not None and stamp < self.newest_stamp:
            self.bins.clear()
        angle = float(cfg.get(self.sweep_joint, 0.0))
        pts = self.scan_points(ranges, angle_min, angle_increment, cfg)
        base = np.eye(4) if base is None else base
        self.bins[math.floor(angle / self.angle_bin)] = (stamp, angle, pts @ base[:3, :3].T + base[:3, 3])
        self.newest_stamp, self.newest_base = stamp, base
        for key in [k for k, (t, _, _) in self.bins.items() if stamp - t > self.max_window]:
            del self.bins[key]

    def cloud(self) -> np.ndarray:
        """The held scans as one structured XYZ array, in the base frame at the newest scan, in wrist-angle
        order."""
        if not self.bins:
            return _xyz(np.zeros((0, 3)))
        pts = np.concatenate([self.bins[k][2] for k in sorted(self.bins)])
        inverse = np.linalg.inv(self.newest_base)
        return _xyz(pts @ inverse[:3, :3].T + inverse[:3, 3])


class SweepStitcher(ScanProjector):
    """One cloud per finished sweep (the node's ``~mode: sweep``)."""

    def __init__(self, model: TreeModel, sweep_joint: str, sensor_frame: str = 'hokuyo_link',
                 base_frame: str = 'base_link', sweep_angle: float = math.pi, min_angle: float = 0.2,
                 max_window: float = 3.0, self_box: tuple | None = None):
        super().__init__(model, sweep_joint, sensor_frame, base_frame, sweep_angle, max_window, self_box)
        self.min_angle = min_angle
        self.last_base = np.eye(4)             # odom -> base at the last scan added
        self._reset()

    def _reset(self) -> None:
        self.chunks: list[np.ndarray] = []
        self.t0: float | None = None
        self.lo = self.hi = None
        self.last_angle: float | None = None
        self.direction = 0.0

    def add(self, stamp: float, ranges, angle_min: float, angle_increment: float,
            cfg: Mapping[str, float], base: np.ndarray | None = None) -> np.ndarray | None:
        """Add one scan (``base`` as for ``RollingStitcher.add``); returns the finished sweep's cloud
        (structured XYZ array, in the base frame of the sweep's last scan) or None."""
        pts = self.scan_points(ranges, angle_min, angle_increment, cfg)
        base = np.eye(4) if base is None else base
        pts = pts @ base[:3, :3].T + base[:3, 3]
        angle = float(cfg.get(self.sweep_joint, 0.0))
        done = None
        if self.t0 is not None:
            step = angle - self.last_angle
            direction = math.copysign(1.0, step) if abs(step) > 1e-6 else self.direction
            reversed_ = self.direction != 0.0 and direction != self.direction
            span = self.hi - self.lo
            if (reversed_ and span >= self.min_angle) or stamp - self.t0 >= self.max_window:
                done = self._finish()
            self.direction = direction
        self._append(stamp, angle, pts)
        self.last_base = base
        if done is None and self.hi - self.lo >= self.sweep_angle - 1e-3:
            done = self._finish()
            self._append(stamp, angle, pts)   # the boundary scan also starts the next sweep
        return done

    def clear(self) -> None:
        """Drop the sweep in progress (the frame its scans were kept in changed)."""
        self._reset()

    def _append(self, stamp: float, angle: float, pts: np.ndarray) -> None:
        if self.t0 is None:
            self.t0, self.lo, self.hi = stamp, angle, angle
        self.lo, self.hi = min(self.lo, angle), max(self.hi, angle)
        self.last_angle = angle
        self.chunks.append(pts)

    def _finish(self) -> np.ndarray:
        direction, inverse = self.direction, np.linalg.inv(self.last_base)
        pts = np.concatenate(self.chunks) if self.chunks else np.zeros((0, 3))
        self._reset()
        self.direction = direction
        return _xyz(pts @ inverse[:3, :3].T + inverse[:3, 3])
