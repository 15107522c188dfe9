"""bench/run_all.py: a run replaces its own sections of BENCHMARKS.md and keeps the others, hand-written ones too."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'bench'))

import run_all  # noqa: E402


def test_a_partial_run_replaces_its_sections_and_keeps_the_rest(tmp_path):
    path = tmp_path / 'BENCHMARKS.md'
    path.write_text('# Benchmarks\n\nold header\n\n## bench_rr.py (ok, 5 s, 2026-11-01)\n\n| rr old |\n\n'
                    '## bench_er.py (ok, 9 s, 2026-11-01)\n\n| er old |\n| --- |\n')
    old = run_all.read_sections(str(path))
    assert [run_all.section_name(s) for s in old] == ['bench_rr.py', 'bench_er.py']
    new = ['## bench_er.py (ok, 8 s, 2026-11-22)\n\n| er new |\n',
           '## bench_node_stop.py (ok, 3 s, 2026-11-22)\n\n| x |\n']
    merged = run_all.merge_sections(old, new, ['bench_rr.py', 'bench_node_stop.py', 'bench_er.py'])
    assert [run_all.section_name(s) for s in merged] == ['bench_rr.py', 'bench_node_stop.py', 'bench_er.py']
    assert '| rr old |' in merged[0] and '| er new |' in merged[2] and 'er old' not in ''.join(merged)
    assert run_all.read_sections(str(tmp_path / 'missing.md')) == []


def test_a_full_run_keeps_the_sections_written_by_hand(tmp_path):
    path = tmp_path / 'BENCHMARKS.md'
    path.write_text('# Benchmarks\n\nold header\n\n## bench_rr.py (ok, 5 s, 2026-11-01)\n\n| rr old |\n\n'
                    '## make test loops (by hand, 2026-11-26)\n\n| loops |\n')
    run_all.write_benchmarks(str(path), '# Benchmarks\n\nnew header\n\n',
                             ['## bench_rr.py (ok, 4 s, 2026-11-27)\n\n| rr new |\n'], ['bench_rr.py'])
    text = path.read_text()
    assert 'new header' in text and '| rr new |' in text and 'rr old' not in text
    assert '## make test loops (by hand, 2026-11-26)' in text and '| loops |' in text
