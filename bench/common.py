"""What several benchmarks share: a master of their own, a clean environment for the commands they time,
percentiles, and the CPU a set of processes uses over a window."""
import json
import os
import subprocess
import sys
import tempfile
import time
from typing import Dict, Iterable, List, Sequence, Tuple

import psutil

from temoto_core.master import RosMaster
from temoto_core.processes import ProcessGroupLauncher

# what a command started by a benchmark must not inherit: it starts its own master, and its own headless RViz
MASTER_VARS = ('ROS_MASTER_URI', 'ROS_IP', 'ROS_HOSTNAME', 'ROS_LOG_DIR', 'ROS_HOME', 'DISPLAY')


def loopback_master(prefix: str) -> Tuple[RosMaster, ProcessGroupLauncher]:
    """A roscore of the benchmark's own on loopback (in a new temporary folder), this process pointed at it, and
    a launcher for nodes against it (its ``workdir`` is that folder)."""
    work = tempfile.mkdtemp(prefix=prefix)
    master = RosMaster(work).start()
    master.point_this_process()
    return master, ProcessGroupLauncher(master.env, work)


def child_env() -> Dict[str, str]:
    """This process's environment without :data:`MASTER_VARS`, for ``temoto demo`` or ``temoto chaos``."""
    return {k: v for k, v in os.environ.items() if k not in MASTER_VARS}


def pct(values: Sequence[float], p: float) -> float:
    """The ``p``-th percentile (0..100) of ``values``: the nearest rank on (n - 1), no interpolation, so
    every figure printed is one that was measured."""
    ordered = sorted(values)
    if not ordered:
        return float('nan')
    return ordered[min(len(ordered) - 1, int(round(p / 100.0 * (len(ordered) - 1))))]


def cpu_seconds(procs: Iterable[psutil.Process]) -> Dict[int, float]:
    """User + system CPU seconds so far, per pid (a process gone meanwhile is left out)."""
    out = {}
    for proc in procs:
        try:
            out[proc.pid] = sum(proc.cpu_times()[:2])
        except psutil.Error:
            pass
    return out


def cpu_percent_per_process(procs: Sequence[psutil.Process], seconds: float) -> Dict[int, float]:
    """Each process's CPU over the next ``seconds``, in % of one core; only processes alive at both ends."""
    t0, before = time.monotonic(), cpu_seconds(procs)
    time.sleep(seconds)      # the measuring window itself, not a wait for something
    after, took = cpu_seconds(procs), time.monotonic() - t0
    return {pid: 100.0 * (after[pid] - before[pid]) / took for pid in before if pid in after}


def print_table(title: str, rows: Iterable[Tuple[str, str, str]]) -> None:
    """A markdown table of (figure, measured, goal) rows under ``title``."""
    print('\n| %s | measured | goal |\n| --- | --- | --- |' % title)
    for name, value, goal in rows:
        print('| %s | %s | %s |' % (name, value, goal))


def cpu_hogs(n: int) -> List[subprocess.Popen]:
    """``n`` busy-looping processes: the loaded machine a benchmark runs beside."""
    return [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(n)]


def stop_hogs(hogs: Iterable[subprocess.Popen]) -> None:
    for proc in hogs:
        proc.kill()
        proc.wait()


def write_results(name: str, results: dict) -> str:
    """``bench/results/<name>.json``, the figures a benchmark measured; returns the path."""
    folder = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'bench', 'results')
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, '%s.json' % name)
    with open(path, 'w') as f:
        json.dump(results, f, indent=1, default=str)
    return path
