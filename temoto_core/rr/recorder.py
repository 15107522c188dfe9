"""What the registrar's sides tell its journal: one call per change of the registry.

Without a journal every call is a no-op, so the sides never ask whether there is
one. Calls are made with the registrar's lock held, so the journal sees changes
in the order the registry made them.

The writes themselves leave the registry's lock: each call takes what it needs
from the registry *now* (a consumer count, a consumer's record) and queues the
write; one writer thread commits what is queued, many changes per transaction
(group commit), in order. The registrar's messages are never changed once
stored, so serialising them on the writer thread reads what they were when
queued.

Written behind, reconciled at restart: no answer waits for the journal. A
change that comes alone is committed at once; what comes while a commit is
written goes into the next one, and the writer waits ``COMMIT_PAUSE`` between
commits (see :class:`JournalWriter`), so a SIGKILL can
lose the last changes. What they recorded is not lost: every
acknowledged load carries the owner's record to its consumer (``backup.py``),
and a restarted registrar always checks its journal against its neighbours'
copies, which give back a load whose commit was lost and release a consumer
that left meanwhile.

What it costs (``bench_journal.py``, a load through three journaling
registrars against a bare chain of service calls): waiting for the commit
before each answer, as this registrar once did, 2.67 against 1.54 without
journals; written behind, one commit per change, 1.84 against 1.60; with a 50 ms
pause (the default) and records that name their links, 1.85 against 1.70 to 1.74.
Measured per load across the three processes, the CPU the journal adds went from
1.26 ms to 0.40 ms with the pause, against 1.0 ms without it.
"""
import collections
import io
import threading
from typing import Callable, Deque, Optional, Tuple

import rospy

from temoto_core.rr.journal import Journal, JournaledConsumer
from temoto_core.rr.query import ClientQuery, Consumer, ServerQuery

# changes committed together at most: bounds a transaction's time under a burst
MAX_BATCH = 500
# seconds between two commits under a burst (JournalWriter; a registrar's ~journal_pause). 50 ms halves the
# journal's CPU on a chain of loads; 100 and 200 ms save no more (BENCHMARKS.md, "the journal's chain cost")
COMMIT_PAUSE = 0.05
# the longest pause a registrar accepts (~journal_pause): beyond it the journal lags more than it saves
MAX_COMMIT_PAUSE = 5.0


def serialized(msg) -> bytes:
    buf = io.BytesIO()
    msg.serialize(buf)
    return buf.getvalue()


def wire_of(query: ClientQuery) -> Tuple[bytes, bytes]:
    """The request and response of active ``query``, serialised once however many local ids hold it: neither
    changes once the query is active."""
    if query.wire is None:
        query.wire = (serialized(query.request), serialized(query.response))
    return query.wire


def journaled(consumer: Consumer, external_id: int) -> JournaledConsumer:
    return JournaledConsumer(external_id, consumer.status_topic, consumer.client_name, consumer.namespace,
                             consumer.uri, consumer.incarnation)


class JournalWriter:
    """Queued changes, committed in order, many per transaction, by a background thread (and by
    :meth:`close` for what is left). One committer at a time takes what is queued, in order, so the journal
    sees the changes in the order they were put, whoever commits them.

    A change that comes alone is committed at once. After each commit the writer pauses for ``pause``
    seconds, and what comes meanwhile is committed together when the pause ends: under a burst of loads
    the writer commits, and wakes, at most once per pause. A commit costs about 60 us of CPU whatever it
    holds, and waking the writer about as much again, against about 12 us per change in a batch
    (``bench_journal.py``); committing every change on its own made a load through three journaling
    registrars cost twice the CPU of one without. The pause bounds how far the journal lags a burst; what a
    SIGKILL takes from that lag comes back from the neighbours at the restart (``backup.py``).
    """

    def __init__(self, journal: Journal, pause: float = COMMIT_PAUSE) -> None:
        self.journal = journal
        self.pause = pause
        self._pending: Deque[Callable[[], None]] = collections.deque()
        self._cond = threading.Condition()
        self._commit_lock = threading.Lock()
        self._closed = False
        self._idle = False             # the writer waits for a change: the next put wakes it
        self._thread = threading.Thread(target=self._run, name='rr-journal-writer', daemon=True)
        self._thread.start()

    def put(self, change: Callable[[], None]) -> None:
        with self._cond:
            self._pending.append(change)
            if self._idle:
                self._idle = False     # one wake is enough: later changes wait for the commit it makes
                self._cond.notify_all()

    def _commit_pending(self) -> None:
        with self._commit_lock:
            with self._cond:
                changes = [self._pending.popleft() for _ in range(min(MAX_BATCH, len(self._pending)))]
            if not changes:
                return
            try:
                with self.journal.batch():
                    for change in changes:
                        change()
            except Exception as err:        # a full disk, say: the registry goes on, the journal is behind
                rospy.logerr('journal %s: %d change(s) not written: %r', self.journal.path, len(changes), err)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._idle = not self._pending
                self._cond.wait_for(lambda: self._pending or self._closed)
                self._idle = False
                if self._closed and not self._pending:
                    return
            self._commit_pending()
            if self.pause > 0:
                with self._cond:
                    self._cond.wait_for(lambda: self._closed, self.pause)

    def close(self) -> None:
        """Write what is queued, then stop the thread."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(10.0)
        self._commit_pending()


class Recorder:
    def __init__(self, journal: Optional[Journal] = None, pause: float = COMMIT_PAUSE) -> None:
        self.journal = journal
        self.writer = JournalWriter(journal, pause) if journal is not None else None

    def attached(self, query: ServerQuery, external_id: int, consumer: Consumer) -> None:
        if self.writer is None:
            return
        record = journaled(consumer, external_id)
        if len(query.consumers) == 1:
            internal_id, server, request, response = query.internal_id, query.server.name, query.request, query.response
            self.writer.put(lambda: self.journal.serve(internal_id, server, request._type, serialized(request),
                                                       serialized(response), external_id, record))
        else:
            server, internal_id = query.server.name, query.internal_id
            self.writer.put(lambda: self.journal.attach(server, internal_id, record))

    def reattached(self, query: ServerQuery, external_id: int, consumer: Consumer) -> None:
        """A consumer's new incarnation took its resource back (new URI, status topic, incarnation)."""
        if self.writer is not None:
            server, internal_id, record = query.server.name, query.internal_id, journaled(consumer, external_id)
            self.writer.put(lambda: self.journal.attach(server, internal_id, record))

    def detached(self, server_name: str, external_id: int) -> None:
        if self.writer is not None:
            self.writer.put(lambda: self.journal.detach(server_name, external_id))

    def failed(self, query: ServerQuery) -> None:
        if self.writer is not None:
            internal_id, state = query.internal_id, query.state.value
            reason = str(query.failure) if query.failure is not None else ''
            self.writer.put(lambda: self.journal.mark(internal_id, state, reason))

    def gone(self, query: ServerQuery) -> None:
        if self.writer is not None:
            internal_id = query.internal_id
            self.writer.put(lambda: self.journal.unserve(internal_id))

    def held(self, local_id: int, query: ClientQuery, parent: Optional[ServerQuery]) -> None:
        if self.writer is not None:
            target, external_id, request_type = query.target, query.external_id, query.request._type
            parent_id = parent.internal_id if parent is not None else None
            self.writer.put(lambda: self.journal.hold(local_id, target, external_id, request_type, *wire_of(query),
                                                      parent_id))

    def linked(self, local_id: int, parent: ServerQuery) -> None:
        if self.writer is not None:
            internal_id = parent.internal_id
            self.writer.put(lambda: self.journal.link(local_id, internal_id))

    def released(self, local_id: int) -> None:
        if self.writer is not None:
            self.writer.put(lambda: self.journal.release(local_id))

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
