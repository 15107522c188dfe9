"""Every name the demo subscribes to, records, or reads back from a bag.

Recording, the live run and the report all import these, so a bag recorded by
``temoto record`` on another machine is read with exactly the names it was
written with.
"""
from __future__ import annotations

import re
from typing import Dict, List

DEFAULT_NS = 'temoto'
SIM_NODE = 'vaultbot_sim'


def of_robot(robot: str, name: str) -> str:
    """The global name of a robot's relative ``name``: ``robot`` is its ROS namespace ('' for a robot at the
    root, as on one host; ``robot.launch robot:=vaultbot`` puts every name of the robot under /vaultbot)."""
    robot = robot.strip('/')
    return '/%s/%s' % (robot, name) if robot else '/' + name


def sim_ns(robot: str = '') -> str:
    """The simulation node of ``robot``."""
    return of_robot(robot, SIM_NODE)


def device_states(robot: str = '') -> str:
    return sim_ns(robot) + '/device_states'


def set_device_state(robot: str = '') -> str:
    return sim_ns(robot) + '/set_device_state'


def is_device_states(topic: str) -> bool:
    """Whether ``topic`` is some robot's device states (a bag names the robot it was recorded with)."""
    return re.match(r'^(/[A-Za-z][A-Za-z0-9_]*)?/%s/device_states$' % SIM_NODE, topic) is not None


def robot_description(robot: str = '') -> str:
    return of_robot(robot, 'robot_description')


DEVICE_STATES = device_states()          # a robot at the root (one host)

# Published by the demo's own relay / orchestrator (not by any TeMoto subsystem).
DEMO_NS = '/temoto_demo'
TICKS = DEMO_NS + '/ticks'                  # std_msgs/Header per frame: frame_id = source topic, stamp = arrival
STREAMS_PREFIX = DEMO_NS + '/streams'       # STREAMS_PREFIX + source topic: a displayed stream, as recorded
SCREENSHOTS = DEMO_NS + '/screenshots'      # sensor_msgs/CompressedImage (png); frame_id = stage name
STAGES = DEMO_NS + '/stages'                # std_msgs/String JSON: what the orchestrator did and when
ROBOT_DESCRIPTION = DEMO_NS + '/robot_description'   # std_msgs/String, latched: the URDF the views were drawn with
# Topics a live node acts on or announces (an instruction, a cable, a status into a registrar, the action
# engine's events and feedback, which the speech node announces and consoles show, the displays' events,
# what the speech node heard and said) are kept in the bag under this prefix, so that a plain `rosbag play`
# cannot start a graph, unplug a device, fail a resource, or make a live station speak of failures that
# never happened; `temoto report` and `temoto replay` read them back under their own names.
INERT_PREFIX = DEMO_NS + '/recorded'

# The VaultBot's displayed streams (temoto_sensor_manager/config/vaultbot.yaml); the relay also follows
# whatever the Output Manager displays, so other sensors are covered as they appear.
DEFAULT_STREAMS = ['/d435/depth_registered/points', '/laser_stitcher/cloud', '/sick/scan']
STREAM_TYPES = {'/d435/depth_registered/points': 'sensor_msgs/PointCloud2',
                '/laser_stitcher/cloud': 'sensor_msgs/PointCloud2', '/sick/scan': 'sensor_msgs/LaserScan'}
# How a displayed stream is recorded: every message, except clouds larger than BIG_CLOUD_BYTES (the D435's
# is 1.6 MB at 30 Hz), which are kept at BIG_CLOUD_HZ with every DECIMATE-th point in both directions.
BIG_CLOUD_BYTES = 256 * 1024
BIG_CLOUD_HZ = 5.0
DECIMATE = 2
# Any other message type of a displayed stream (images, markers, ...) is recorded at most this often.
OTHER_HZ = 5.0


def chatter(ns: str = DEFAULT_NS) -> str:
    return '/%s/human_chatter' % ns.strip('/')


def speech_audio(ns: str = DEFAULT_NS) -> str:
    """The speech node's audio in (temoto_speech/AudioData): what ``temoto demo --voice`` says."""
    return '/%s/speech/audio' % ns.strip('/')


def speech_topics(ns: str = DEFAULT_NS) -> List[str]:
    """What a spoken demo records besides the rest: the audio, what was heard, what was said."""
    return [speech_audio(ns)] + ['/%s/speech/%s' % (ns.strip('/'), t) for t in ('heard', 'announcements')]


def display_events(ns: str = DEFAULT_NS) -> str:
    return '/%s/temoto_output_manager/display_events' % ns.strip('/')


def action_events(ns: str = DEFAULT_NS) -> str:
    return '/%s/action_engine/events' % ns.strip('/')


def action_feedback(ns: str = DEFAULT_NS) -> str:
    return '/%s/action_engine/feedback' % ns.strip('/')


def status_regex(ns: str = DEFAULT_NS) -> str:
    """Every Resource Registrar's status topic, the action's interfaces' included."""
    return '/%s/[^/]+/status' % ns.strip('/')


def fixed_topics(ns: str = DEFAULT_NS, robot: str = '') -> Dict[str, str]:
    """Topics recorded by name, with their types (the relay announces them so the recorder subscribes early).
    ``robot``: the ROS namespace of the robot whose devices are recorded ('' for the root)."""
    return {
        chatter(ns): 'std_msgs/String',
        device_states(robot): 'vaultbot_sim/DeviceStates',
        display_events(ns): 'temoto_output_manager/DisplayEvent',
        action_events(ns): 'std_msgs/String',
        action_feedback(ns): 'std_msgs/String',
        TICKS: 'std_msgs/Header',
        SCREENSHOTS: 'sensor_msgs/CompressedImage',
        STAGES: 'std_msgs/String',
        ROBOT_DESCRIPTION: 'std_msgs/String',
        '/tf': 'tf2_msgs/TFMessage',
        '/tf_static': 'tf2_msgs/TFMessage',
    }


def record_regexes(ns: str = DEFAULT_NS, robot: str = '', extra: List[str] = ()) -> List[str]:
    """The recorder's topic set, as anchored regular expressions (the C++ recorder's ``-e``); ``extra``: more
    topics by name (``teleop_topics``)."""
    exact = ['^%s$' % t.replace('.', r'\.') for t in list(fixed_topics(ns, robot)) + speech_topics(ns) + list(extra)]
    return exact + ['^%s$' % status_regex(ns), '^%s/.*' % STREAMS_PREFIX]


def motion_inputs(ns: str = DEFAULT_NS) -> List[str]:
    """Anchored patterns of the topics that move a live robot: RViz's pointing tools, the halt, the hand and
    its dial, the arms' servo streams, the base's velocity. A bag keeps them under inert names, so that a
    replay never drives, points or follows a hand on a live system."""
    ns = ns.strip('/')
    return [r'^/move_base_simple/goal$', r'^/clicked_point$', r'^/%s/halt$' % ns, r'^(/[^/]+)?/%s/halt$' % ns,
            r'^/%s/pointed_goal/used$' % ns, r'^/%s/dial(/step)?$' % ns, r'^(/[^/]+)*/servo_(target|hold)$',
            r'^(/[^/]+)*/hand/sample$', r'^/virtual_hand/(sample|feedback)$', r'^(/[^/]+)*/cmd_vel$',
            r'^(/[^/]+)*/move_base/(goal|cancel)$']


def teleop_topics(ns: str = DEFAULT_NS, robot: str = '') -> List[str]:
    """What ``temoto demo teleop`` records besides the failover set: the sim's ground truth of the base, the
    arms and the gripper, the map and the plan, the pointed goal, the hand, the servo stream, and the halt."""
    ns = ns.strip('/')
    return [of_robot(robot, 'vaultbot_sim/base_state'), of_robot(robot, 'vaultbot_sim/arm_states'),
            of_robot(robot, 'vaultbot_sim/gripper_state'), of_robot(robot, 'map'),
            of_robot(robot, 'vaultbot_navigator/plan'), '/move_base_simple/goal', '/%s/pointed_goal' % ns,
            '/%s/pointed_goal/marker' % ns, '/%s/halt' % ns, '/hand/sample', '/virtual_hand/sample',
            of_robot(robot, 'left_arm/servo_target'), of_robot(robot, 'left_arm/servo_hold'),
            of_robot(robot, 'left_arm/servo_status'), '/%s/dial/scale' % ns]


def acts_on_a_live_system(topic: str, ns: str = DEFAULT_NS) -> bool:
    """Whether a recorded topic, played back under its own name, would drive a live stack or be taken by it
    for its own news (announced, shown as the state of a graph or a display)."""
    if topic.startswith(INERT_PREFIX + '/'):
        return False                    # kept apart already
    heeded = (chatter(ns), action_events(ns), action_feedback(ns), display_events(ns)) + tuple(speech_topics(ns))
    return topic in heeded or is_device_states(topic) or re.match('^%s$' % status_regex(ns), topic) is not None \
        or any(re.match(p, topic) for p in motion_inputs(ns))


def inert_name(topic: str) -> str:
    return INERT_PREFIX + topic


def live_name(topic: str) -> str:
    """The name a bag topic had on the live system (undoes :func:`inert_name`)."""
    return topic[len(INERT_PREFIX):] if topic.startswith(INERT_PREFIX + '/') else topic


# Managers' services the demo waits for before it speaks (the wire contract's names).
def manager_services(ns: str = DEFAULT_NS, robot: str = '') -> List[str]:
    """``robot``: the TeMoto namespace of the robot's own ER and Sensor Managers, when they run apart from the
    operator's (two hosts); the operator's station then has an ER Manager of its own, for RViz."""
    ns = ns.strip('/')
    robot = robot.strip('/')
    return ['/%s/temoto_er_manager/load_process' % ns,
            '/%s/temoto_sensor_manager/start_sensor' % (robot or ns),
            '/%s/temoto_output_manager/load_rviz_plugin' % ns,
            '/%s/action_engine/list_actions' % ns,
            set_device_state(robot)] + (['/%s/temoto_er_manager/load_process' % robot] if robot else [])
