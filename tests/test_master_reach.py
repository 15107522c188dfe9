"""MasterReach: a bounded verdict on whether the master takes connections, for threads that must not block
(the RViz host defers destroying a display while it is out of reach; the two-host demo under hot standby
shows why)."""
import socket
import time

from temoto_core.master_reach import MasterReach
from temoto_core.wait import wait_for


def listening():
    server = socket.socket()
    server.bind(('127.0.0.1', 0))
    server.listen(8)
    return server


def test_a_master_that_accepts_is_reachable_and_a_closed_port_is_not_within_the_timeout():
    server = listening()
    port = server.getsockname()[1]
    try:
        reach = MasterReach('http://127.0.0.1:%d/' % port, timeout=0.2)
        assert reach.probe() is True and reach.unreachable_now() is False
    finally:
        server.close()
    t0 = time.monotonic()
    assert reach.unreachable_now() is True
    assert time.monotonic() - t0 < 1.0


def test_a_fresh_negative_verdict_is_trusted_and_a_stale_one_is_asked_again_in_the_background():
    server = listening()
    port = server.getsockname()[1]
    server.close()
    reach = MasterReach('http://127.0.0.1:%d/' % port, timeout=0.2, stale_after=0.2)
    assert reach.last() is None            # nothing asked yet: the first ask starts in the background
    wait_for(lambda: reach.last() is False, 5, 'the background verdict: out of reach')
    again = socket.socket()
    again.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    again.bind(('127.0.0.1', port))
    again.listen(8)
    try:
        # a stale verdict is asked again off the caller's thread; the caller sees the new one once it is in
        wait_for(lambda: reach.last() is True, 5, 'the master back, seen by the background ask')
    finally:
        again.close()
