"""`temoto robots ...`: the robots the Robot Manager serves, and the files that describe them.

    temoto robots [--ns NS]              the running manager's robots: features, reliability, what is loaded
    temoto robots check FILE [FILE...]   validate description files offline (problems with file:line)
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import List

import rospy

from temoto_core.rr.deadlines import call_once
from temoto_core.srv import GetRegistry
from temoto_robot_manager.contract import ROBOTS, RR_NAME
from temoto_robot_manager.description import load_file

TIMEOUT = 5.0


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='temoto robots', description='The Robot Manager\'s robots.')
    ap.add_argument('--ns', '--namespace', dest='ns', default='temoto', help='TeMoto namespace (default temoto)')
    sub = ap.add_subparsers(dest='cmd')
    sub.add_parser('list', help='the running manager\'s robots (the default)')
    c = sub.add_parser('check', help='validate robot description files without ROS')
    c.add_argument('files', nargs='+')
    return ap


def _check(files: List[str]) -> int:
    failed = False
    for path in files:
        robots, problems = load_file(path)
        for robot in robots:
            arms = ', '.join('%s (%d joints, poses: %s)' % (a.name, len(a.joints), ', '.join(a.named_poses) or 'none')
                             for a in robot.manipulation.values())
            print('ok    %s: %s, reliability %.2f; %s' % (robot.source, robot.name, robot.reliability, '; '.join(
                filter(None, ['navigation (places: %s)' % (', '.join(robot.navigation.places) or 'none')
                              if robot.navigation else '',
                              'manipulation: ' + arms if arms else '',
                              'gripper on %s' % robot.gripper.arm if robot.gripper else '']))))
        for problem in problems:
            print('error %s' % problem)
        failed = failed or bool(problems)
    return 1 if failed else 0


def _list(ns: str) -> int:
    service = '/%s/%s/%s' % (ns.strip('/'), RR_NAME, ROBOTS)
    try:
        data = json.loads(call_once(service, GetRegistry, GetRegistry._request_class(), TIMEOUT).json)
    except (rospy.ServiceException, rospy.ROSException, OSError, ValueError) as err:
        print('error: the Robot Manager does not answer (%s: %s)' % (service, err), file=sys.stderr)
        return 1
    print('%-14s %-6s %-34s %s' % ('robot', 'rel.', 'features', 'loaded'))
    for r in data['robots']:
        loaded = '; '.join('%s (%d parts)' % (', '.join(e['features']), len(e['parts'])) for e in r['loaded'])
        print('%-14s %.3f  %-34s %s' % (r['name'], r['reliability'], ', '.join(r['features']), loaded or '-'))
        if r['places']:
            print('    places: %s' % ', '.join(r['places']))
        for arm, poses in sorted(r['arms'].items()):
            print('    %s poses: %s' % (arm, ', '.join(poses) or 'none'))
    for problem in data.get('problems', []):
        print('description problem: %s' % problem)
    return 0


def main(argv: List[str]) -> int:
    opts = _parser().parse_args(argv)
    if opts.cmd == 'check':
        return _check(opts.files)
    return _list(opts.ns)
