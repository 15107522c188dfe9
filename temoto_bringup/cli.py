"""``temoto``: one command, subcommands from every package.

Subcommands are named here as ``module:function`` strings and imported only
when used, so ``temoto registry`` does not pay for pybullet or RViz. It lives in
the top layer (temoto_bringup), the one package that may know every other.
"""
import importlib
import os
import shlex
import sys
from typing import List, Optional

# the folder that holds the TeMoto packages: the checkout, or site-packages after `pip install .`
PACKAGES_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

COMMANDS = {
    'registry': ('temoto_core.registry_cli:main', 'show a registrar\'s registry (all registrars without an argument)'),
    'ps': ('temoto_er_manager.cli:ps_main', 'list the processes the ER Manager runs'),
    'sensors': ('temoto_sensor_manager.cli:main', 'list the Sensor Manager\'s sensors, or check catalogue files'),
    'robots': ('temoto_robot_manager.cli:main', 'list the Robot Manager\'s robots, or check description files'),
    'dial': ('temoto_operator.dial_cli:main', 'the dial that scales the hand while an arm follows it'),
    'sim': ('vaultbot_sim.cli:main', 'plug or unplug a simulated device, or show their states'),
    'screenshot': ('temoto_output_manager.cli:screenshot_main', 'save a PNG of the operator\'s RViz view'),
    'displays': ('temoto_output_manager.cli:displays_main', 'list the displays shown in RViz'),
    'say': ('temoto_speech.cli:say_main', 'give the action engine an instruction in words (--voice: spoken)'),
    'listen': ('temoto_speech.cli:listen_main', 'what the speech node hears; or send it a WAV file (--wav)'),
    'actions': ('temoto_action_engine.cli:actions_main', 'list the indexed actions'),
    'graphs': ('temoto_action_engine.cli:graphs_main', 'list or stop running action graphs'),
    'demo': ('temoto_demo.cli:demo_main', 'run the paper\'s sensor-failover demonstration (\'demo teleop\': the '
                                          'operator moves the robot)'),
    'record': ('temoto_demo.cli:record_main', 'record the failover topic set to a bag'),
    'report': ('temoto_demo.cli:report_main', 'make the report of a recorded run from its bag'),
    'replay': ('temoto_demo.replay:replay_main', 'show the views of a recorded run again in RViz'),
    'env': ('temoto_bringup.cli:env_main', 'print the exports that let roslaunch and rosrun find the TeMoto packages'),
    'chaos': ('temoto_chaos.cli:chaos_main', 'a seeded history of operations and faults, checked after every step'),
}


def usage() -> str:
    width = max(len(name) for name in COMMANDS)
    lines = ['usage: temoto COMMAND [ARGS...]', '', 'commands:']
    lines += ['  %-*s  %s' % (width, name, help_text) for name, (_, help_text) in COMMANDS.items()]
    return '\n'.join(lines)


def find_packages_through_ros() -> None:
    """Put the TeMoto packages on ROS_PACKAGE_PATH (for this process and what it starts) if they are not there:
    an installed copy lives in site-packages, where rospack does not look by itself."""
    paths = [p for p in os.environ.get('ROS_PACKAGE_PATH', '').split(os.pathsep) if p]
    if not any(os.path.realpath(p) == os.path.realpath(PACKAGES_ROOT) for p in paths):
        os.environ['ROS_PACKAGE_PATH'] = os.pathsep.join([PACKAGES_ROOT] + paths)


def env_main(argv: List[str]) -> int:
    """``eval "$(temoto env)"``: this shell's roslaunch and rosrun find the TeMoto packages."""
    if argv:
        print('usage: temoto env', file=sys.stderr)
        return 2
    find_packages_through_ros()
    print('export ROS_PACKAGE_PATH=%s' % shlex.quote(os.environ['ROS_PACKAGE_PATH']))
    return 0


def main(argv: Optional[List[str]] = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    find_packages_through_ros()
    if not argv or argv[0] in ('-h', '--help', 'help'):
        print(usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print('temoto: unknown command %r\n\n%s' % (name, usage()), file=sys.stderr)
        return 2
    module_name, func_name = COMMANDS[name][0].split(':')
    try:
        func = getattr(importlib.import_module(module_name), func_name)
    except (ImportError, AttributeError) as err:
        print('temoto %s: not available (%s)' % (name, err), file=sys.stderr)
        return 2
    return int(func(rest) or 0)


if __name__ == '__main__':
    sys.exit(main())
