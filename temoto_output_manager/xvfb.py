"""A private Xvfb for a headless RViz host.

RViz (Ogre over GLX) needs an X server; Qt's offscreen platform is not enough.
When there is no DISPLAY the host starts its own
Xvfb and owns its whole lifetime:

- the display number is picked by Xvfb itself (``-displayfd``): it claims the
  first free number and writes it back only once it accepts connections, so
  there is no race with other X servers started at the same time and no
  sleep-polling for readiness;
- ``-nolisten tcp``: only the local unix socket;
- the server gets ``PR_SET_PDEATHSIG`` = SIGTERM, so it stops even when the
  host is SIGKILLed or segfaults (SIGTERM lets Xvfb remove its lock file and
  socket);
- it runs in its own session, so a SIGINT sent to the host's process group
  (how process managers stop a node) does not pull the X server from under a
  RViz that is still shutting down.
"""
from __future__ import annotations

import os
import select
import shutil
import signal
import stat
import subprocess
import tempfile
import time
from typing import Optional

from temoto_core.process_group import popen_dying_with_this_thread


class XvfbError(RuntimeError):
    """Xvfb could not be started (missing binary, crashed, or not ready in time)."""


class Xvfb:
    """One Xvfb child process. ``start()`` returns the DISPLAY string (":N")."""

    def __init__(self, screen: str = '1280x800x24', binary: str = 'Xvfb', start_timeout: float = 10.0):
        self.screen = screen
        self.binary = binary
        self.start_timeout = start_timeout
        self.proc: Optional[subprocess.Popen] = None
        self.display: Optional[str] = None

    @property
    def pid(self) -> Optional[int]:
        return self.proc.pid if self.proc else None

    def start(self) -> str:
        exe = shutil.which(self.binary)
        if exe is None:
            raise XvfbError("no DISPLAY and '%s' is not installed (apt-get install xvfb)" % self.binary)
        read_fd, write_fd = os.pipe()
        try:
            self.proc = popen_dying_with_this_thread(
                [exe, '-displayfd', str(write_fd), '-screen', '0', self.screen, '-nolisten', 'tcp', '-noreset'],
                signal.SIGTERM, pass_fds=(write_fd,), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL, start_new_session=True)
        finally:
            os.close(write_fd)
        try:
            number = self._read_display_number(read_fd)
        except BaseException:
            os.close(read_fd)
            self.stop()
            raise
        os.close(read_fd)
        self.display = ':%d' % number
        return self.display

    def _read_display_number(self, fd: int) -> int:
        deadline = time.monotonic() + self.start_timeout
        data = b''
        while not data.endswith(b'\n'):
            left = deadline - time.monotonic()
            if left <= 0:
                raise XvfbError('Xvfb did not become ready within %.1f s' % self.start_timeout)
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                continue
            chunk = os.read(fd, 64)
            if not chunk:       # pipe closed: Xvfb exited before writing its display number
                rc = self.proc.wait(timeout=5) if self.proc else None
                raise XvfbError('Xvfb exited during start-up (rc %s)' % rc)
            data += chunk
        return int(data.strip())

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self, timeout: float = 5.0) -> None:
        """SIGTERM, then SIGKILL after ``timeout``; always reaps the child."""
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=timeout)
        self.proc = None


def runtime_dir(parent: Optional[str] = None) -> Optional[str]:
    """This user's one XDG_RUNTIME_DIR for headless hosts, made once and kept, as /run/user/UID is.

    One folder per user, not one per host: a host that is SIGKILLed cannot remove its own, and a folder per
    start filled /tmp by the hundred. Qt wants it private (0700, ours), and since /tmp is shared, a folder
    already there that is a link, someone else's or open to others is not used: None (Qt then only warns).
    """
    path = os.path.join(parent or tempfile.gettempdir(), 'temoto_xdg_%d' % os.getuid())
    try:
        os.mkdir(path, 0o700)
    except FileExistsError:
        pass
    info = os.lstat(path)
    if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid() or info.st_mode & 0o077:
        return None
    return path


def ensure_display(env=None) -> Optional[Xvfb]:
    """Make ``env['DISPLAY']`` usable: keep a real one, or start a private Xvfb.

    Returns the Xvfb (the caller stops it) or None when a DISPLAY was given.
    Also points XDG_RUNTIME_DIR at this user's private folder when unset (silences Qt).
    """
    env = os.environ if env is None else env
    if not env.get('XDG_RUNTIME_DIR'):
        folder = runtime_dir()
        if folder:
            env['XDG_RUNTIME_DIR'] = folder
    if env.get('DISPLAY'):
        return None
    server = Xvfb()
    env['DISPLAY'] = server.start()
    return server
