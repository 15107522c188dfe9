"""Running ``temoto demo`` from a test, as a user runs it.

The demo starts its own roscore, so it runs as a subprocess with an environment that does not point at the
test session's master, and with a token of its own: every process it starts inherits the token, so the
census finds anything it leaves behind, at any depth. (Not the session's token: the demo's own census would
count the test worker's roscore as its leftover.)
"""
from __future__ import annotations

import os
import subprocess
import sys
from typing import List, Sequence, Tuple

from temoto_core.processes import SESSION_ENV, leftover_processes

MASTER_VARS = ('ROS_MASTER_URI', 'ROS_IP', 'ROS_HOSTNAME', 'ROS_LOG_DIR', 'ROS_HOME', 'DISPLAY')


def run_demo_cli(args: Sequence[str], timeout: float, token_prefix: str = 'test_demo_'
                 ) -> Tuple[subprocess.CompletedProcess, List[tuple]]:
    """``temoto demo ARGS``: its completed process, and the processes it left (none, if it kept its word)."""
    token = token_prefix + os.urandom(6).hex()
    env = {k: v for k, v in os.environ.items() if k not in MASTER_VARS}
    env[SESSION_ENV] = token
    proc = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'demo'] + list(args), env=env,
                          capture_output=True, text=True, timeout=timeout)
    left = [p for p in leftover_processes(token) if p[0] != os.getpid()]
    return proc, left
