"""``temoto ps``: the ER Manager's running resources with pid(s), uptime, consumers and log path.

One row per resource: a node, a command, or a launch file (its nodes' pids joined by commas).

Joins two services of the manager: ``/<ns>/temoto_er_manager/registry`` (the
Resource Registrar's queries and their consumers) and
``/<ns>/temoto_er_manager/processes`` (the supervisor's children, with start times).
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Optional

import rospy

from temoto_core.srv import GetRegistry

MANAGER = 'temoto_er_manager'


def _fetch(service: str, timeout: float) -> dict:
    rospy.wait_for_service(service, timeout=timeout)
    return json.loads(rospy.ServiceProxy(service, GetRegistry)().json)


def process_rows(registry: dict, processes: dict) -> list[dict]:
    """One row per live resource (a launch file's nodes share one row, with all their pids);
    consumers from the registry query whose response has the resource's pid."""
    consumers = {}
    for q in registry.get('server_queries', []):
        pid = q.get('details', {}).get('pid')
        if pid:
            consumers[pid] = consumers.get(pid, 0) + len(q.get('consumers', []))
    rows = []
    for p in processes.get('processes', []):
        if p['state'] == 'exited':
            continue
        rows.append({'pid': p['pid'], 'pids': p.get('pids') or [p['pid']], 'nodes': p.get('node_names') or p.get('nodes', []),
                     'uptime': p['uptime'], 'consumers': consumers.get(p['pid'], 0),
                     'state': p['state'], 'resource': p['label'], 'resource_id': p.get('resource_id'),
                     'log_path': p['log_path'], 'command': p['command']})
    return sorted(rows, key=lambda r: -r['uptime'])


def _uptime(seconds: float) -> str:
    seconds = int(seconds)
    if seconds < 60:
        return '%ds' % seconds
    if seconds < 3600:
        return '%dm%02ds' % divmod(seconds, 60)
    return '%dh%02dm' % (seconds // 3600, seconds % 3600 // 60)


def ps_main(argv: Optional[list] = None) -> int:
    parser = argparse.ArgumentParser(prog='temoto ps', description=__doc__.split('\n')[0])
    parser.add_argument('--namespace', '--ns', '-n', dest='namespace', default='temoto',
                        help='TeMoto namespace (default: temoto)')
    parser.add_argument('--json', action='store_true', help='print the rows as JSON')
    parser.add_argument('--timeout', type=float, default=3.0, help='seconds to wait for the manager')
    args = parser.parse_args(argv)
    base = '/%s/%s' % (args.namespace.strip('/'), MANAGER)
    try:
        registry = _fetch(base + '/registry', args.timeout)
        processes = _fetch(base + '/processes', args.timeout)
    except Exception as e:        # no master, no manager, timeout: one clear line
        print('temoto ps: cannot reach %s: %s' % (base, e), file=sys.stderr)
        return 1
    rows = process_rows(registry, processes)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    if not rows:
        print('no running processes (%s)' % base)
        return 0
    header = ('PID', 'UPTIME', 'CONSUMERS', 'STATE', 'RESOURCE', 'LOG')
    table = [header] + [(','.join(str(pid) for pid in r['pids']), _uptime(r['uptime']), str(r['consumers']),
                         r['state'], r['resource'], r['log_path']) for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(header) - 1)]
    for row in table:
        print('  '.join(cell.ljust(w) for cell, w in zip(row, widths)) + '  ' + row[-1])
    return 0


def main(argv: Optional[list] = None) -> int:
    """Entry point for the lead's ``temoto`` dispatcher: ``temoto ps [...]``."""
    return ps_main(argv)


if __name__ == '__main__':
    sys.exit(ps_main())
