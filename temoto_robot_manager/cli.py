"""`temoto robots ...`: the robots the Robot Manager serves, and the files that describe them.

    temoto robots [--ns NS]              the running manager's robots: features, reliability, what is loaded
    temoto robots check FILE [FILE...] [--map MAP.yaml]   validate description files offline (problems with
                                         file:line); with a map (map_server's YAML), each named place too
    temoto robots go PLACE | X Y YAW     load a robot's navigation, drive it there, release it
                                         (Ctrl-C cancels the goal: the robot stops)
    temoto robots gripper open | close | GAP   load a robot's gripper, open, close or set the gap
                                         between its pads (m), print how it ended, release it
    temoto robots arm ARM POSE | --joints Q.. | --pose X Y Z [R P Y]   load a robot's manipulation, move
                                         the arm to a named pose, joint positions or a tool pose in --frame
                                         (Ctrl-C cancels: the arm holds)
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import Callable, List, Optional

import rospy
from actionlib_msgs.msg import GoalStatus
from control_msgs.msg import GripperCommand, GripperCommandAction, GripperCommandGoal
from geometry_msgs.msg import PoseStamped
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
from std_msgs.msg import Float32

from temoto_core.action_client import TrackingActionClient
from temoto_core import map_file
from temoto_core.errors import TemotoError
from temoto_core.msg import MotionStatus
from temoto_core.rr.deadlines import call_once
from temoto_core.srv import GetRegistry
from temoto_robot_manager.contract import ROBOTS, RR_NAME
from temoto_robot_manager.description import load_file
from temoto_robot_manager.interface import RobotManagerInterface
from temoto_robot_manager.navigation.place_check import places_off_map
from temoto_robot_manager.msg import MoveArmAction, MoveArmGoal

TIMEOUT = 5.0


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='temoto robots', description='The Robot Manager\'s robots.')
    ap.add_argument('--ns', '--namespace', dest='ns', default='temoto', help='TeMoto namespace (default temoto)')
    sub = ap.add_subparsers(dest='cmd')
    sub.add_parser('list', help='the running manager\'s robots (the default)')
    c = sub.add_parser('check', help='validate robot description files without ROS')
    c.add_argument('files', nargs='+')
    c.add_argument('--map', default='', help='a map (map_server\'s YAML and image): every named place is checked '
                   'against it, as the navigator checks a goal')
    g = sub.add_parser('go', help='drive a robot to a named place or to X Y YAW (m, m, rad) in --frame')
    g.add_argument('target', nargs='+', help='a place of the robot\'s description, or X Y YAW')
    g.add_argument('--robot', default='', help='the robot (default: the most reliable one with navigation)')
    g.add_argument('--frame', default='world', help='the frame of X Y YAW (default world)')
    g.add_argument('--timeout', type=float, default=300.0, help='seconds before the goal is cancelled (300)')
    h = sub.add_parser('gripper', help='open or close a robot\'s gripper, or set the gap between its pads (m)')
    h.add_argument('target', help='a position of the robot\'s description (open, closed; close = closed), or a gap in m')
    h.add_argument('--robot', default='', help='the robot (default: the most reliable one with a gripper)')
    h.add_argument('--effort', type=float, default=0.0, help='the most force, N (default: the gripper\'s own)')
    h.add_argument('--timeout', type=float, default=30.0, help='seconds before the goal is cancelled (30)')
    a = sub.add_parser('arm', help='move an arm to a named pose, joint positions, or a pose of its tool')
    a.add_argument('arm', help='an arm of the robot\'s manipulation (left_arm, right_arm for the VaultBot)')
    a.add_argument('pose', nargs='?', default='', help='a named pose of the arm (stow)')
    a.add_argument('--joints', nargs='+', type=float, metavar='Q', help='one position per joint, rad')
    a.add_argument('--pose', dest='tool', nargs='+', type=float, metavar='V',
                   help='the tool\'s X Y Z (m), and optionally ROLL PITCH YAW (rad; default 0 0 0)')
    a.add_argument('--frame', default='base_link', help='the frame of --pose (default base_link)')
    a.add_argument('--speed', type=float, default=0.0, help='of each joint\'s speed limit, (0, 1] (default 0.5)')
    a.add_argument('--robot', default='', help='the robot (default: the most reliable one with manipulation)')
    a.add_argument('--timeout', type=float, default=60.0, help='seconds before the goal is cancelled (60)')
    return ap


def _check(files: List[str], map_path: str = '') -> int:
    grid = None
    if map_path:
        try:
            grid = map_file.read(map_path)
        except map_file.MapError as err:
            print('error %s' % err)
            return 1
    failed = False
    for path in files:
        robots, problems = load_file(path)
        off_map = {r.name: places_off_map(r.navigation, grid) for r in robots if grid is not None and r.navigation}
        problems = list(problems) + [p for found in off_map.values() for p in found]
        for robot in (r for r in robots if not off_map.get(r.name)):
            arms = ', '.join('%s (%d joints, poses: %s)' % (a.name, len(a.joints), ', '.join(a.named_poses) or 'none')
                             for a in robot.manipulation.values())
            print('ok    %s: %s, reliability %.2f; %s' % (robot.source, robot.name, robot.reliability, '; '.join(
                filter(None, ['navigation (places: %s)' % (', '.join(robot.navigation.places) or 'none')
                              if robot.navigation else '',
                              'manipulation: ' + arms if arms else '',
                              'gripper on %s' % robot.gripper.arm if robot.gripper else '']))))
        for problem in problems:
            print('error %s' % problem)
        if grid is not None:
            print('      %d places checked against %s' % (sum(len(r.navigation.places) for r in robots
                                                           if r.navigation), map_path))
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


def _target(words: List[str], places: dict) -> Optional[tuple]:
    if len(words) == 1:
        return tuple(places[words[0]]) if words[0] in places else None
    try:
        values = tuple(float(w) for w in words)
    except ValueError:
        return None
    return values if len(values) == 3 and all(math.isfinite(v) for v in values) else None


def _robot_with(ns: str, feature: str, name: str) -> Optional[dict]:
    """The running manager's robot ``name`` (or its first) that has ``feature``; prints why there is none."""
    service = '/%s/%s/%s' % (ns.strip('/'), RR_NAME, ROBOTS)
    try:
        data = json.loads(call_once(service, GetRegistry, GetRegistry._request_class(), TIMEOUT).json)
    except (rospy.ServiceException, rospy.ROSException, OSError, ValueError) as err:
        print('error: the Robot Manager does not answer (%s: %s)' % (service, err), file=sys.stderr)
        return None
    robots = {r['name']: r for r in data['robots'] if feature in r['features']}
    robot = robots.get(name) if name else next(iter(robots.values()), None)
    if robot is None:
        print('error: no robot %s with %s (described: %s)' % (name, feature, ', '.join(robots) or 'none'),
              file=sys.stderr)
    return robot


def _claim(ns: str, robot: dict, feature: str, node: str):
    """Load ``robot`` with ``feature`` through the Robot Manager, as an action would: the robot moves for a
    holder. Returns (interface, loaded) or None, having printed why."""
    rospy.init_node(node, anonymous=True, disable_signals=True)
    rmi = RobotManagerInterface(namespace=ns)
    print('loading %s with %s ...' % (robot['name'], feature), flush=True)
    try:
        return rmi, rmi.load_robot([feature], robot_name=robot['name'],
                                   on_status=lambda e: print('robot: %s' % e.message, flush=True))
    except TemotoError as err:
        print('error: %s' % err, file=sys.stderr)
        rmi.shutdown()
        return None


def _let_go(held, node: str) -> None:
    rmi, loaded = held
    rmi.release(loaded.resource_id)
    rmi.shutdown()
    rospy.signal_shutdown('%s: done' % node)


def _one_goal(held, node: str, client, server: str, starting: str, goal, timeout: float, stops: str,
              report: Callable[[int, str, object], int]) -> int:
    """Send one goal while the robot is held, print how it ended (``report`` returns the exit code), release the
    robot. No result within ``timeout``, or Ctrl-C: the goal is cancelled and the motion ``stops``."""
    try:
        if not client.wait_for_server(rospy.Duration(30.0)):
            print('error: no %s after 30 s' % server, file=sys.stderr)
            return 1
        print(starting, flush=True)
        client.send_goal(goal)
        if not client.wait_for_result(rospy.Duration(timeout)):
            client.cancel_goal()
            print('error: no result after %.0f s: cancelled, %s' % (timeout, stops), file=sys.stderr)
            return 1
        return report(client.get_state(), client.get_goal_status_text(), client.get_result())
    except KeyboardInterrupt:
        client.cancel_goal()
        print('cancelled: %s' % stops, flush=True)
        return 130
    finally:
        _let_go(held, node)


def _go(opts) -> int:
    """Hold the robot's navigation for the goal's length, as an action would: the robot drives for a holder."""
    robot = _robot_with(opts.ns, 'navigation', opts.robot)
    if robot is None:
        return 2
    target = _target(opts.target, robot.get('place_poses', {}))
    if target is None:
        print('error: target %s: give a place of %s (%s) or X Y YAW' % (' '.join(opts.target), robot['name'],
                                                                       ', '.join(robot['places']) or 'none'),
              file=sys.stderr)
        return 2
    held = _claim(opts.ns, robot, 'navigation', 'temoto_robots_go')
    if held is None:
        return 1
    client = TrackingActionClient('/move_base', MoveBaseAction)
    left = {'m': float('nan')}
    sub = rospy.Subscriber('/move_base/distance_remaining', Float32,
                           lambda m: left.update(m=m.data), queue_size=1)
    # the base's gate: a pause (no fresh obstacle source, an arm out) is said as it comes, and its end
    paused = {'held': False}
    status = rospy.Subscriber('%s/motion_status' % (robot.get('navigator') or 'navigator'), MotionStatus,
                              lambda m: _say_pause(m, paused), queue_size=10)
    code = 1
    try:
        if not client.wait_for_server(rospy.Duration(30.0)):
            print('error: no move_base server after 30 s', file=sys.stderr)
            return 1
        goal = MoveBaseGoal()
        goal.target_pose.header.frame_id, goal.target_pose.header.stamp = opts.frame, rospy.Time.now()
        goal.target_pose.pose.position.x, goal.target_pose.pose.position.y = target[0], target[1]
        goal.target_pose.pose.orientation.z = math.sin(target[2] / 2)
        goal.target_pose.pose.orientation.w = math.cos(target[2] / 2)
        print('driving to (%.2f, %.2f, %.0f deg) in %s' % (target[0], target[1], math.degrees(target[2]), opts.frame),
              flush=True)
        client.send_goal(goal)
        deadline, shown = time.monotonic() + opts.timeout, 0.0
        while client.get_state() in (GoalStatus.PENDING, GoalStatus.ACTIVE) and time.monotonic() < deadline:
            if time.monotonic() - shown >= 2.0 and math.isfinite(left['m']) and not paused['held']:
                shown = time.monotonic()
                print('  %.1f m to go' % left['m'], flush=True)
            time.sleep(0.1)
        if client.get_state() in (GoalStatus.PENDING, GoalStatus.ACTIVE):
            client.cancel_goal()
            print('error: not there after %.0f s: cancelled, the robot stops' % opts.timeout, file=sys.stderr)
            return 1
        state, text = client.get_state(), client.get_goal_status_text()
        print('%s: %s' % ({GoalStatus.SUCCEEDED: 'arrived', GoalStatus.REJECTED: 'refused'}.get(state, 'failed'),
                          text), flush=True)
        code = 0 if state == GoalStatus.SUCCEEDED else 1
    except KeyboardInterrupt:
        client.cancel_goal()
        print('cancelled: the robot stops', flush=True)
        code = 130
    finally:
        sub.unregister()
        status.unregister()
        _let_go(held, 'temoto robots go')
    return code


def _say_pause(msg: MotionStatus, paused: dict) -> None:
    """One line when the drive pauses (the gate holds the base at zero, saying why) and one when it goes on."""
    if msg.state == MotionStatus.HELD and not paused['held']:
        paused['held'] = True
        print('  paused: %s' % msg.text, flush=True)
    elif msg.state == MotionStatus.MOVING and paused['held']:
        paused['held'] = False
        print('  driving on', flush=True)


def _gap(word: str, positions: dict) -> Optional[float]:
    word = {'close': 'closed'}.get(word, word)
    if word in positions:
        return positions[word]
    try:
        gap = float(word)
    except ValueError:
        return None
    return gap if math.isfinite(gap) else None


def _gripper(opts) -> int:
    """Hold the robot's gripper for one command: open, close, or a gap between the pads."""
    robot = _robot_with(opts.ns, 'gripper', opts.robot)
    if robot is None:
        return 2
    gripper = robot['gripper']
    gap = _gap(opts.target, gripper['positions'])
    if gap is None:
        print('error: gripper target %r: give a position of %s (%s) or a gap in m'
              % (opts.target, robot['name'], ', '.join(sorted(gripper['positions'])) or 'none'), file=sys.stderr)
        return 2
    held = _claim(opts.ns, robot, 'gripper', 'temoto_robots_gripper')
    if held is None:
        return 1
    client = TrackingActionClient('/' + gripper['action'].lstrip('/'), GripperCommandAction)

    def report(state: int, text: str, result) -> int:
        if state == GoalStatus.SUCCEEDED:
            print('%s: %s' % ('holding an object' if result.stalled else 'done', text), flush=True)
            return 0
        print('failed: %s' % text, flush=True)
        return 1
    return _one_goal(held, 'temoto robots gripper', client, 'gripper server on %s' % gripper['action'],
                     'gripper to %.1f mm' % (1000 * gap),
                     GripperCommandGoal(command=GripperCommand(position=gap, max_effort=opts.effort)),
                     opts.timeout, 'the fingers stop', report)


def _arm_goal(opts) -> Optional[MoveArmGoal]:
    """The goal the options ask for; None (said why) when they ask for none or for two."""
    given = [w for w, v in (('POSE', opts.pose), ('--joints', opts.joints), ('--pose', opts.tool)) if v]
    if len(given) != 1:
        print('error: give one of a named POSE, --joints and --pose (given: %s)' % (', '.join(given) or 'none'),
              file=sys.stderr)
        return None
    if opts.tool:
        if len(opts.tool) not in (3, 6):
            print('error: --pose takes X Y Z, or X Y Z ROLL PITCH YAW', file=sys.stderr)
            return None
        pose = PoseStamped()
        pose.header.frame_id = opts.frame
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = opts.tool[:3]
        roll, pitch, yaw = opts.tool[3:] if len(opts.tool) == 6 else (0.0, 0.0, 0.0)
        cr, sr, cp, sp, cy, sy = (math.cos(roll / 2), math.sin(roll / 2), math.cos(pitch / 2), math.sin(pitch / 2),
                                  math.cos(yaw / 2), math.sin(yaw / 2))
        o = pose.pose.orientation
        o.w, o.x = cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy
        o.y, o.z = cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy
        return MoveArmGoal(pose=pose, speed_scale=opts.speed)
    return MoveArmGoal(named_pose=opts.pose, joint_positions=opts.joints or [], speed_scale=opts.speed)


def _arm(opts) -> int:
    """Hold the robot's manipulation for one arm goal."""
    robot = _robot_with(opts.ns, 'manipulation', opts.robot)
    if robot is None:
        return 2
    if opts.arm not in robot['arms']:
        print('error: %s has no arm %r (its arms: %s)' % (robot['name'], opts.arm, ', '.join(sorted(robot['arms']))),
              file=sys.stderr)
        return 2
    goal = _arm_goal(opts)
    if goal is None:
        return 2
    held = _claim(opts.ns, robot, 'manipulation', 'temoto_robots_arm')
    if held is None:
        return 1
    client = TrackingActionClient('/%s/move_arm' % opts.arm, MoveArmAction)

    def report(state: int, text: str, _result) -> int:
        print('%s: %s' % ({GoalStatus.SUCCEEDED: 'there', GoalStatus.REJECTED: 'refused'}.get(state, 'failed'), text),
              flush=True)
        return 0 if state == GoalStatus.SUCCEEDED else 1
    return _one_goal(held, 'temoto robots arm', client, 'manipulator for %s' % opts.arm, 'moving %s' % opts.arm,
                     goal, opts.timeout, 'the arm holds', report)


def main(argv: List[str]) -> int:
    opts = _parser().parse_args(argv)
    if opts.cmd == 'check':
        return _check(opts.files, opts.map)
    if opts.cmd == 'go':
        return _go(opts)
    if opts.cmd == 'gripper':
        return _gripper(opts)
    if opts.cmd == 'arm':
        return _arm(opts)
    return _list(opts.ns)
