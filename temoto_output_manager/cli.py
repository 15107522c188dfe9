"""``temoto screenshot [file]`` and ``temoto displays``: what the operator's RViz shows.

Both talk to the RViz host's services (/<ns>/rviz_host/...). The PNG travels in
the service response, so the file is written where the command runs.
"""
from __future__ import annotations

import argparse
import http.client
import json
import sys
import time
import xmlrpc.client
from typing import Optional

import rosgraph

from temoto_core.master_lookup import lookup_node

from .host_client import RvizHostClient, RvizHostError, host_node_name


def _client(args) -> RvizHostClient:
    node = host_node_name(args.namespace)
    try:
        running = lookup_node(rosgraph.get_master_uri(), node, timeout=min(args.timeout, 1.0)) is not None
    except (OSError, xmlrpc.client.Error, http.client.HTTPException) as err:
        raise RvizHostError('the ROS master at %s does not answer: %s' % (rosgraph.get_master_uri(), err)) from None
    if not running:
        # not a fault: the Output Manager starts the host for the first display and stops it with the last
        raise RvizHostError('no RViz host is running in namespace %r (%s): it starts with the first display '
                            'and stops with the last' % (args.namespace, node))
    client = RvizHostClient(node, timeout=args.timeout)
    client.wait_ready(args.timeout)
    return client


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--namespace', '--ns', '-n', dest='namespace', default='temoto',
                        help='TeMoto namespace (default: temoto)')
    parser.add_argument('--timeout', type=float, default=3.0, help='seconds to wait for the RViz host')


def screenshot_main(argv: Optional[list] = None) -> int:
    parser = argparse.ArgumentParser(prog='temoto screenshot', description='Save a PNG of the operator\'s RViz.')
    parser.add_argument('file', nargs='?', default='', help='output file (default: temoto_screenshot_<time>.png)')
    parser.add_argument('--window', action='store_true', help='the whole window incl. image panes, not only 3D')
    _common(parser)
    args = parser.parse_args(argv)
    path = args.file or time.strftime('temoto_screenshot_%Y%m%d_%H%M%S.png')
    try:
        resp = _client(args).screenshot('window' if args.window else 'view')
        with open(path, 'wb') as f:
            f.write(bytes(resp.png))
    except (RvizHostError, OSError) as e:
        print('temoto screenshot: %s' % e, file=sys.stderr)
        return 1
    print('%s (%dx%d, frame %d)' % (path, resp.width, resp.height, resp.frame_count))
    return 0


def displays_main(argv: Optional[list] = None) -> int:
    parser = argparse.ArgumentParser(prog='temoto displays', description='List the displays shown in RViz.')
    parser.add_argument('--json', action='store_true', help='print JSON')
    _common(parser)
    args = parser.parse_args(argv)
    try:
        resp = _client(args).list_displays()
    except RvizHostError as e:
        print('temoto displays: %s' % e, file=sys.stderr)
        return 1
    rows = [{'name': d.name, 'class': d.display_class, 'topic': d.topic, 'enabled': d.enabled, 'visible': d.visible, 'drawn': d.drawn,
             'status': d.status} for d in resp.displays]
    if args.json:
        print(json.dumps({'fixed_frame': resp.fixed_frame, 'frame_count': resp.frame_count,
                          'frame_rate': resp.frame_rate, 'displays': rows}, indent=2))
        return 0
    print('RViz: fixed frame %s, %d frames rendered, cap %g fps' % (resp.fixed_frame, resp.frame_count,
                                                                     resp.frame_rate))
    table = [('NAME', 'CLASS', 'TOPIC', 'DRAWN', 'STATUS')] + [
        (r['name'], r['class'], r['topic'] or '-',
         'hidden' if not r['visible'] else 'yes' if r['drawn'] else 'no', r['status']) for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(4)]
    for row in table:
        print('  '.join(c.ljust(w) for c, w in zip(row, widths)) + '  ' + row[-1])
    return 0


def main(argv: Optional[list] = None) -> int:
    """``temoto displays`` by default."""
    return displays_main(argv)


if __name__ == '__main__':
    sys.exit(displays_main())
