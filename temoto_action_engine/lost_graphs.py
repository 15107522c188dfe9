"""Graphs that were running when an earlier incarnation of the engine died: reported FAILED, never lost.

The engine cannot take a running graph back. Its worker talks to it over a pipe, which dies with the
engine, and a worker whose engine is gone stops its graph and releases what it held
(``worker.py``, ``engine_gone``). What must not happen is that the graph silently disappears. So,
with a journal (``~journal``), the engine records every graph while it runs. The next incarnation
reads what is left and reports each graph FAILED, with the reason, in its listing and on its events
and feedback topics. It also makes sure the graph's worker is gone within the stop bound
(``stop_timeout_s`` + 5 s): a worker still there then is ended, SIGTERM first, its start time checked
before every signal.
"""
from __future__ import annotations

import json
import os
import signal
import threading
import time
from typing import Callable, List

from temoto_core.process_group import start_ticks
from temoto_core.rr.journal import Journal

from .graph import FAILED, TERMINAL

GRAPH_KEY = 'graph/'
WORKER_TERM_GRACE_S = 5.0


def reason_for(record: dict) -> str:
    return ('the action engine died while this graph ran (it started %s); its worker stopped the graph and '
            'released what it held' % time.strftime('%H:%M:%S', time.localtime(record['started_at'])))


class GraphRecords:
    """The running graphs, in the engine's journal (one owner-state entry per graph)."""

    def __init__(self, journal: Journal) -> None:
        self.journal = journal

    def started(self, name: str, snapshot: dict, worker_pid: int) -> None:
        self.journal.put_owner_state(GRAPH_KEY + name, json.dumps({
            'snapshot': snapshot, 'worker_pid': worker_pid, 'worker_start': start_ticks(worker_pid) if worker_pid else
            None, 'started_at': snapshot.get('started_at') or time.time()}))

    def finished(self, name: str) -> None:
        self.journal.drop_owner_state(GRAPH_KEY + name)

    def take_lost(self) -> List[dict]:
        """The graphs an earlier incarnation left running; their records are dropped."""
        lost = []
        for key, value in sorted(self.journal.owner_state().items()):
            if key.startswith(GRAPH_KEY):
                lost.append(json.loads(value))
                self.journal.drop_owner_state(key)
        return lost


class LostGraph:
    """A graph of an earlier incarnation, with the face the listing needs: FAILED, with the reason."""

    finished = True

    def __init__(self, record: dict) -> None:
        self.reason = reason_for(record)
        snapshot = dict(record['snapshot'])
        self.name = snapshot['graph_name']
        nodes = []
        for node in snapshot.get('nodes', []):
            if node.get('state') not in TERMINAL:
                node = dict(node, state=FAILED, message=self.reason)
            nodes.append(node)
        self._json = dict(snapshot, state=FAILED, reason=self.reason, nodes=nodes)

    @property
    def state(self) -> str:
        return FAILED

    def to_json(self) -> dict:
        return dict(self._json)

    def running_nodes(self) -> list:
        return []

    def stop(self, timeout: float = 0.0) -> list:
        return []


def end_worker(pid: int, start: int, bound: float, log: Callable[[str], None]) -> None:
    """Wait up to ``bound`` for a dead engine's worker to finish by itself; then end its group."""
    deadline = time.monotonic() + bound
    while start_ticks(pid) == start and time.monotonic() < deadline:
        time.sleep(0.1)
    for sig, grace in ((signal.SIGTERM, WORKER_TERM_GRACE_S), (signal.SIGKILL, WORKER_TERM_GRACE_S)):
        if start_ticks(pid) != start:
            return
        log('the worker (pid %d) of a graph of the previous engine did not finish within %.0f s: sending %s'
            % (pid, bound, sig.name))
        try:
            os.killpg(pid, sig)
        except (ProcessLookupError, PermissionError):
            return
        deadline = time.monotonic() + grace
        while start_ticks(pid) == start and time.monotonic() < deadline:
            time.sleep(0.05)


def end_workers_in_background(records: List[dict], bound: float, log: Callable[[str], None]) -> None:
    for record in records:
        if record.get('worker_pid') and record.get('worker_start') is not None:
            threading.Thread(target=end_worker, args=(record['worker_pid'], record['worker_start'], bound, log),
                             name='end-lost-worker', daemon=True).start()
