#!/usr/bin/env python3
"""``make bench``: run every ``bench/bench_*.py`` one after another and write one
results file, ``BENCHMARKS.md``, from the markdown tables they print (each
table carries the goal beside each figure).

Benchmarks run one at a time because these machines have 2 cores: two at once
would measure each other.
"""
import datetime
import glob
import os
import platform
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ORDER = ['rr', 'journal', 'recovery', 'hosts', 'master_check', 'er', 'node_stop', 'sim', 'sensor', 'stall', 'stall_hosts', 'output', 'action_start',
         'demo', 'all_failed', 'standby', 'chaos']


def scripts():
    found = {os.path.basename(p)[len('bench_'):-3]: p for p in glob.glob(os.path.join(ROOT, 'bench', 'bench_*.py'))}
    return [found[k] for k in ORDER if k in found] + [p for k, p in sorted(found.items()) if k not in ORDER]


def section_name(section):
    """'bench_rr.py' from a section's heading line '## bench_rr.py (ok, 12 s)'."""
    return section.split('\n', 1)[0][3:].split(' ', 1)[0]


def read_sections(path):
    """The '## bench_x.py' sections of an existing BENCHMARKS.md, in order."""
    if not os.path.exists(path):
        return []
    with open(path) as f:
        text = f.read()
    return ['## ' + part.rstrip('\n') + '\n' for part in text.split('\n## ')[1:]]


def merge_sections(old, new, order=()):
    """``old`` with the sections that ``new`` has run again replaced; new ones join them; in ``order`` of names."""
    fresh = {section_name(s): s for s in new}
    merged = [fresh.pop(section_name(s), s) for s in old] + [s for s in new if section_name(s) in fresh]
    rank = {name: i for i, name in enumerate(order)}
    return sorted(merged, key=lambda s: rank.get(section_name(s), len(rank)))


def main(argv):
    only = set(argv)
    sections = []
    for path in scripts():
        name = os.path.basename(path)
        if only and name[len('bench_'):-3] not in only:
            continue
        print('bench: %s ...' % name, flush=True)
        t0 = time.monotonic()
        out = subprocess.run([sys.executable, path], cwd=ROOT, capture_output=True, text=True, timeout=1800)
        took = time.monotonic() - t0
        lines = out.stdout.splitlines()
        marks = [i for i, line in enumerate(lines) if line.startswith('|')]
        # every table line, and the blank lines that separate one table from the next
        table = [line for line in lines[marks[0]:marks[-1] + 1] if line.startswith('|') or not line.strip()] \
            if marks else []
        status = 'ok' if out.returncode == 0 else 'FAILED (rc %d)' % out.returncode
        print('bench: %s %s in %.0f s' % (name, status, took), flush=True)
        body = '\n'.join(table) if table else '```\n%s\n```' % (out.stdout[-2000:] + out.stderr[-2000:])
        sections.append('## %s (%s, %.0f s, %s)\n\n%s\n'
                        % (name, status, took, datetime.date.today().isoformat(), body))
    header = ('# Benchmarks\n\nWritten by `make bench` (bench/run_all.py; `python bench/run_all.py NAME...` reruns '
              'some and keeps the rest, each section is dated), last on %s, %s, %d cores. '
              'Each table puts the goal beside the figure; the scripts in bench/ say how each is measured.\n\n'
              % (datetime.date.today().isoformat(), platform.platform(), os.cpu_count()))
    write_benchmarks(os.path.join(ROOT, 'BENCHMARKS.md'), header, sections, [os.path.basename(p) for p in scripts()])
    print('bench: wrote BENCHMARKS.md')
    return 0


def write_benchmarks(path: str, header: str, sections: list, order: list) -> None:
    """``path`` with ``header``, the sections of the scripts that ran replacing theirs, and every other section
    kept: the ones written by hand (before/after comparisons, loops) are the project's record, and a full run
    erased them all before."""
    merged = merge_sections(read_sections(path), sections, order)
    with open(path, 'w') as f:
        f.write(header + '\n'.join(merged))


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
