"""``temoto registry [RR] [--json] [--namespace NS]``: what each registrar holds."""
import argparse
import json
import sys
from typing import List

import rosgraph
import rospy
import rosservice

from temoto_core.rr.registry import RegistrySnapshot
from temoto_core.srv import GetRegistry

SUFFIX = '/registry'


def find_registrars(namespace: str) -> List[str]:
    """Registrar names in ``namespace``, from the registry services the master knows."""
    prefix = '/%s/' % namespace.strip('/')
    names = []
    for service in rosservice.get_service_list():
        if service.startswith(prefix) and service.endswith(SUFFIX) and service.count('/') == 3:
            names.append(service[len(prefix):-len(SUFFIX)])
    return sorted(names)


def fetch(namespace: str, rr_name: str, timeout: float = 3.0) -> RegistrySnapshot:
    service = '/%s/%s%s' % (namespace.strip('/'), rr_name, SUFFIX)
    rospy.wait_for_service(service, timeout=timeout)
    return RegistrySnapshot.from_json(rospy.ServiceProxy(service, GetRegistry)().json)


def _summary(d: dict, limit: int = 60) -> str:
    text = ' '.join('%s=%s' % (k, v) for k, v in d.items() if v not in ('', [], {}, 0))
    return text if len(text) <= limit else text[:limit - 1] + '…'


def format_table(snap: RegistrySnapshot) -> str:
    lines = ['registrar %s (namespace %s, node %s); servers: %s'
             % (snap.name, snap.namespace, snap.node, ', '.join(snap.servers) or 'none')]
    if snap.server_queries:
        lines.append('  served resources:')
        lines.append('    %-18s %-14s %-9s %-9s %-6s %s' % ('id', 'server', 'state', 'consumers', 'links', 'request'))
        for q in snap.server_queries:
            lines.append('    %-18d %-14s %-9s %-9d %-6d %s' % (q.internal_id, q.server, q.state, len(q.consumers),
                                                                 len(q.links), _summary(q.summary)))
    if snap.client_queries:
        lines.append('  held resources:')
        lines.append('    %-40s %-18s %-9s %s' % ('target', 'remote id', 'state', 'local ids'))
        for q in snap.client_queries:
            lines.append('    %-40s %-18d %-9s %s' % (q.target, q.external_id, q.state,
                                                      ','.join(str(i) for i in q.local_ids)))
    if snap.is_empty():
        lines.append('  (holds nothing)')
    return '\n'.join(lines)


def main(argv: List[str]) -> int:
    parser = argparse.ArgumentParser(prog='temoto registry', description=__doc__)
    parser.add_argument('rr', nargs='?', help='registrar name (default: every registrar in the namespace)')
    parser.add_argument('--namespace', '--ns', dest='namespace', default='temoto')
    parser.add_argument('--json', action='store_true', help='print JSON instead of a table')
    args = parser.parse_args(argv)
    if not rosgraph.is_master_online():
        print('temoto registry: no ROS master at %s' % rosgraph.get_master_uri(), file=sys.stderr)
        return 1
    rospy.init_node('temoto_registry_cli', anonymous=True, disable_signals=True)
    names = [args.rr] if args.rr else find_registrars(args.namespace)
    if not names:
        print('temoto registry: no registrars in namespace /%s' % args.namespace, file=sys.stderr)
        return 1
    snaps = []
    for name in names:
        try:
            snaps.append(fetch(args.namespace, name))
        except (rospy.ROSException, rospy.ServiceException) as err:
            if args.rr:
                print('temoto registry: registrar %r is not running in /%s (known: %s)'
                      % (name, args.namespace, ', '.join(find_registrars(args.namespace)) or 'none'), file=sys.stderr)
                return 1
            # listing all: a registrar that died leaves its service registered at the master
            print('temoto registry: %s does not answer (%s); skipped' % (name, err), file=sys.stderr)
    if args.json:
        print(json.dumps([json.loads(s.to_json()) for s in snaps], indent=2, sort_keys=True))
    else:
        print('\n\n'.join(format_table(s) for s in snaps))
    return 0
