"""`temoto robots ...`: the robots a description file describes.

    temoto robots check FILE [FILE...]   validate description files offline (problems with file:line)
"""
from __future__ import annotations

import argparse
from typing import List

from temoto_robot_manager.description import load_file


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='temoto robots', description='Robot description files.')
    sub = ap.add_subparsers(dest='cmd', required=True)
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


def main(argv: List[str]) -> int:
    opts = _parser().parse_args(argv)
    if opts.cmd == 'check':
        return _check(opts.files)
    return 2
