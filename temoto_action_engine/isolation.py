"""The engine's side of graph isolation: worker processes, and the graphs they run, seen from here.

Each graph runs in a worker process of its own (``worker.py``). Here:

- ``WorkerPool`` starts workers, keeping ``spares`` of them started ahead of need, so that a new
  graph does not wait for Python, rospy and the master (about 0.5 to 1 s here).
- ``WorkerGraph`` stands for a graph in a worker. It offers what the engine uses of an in-process
  ``GraphRun`` (start, stop, stop one node, running nodes, state, JSON) and mirrors the state the
  worker reports. Its guarantees:

  * a worker that dies without saying its graph finished (``os._exit`` in a plugin, a crash in C,
    SIGKILL) ends the graph FAILED, every node that was not done with it, with the exit reason
    ("its worker process died (killed by SIGSEGV)"); the engine itself carries on;
  * a graph or node that does not stop within the stop timeout has its worker ended (SIGTERM,
    which releases what it can within 3 s, then SIGKILL): it ends FAILED, saying so. What a
    killed worker held is released by the managers, as for any consumer whose node died;
  * a dead worker's registrations are removed from the master, so ``rosnode list`` stays true.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from typing import Callable

import rospy
from temoto_core.master_lookup import cleanup_dead_node
from temoto_core.process_group import escalate

from . import worker_protocol as wp
from .graph import FAILED, TERMINAL, GraphRun
from .umrf import GraphSpec

READY_TIMEOUT_S = 30.0       # s a new worker may take to register (a loaded machine, a slow master)
START_ACK_S = 10.0           # s start() waits for the worker to have started the graph's first nodes
TERM_GRACE_S = 5.0           # s between SIGTERM and SIGKILL when a worker is ended
RESPAWN_BACKOFF_S = (0.5, 1.0, 2.0, 5.0)


def exit_reason(returncode: int | None) -> str:
    if returncode is None:
        return 'still running'
    if returncode < 0:
        try:
            return 'killed by %s' % signal.Signals(-returncode).name
        except ValueError:
            return 'killed by signal %d' % -returncode
    return 'exited with code %d' % returncode


class WorkerProcess:
    """One worker: the child process, its pipe, and the thread that reads what it says."""

    def __init__(self, argv: list[str], env: dict[str, str], node_name: str):
        self.node_name = node_name
        self.ready = threading.Event()
        self.exited = threading.Event()
        self.handler: Callable[[dict], None] | None = None      # set by the WorkerGraph that takes it
        self.on_exit: Callable[['WorkerProcess'], None] | None = None
        self._early: list[dict] = []                             # messages before a handler was set
        self._lock = threading.Lock()
        # its own session: a Ctrl-C in the engine's terminal is the engine's to handle, not the graph's
        self.proc = subprocess.Popen(argv, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     start_new_session=True, close_fds=True)
        self.pid = self.proc.pid
        self.writer = wp.LineWriter(self.proc.stdin)
        self._reader = threading.Thread(target=self._read, daemon=True, name='worker-%d' % self.pid)
        self._reader.start()

    def send(self, **msg) -> bool:
        return self.writer.send(**msg)

    def attach(self, handler: Callable[[dict], None], on_exit: Callable[['WorkerProcess'], None]) -> None:
        with self._lock:
            self.handler, self.on_exit = handler, on_exit
            early, self._early = self._early, []
            exited = self.exited.is_set()
        for msg in early:
            handler(msg)
        if exited:
            on_exit(self)

    def _read(self) -> None:
        for line in iter(self.proc.stdout.readline, b''):
            if len(line) > wp.MAX_LINE:
                rospy.logerr('graph worker %d sent a line of %d bytes; ignored' % (self.pid, len(line)))
                continue
            msg = wp.decode(line)
            if msg is None:
                rospy.logerr('graph worker %d sent a line that is not a JSON object: %r' % (self.pid, line[:200]))
                continue
            if msg.get('kind') == wp.READY:
                self.ready.set()
            with self._lock:
                handler = self.handler
                if handler is None:
                    self._early.append(msg)
            if handler is not None:
                handler(msg)
        self.proc.wait()
        self.writer.close()
        self.proc.stdout.close()
        try:
            cleanup_dead_node(os.environ.get('ROS_MASTER_URI', ''), self.node_name)
        except (OSError, ValueError) as e:
            rospy.logwarn('could not clean %s from the master: %s' % (self.node_name, e))
        with self._lock:
            self.exited.set()
            on_exit = self.on_exit
        if on_exit is not None:
            on_exit(self)

    @property
    def returncode(self) -> int | None:
        return self.proc.returncode

    def end(self, grace: float = TERM_GRACE_S) -> None:
        """SIGTERM (the worker releases what it can), then SIGKILL; returns once it has exited."""
        def send(sig: int) -> None:
            try:
                os.killpg(self.pid, sig)
            except ProcessLookupError:
                pass
        escalate(((signal.SIGTERM, grace), (signal.SIGKILL, grace)), send, self.exited.wait)

    def close(self) -> None:
        """An unused spare: its end of file makes it exit; end it if it does not."""
        self.writer.close()
        if not self.exited.wait(3.0):
            self.end(1.0)


class WorkerPool:
    """Starts workers, from one long-lived thread, keeping ``spares`` started ahead of need."""

    def __init__(self, namespace: str, stop_timeout: float, spares: int = 1, env: dict | None = None):
        self.namespace = namespace
        self.stop_timeout = stop_timeout
        self.spares = max(0, int(spares))
        self._env = dict(env if env is not None else os.environ)
        self._cond = threading.Condition()
        self._ready: list[WorkerProcess] = []
        self._starting = 0
        self._wanted = 0               # take() calls waiting beyond the spares
        self._closed = False
        self._count = 0
        self._last_error = ''
        self._thread = threading.Thread(target=self._keep_spares, daemon=True, name='worker-pool')
        self._thread.start()

    def _argv(self, node_name: str) -> list[str]:
        return [sys.executable, '-m', 'temoto_action_engine.worker', '--node-name', node_name,
                '--temoto-namespace', self.namespace, '--stop-timeout', repr(self.stop_timeout)]

    def _spawn(self) -> WorkerProcess | None:
        self._count += 1
        # beside the engine, in its ROS namespace: /<ns>/<engine>_worker_<engine pid>_<n>
        base = rospy.get_name().rsplit('/', 1)[-1] or 'temoto_action_engine'
        name = '%s_worker_%d_%d' % (base, os.getpid(), self._count)
        env = dict(self._env, ROS_NAMESPACE=rospy.get_namespace())
        try:
            worker = WorkerProcess(self._argv(name), env, rospy.get_namespace() + name)
        except OSError as e:
            self._last_error = 'could not start a graph worker: %s' % e
            return None
        if worker.ready.wait(READY_TIMEOUT_S) and not worker.exited.is_set():
            return worker
        self._last_error = 'a graph worker did not start within %.0f s (%s)' % (
            READY_TIMEOUT_S, exit_reason(worker.returncode) if worker.exited.is_set() else 'no answer')
        worker.close()
        return None

    def _keep_spares(self) -> None:
        failures = 0
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._closed or
                                    len(self._ready) + self._starting < self.spares + self._wanted)
                if self._closed:
                    return
                self._starting += 1
            worker = self._spawn()
            with self._cond:
                self._starting -= 1
                if worker is not None:
                    self._ready.append(worker)
                    failures = 0
                else:
                    failures += 1
                    rospy.logerr(self._last_error)
                self._cond.notify_all()
            if worker is None:
                time.sleep(RESPAWN_BACKOFF_S[min(failures, len(RESPAWN_BACKOFF_S)) - 1])

    def take(self, timeout: float = READY_TIMEOUT_S) -> WorkerProcess:
        """A started worker, for one graph. Raises RuntimeError when none starts within ``timeout``."""
        deadline = time.monotonic() + timeout
        with self._cond:
            self._wanted += 1
            self._cond.notify_all()
            try:
                while True:
                    if self._closed:
                        raise RuntimeError('the engine is shutting down')
                    self._ready = [w for w in self._ready if not w.exited.is_set()]
                    if self._ready:
                        return self._ready.pop(0)
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise RuntimeError(self._last_error or 'no graph worker started within %.0f s' % timeout)
                    self._cond.wait(min(left, 1.0))
            finally:
                self._wanted -= 1
                self._cond.notify_all()

    def shutdown(self) -> None:
        with self._cond:
            self._closed = True
            spares, self._ready = self._ready, []
            self._cond.notify_all()
        for w in spares:
            w.close()


class RemoteNode:
    """A node of a graph in a worker, as ``ActionEngine.stop_actions`` reads it."""

    def __init__(self, key: str, indexed, inputs: dict):
        self.key = key
        self.indexed = indexed
        self.inputs = inputs


class WorkerGraph:
    """A graph running in a worker process, with the face of a ``GraphRun``."""

    def __init__(self, spec: GraphSpec, index, worker: WorkerProcess, config: dict,
                 on_event: Callable[[dict], None], on_feedback: Callable[[str], None],
                 on_finished: Callable[['WorkerGraph'], None],
                 serve_request: Callable[['WorkerGraph', dict], None]):
        self.spec = spec
        self.name = spec.name
        self.worker = worker
        self._index = index
        self._indexed = {key: index.action(n.name) for key, n in spec.nodes.items()}
        self._config = config
        self._on_event = on_event
        self._on_feedback = on_feedback
        self._on_finished = on_finished
        self._serve_request = serve_request
        self._cond = threading.Condition()
        # before the worker says anything: every node WAITING, as an in-process graph starts
        self._snapshot = GraphRun(spec, index, None).to_json()
        self.finished = False
        self._started = False          # the worker has started the nodes that can start
        self._end_reason = ''          # set when the engine ends the worker on purpose

    # ------------------------------------------------------------------ GraphRun's face
    def start(self) -> None:
        plugins = {n.name: self._index.get(n.name).source for n in self.spec.nodes.values()}
        self.worker.attach(self._on_message, self._on_exit)
        if not self.worker.send(op=wp.RUN, graph=self.spec.to_json(self._index), plugins=plugins,
                                config=self._config):
            self.worker.end()
        # as an in-process graph does, return once the first nodes are RUNNING: a list_graphs right
        # after start_graph then shows them running (it showed WAITING, 1 run in 10 of make test under load)
        with self._cond:
            self._cond.wait_for(lambda: self._started or self.finished, START_ACK_S)

    def stop(self, timeout: float = 10.0) -> list[str]:
        """Stop every node; a worker that has not finished its graph within ``timeout`` is ended.

        Returns the keys of the nodes that did not stop in time (they end FAILED, with the worker).
        """
        self.worker.send(op=wp.STOP)
        if self.wait(timeout):
            return []
        left = [k for k, n in self._nodes().items() if n['state'] not in TERMINAL]
        self._end('%s did not stop within %.0f s; its worker process was ended'
                  % (', '.join(left) or 'the graph', timeout))
        return left

    def stop_node(self, key: str, timeout: float = 10.0) -> bool:
        """Stop one node; if it does not end within ``timeout``, the whole worker is ended."""
        self.worker.send(op=wp.STOP_NODE, key=key)
        with self._cond:
            if self._cond.wait_for(lambda: self._nodes().get(key, {}).get('state') in TERMINAL, timeout):
                return True
        self._end('%s did not stop within %.0f s; its worker process was ended' % (key, timeout))
        return False

    def reap(self, timeout: float = TERM_GRACE_S) -> None:
        """Wait for the worker to exit (a finished graph's worker still shuts its rospy down); end it if not."""
        if not self.worker.exited.wait(timeout):
            self.worker.end()

    def wait(self, timeout: float) -> bool:
        """True once the graph is finished (every node done), waiting up to ``timeout`` s."""
        with self._cond:
            return self._cond.wait_for(lambda: self.finished, timeout)

    def running_nodes(self) -> list[RemoteNode]:
        with self._cond:
            return [RemoteNode(k, self._indexed[k], dict(n.get('inputs') or {}))
                    for k, n in self._nodes().items() if n['state'] == 'RUNNING']

    @property
    def state(self) -> str:
        with self._cond:
            return self._snapshot['state']

    def to_json(self) -> dict:
        with self._cond:
            return dict(self._snapshot, worker_pid=self.worker.pid)

    # ------------------------------------------------------------------ internals
    def _nodes(self) -> dict[str, dict]:
        return {'%s_%d' % (n['name'], n['instance_id']): n for n in self._snapshot['nodes']}

    def _end(self, reason: str) -> None:
        with self._cond:
            if self.finished:
                return
            self._end_reason = self._end_reason or reason
        rospy.logwarn('graph %s: %s' % (self.name, reason))
        self.worker.end()
        with self._cond:
            self._cond.wait_for(lambda: self.finished, TERM_GRACE_S)

    def _on_message(self, msg: dict) -> None:
        kind = msg.get('kind')
        if kind == wp.EVENT and isinstance(msg.get('event'), dict):
            self._on_event(msg['event'])
        elif kind == wp.FEEDBACK:
            self._on_feedback(str(msg.get('text', '')))
        elif kind in (wp.SNAPSHOT, wp.FINISHED) and isinstance(msg.get('graph'), dict):
            with self._cond:
                if not self.finished:
                    self._snapshot = msg['graph']
                self._started = self._started or bool(msg.get('started'))
                self._cond.notify_all()
            if kind == wp.FINISHED:
                # everything it held is released: done now, not once its rospy has shut down
                self._finish(announce=False)
        elif kind == wp.REQUEST:
            threading.Thread(target=self._serve_request, args=(self, msg), daemon=True).start()
        elif kind == wp.REFUSED:
            self._fail_open_nodes('the worker could not start it: %s' % msg.get('message', ''))
        elif kind != wp.READY:
            rospy.logwarn('graph %s: its worker sent an unknown message %r' % (self.name, kind))

    def _on_exit(self, worker: WorkerProcess) -> None:
        with self._cond:
            if self.finished:
                return
            reason = self._end_reason or 'its worker process died (%s)' % exit_reason(worker.returncode)
        self._fail_open_nodes(reason)

    def _fail_open_nodes(self, reason: str) -> None:
        """Every node not done is FAILED with ``reason``, and so is the graph; then it is finished."""
        events = []
        with self._cond:
            if self.finished:
                return
            for n in self._snapshot['nodes']:
                if n['state'] not in TERMINAL:
                    n['state'], n['message'] = FAILED, reason
                    events.append({'event': 'state', 'graph': self.name, 'action': n['name'],
                                   'instance_id': n['instance_id'], 'state': FAILED, 'message': reason})
            self._snapshot['state'] = FAILED
            if not self._snapshot.get('reason'):
                self._snapshot['reason'] = reason
        for ev in events:
            self._on_event(ev)
        self._finish()

    def _finish(self, announce: bool = True) -> None:
        """The graph is done. ``announce``: the worker did not say so itself (it died, or refused it)."""
        with self._cond:
            if self.finished:
                return
            self.finished = True
            if self._snapshot['state'] not in (FAILED, 'FINISHED'):
                self._snapshot['state'] = FAILED if self._snapshot.get('reason') else 'FINISHED'
            self._cond.notify_all()
            state, reason = self._snapshot['state'], self._snapshot.get('reason', '')
        if announce:
            self._on_event({'event': 'graph_finished', 'graph': self.name, 'state': state, 'reason': reason})
        self._on_finished(self)
