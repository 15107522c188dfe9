"""`temoto say`, `temoto actions`, `temoto graphs`: the action engine from a shell.

Each talks to a running engine node through its services under /<ns>/action_engine/.
The lead's dispatcher maps subcommands to ``say``, ``actions`` and ``graphs`` here
(``main`` also dispatches on the first word, for use on its own).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import rospy

from .srv import ListActions, ListGraphs, StartGraph, StopGraph

DEFAULT_NS = os.environ.get('TEMOTO_NAMESPACE', 'temoto')
SERVICE_WAIT_S = 5.0
SAY_WAIT_S = 30.0       # `temoto say` right after `roslaunch ... &` finds the engine still starting


def _wait_for_service(full: str, timeout: float) -> None:
    """rospy's wait, through a master that is not up yet (its wait raises at once then), with one line of
    progress when the wait is longer than a second."""
    deadline = time.monotonic() + timeout
    told = False
    while True:
        try:
            rospy.wait_for_service(full, timeout=max(0.1, min(1.0, deadline - time.monotonic())))
            return
        except rospy.ROSException:
            if time.monotonic() >= deadline:
                raise
            if not told:
                print('waiting for the action engine (%s), up to %.0f s ...' % (full, timeout), flush=True)
                told = True
            time.sleep(0.2)     # the master may not answer yet: rospy's wait then returns at once


def _service(ns: str, name: str, srv_type, timeout: float = SERVICE_WAIT_S):
    """A caller of the engine's service ``name``: it waits for it, and turns every failure into one line."""
    full = '/%s/action_engine/%s' % (ns.strip('/'), name)
    try:
        _wait_for_service(full, timeout)
    except rospy.ROSException:
        raise SystemExit('error: %s is not available (is the action engine running in namespace %r?)'
                         % (full, ns)) from None
    except rospy.ROSInterruptException:
        raise SystemExit(1) from None
    proxy = rospy.ServiceProxy(full, srv_type)

    def call(**request):
        try:
            return proxy(**request)
        except (rospy.ServiceException, rospy.ROSException) as e:
            # the engine went away mid-call, or refused the call: one line, never a traceback
            raise SystemExit('error: %s failed: %s' % (full, e)) from None
    return call


def _parser(prog: str, help_text: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=help_text)
    p.add_argument('--ns', '--namespace', dest='ns', default=DEFAULT_NS, help='TeMoto namespace (default: %(default)s)')
    return p


def say(argv: list[str]) -> int:
    """temoto say "track the hand and show it on the screen" """
    p = _parser('temoto say', 'Ground an instruction and run it as an action graph.')
    p.add_argument('text', nargs='+', help='the instruction')
    p.add_argument('--wait', type=float, default=SAY_WAIT_S,
                   help='seconds to wait for the action engine to come up (default %(default).0f)')
    args = p.parse_args(argv)
    if args.wait <= 0:
        p.error('--wait must be a positive number of seconds')
    resp = _service(args.ns, 'start_graph', StartGraph, args.wait)(graph_json='', text=' '.join(args.text))
    print(resp.message)
    if resp.code == 0:
        print('graph: %s (stop it with: temoto graphs stop %s)' % (resp.graph_name, resp.graph_name))
    return resp.code


def actions(argv: list[str]) -> int:
    """temoto actions [--reindex] [--json]: the action index and the plugin problems."""
    p = _parser('temoto actions', 'List indexed actions and broken plugins.')
    p.add_argument('--reindex', action='store_true', help='scan the action folders again first')
    p.add_argument('--json', action='store_true', help='print the raw JSON')
    args = p.parse_args(argv)
    data = json.loads(_service(args.ns, 'list_actions', ListActions)(reindex=args.reindex).json)
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    for a in data['actions']:
        ins = ', '.join('%s:%s%s' % (k, v['pvf_type'], '' if v.get('pvf_required') else '?')
                        for k, v in a['input_parameters'].items())
        outs = ', '.join('%s:%s' % (k, v['pvf_type']) for k, v in a['output_parameters'].items())
        print('%-18s %-5s (%s) -> (%s)  says: %s' % (a['name'], 'async' if a['effect'] == 'asynchronous' else 'sync',
                                                    ins, outs, '/'.join(a['grounding']['verbs'])))
    for e in data['errors']:
        print('BROKEN %s [%s]: %s' % (e['path'], e['kind'], e['message']))
    print('%d action(s), %d problem(s); folders: %s' % (len(data['actions']), len(data['errors']),
                                                        ', '.join(data['paths'])))
    return 1 if data['errors'] else 0


def graphs(argv: list[str]) -> int:
    """temoto graphs [--json] | temoto graphs stop NAME | temoto graphs start FILE.umrfg.json"""
    p = _parser('temoto graphs', 'List, stop or start action graphs.')
    p.add_argument('--json', action='store_true', help='print the raw JSON')
    p.add_argument('command', nargs='?', choices=('list', 'stop', 'start'), default='list')
    p.add_argument('target', nargs='?', help='graph name (stop) or graph file (start)')
    args = p.parse_args(argv)
    if args.command == 'stop':
        if not args.target:
            p.error('stop needs a graph name')
        print('stopping %s ...' % args.target, flush=True)
        resp = _service(args.ns, 'stop_graph', StopGraph)(graph_name=args.target)
        print(resp.message)
        return resp.code
    if args.command == 'start':
        if not args.target:
            p.error('start needs a graph file')
        try:
            with open(args.target, encoding='utf-8') as f:
                text = f.read()
        except OSError as e:
            raise SystemExit('error: %s' % e) from None
        resp = _service(args.ns, 'start_graph', StartGraph)(graph_json=text, text='')
        print(resp.message)
        return resp.code
    data = json.loads(_service(args.ns, 'list_graphs', ListGraphs)().json)
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    if not data:
        print('no graphs')
    for g in data:
        print('%s  %s  "%s"' % (g['graph_name'], g['state'], g['graph_description']))
        for n in g['nodes']:
            print('    %s_%d  %s%s' % (n['name'], n['instance_id'], n['state'],
                                      ('  ' + n['message']) if n['message'] else ''))
    return 0


COMMANDS = {'say': say, 'actions': actions, 'graphs': graphs}
# The names temoto_bringup/cli.py dispatches to.
say_main, actions_main, graphs_main = say, actions, graphs


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in COMMANDS:
        print('usage: temoto {say,actions,graphs} ...', file=sys.stderr)
        return 2
    return COMMANDS[argv[0]](argv[1:])


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
