"""`temoto sim ...`: plug and unplug the simulated devices' cables, and show their states.

    temoto sim status
    temoto sim unplug DEVICE [--mode crash|stall]
    temoto sim plug DEVICE
    temoto sim sweep on|off [--speed RAD_S]
    temoto sim map WORLD OUT.yaml       write a world's map as map_server saves one (no ROS needed)

main(argv) receives the arguments after `sim`. Exit codes: 0 ok, 1 the sim
refused or is not running, 2 bad arguments (argparse).
"""
from __future__ import annotations

import argparse
import socket
import sys

import rosgraph
import rospy

from temoto_core import map_file
from vaultbot_sim.kinematics import WORLDS, TreeModel, resolve_world
from vaultbot_sim.spec import DEVICES, MODES
from vaultbot_sim.world_map import world_map
from vaultbot_sim.msg import DeviceStates
from vaultbot_sim.srv import SetDeviceState, SetSweep

SIM_NS = '/vaultbot_sim'
TIMEOUT = 3.0


class SimNotRunning(RuntimeError):
    pass


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='temoto sim', description='Simulated VaultBot: device cables and wrist sweep.')
    ap.add_argument('--ns', default=SIM_NS, help=f'the sim node\'s namespace (default {SIM_NS})')
    sub = ap.add_subparsers(dest='cmd', required=True)
    sub.add_parser('status', help='show every device\'s cable state')
    u = sub.add_parser('unplug', help='pull a device\'s cable')
    u.add_argument('device', choices=DEVICES)
    u.add_argument('--mode', choices=MODES, default='crash',
                   help='crash: the driver exits non-zero; stall: it stays alive and publishes nothing')
    p = sub.add_parser('plug', help='plug a device back in (drivers started afterwards work again)')
    p.add_argument('device', choices=DEVICES)
    s = sub.add_parser('sweep', help='turn the Hokuyo wrist sweep on or off')
    s.add_argument('state', choices=('on', 'off'))
    s.add_argument('--speed', type=float, default=0.0, help='rad/s, 0 < speed <= pi (default: unchanged)')
    m = sub.add_parser('map', help='write a world\'s map (a map_server YAML and a PGM beside it), as the sim '
                       'publishes it on /map')
    m.add_argument('world', help='%s, or a world URDF' % ' or '.join(sorted(WORLDS)))
    m.add_argument('out', help='the YAML file to write (its image: the same name, .pgm)')
    return ap


def _map(world: str, out: str) -> int:
    try:
        grid = world_map(TreeModel(resolve_world(world)))
    except ValueError as e:
        print(f'error: {e}', file=sys.stderr)
        return 2
    try:
        image = map_file.write(out, map_file.MapGrid(grid.origin, grid.resolution, grid.cells))
    except OSError as e:
        print(f'error: {out}: {e}', file=sys.stderr)
        return 1
    width, height = grid.size
    print(f'{out}: {width} x {height} cells of {grid.resolution} m, image {image}')
    return 0


def _check_master() -> None:
    old = socket.getdefaulttimeout()
    socket.setdefaulttimeout(TIMEOUT)
    try:
        rosgraph.Master('/temoto_sim_cli').getPid()
    except Exception as e:
        raise SimNotRunning(f'no ROS master at {rosgraph.get_master_uri()} ({e.__class__.__name__}): '
                            'the simulation is not running') from None
    finally:
        socket.setdefaulttimeout(old)


def _wait_service(ns: str, name: str) -> str:
    service = f'{ns}/{name}'
    try:
        rospy.wait_for_service(service, timeout=TIMEOUT)
    except rospy.ROSException:
        raise SimNotRunning(f'service {service} not available: the simulation is not running '
                            '(start it with: roslaunch vaultbot_sim sim.launch)') from None
    return service


def _proxy(ns: str, name: str, srv_type):
    return rospy.ServiceProxy(_wait_service(ns, name), srv_type)


def _set_device(ns: str, device: str, state: str, mode: str) -> int:
    resp = _proxy(ns, 'set_device_state', SetDeviceState)(device=device, state=state, mode=mode)
    if not resp.success:
        print(f'error: {resp.message}', file=sys.stderr)
        return 1
    print(resp.message)
    return 0


def _status(ns: str) -> int:
    _wait_service(ns, 'set_device_state')  # fails fast, with a clear message, when the sim is down
    rospy.init_node('temoto_sim_cli', anonymous=True, disable_signals=True, log_level=rospy.ERROR)
    try:
        msg = rospy.wait_for_message(f'{ns}/device_states', DeviceStates, timeout=TIMEOUT)
    except rospy.ROSException:
        raise SimNotRunning(f'nothing on {ns}/device_states within {TIMEOUT:.0f} s') from None
    for d in msg.devices:
        print(f'{d.name:7s} {"plugged" if d.plugged else "UNPLUGGED (" + d.mode + ")"}')
    return 0


def _sweep(ns: str, on: bool, speed: float) -> int:
    resp = _proxy(ns, 'set_sweep', SetSweep)(enabled=on, speed=speed)
    if not resp.success:
        print(f'error: {resp.message}', file=sys.stderr)
        return 1
    print(resp.message)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    ns = args.ns.rstrip('/')
    if args.cmd == 'map':
        return _map(args.world, args.out)
    try:
        _check_master()
        if args.cmd == 'status':
            return _status(ns)
        if args.cmd == 'unplug':
            return _set_device(ns, args.device, 'unplugged', args.mode)
        if args.cmd == 'plug':
            return _set_device(ns, args.device, 'plugged', '')
        return _sweep(ns, args.state == 'on', args.speed)
    except SimNotRunning as e:
        print(f'error: {e}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
