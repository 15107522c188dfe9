#!/usr/bin/env python3
"""No false stall on two hosts whose link is cut and healed every 10 s, with two CPU hogs beside them.

The case the stall detector once got wrong: a healthy 20 Hz scanner on the operator's station was
called stalled right after a partition healed, both cores busy (the station's nodes all rejoin the
master at once). Here, for ``--minutes``:
- the robot host runs the master, the simulated VaultBot and the robot's managers (robot.launch); this
  process, on the robot host too, holds its three sensors (D435 cloud 30 Hz, SICK scan 25 Hz, Hokuyo
  scan 40 Hz) from the robot's Sensor Manager;
- the station host runs its own ER and Sensor Managers (config/station.yaml: the lab's fixed scanner,
  20 Hz) and a holder process that keeps the scanner, as the action engine does under hot standby;
- two busy-looping processes load both cores;
- every ``--period`` s the cable between the hosts is pulled for half the period, then plugged back.

Every sensor's data path stays on one host, so no cut can starve it: every FAILED is a false one, and
so is a held stream that stops. Goal (issue 38): 0 false FAILED in 10 minutes.

Needs root (network namespaces). Prints a markdown table and writes bench/results/stall_hosts.json.
Usage: python bench/bench_stall_hosts.py [--minutes M] [--period S] [--hogs N]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from common import cpu_hogs, print_table, stop_hogs  # noqa: E402

ROBOT = 'vaultbot'
# sensor, topic type, sensor type, executable, nominal Hz: the robot's three, held from the robot host
SENSORS = [('realsense_d435', 'camera_data', 'depth camera', 'd435_driver', 30.0),
           ('sick_lms511', 'lidar_data', 'lidar', 'sick_driver', 25.0),
           ('hokuyo_utm30lx', 'lidar_data', 'lidar', 'hokuyo.launch', 40.0)]
STATION_SENSOR = ('site_lidar', 'lidar_data', 'lidar', 'site_lidar.launch', 20.0)
LOAD_BOUND = 60.0        # s for a sensor's load, generous: a load that hangs ends the run


def station_holder() -> int:
    """On the station: hold the station's scanner, print every status and, on a closed stdin, the count of
    scans received, then release it. One JSON object per line."""
    import rospy
    from temoto_sensor_manager.interface import SensorManagerInterface
    rospy.init_node('bench_station_holder', disable_signals=True)
    name, key, kind, exe, _ = STATION_SENSOR
    sm = SensorManagerInterface()

    def say(**fields) -> None:
        sys.stdout.write(json.dumps(fields) + '\n')
        sys.stdout.flush()
    sm.register_update_callback(lambda e: say(event=e.code, failed=e.failed, message=e.message, sensor=name))
    held = sm.start_sensor(kind, [key], executable=exe)
    received = [0]
    sub = rospy.Subscriber(held.topic(key), rospy.AnyMsg, lambda _m: received.__setitem__(0, received[0] + 1),
                           queue_size=5)
    say(held=held.topic(key))
    sys.stdin.read()                 # until the bench closes it
    sub.unregister()
    say(received=received[0])
    sm.stop_sensor(held.resource_id)
    rospy.signal_shutdown('done')
    return 0


class Holder:
    """The station's holder process, its lines read as they come."""

    def __init__(self, hosts, master, workdir: str) -> None:
        env = hosts.env(hosts.operator, master.uri, base=master.env)
        env['PYTHONPATH'] = ROOT + os.pathsep + env.get('PYTHONPATH', '')
        self.log = open(os.path.join(workdir, 'station_holder.log'), 'w')
        self.proc = subprocess.Popen(hosts.argv(hosts.operator, [sys.executable, os.path.abspath(__file__),
                                                                 '--station-holder']),
                                     env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log,
                                     text=True)
        self.lines = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(json.loads(line))

    def first(self, key: str, timeout: float):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self.proc.poll() is None:
            for line in self.lines:
                if key in line:
                    return line[key]
            time.sleep(0.05)
        raise RuntimeError('the station holder gave no %r within %.0f s (exit %s); see %s'
                           % (key, timeout, self.proc.poll(), self.log.name))

    def failed(self):
        return [line['message'] for line in self.lines if line.get('failed')]

    def finish(self, timeout: float = 30.0) -> int:
        self.proc.stdin.close()
        received = self.first('received', timeout)
        self.proc.wait(timeout)
        return received

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--minutes', type=float, default=10.0, help='how long every sensor is held')
    ap.add_argument('--period', type=float, default=10.0, help='s from one cut to the next (cut for half)')
    ap.add_argument('--hogs', type=int, default=2, help='busy-looping processes beside the stack')
    ap.add_argument('--station-holder', action='store_true', help=argparse.SUPPRESS)
    opts = ap.parse_args(argv)
    if opts.station_holder:
        return station_holder()

    from temoto_core.hosts import TwoHosts, unavailable
    from temoto_core.processes import ProcessGroupLauncher
    from temoto_demo.scenario import write_station_catalogue
    why = unavailable()
    if why:
        print('bench_stall_hosts: %s' % why)
        return 1
    workdir = tempfile.mkdtemp(prefix='bench_stall_hosts_')
    hosts = TwoHosts('bsh%d' % (os.getpid() % 10000))
    hosts.up()
    leave = hosts.enter(hosts.robot)       # this process's ROS is on the robot host, beside the drivers
    busy, launchers, holder = [], [], None
    false_failed, cycles, counts = [], 0, {}
    try:
        import rospy
        from temoto_sensor_manager.interface import SensorManagerInterface
        master = hosts.master(os.path.join(workdir, 'master'))
        os.makedirs(master.workdir, exist_ok=True)
        master.start()
        master.point_this_process()
        os.environ['ROS_IP'] = hosts.robot.address
        os.environ.pop('ROS_HOSTNAME', None)
        robot = ProcessGroupLauncher(hosts.env(hosts.robot, master.uri, base=master.env), workdir,
                                     wrap=lambda a: hosts.argv(hosts.robot, a))
        station = ProcessGroupLauncher(hosts.env(hosts.operator, master.uri, base=master.env), workdir,
                                       wrap=lambda a: hosts.argv(hosts.operator, a),
                                       run_in=lambda fn: hosts.run_in(hosts.operator, fn, 60.0))
        launchers = [station, robot]
        print('bench_stall_hosts: robot %s (master, simulation, managers), station %s (its managers) ...'
              % (hosts.robot.address, hosts.operator.address), flush=True)
        robot.launch('temoto_bringup', 'robot.launch', ['robot:=' + ROBOT], timeout=60)
        station.launch('temoto_er_manager', 'er_manager.launch', timeout=60)
        station.launch('temoto_sensor_manager', 'sensor_manager.launch',
                       ['catalogue:=' + write_station_catalogue(ROBOT, workdir)], timeout=60)
        rospy.init_node('bench_stall_hosts', disable_signals=True)
        sm = SensorManagerInterface(namespace=ROBOT)
        events = []
        sm.register_update_callback(events.append)      # no reload: a FAILED is counted, not repaired
        held = {name: sm.start_sensor(kind, [key], executable=exe) for name, key, kind, exe, _ in SENSORS}
        received = {name: 0 for name, _, _, _, _ in SENSORS}

        def counter(name):
            return lambda _m: received.__setitem__(name, received[name] + 1)
        subs = [rospy.Subscriber(held[name].topic(key), rospy.AnyMsg, counter(name), queue_size=5)
                for name, key, _, _, _ in SENSORS]
        holder = Holder(hosts, master, workdir)
        holder.first('held', LOAD_BOUND)
        busy = cpu_hogs(opts.hogs)
        print('bench_stall_hosts: 4 sensors held (3 on the robot, 1 on the station) beside %d CPU hogs; '
              'the link cut for %.0f s every %.0f s, for %.1f min ...'
              % (len(busy), opts.period / 2, opts.period, opts.minutes), flush=True)
        start = time.monotonic()
        end = start + opts.minutes * 60
        while time.monotonic() < end:
            hosts.link(False)
            time.sleep(opts.period / 2)       # the cut's length: the fault itself, not a wait for a condition
            hosts.link(True)
            cycles += 1
            time.sleep(max(0.0, min(opts.period / 2, end - time.monotonic())))
            if cycles % 6 == 0:
                bad = [e for e in events if e.failed] + holder.failed()
                print('  %.0f s left: %d cycles, %d FAILED' % (max(0.0, end - time.monotonic()), cycles, len(bad)),
                      flush=True)
        took = time.monotonic() - start
        false_failed = ['%s: %s' % (e.resource_id, e.message) for e in events if e.failed] + holder.failed()
        for sub in subs:
            sub.unregister()
        counts = {name: received[name] / took for name in received}
        counts[STATION_SENSOR[0]] = holder.finish() / took
        for result in held.values():
            sm.stop_sensor(result.resource_id)
    finally:
        stop_hogs(busy)
        hosts.link(True)
        if holder is not None:
            holder.kill()
        for launcher in launchers:
            launcher.stop_all()
        leave()
        hosts.down()

    rows = [('false FAILED in %.1f min: 4 sensors held on 2 hosts, %d CPU hogs, a cut every %.0f s (%d cycles)'
             % (opts.minutes, opts.hogs, opts.period, cycles), '%d' % len(false_failed), '0 (10 min)')]
    for name, _, _, _, rate in SENSORS + [STATION_SENSOR]:
        rows.append(('messages received from %s (%.0f Hz nominal)' % (name, rate),
                     '%.1f Hz' % counts.get(name, 0.0), '-'))
    print_table('Stall detection on two hosts', rows)
    for message in false_failed:
        print('false FAILED: %s' % message)
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'stall_hosts.json'), 'w') as f:
        json.dump({'rows': rows, 'false_failed': false_failed, 'cycles': cycles, 'minutes': opts.minutes,
                   'rates_hz': counts}, f, indent=2)
    return 0 if not false_failed else 1


if __name__ == '__main__':
    sys.exit(main())
