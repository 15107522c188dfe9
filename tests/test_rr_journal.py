"""The registrar's journal: what it records, incarnations, ids, and surviving a SIGKILL at any point."""
import os
import random
import signal
import sqlite3
import subprocess
import sys
import threading
import time

import pytest

from temoto_core.errors import TemotoError
from temoto_core.rr import ResourceRegistrar
from temoto_core.rr.journal import Journal, JournalError, JournaledConsumer
from temoto_core.rr.recorder import JournalWriter
from temoto_testing import wait_for

WRITER = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'journal_writer.py')


def consumer(ext: int) -> JournaledConsumer:
    return JournaledConsumer(ext, '/temoto/a/status', '/a', 'temoto', 'http://h:1/')


def test_it_records_served_and_held_resources_and_forgets_released_ones(tmp_path):
    path = str(tmp_path / 'rr.sqlite3')
    j = Journal(path, run_id='r1')
    j.serve(10, 'cam', 'p/Req', b'req', b'res', 11, consumer(11))
    j.attach('cam', 10, consumer(12))
    j.hold(20, ('temoto', 'er', 'load_process'), 99, 'p/Proc', b'q', b's', 10)
    j.hold(21, ('temoto', 'er', 'load_process'), 99, 'p/Proc', b'q', b's', None)
    j.detach('cam', 11)
    j.release(21)
    j.close()
    again = Journal(path, run_id='r1')
    contents = again.contents()
    assert [(s.internal_id, s.server, s.request, [c.external_id for c in s.consumers]) for s in contents.served] == \
        [(10, 'cam', b'req', [12])]
    assert [(h.local_id, h.target, h.external_id, h.parent) for h in contents.holds] == \
        [(20, ('temoto', 'er', 'load_process'), 99, 10)]
    again.release(20)
    again.unserve(10)
    assert again.contents().served == [] and again.contents().holds == []


def test_every_open_is_a_new_incarnation_and_ids_stay_above_the_last_ones(tmp_path):
    path = str(tmp_path / 'rr.sqlite3')
    first = Journal(path, run_id='r1')
    far = time.time_ns() + 10 ** 15           # ids from a clock that was ahead
    first.serve(far, 'cam', 'p/Req', b'', b'', far + 1, consumer(far + 1))
    first.close()
    second = Journal(path, run_id='r1')
    assert (first.incarnation, second.incarnation) == (1, 2)
    assert second.id_floor == far + 1


def test_a_new_master_run_starts_an_empty_journal_but_keeps_counting(tmp_path):
    path = str(tmp_path / 'rr.sqlite3')
    first = Journal(path, run_id='r1')
    first.serve(5, 'cam', 'p/Req', b'', b'', 6, consumer(6))
    first.close()
    second = Journal(path, run_id='r2')
    assert second.contents().served == [] and second.incarnation == 2 and second.id_floor == 6


def test_a_file_that_is_not_a_journal_is_refused_with_its_name(tmp_path):
    path = tmp_path / 'rr.sqlite3'
    path.write_bytes(b'not a database at all' * 100)
    with pytest.raises(JournalError, match='rr.sqlite3'):
        Journal(str(path))


def _check(path: str, acknowledged: int) -> None:
    """The journal after a kill: intact, every step whole (never half of one), nothing acknowledged lost."""
    db = sqlite3.connect(path)
    assert db.execute('PRAGMA integrity_check').fetchone()[0] == 'ok'
    db.close()
    journal = Journal(path, run_id='run')
    contents = journal.contents()
    served = {s.internal_id: s for s in contents.served}
    for s in served.values():
        assert [c.external_id for c in s.consumers] == [s.internal_id]       # served and consumer: one commit
        assert len(s.request) == 2048 and len(s.response) == 2048
    for h in contents.holds:
        assert (h.parent is None or h.parent in served) and len(h.response) == 2048
    assert journal.id_floor >= acknowledged
    # a step whose resource is never released (all but every third one) is there if it was reported committed
    lost = [t for t in range(1, acknowledged + 1) if t % 3 != 1 and t not in served]
    assert not lost, 'steps %s lost (acknowledged up to %d)' % (lost[:5], acknowledged)
    journal.close()


def test_the_journal_survives_a_sigkill_at_any_point_of_a_write_loop(tmp_path):
    path = str(tmp_path / 'torn.sqlite3')
    rng = random.Random(14)
    runs = 25
    for _ in range(runs):
        writer = subprocess.Popen([sys.executable, WRITER, path], stdout=subprocess.PIPE, text=True)
        try:
            first = writer.stdout.readline()      # it is writing: kill it somewhere inside its loop
            assert first.strip().isdigit(), first
            acknowledged = int(first)
            deadline = time.monotonic() + rng.uniform(0.0, 0.15)
            while time.monotonic() < deadline:
                acknowledged = int(writer.stdout.readline())
            writer.send_signal(signal.SIGKILL)
            rest = writer.communicate(timeout=10)[0].split()
            acknowledged = int(rest[-1]) if rest else acknowledged
        finally:
            if writer.poll() is None:
                writer.kill()
                writer.wait(10)
        assert writer.returncode == -signal.SIGKILL
        _check(path, acknowledged)
    assert Journal(path, run_id='run').incarnation == 2 * runs + 1      # each writer and each check opened it


def test_the_writer_commits_in_order_many_changes_per_transaction_and_close_writes_the_rest(tmp_path):
    """The registrar's writes leave its hot path: queued, then committed by one thread in batches."""
    path = str(tmp_path / 'w.sqlite3')
    journal = Journal(path, run_id='run')
    batches = []
    real_batch = journal.batch

    def counting_batch():
        batches.append(1)
        return real_batch()
    journal.batch = counting_batch
    writer = JournalWriter(journal)
    started, go = threading.Event(), threading.Event()

    def first():
        started.set()
        assert go.wait(10)
        journal.put_owner_state('order', '0')
    writer.put(first)
    assert started.wait(10)
    for i in range(1, 101):                 # queued while the first batch is being written
        writer.put(lambda i=i: journal.put_owner_state('order', str(i)))
        writer.put(lambda i=i: journal.put_owner_state('k%d' % i, str(i)))
    go.set()
    writer.close()
    journal.close()
    assert len(batches) == 2, 'the 200 changes queued meanwhile went in one transaction'
    kept = Journal(path, run_id='run').owner_state()
    assert kept['order'] == '100', 'in the order queued'
    assert len([k for k in kept if k.startswith('k')]) == 100


def test_a_lone_change_is_committed_at_once_and_a_burst_at_most_once_per_pause(tmp_path):
    """Each commit costs the same whatever it holds: under a burst the writer commits, and wakes, once per pause;
    a change on its own does not wait for the pause."""
    journal = Journal(str(tmp_path / 'p.sqlite3'), run_id='run')
    batches = []
    real_batch = journal.batch

    def counting_batch():
        batches.append(time.monotonic())
        return real_batch()
    journal.batch = counting_batch
    writer = JournalWriter(journal, pause=3600.0)        # a pause no test outlives: only the first commit is free
    try:
        writer.put(lambda: journal.put_owner_state('alone', '1'))
        wait_for(lambda: 'alone' in journal.owner_state(), 10, 'the lone change committed')
        for i in range(50):
            writer.put(lambda i=i: journal.put_owner_state('burst%d' % i, str(i)))
        assert len(batches) == 1 and not any(k.startswith('burst') for k in journal.owner_state()), \
            'the burst waits for the pause'
    finally:
        writer.close()
    assert len(batches) == 2 and len([k for k in journal.owner_state() if k.startswith('burst')]) == 50, \
        'close writes what waited, in one transaction'
    journal.close()


def test_a_batch_writes_the_highest_id_once_and_a_rolled_back_batch_raises_nothing(tmp_path):
    path = str(tmp_path / 'rr.sqlite3')
    journal = Journal(path, run_id='r1')
    with journal.batch():
        for i in range(1, 6):
            journal.serve(10 * i, 'cam', 'p/Req', b'', b'', 10 * i + 1, consumer(10 * i + 1))
        journal.hold(70, ('temoto', 'er', 'load_process'), 3, 'p/Proc', b'q', b's', 10)
    assert journal.id_floor == 70
    with pytest.raises(RuntimeError):
        with journal.batch():
            journal.serve(500, 'cam', 'p/Req', b'', b'', 501, consumer(501))
            raise RuntimeError('a change failed half-way')
    assert journal.id_floor == 70                 # the batch is not in the file: its ids are not either
    journal.close()
    again = Journal(path, run_id='r1')
    assert again.id_floor == 70 and [s.internal_id for s in again.contents().served] == [10, 20, 30, 40, 50]


@pytest.mark.parametrize('pause', [-0.1, 60.0, 'soon', True])
def test_a_bad_journal_pause_is_refused_by_name_before_the_journal_opens(rospy_client, tmp_path, pause):
    path = tmp_path / 'bad_pause.sqlite3'
    with pytest.raises(TemotoError, match=r'parameter ~journal_pause: .* is not a number >= 0 and <= 5'):
        ResourceRegistrar('rr_bad_pause', journal=str(path), journal_pause=pause)
    assert not path.exists(), 'a refused registrar starts no incarnation'
