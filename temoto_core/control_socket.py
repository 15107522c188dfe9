"""One JSON command over a Unix socket, one JSON answer: how a runner drives a node from outside the ROS graph.

A file-system socket is reached from every network namespace and works while the master is out of reach,
which is exactly when a test or a chaos runner needs to see both sides.
"""
import json
import socket


def ask(path: str, cmd: dict, timeout: float) -> dict:
    """Send ``cmd`` to the node listening on ``path``; its answer. Raises OSError (or ValueError on a garbled
    answer) if it does not answer within ``timeout``."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        sock.connect(path)
        sock.sendall(json.dumps(cmd).encode() + b'\n')
        with sock.makefile('rb') as answer:
            return json.loads(answer.readline())
