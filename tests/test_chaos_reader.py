"""The chaos checker's registry reader against real registrar nodes: connections kept from one look to the
next, and never an answer older than the look (temoto_chaos/checker.py, RegistryReader)."""
import os
import signal
import time

from rr_helpers import RegistrarNode
from temoto_chaos.checker import RegistryReader
from temoto_testing import signals, wait_for

HANG = 5.0           # generous: catches a read that hangs, not a slow machine


def test_a_kept_connection_to_a_node_that_started_again_is_replaced_within_the_same_read(rospy_client, procs):
    node = RegistrarNode(procs, 'rr_reader')
    reader = RegistryReader()
    service = '/temoto/rr_reader/registry'
    try:
        assert reader.read_json(service)['name'] == 'rr_reader'
        assert reader.read_json(service)['name'] == 'rr_reader'        # on the kept connection
        node.process.proc.kill()
        node.process.proc.wait(timeout=10)
        RegistrarNode(procs, 'rr_reader')                              # a new incarnation, the same name
        # the kept connection is to the dead one: this read must still answer, from the new one
        assert reader.read_json(service)['name'] == 'rr_reader'
    finally:
        reader.close()


def test_a_stopped_server_is_no_answer_within_the_timeout_and_answers_again_once_it_runs(rospy_client, procs):
    node = RegistrarNode(procs, 'rr_reader_stop')
    reader = RegistryReader()
    service = '/temoto/rr_reader_stop/registry'
    try:
        assert reader.read_json(service) is not None
        signals.stop(node.process.pid, group=True)
        try:
            t0 = time.monotonic()
            assert reader.read_json(service, timeout=0.5) is None
            # the first read still hangs on the kept connection: the next is no answer too, not a second call on it
            assert reader.read_json(service, timeout=0.5) is None
            assert time.monotonic() - t0 < HANG
        finally:
            os.killpg(node.process.pid, signal.SIGCONT)
        wait_for(lambda: reader.read_json(service) is not None, 10, 'the registry once the node runs again')
    finally:
        reader.close()


def test_what_is_no_longer_kept_leaves_no_connection_and_no_lock_behind(rospy_client, procs):
    RegistrarNode(procs, 'rr_reader_keep')
    reader = RegistryReader()
    kept, dropped = '/temoto/rr_reader_keep/registry', '/temoto/rr_reader_killed_client/registry'
    try:
        assert reader.read_json(kept) is not None
        assert reader.read_json(dropped, timeout=2.0) is None        # never up: read, and no answer
        assert set(reader._busy) == {kept, dropped}
        reader.keep_only([kept])
        assert set(reader._busy) == {kept} and set(reader._proxies) == {kept}
        assert reader.read_json(kept) is not None
    finally:
        reader.close()
    assert not reader._busy and not reader._proxies
