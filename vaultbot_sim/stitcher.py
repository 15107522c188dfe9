"""Stitch the Hokuyo's 2D scans over one wrist sweep into a 3D cloud in the base frame.

Each scan is placed with the hokuyo_link pose at its stamp, computed by forward
kinematics from the sim's joint states (JointHistory applies the same
extrapolation rule the driver used when rendering). A sweep is complete when the
wrist has turned through `sweep_angle` (pi by default: half a turn of a 270 deg
scan plane that contains the turning axis covers everything around it), when the
wrist reverses after turning at least `min_angle`, or after `max_window`
seconds, so that a still wrist still yields a (planar) cloud now and then.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from vaultbot_sim.kinematics import TreeModel
from vaultbot_sim.rosmsgs import XYZ


class SweepStitcher:
    def __init__(self, model: TreeModel, sweep_joint: str, sensor_frame: str = 'hokuyo_link',
                 base_frame: str = 'base_link', sweep_angle: float = math.pi, min_angle: float = 0.2,
                 max_window: float = 3.0):
        if base_frame != model.root and base_frame not in model.links():
            raise ValueError(f'base frame {base_frame!r} is not a link of {model.path}')
        self.model, self.sweep_joint = model, sweep_joint
        self.sensor_frame, self.base_frame = sensor_frame, base_frame
        self.sweep_angle, self.min_angle, self.max_window = sweep_angle, min_angle, max_window
        self._reset()

    def _reset(self) -> None:
        self.chunks: list[np.ndarray] = []
        self.t0: float | None = None
        self.lo = self.hi = None
        self.last_angle: float | None = None
        self.direction = 0.0

    def scan_points(self, ranges: np.ndarray, angle_min: float, angle_increment: float,
                    cfg: Mapping[str, float]) -> np.ndarray:
        """One scan as an (n,3) array in the base frame (beams with no return dropped)."""
        r = np.asarray(ranges, dtype=np.float64)
        a = angle_min + np.arange(len(r)) * angle_increment
        ok = np.isfinite(r)
        local = np.stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok]), np.zeros(ok.sum())], axis=1)
        t = self.model.transform(self.sensor_frame, self.base_frame, cfg)
        return local @ t[:3, :3].T + t[:3, 3]

    def add(self, stamp: float, ranges, angle_min: float, angle_increment: float,
            cfg: Mapping[str, float]) -> np.ndarray | None:
        """Add one scan; returns the finished sweep's cloud (structured XYZ array) or None."""
        pts = self.scan_points(ranges, angle_min, angle_increment, cfg)
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
        if done is None and self.hi - self.lo >= self.sweep_angle - 1e-3:
            done = self._finish()
            self._append(stamp, angle, pts)   # the boundary scan also starts the next sweep
        return done

    def _append(self, stamp: float, angle: float, pts: np.ndarray) -> None:
        if self.t0 is None:
            self.t0, self.lo, self.hi = stamp, angle, angle
        self.lo, self.hi = min(self.lo, angle), max(self.hi, angle)
        self.last_angle = angle
        self.chunks.append(pts)

    def _finish(self) -> np.ndarray:
        direction = self.direction
        pts = np.concatenate(self.chunks) if self.chunks else np.zeros((0, 3))
        self._reset()
        self.direction = direction
        out = np.empty(len(pts), dtype=XYZ)
        out['x'], out['y'], out['z'] = pts[:, 0], pts[:, 1], pts[:, 2]
        return out
