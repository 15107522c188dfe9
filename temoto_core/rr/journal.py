"""A registrar's crash-safe local journal: every change of its registry, in SQLite.

Why SQLite in WAL mode: a registrar's process can be killed at any instruction.
SQLite commits atomically, WAL mode never rewrites the database file in place
while a transaction is open, and a torn last transaction is rolled back when
the file is next opened. ``synchronous=NORMAL`` makes a commit durable against
a crash of the *process* (the write has reached the kernel when ``commit``
returns), which is what a registrar must survive; a power cut may lose the
last few commits, never the file's consistency.

Every open is a new *incarnation* of the registrar: its number is one more
than the last one recorded. Ids stay unique across incarnations because the
journal also keeps the highest id ever handed out, and the id generator of the
next incarnation starts above it (``id_floor``), whatever the clock says.

A journal belongs to one run of the ROS master: a new master (``/run_id``)
means the processes, topics and consumers it records are gone, so the journal
starts empty (its incarnation count and id floor are kept).
"""
import contextlib
import dataclasses
import os
import sqlite3
import threading
import time
from typing import Dict, Iterator, List, Optional

SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS incarnations (n INTEGER PRIMARY KEY, pid INTEGER NOT NULL, started REAL NOT NULL);
CREATE TABLE IF NOT EXISTS served (
    internal_id INTEGER PRIMARY KEY, server TEXT NOT NULL, state TEXT NOT NULL,
    request_type TEXT NOT NULL, request BLOB NOT NULL, response BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS consumers (
    server TEXT NOT NULL, external_id INTEGER NOT NULL, internal_id INTEGER NOT NULL,
    status_topic TEXT NOT NULL, client_name TEXT NOT NULL, namespace TEXT NOT NULL, uri TEXT NOT NULL,
    incarnation INTEGER NOT NULL, PRIMARY KEY (server, external_id));
CREATE TABLE IF NOT EXISTS held (
    namespace TEXT NOT NULL, rr TEXT NOT NULL, server TEXT NOT NULL, external_id INTEGER NOT NULL,
    request_type TEXT NOT NULL, request BLOB NOT NULL, response BLOB NOT NULL,
    PRIMARY KEY (namespace, rr, server, external_id));
CREATE TABLE IF NOT EXISTS holds (
    local_id INTEGER PRIMARY KEY, namespace TEXT NOT NULL, rr TEXT NOT NULL, server TEXT NOT NULL,
    external_id INTEGER NOT NULL, parent INTEGER);
CREATE TABLE IF NOT EXISTS owner_state (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS failures (internal_id INTEGER PRIMARY KEY, reason TEXT NOT NULL);
"""


@dataclasses.dataclass
class JournaledConsumer:
    external_id: int
    status_topic: str
    client_name: str
    namespace: str
    uri: str
    incarnation: int = 0


@dataclasses.dataclass
class JournaledServed:
    internal_id: int
    server: str
    state: str
    request_type: str
    request: bytes
    response: bytes
    consumers: List[JournaledConsumer]
    reason: str = ''          # why it failed, when its state is FAILED ('' in a journal of an older version)


@dataclasses.dataclass
class JournaledHold:
    local_id: int
    target: tuple             # (namespace, registrar, server)
    external_id: int
    request_type: str
    request: bytes
    response: bytes
    parent: Optional[int]     # internal id of the served resource it is linked to


@dataclasses.dataclass
class JournalContents:
    served: List[JournaledServed]
    holds: List[JournaledHold]


class JournalError(RuntimeError):
    """The journal file cannot be used (not a journal, a newer schema, or unreadable)."""


class Journal:
    """One registrar's journal. Thread-safe; every method is one transaction."""

    def __init__(self, path: str, run_id: str = '') -> None:
        directory = os.path.dirname(os.path.abspath(path))
        os.makedirs(directory, exist_ok=True)
        self.path = path
        self._lock = threading.RLock()
        self._in_batch = False
        self._floor_dirty = False      # the id floor was raised in the batch under way
        try:
            self._db = sqlite3.connect(path, timeout=5.0, isolation_level=None, check_same_thread=False)
            self._db.execute('PRAGMA journal_mode=WAL')
            self._db.execute('PRAGMA synchronous=NORMAL')
            self._db.executescript(_SCHEMA)
            with self._transaction() as db:
                version = self._meta(db, 'schema', str(SCHEMA_VERSION))
                if int(version) > SCHEMA_VERSION:
                    raise JournalError('%s has journal schema %s; this registrar reads up to %d'
                                       % (path, version, SCHEMA_VERSION))
                last = db.execute('SELECT COALESCE(MAX(n), 0) FROM incarnations').fetchone()[0]
                self.incarnation = last + 1
                db.execute('INSERT INTO incarnations VALUES (?, ?, ?)', (self.incarnation, os.getpid(), time.time()))
                self.previous_run = self._meta(db, 'run_id', run_id)
                if run_id and self.previous_run != run_id:
                    # another master: nothing it recorded exists any more
                    for table in ('served', 'consumers', 'held', 'holds', 'failures'):
                        db.execute('DELETE FROM %s' % table)
                    db.execute('UPDATE meta SET value = ? WHERE key = ?', (run_id, 'run_id'))
                self._id_floor = int(self._meta(db, 'id_floor', '0'))
        except sqlite3.DatabaseError as err:
            raise JournalError('journal %s cannot be used: %s' % (path, err)) from err

    # ------------------------------------------------------------------------------------------ plumbing
    class _Tx:
        """One transaction, or one step of the batch under way (:meth:`Journal.batch`)."""

        def __init__(self, journal: 'Journal') -> None:
            self._journal = journal
            self._own = False

        def __enter__(self) -> sqlite3.Connection:
            self._journal._lock.acquire()
            self._own = not self._journal._in_batch
            if self._own:
                self._journal._db.execute('BEGIN IMMEDIATE')
            return self._journal._db

        def __exit__(self, kind, value, tb) -> None:
            try:
                if self._own:
                    self._journal._db.execute('COMMIT' if kind is None else 'ROLLBACK')
            finally:
                self._journal._lock.release()

    @contextlib.contextmanager
    def batch(self) -> Iterator[None]:
        """Many changes in one transaction (group commit): all of them are there after a crash, or none."""
        with self._lock:
            self._db.execute('BEGIN IMMEDIATE')
            self._in_batch, self._floor_dirty = True, False
            floor = self._id_floor
            try:
                yield
                if self._floor_dirty:
                    self._write_floor(self._db)
            except BaseException:
                self._db.execute('ROLLBACK')
                self._id_floor = floor
                raise
            else:
                self._db.execute('COMMIT')
            finally:
                self._in_batch = False

    def _transaction(self) -> '_Tx':
        return Journal._Tx(self)

    @staticmethod
    def _meta(db: sqlite3.Connection, key: str, default: str) -> str:
        row = db.execute('SELECT value FROM meta WHERE key = ?', (key,)).fetchone()
        if row is None:
            db.execute('INSERT INTO meta VALUES (?, ?)', (key, default))
            return default
        return row[0]

    def _raise_floor(self, db: sqlite3.Connection, *ids: int) -> None:
        """Raise the id floor; within a batch, written once when the batch commits (ids only grow, so one
        write of the highest does for all)."""
        top = max(ids)
        if top > self._id_floor:
            self._id_floor = top
            if self._in_batch:
                self._floor_dirty = True
            else:
                self._write_floor(db)

    def _write_floor(self, db: sqlite3.Connection) -> None:
        db.execute('UPDATE meta SET value = ? WHERE key = ?', (str(self._id_floor), 'id_floor'))

    @property
    def id_floor(self) -> int:
        """Every id handed out by an earlier incarnation is at most this."""
        return self._id_floor

    # ------------------------------------------------------------------------------------------ served
    def serve(self, internal_id: int, server: str, request_type: str, request: bytes, response: bytes,
              external_id: int, consumer: JournaledConsumer) -> None:
        """A resource has loaded, with its first consumer."""
        with self._transaction() as db:
            db.execute('INSERT OR REPLACE INTO served VALUES (?, ?, ?, ?, ?, ?)',
                       (internal_id, server, 'active', request_type, request, response))
            self._put_consumer(db, server, internal_id, consumer)
            self._raise_floor(db, internal_id, external_id)

    def attach(self, server: str, internal_id: int, consumer: JournaledConsumer) -> None:
        with self._transaction() as db:
            self._put_consumer(db, server, internal_id, consumer)
            self._raise_floor(db, consumer.external_id)

    @staticmethod
    def _put_consumer(db: sqlite3.Connection, server: str, internal_id: int, c: JournaledConsumer) -> None:
        db.execute('INSERT OR REPLACE INTO consumers VALUES (?, ?, ?, ?, ?, ?, ?, ?)',
                   (server, c.external_id, internal_id, c.status_topic, c.client_name, c.namespace, c.uri,
                    c.incarnation))

    def detach(self, server: str, external_id: int) -> None:
        with self._transaction() as db:
            db.execute('DELETE FROM consumers WHERE server = ? AND external_id = ?', (server, external_id))

    def mark(self, internal_id: int, state: str, reason: str = '') -> None:
        """A served resource's new state, and why (a FAILED's reason survives a restart of the owner)."""
        with self._transaction() as db:
            db.execute('UPDATE served SET state = ? WHERE internal_id = ?', (state, internal_id))
            if reason:
                db.execute('INSERT OR REPLACE INTO failures VALUES (?, ?)', (internal_id, reason))

    def unserve(self, internal_id: int) -> None:
        """A served resource is gone: with its consumers, and the links to what it held."""
        with self._transaction() as db:
            db.execute('DELETE FROM served WHERE internal_id = ?', (internal_id,))
            db.execute('DELETE FROM failures WHERE internal_id = ?', (internal_id,))
            db.execute('DELETE FROM consumers WHERE internal_id = ?', (internal_id,))
            db.execute('UPDATE holds SET parent = NULL WHERE parent = ?', (internal_id,))

    # ------------------------------------------------------------------------------------------ held
    def hold(self, local_id: int, target: tuple, external_id: int, request_type: str, request: bytes,
             response: bytes, parent: Optional[int]) -> None:
        """This registrar holds a resource of another under ``local_id``."""
        with self._transaction() as db:
            db.execute('INSERT OR IGNORE INTO held VALUES (?, ?, ?, ?, ?, ?, ?)',
                       tuple(target) + (external_id, request_type, request, response))
            db.execute('INSERT OR REPLACE INTO holds VALUES (?, ?, ?, ?, ?, ?)',
                       (local_id,) + tuple(target) + (external_id, parent))
            self._raise_floor(db, local_id)

    def link(self, local_id: int, parent: Optional[int]) -> None:
        with self._transaction() as db:
            db.execute('UPDATE holds SET parent = ? WHERE local_id = ?', (parent, local_id))

    def release(self, local_id: int) -> None:
        """``local_id`` is released; the held resource goes with its last local id."""
        with self._transaction() as db:
            row = db.execute('SELECT namespace, rr, server, external_id FROM holds WHERE local_id = ?',
                             (local_id,)).fetchone()
            if row is None:
                return
            db.execute('DELETE FROM holds WHERE local_id = ?', (local_id,))
            left = db.execute('SELECT COUNT(*) FROM holds WHERE namespace = ? AND rr = ? AND server = ? AND '
                              'external_id = ?', row).fetchone()[0]
            if not left:
                db.execute('DELETE FROM held WHERE namespace = ? AND rr = ? AND server = ? AND external_id = ?', row)

    # ------------------------------------------------------------------------------------------ owner state
    def put_owner_state(self, key: str, value: str) -> None:
        """State of the registrar's owner that must survive it (a sensor's reliability history)."""
        with self._transaction() as db:
            db.execute('INSERT OR REPLACE INTO owner_state VALUES (?, ?)', (key, value))

    def drop_owner_state(self, key: str) -> None:
        with self._transaction() as db:
            db.execute('DELETE FROM owner_state WHERE key = ?', (key,))

    def owner_state(self) -> Dict[str, str]:
        with self._lock:
            return dict(self._db.execute('SELECT key, value FROM owner_state').fetchall())

    # ------------------------------------------------------------------------------------------ reading
    def contents(self) -> JournalContents:
        """Everything recorded, as the last incarnation left it."""
        with self._lock:
            db = self._db
            consumers: Dict[int, List[JournaledConsumer]] = {}
            for server, ext, internal, topic, name, ns, uri, incarnation in db.execute(
                    'SELECT * FROM consumers ORDER BY external_id'):
                consumers.setdefault(internal, []).append(JournaledConsumer(ext, topic, name, ns, uri, incarnation))
            reasons = dict(db.execute('SELECT internal_id, reason FROM failures').fetchall())
            served = [JournaledServed(i, server, state, rtype, bytes(req), bytes(res), consumers.get(i, []),
                                      reasons.get(i, ''))
                      for i, server, state, rtype, req, res in db.execute('SELECT * FROM served ORDER BY internal_id')]
            holds = [JournaledHold(local_id, (ns, rr, server), ext, rtype, bytes(req), bytes(res), parent)
                     for local_id, ns, rr, server, ext, parent, rtype, req, res in db.execute(
                         'SELECT h.local_id, h.namespace, h.rr, h.server, h.external_id, h.parent, d.request_type, '
                         'd.request, d.response FROM holds h JOIN held d USING (namespace, rr, server, external_id) '
                         'ORDER BY h.local_id')]
            return JournalContents(served, holds)

    def incarnations(self) -> List[tuple]:
        with self._lock:
            return self._db.execute('SELECT n, pid, started FROM incarnations ORDER BY n').fetchall()

    def close(self) -> None:
        with self._lock:
            self._db.close()
