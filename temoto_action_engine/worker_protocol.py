"""The pipe between the engine and a graph worker: one JSON object per line, each way.

Why a pipe and not ROS: the worker is the engine's own child. The pipe needs no name on the
master, cannot be reached by anyone else, and its end of file tells each side at once that the
other is gone (a SIGKILLed engine closes every worker's stdin; a dead worker closes its stdout).

Engine to worker (the worker's stdin), field ``op``:
- ``run``        the graph to run: ``graph`` (UMRF JSON), ``plugins`` (action name -> descriptor
                 path, the files the engine indexed), ``config`` (per-action settings)
- ``stop``       stop the whole graph
- ``stop_node``  stop one node: ``key``
- ``reply``      the answer to a worker's ``request``: ``id``, ``result`` or ``error``

Worker to engine (the worker's stdout), field ``kind``:
- ``ready``      started, registered with the master, waiting for ``run``: ``pid``, ``node``
- ``event``      an event for the events topic (state changes, action events): ``event``
- ``feedback``   a sentence for the operator: ``text``
- ``snapshot``   the graph's state as ``list_graphs`` shows it: ``graph``; ``started`` on the one
                 sent once the nodes that could start are RUNNING (``start_graph`` waits for it)
- ``request``    a question to the engine (``stop_actions``, ``running_actions``): ``id``, ``op``, ...
- ``refused``    the graph could not be started here: ``message``
- ``finished``   the graph is done and everything it held is released: ``graph``
"""
from __future__ import annotations

import json
import threading
from typing import IO, Any

# engine -> worker
RUN = 'run'
STOP = 'stop'
STOP_NODE = 'stop_node'
REPLY = 'reply'
# worker -> engine
READY = 'ready'
EVENT = 'event'
FEEDBACK = 'feedback'
SNAPSHOT = 'snapshot'
REQUEST = 'request'
REFUSED = 'refused'
FINISHED = 'finished'

MAX_LINE = 4 << 20     # bytes; a graph snapshot is a few kB, so a longer line is a broken peer


def decode(line: bytes) -> dict | None:
    """One message, or None for a line that is not a JSON object (logged by the caller)."""
    try:
        msg = json.loads(line.decode('utf-8'))
    except (UnicodeDecodeError, ValueError):
        return None
    return msg if isinstance(msg, dict) else None


class LineWriter:
    """Writes messages to a binary stream from any thread; a closed peer makes ``send`` return False."""

    def __init__(self, stream: IO[bytes]):
        self._stream = stream
        self._lock = threading.Lock()
        self.closed = False

    def send(self, **msg: Any) -> bool:
        data = (json.dumps(msg, sort_keys=True, default=str) + '\n').encode('utf-8')
        with self._lock:
            if self.closed:
                return False
            try:
                self._stream.write(data)
                self._stream.flush()
                return True
            except (BrokenPipeError, ValueError, OSError):
                self.closed = True     # the peer is gone; its end of file tells it the rest
                return False

    def close(self) -> None:
        with self._lock:
            self.closed = True
            try:
                self._stream.close()
            except OSError:
                pass
