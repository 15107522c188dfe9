"""Whether the master takes a connection now: a cheap verdict for a thread that must never block on it.

roscpp asks the master synchronously, on whichever thread subscribes or unsubscribes. RViz destroys a
display on its main thread, and that thread also renders every frame: with the master across a cut link
(two hosts, the master on the robot), destroying one display held RViz's main thread for seconds per call
to the master (a connect to a host with no carrier ends only when ARP gives up), so a view that should
have switched by a visibility change froze instead (``tests/test_demo.py``, two hosts under hot
standby). A process that must not block asks :class:`MasterReach` first, and defers such work while the
master is out of reach.

The verdict comes from a TCP connect to the master's port, bounded by ``timeout``: the master is a server
that accepts at once when it is there.
"""
import socket
import threading
import time
import urllib.parse
from typing import Optional

import rosgraph

PROBE_TIMEOUT = 0.2      # s: a master on the same network accepts within a millisecond
STALE_AFTER = 0.5        # s: a verdict older than this is asked again


class MasterReach:
    """The last verdict on the master's reachability, asked again when it is older than ``stale_after``."""

    def __init__(self, master_uri: Optional[str] = None, timeout: float = PROBE_TIMEOUT,
                 stale_after: float = STALE_AFTER) -> None:
        parsed = urllib.parse.urlparse(master_uri or rosgraph.get_master_uri())
        self.address = (parsed.hostname or 'localhost', parsed.port or 11311)
        self.timeout = timeout
        self.stale_after = stale_after
        self._lock = threading.Lock()
        self._verdict: Optional[bool] = None
        self._when = 0.0
        self._asking: Optional[threading.Thread] = None

    def probe(self) -> bool:
        """Ask now (blocks for at most ``timeout``)."""
        try:
            socket.create_connection(self.address, timeout=self.timeout).close()
            reachable = True
        except OSError:
            reachable = False
        with self._lock:
            self._verdict, self._when = reachable, time.monotonic()
        return reachable

    def last(self) -> Optional[bool]:
        """The latest verdict, however old (None before the first); asks again in the background if it is
        stale, so a caller that polls never blocks."""
        with self._lock:
            verdict, stale = self._verdict, time.monotonic() - self._when >= self.stale_after
            if stale and (self._asking is None or not self._asking.is_alive()):
                self._asking = threading.Thread(target=self.probe, name='master-reach', daemon=True)
                self._asking.start()
        return verdict

    def unreachable_now(self) -> bool:
        """True when the master does not take a connection: a fresh negative verdict is trusted as it is,
        anything else is asked again (blocking for at most ``timeout``), since a cut may have just happened."""
        with self._lock:
            known_down = self._verdict is False and time.monotonic() - self._when < self.stale_after
        return known_down or not self.probe()
