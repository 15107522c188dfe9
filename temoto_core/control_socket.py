"""One JSON command over a Unix socket, one JSON answer: how a runner drives a node from outside the ROS graph.

A file-system socket is reached from every network namespace and works while the master is out of reach,
which is exactly when a test or a chaos runner needs to see both sides.
"""
import json
import os
import socket
import socketserver
import threading
from typing import Callable, Optional

BAD_COMMAND = (ValueError, KeyError, TypeError)    # a line that is not JSON, or a command missing or mistyping a field


def ask(path: str, cmd: dict, timeout: float) -> dict:
    """Send ``cmd`` to the node listening on ``path``; its answer. Raises OSError (or ValueError on a garbled
    answer) if it does not answer within ``timeout``."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        sock.connect(path)
        sock.sendall(json.dumps(cmd).encode() + b'\n')
        with sock.makefile('rb') as answer:
            return json.loads(answer.readline())


class Server(socketserver.ThreadingMixIn, socketserver.UnixStreamServer):
    """A threaded Unix stream server whose path appears only once it listens.

    Bound at its path, a socket file exists from ``bind()`` on, and a connection is refused until
    ``listen()``; a node's other threads may run in between for several milliseconds. A runner that took
    the file for the node's readiness asked at once, was refused, and reported a client that did not
    answer (chaos seed 17, step 8077, right after a killed client started again). So the server binds at a
    private path, listens, and only then moves its socket to ``path`` (``os.replace``, atomic; a socket
    file a killed incarnation left there is replaced in the same step).
    """
    daemon_threads = True

    def __init__(self, path: str, handler: type) -> None:
        private = '%s.%d' % (path, os.getpid())
        if os.path.exists(private):
            os.unlink(private)
        super().__init__(private, handler)       # bind and listen
        try:
            os.replace(private, path)
        except OSError:
            self.server_close()
            os.unlink(private)
            raise
        self.server_address = path


def serve(path: str, handle: Callable[[dict], dict], thread_name: str,
          unexpected: Optional[Callable[[bytes, Exception], dict]] = None) -> Server:
    """Answer, from a daemon thread, each JSON line sent to ``path`` with ``handle(command)``; the server,
    to ``shutdown()`` when the node ends.

    A bad command (``BAD_COMMAND``) is answered ``{'ok': False, 'error': ...}`` naming the line. Anything else
    ``handle`` raises goes to ``unexpected(line, error)`` for its answer, when given; otherwise it ends that
    connection, and the runner's read of the answer fails.
    """
    class Handler(socketserver.StreamRequestHandler):
        def handle(self) -> None:
            for line in self.rfile:
                try:
                    answer = handle(json.loads(line))
                except BAD_COMMAND as e:
                    answer = {'ok': False, 'error': 'bad command %r: %s' % (line[:200], e)}
                except Exception as e:
                    if unexpected is None:
                        raise
                    answer = unexpected(line, e)
                self.wfile.write(json.dumps(answer).encode() + b'\n')
                self.wfile.flush()

    server = Server(path, Handler)
    threading.Thread(target=server.serve_forever, name=thread_name, daemon=True).start()
    return server
