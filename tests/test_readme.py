"""The README's quick start works as typed: its block runs in a clean shell, start to end.

It once began ``source env.sh && roscore &``, which runs the source in the background subshell: the
user's shell never got the environment, roslaunch found no package and ``temoto`` was "command not
found". The block runs here as a script (with job control on, as in a terminal), in a network
namespace of its own (``unshare --net``: its roscore takes the default port 11311 on a loopback that
nothing else shares), with nothing of this process's environment but HOME and a plain PATH.
"""
import os
import re
import shutil
import subprocess
import time
import uuid

from temoto_core.hosts import unavailable
from temoto_core.processes import SESSION_ENV, kill_leftovers, leftover_processes

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BLOCK_AFTER = 'Running the pieces by hand'
RUN_BOUND_S = 240


def quick_start_block() -> str:
    with open(os.path.join(ROOT, 'README.md'), encoding='utf-8') as f:
        text = f.read()
    after = text[text.index(BLOCK_AFTER):]
    return re.search(r'```bash\n(.*?)```', after, re.S).group(1)


def test_the_block_sources_before_it_backgrounds():
    block = quick_start_block()
    assert not re.search(r'source env\.sh\s*&&[^\n]*&\s*$', block, re.M), block
    assert block.splitlines()[0].startswith('source env.sh')


def test_the_readme_quick_start_runs_as_typed_in_a_clean_shell(tmp_path):
    assert not unavailable() and shutil.which('unshare'), 'a network namespace of its own needs root and unshare'
    token = 'readme-%s' % uuid.uuid4().hex[:8]
    script = tmp_path / 'quick_start.sh'
    script.write_text('set -e -m\n' + quick_start_block())
    env = {'HOME': str(tmp_path), 'PATH': '/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin',
           'TERM': 'dumb', SESSION_ENV: token}
    log = tmp_path / 'quick_start.log'
    started = time.monotonic()
    # output to a file, not a pipe: a background job left running would hold a pipe open past the script
    with open(log, 'w') as out_file:
        proc = subprocess.Popen(['unshare', '--net', 'sh', '-c', 'ip link set lo up && exec bash "$0"', str(script)],
                                cwd=ROOT, env=env, stdout=out_file, stderr=subprocess.STDOUT,
                                start_new_session=True)
    try:
        rc = proc.wait(timeout=RUN_BOUND_S)
    finally:
        # whatever the block left (it stops its own stack and master): nothing may outlive the test
        leftovers = leftover_processes(token)
        kill_leftovers(token)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    out = log.read_text(errors='replace')
    # the motion's story, from anywhere in the log (a retrying camera can fill its tail)
    motion = '\n'.join(line[:300] for line in out.splitlines() if re.search(
        r'navigator|obstacle|robot_manager|driving|arrived|refused|stale|stopped', line))[-6000:]
    assert rc == 0, out[-3000:] + '\n--- the motion, from the whole log ---\n' + motion
    assert 'command not found' not in out and 'neither a launch file' not in out, out[-4000:]
    assert re.search(r'graph: show_environment\S*', out), out[-4000:]        # temoto say started the graph
    assert 'temoto_sensor_manager' in out, out[-4000:]                       # temoto registry listed the managers
    assert not leftovers, leftovers
    assert time.monotonic() - started < RUN_BOUND_S
