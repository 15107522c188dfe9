"""The D435's rendering, in a child process.

A pybullet render holds the GIL for its whole ~30 ms, so in-process rendering
delays the driver's device-state callback by several frames and an unplug in
crash mode would take longer than the 100 ms a real crash takes. With the render
in a child, the driver's GIL is free while it waits on the pipe. The child exits
when the pipe closes (the driver exited or crashed), so it never outlives it.
"""
from __future__ import annotations

import multiprocessing
import signal

from vaultbot_sim.scene import Intrinsics, Scene


def _serve(conn, robot_urdf: str, world_urdf: str, renderer: str, frame: str, intr: Intrinsics,
           near: float, far: float) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # the driver decides when we stop: pipe EOF
    scene = Scene(robot_urdf, world_urdf, renderer=renderer)
    conn.send('ready')
    while True:
        try:
            robot, world = conn.recv()
        except (EOFError, OSError):
            break
        scene.set_robot(robot)
        scene.set_world(world)
        rgb, z, _ = scene.render(scene.robot_link_pose(frame), intr, near, far)
        try:
            conn.send((rgb, z))
        except (BrokenPipeError, OSError):
            break
    scene.close()


class RenderWorker:
    def __init__(self, robot_urdf: str, world_urdf: str, renderer: str, frame: str, intr: Intrinsics,
                 near: float, far: float, timeout: float = 30.0):
        ctx = multiprocessing.get_context('spawn')
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_serve, name='d435_render',
                                args=(child, robot_urdf, world_urdf, renderer, frame, intr, near, far),
                                daemon=True)
        self.proc.start()
        child.close()
        if not self.conn.poll(timeout) or self.conn.recv() != 'ready':
            raise RuntimeError('render worker did not start')

    def request(self, robot: dict, world: dict) -> None:
        """Start rendering a frame; collect it with result()."""
        self.conn.send((robot, world))

    def result(self):
        """(rgb uint8 h x w x 3, depth z in metres) of the last request."""
        for _ in range(100):   # bounded: 100 x 0.2 s
            if self.conn.poll(0.2):
                return self.conn.recv()
            if not self.proc.is_alive():
                break
        raise RuntimeError('render worker died or hung')

    def render(self, robot: dict, world: dict):
        self.request(robot, world)
        return self.result()

    def close(self) -> None:
        self.conn.close()
        self.proc.join(2.0)
