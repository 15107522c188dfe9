"""One loaded resource: the processes of a node, a command, or every node of a launch file.

They live and die together: the resource is ready once every process is, it
fails when any of them exits on its own, and unloading it stops them all. The
flags below are changed under ``lock`` so that a load, an unload and an exit
report that race each other agree on what happened (exactly one of: the load
fails, the unload stops it, or one FAILED is reported).
"""
from __future__ import annotations

import threading
import time
from typing import Optional

from .resolve import Plan
from .supervisor import ManagedProcess


class Resource:
    def __init__(self, resource_id: int, plan: Plan):
        self.resource_id = resource_id
        self.plan = plan
        self.procs: list[ManagedProcess] = []
        self.lock = threading.Lock()
        self.ready = False          # every process started: later exits are failures of the resource
        self.stopping = False       # unloaded or shutting down: exits are intentional
        self.failed_by: Optional[ManagedProcess] = None     # the process whose exit failed it
        self.created = time.time()

    @property
    def label(self) -> str:
        return self.plan.label

    @property
    def pid(self) -> int:
        """The pid in the load response: the process, or a launch file's first node."""
        return self.procs[0].pid if self.procs else 0

    def node_of(self, proc: ManagedProcess) -> str:
        return ', '.join(proc.spec.node_names) or proc.spec.label

    def state(self) -> str:
        states = [p.state for p in self.procs]
        if states and all(s == 'exited' for s in states):
            return 'exited'
        if self.stopping or self.failed_by is not None or 'stopping' in states:
            return 'stopping'
        if not self.ready:
            return 'starting'
        return 'running'

    def snapshot(self) -> dict:
        """One row for ``temoto ps``: the resource, with a sub-row per process."""
        procs = [p.snapshot() for p in self.procs]
        started = min((p['started'] for p in procs), default=self.created)
        ended = [p.exit_info.when for p in self.procs if p.exit_info is not None]
        end = max(ended) if ended and len(ended) == len(self.procs) else time.time()
        failed = self.failed_by.exit_info if self.failed_by is not None else None
        return {
            'resource_id': self.resource_id, 'label': self.label, 'pid': self.pid,
            'pids': [p['pid'] for p in procs], 'command': self.plan.command, 'log_path': self.plan.log_path,
            'node_names': [n for p in procs for n in p['node_names']], 'nodes': [n for p in procs for n in p['nodes']],
            'started': started,
            'uptime': end - started, 'state': self.state(),
            'returncode': failed.returncode if failed else None,
            'processes': procs,
        }
