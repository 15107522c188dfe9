"""The control socket (temoto_core/control_socket.py): its path appears only once the server listens, so
whoever waits for the file may connect at once (chaos seed 17, step 8077: a restarted client's socket file
was there, and its first two calls were refused)."""
import os
import socket
import socketserver
import threading

from temoto_core import control_socket


class Echo(socketserver.StreamRequestHandler):
    def handle(self):
        self.wfile.write(self.rfile.readline())


def test_the_path_appears_only_once_the_server_listens(tmp_path):
    path = str(tmp_path / 'node.sock')
    seen_before_listen = []

    class Watched(control_socket.Server):
        def server_activate(self):
            seen_before_listen.append(os.path.exists(path))
            super().server_activate()

    server = Watched(path, Echo)
    try:
        assert seen_before_listen == [False]
        assert os.path.exists(path) and sorted(os.listdir(tmp_path)) == ['node.sock']   # no private path left
    finally:
        server.server_close()


def test_a_socket_file_a_killed_incarnation_left_is_replaced_and_answers(tmp_path):
    path = str(tmp_path / 'node.sock')
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(path)            # bound, never listening: connections to it are refused, as to a dead node's
    stale.close()
    server = control_socket.Server(path, Echo)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        assert control_socket.ask(path, {'op': 'state'}, 5.0) == {'op': 'state'}
    finally:
        server.shutdown()
        server.server_close()


def test_serve_answers_each_command_and_names_a_bad_one(tmp_path):
    path = str(tmp_path / 'node.sock')
    seen = []

    def handle(cmd: dict) -> dict:
        if cmd['op'] == 'boom':
            raise RuntimeError('kaput')
        seen.append(cmd)
        return {'ok': True, 'op': cmd['op']}

    server = control_socket.serve(path, handle, 'test-control',
                                  lambda line, e: {'ok': False, 'unexpected': '%s: %s' % (type(e).__name__, e)})
    try:
        assert control_socket.ask(path, {'op': 'state'}, 5.0) == {'ok': True, 'op': 'state'}
        missing = control_socket.ask(path, {'no_op': 1}, 5.0)       # KeyError in handle: a bad command
        assert missing['ok'] is False and 'bad command' in missing['error'] and 'no_op' in missing['error']
        assert control_socket.ask(path, {'op': 'boom'}, 5.0) == {'ok': False, 'unexpected': 'RuntimeError: kaput'}
        assert seen == [{'op': 'state'}]
    finally:
        server.shutdown()
        server.server_close()
