"""`temoto sensors ...`: the sensor catalogue, live or from files.

    temoto sensors [--ns temoto]          every sensor of the running Sensor Manager: type, reliability, in use,
                                          and the stall limit each held topic is watched with now
    temoto sensors check FILE [FILE...]   validate catalogue files offline (problems with file:line)

Exit codes: 0 ok, 1 the manager is not running or a file has problems, 2 bad arguments.
"""
import argparse
import json
import sys
from typing import List

import rospy

from temoto_core.srv import GetRegistry
from temoto_sensor_manager.catalogue import Catalogue

TIMEOUT = 3.0


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='temoto sensors', description='The Sensor Manager\'s catalogue.')
    ap.add_argument('--ns', '--namespace', dest='ns', default='temoto', help='TeMoto namespace (default temoto)')
    sub = ap.add_subparsers(dest='cmd')
    sub.add_parser('list', help='the running manager\'s sensors (the default)')
    c = sub.add_parser('check', help='validate catalogue files without ROS')
    c.add_argument('files', nargs='+')
    return ap


def _check(files: List[str]) -> int:
    cat = Catalogue.from_files(files)
    for entry in cat.entries:
        print('ok    %s: %s (%s) %s/%s -> %s' % (entry.source, entry.name, entry.type, entry.package, entry.executable,
                                               ', '.join(entry.output_topics)))
    for problem in cat.problems:
        print('error %s' % problem)
    return 1 if cat.problems else 0


def _list(ns: str) -> int:
    service = '/%s/temoto_sensor_manager/catalogue' % ns.strip('/')
    try:
        rospy.wait_for_service(service, timeout=TIMEOUT)
        data = json.loads(rospy.ServiceProxy(service, GetRegistry)().json)
    except (rospy.ROSException, OSError) as err:
        print('error: the Sensor Manager is not running (%s: %s)' % (service, err), file=sys.stderr)
        return 1
    rows = sorted(data['sensors'], key=lambda s: (s['type'], -s['reliability']))
    print('%-22s %-14s %-6s %-6s %s' % ('sensor', 'type', 'rel.', 'in use', 'topics'))
    for s in rows:
        print('%-22s %-14s %.3f  %-6s %s' % (s['name'], s['type'], s['reliability'], 'yes' if s['active'] else '',
                                            ', '.join('%s=%s' % (k, v['topic'])
                                                      for k, v in sorted(s['output_topics'].items()))))
    for s in rows:
        for topic, limit in sorted(s.get('watched', {}).items()):
            pid = s.get('driver_pids', {}).get(topic)
            print('watching %s of %s: stall limit %.0f ms%s' % (
                topic, s['name'], limit * 1e3, ", plus what its driver (pid %d) waits for a CPU" % pid if pid else ''))
    for problem in data.get('problems', []):
        print('catalogue problem: %s' % problem)
    return 0


def main(argv: List[str]) -> int:
    try:
        opts = _parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0) and 2
    if opts.cmd == 'check':
        return _check(opts.files)
    return _list(opts.ns)
