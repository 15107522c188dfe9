"""The Robot Manager's logic: a described robot loaded with the features wanted, its parts linked to it.

``load_robot`` is a resource of this manager's registrar. Its parts are linked sub-resources,
each asked for inside the load (``temoto_core.rr``: a call made in a load callback is linked
to the resource being loaded):
- each feature's controller and driver, started through the ER Manager, unless the
  description says it runs with the robot already (``running: true``), which is then checked:
  its topic must have a publisher;
- for navigation, the best obstacle source that works, asked of the Sensor Manager down the
  description's ranking and held on this manager's own account, failed over when it fails
  (``obstacle_failover.py``), and the navigator (``navigator_node.py``), told the description,
  the robot and the source's topic.

So a part that fails (a controller that crashes, an obstacle sensor that stalls) reaches the
holder of the robot as FAILED through the registrar, with the part named on the error stack, and
an unload releases every part. A load that fails is rolled back by the registrar (nothing stays
started), and the error names the part and the reason. A robot whose load fails, or whose part
fails, is less reliable next time (``temoto_core.reliability``), as the original's manager
lowered a failed robot's reliability.

What the original did wrong and this does not: it reported success when a part had failed
(``res.success = true`` after forwarding), waited for drivers without a bound, and never
passed a failure on to its client.
"""
from __future__ import annotations

import dataclasses
import json
import threading
import time
from typing import Dict, List, Optional, Sequence

import rosgraph
import rospy
from diagnostic_msgs.msg import KeyValue
from std_msgs.msg import String

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_core.halt import halt_topic
from temoto_core.reliability import Reliability
from temoto_core.rr import ResourceRegistrar, StatusEvent
from temoto_core.rr.settings import journal_param
from temoto_core.srv import GetRegistry, GetRegistryResponse
from temoto_er_manager.contract import LOAD_PROCESS, LOAD_PROCESS_TYPE, RR_NAME as ER_MANAGER
from temoto_robot_manager.contract import LOAD_ROBOT, LOAD_ROBOT_TYPE, ROBOTS, RR_NAME as NAME
from temoto_robot_manager.description import ObstacleSource, Part, RobotDescription
from temoto_robot_manager.obstacle_failover import ObstacleFailover, Served
from temoto_robot_manager.selection import choose_robot
from temoto_sensor_manager.contract import RR_NAME as SENSOR_MANAGER, START_SENSOR, START_SENSOR_TYPE

SUB = Subsystem.ROBOT_MANAGER
LOADED_KEY = 'robot/%d'            # owner state: what a load holds, for the next incarnation (``_recover``)
RELIABILITIES_KEY = 'reliabilities'
RUNNING_CHECK_S = 5.0          # a part that runs with the robot must show its topic within this
CHECK_PERIOD_S = 0.1


class RobotManager:
    def __init__(self, robots: Sequence[RobotDescription], problems: Sequence[object] = (),
                 namespace: Optional[str] = None) -> None:
        self.robots: Dict[str, RobotDescription] = {r.name: r for r in robots}
        self.reliability: Dict[str, Reliability] = {r.name: Reliability(prior=r.reliability) for r in robots}
        self.problems = [str(p) for p in problems]
        for problem in self.problems:
            rospy.logerr('%s: description: %s', NAME, problem)
        self._lock = threading.Lock()
        self._robot_of_part: Dict[int, str] = {}     # a part's local id -> the robot it serves
        self._loaded: Dict[int, dict] = {}           # load_robot internal id -> what it holds
        self._held: Dict[int, List[int]] = {}         # load_robot internal id -> its linked parts' local ids
        self.rr = ResourceRegistrar(NAME, namespace=namespace, subsystem=SUB, journal=journal_param())
        self.namespace = self.rr.namespace
        self._source_topics: Dict[str, rospy.Publisher] = {}
        self._owner_topics = {r.name: rospy.Publisher(self.owner_topic(r.name), String, queue_size=1, latch=True)
                              for r in robots}
        for pub in self._owner_topics.values():
            pub.publish(String(rospy.get_name()))
        self.obstacles = ObstacleFailover(self._start_source, self.rr.unload, self._tell, self._announce_source,
                                          SUB, lambda text: rospy.logwarn('%s: %s', NAME, text))
        kept = self.rr.owner_state()
        self._restore_reliabilities(kept.get(RELIABILITIES_KEY))
        self._records = {int(k.split('/')[1]): json.loads(v) for k, v in kept.items() if k.startswith('robot/')}
        self.rr.register_status_callback(self._on_part_status)
        self.rr.add_server(LOAD_ROBOT, LOAD_ROBOT_TYPE, self._load, self._unload, recover=self._recover)
        for stale in self._records:                   # a load the registry did not bring back
            self.rr.drop_owner_state(LOADED_KEY % stale)
        self._records.clear()
        self._info_srv = rospy.Service('/%s/%s/%s' % (self.namespace, NAME, ROBOTS), GetRegistry,
                                       lambda _req: GetRegistryResponse(json=self.info_json()))
        self.rr.resume()
        rospy.loginfo('%s: ready with robots %s', NAME, ', '.join(
            '%s (%s)' % (r.name, ', '.join(r.features)) for r in robots) or 'none')

    # -- load_robot --------------------------------------------------------------------------------------
    def choose(self, robot_name: str, features: List[str]) -> RobotDescription:
        return choose_robot(self.robots, lambda name: self.reliability[name].value, robot_name, features)

    def _gripper(self, robot: RobotDescription, held: List[int]) -> List[KeyValue]:
        """The gripper's controller and, when described, its command gate. The operator's stop goes to the gate (the
        stack's own stop), else to the controller, as it reaches the base and the arms."""
        gripper, halt = robot.gripper, '_halt_topic:=%s' % halt_topic(self.namespace)
        if gripper.node is None:
            args = ' '.join(a for a in (gripper.controller.args, halt) if a)
            return [self._part(robot, 'gripper.controller', dataclasses.replace(gripper.controller, args=args),
                               gripper.action + '/status', held)]
        args = ' '.join(a for a in (gripper.node.args, '_description:=%s' % robot.path, '_robot:=%s' % robot.name,
                                    '_owner_topic:=%s' % self.owner_topic(robot.name), halt) if a)
        return [self._part(robot, 'gripper.controller', gripper.controller, gripper.action + '/status', held),
                self._part(robot, 'gripper.node', dataclasses.replace(gripper.node, args=args),
                           gripper.command_action + '/status', held)]

    def _load(self, req, res) -> None:
        features = [f.strip() for f in req.features if f.strip()]
        robot = self.choose(req.robot_name.strip(), features)
        features = features or robot.features
        load_id = res.trr.resource_id
        parts: List[KeyValue] = []
        held: List[int] = []                       # the local ids of the linked parts, for the journal
        try:
            if 'navigation' in features:
                parts += self._navigation(robot, load_id, held)
            if 'manipulation' in features:
                for arm in robot.manipulation.values():
                    parts.append(self._part(robot, 'manipulation.%s.controller' % arm.name, arm.controller,
                                            arm.action + '/status', held))
                    if arm.manipulator is not None:
                        args = ' '.join(a for a in (arm.manipulator.args, '_description:=%s' % robot.path,
                                                    '_robot:=%s' % robot.name, '_arm:=%s' % arm.name,
                                                    '_owner_topic:=%s' % self.owner_topic(robot.name),
                                                    '_halt_topic:=%s' % halt_topic(self.namespace)) if a)
                        parts.append(self._part(robot, 'manipulation.%s.manipulator' % arm.name,
                                                dataclasses.replace(arm.manipulator, args=args),
                                                '%s/move_arm/status' % arm.name, held))
            if 'gripper' in features:
                parts += self._gripper(robot, held)
        except TemotoError:
            self.obstacles.release(load_id)       # held on this manager's account: the registrar's rollback skips it
            self.reliability[robot.name].failure()
            self._keep_reliabilities()
            raise
        self.reliability[robot.name].success()
        self._keep_reliabilities()
        res.robot_name, res.features, res.parts = robot.name, features, parts
        entry = {'robot': robot.name, 'features': features, 'parts': {kv.key: kv.value for kv in parts}}
        with self._lock:
            self._loaded[load_id] = entry
            self._held[load_id] = held
        self._keep_load(load_id)
        rospy.loginfo('%s: loaded %s with %s: %s', NAME, robot.name, ', '.join(features),
                      '; '.join('%s = %s' % (kv.key, kv.value) for kv in parts))

    def _unload(self, req, res) -> None:
        """The registrar releases the linked parts; the obstacle source is this manager's to release."""
        self.obstacles.release(res.trr.resource_id)
        with self._lock:
            self._loaded.pop(res.trr.resource_id, None)
            self._held.pop(res.trr.resource_id, None)
        if self.rr.journaled:
            self.rr.drop_owner_state(LOADED_KEY % res.trr.resource_id)

    def _keep_load(self, load_id: int) -> None:
        """What load ``load_id`` holds, kept across a crash of this manager (the journal, and the holder's
        copy of the record): the robot, its parts and the obstacle source, watched again by ``_recover``."""
        with self._lock:
            entry, held = self._loaded.get(load_id), self._held.get(load_id, [])
        if entry is None or not self.rr.journaled:       # a load in progress journals itself at its end
            return
        record = dict(entry, held=list(held))
        served = self.obstacles.served(load_id)
        if served is not None:
            record['obstacles'] = {'source': served.source.label if served.source else '',
                                   'local_id': served.local_id, 'sensor': served.sensor, 'topic': served.topic}
        self.rr.put_owner_state(LOADED_KEY % load_id, json.dumps(record))

    def _keep_reliabilities(self) -> None:
        if self.rr.journaled:
            self.rr.put_owner_state(RELIABILITIES_KEY, json.dumps(
                {name: r.samples() for name, r in self.reliability.items()}))

    def _restore_reliabilities(self, kept: Optional[str]) -> None:
        for name, samples in (json.loads(kept) if kept else {}).items():
            if name in self.reliability:
                self.reliability[name].restore(samples)

    # -- recovery after a restart ----------------------------------------------------------------------------
    def _recover(self, req, res) -> None:
        """A robot the previous incarnation loaded: its parts run on (their owners say so when this
        registrar reclaims them, right after), so take back what this manager kept of it: which robot each
        part serves, and the obstacle source, to fail over again when it fails."""
        load_id = res.trr.resource_id
        record = self._records.pop(load_id, None)
        robot = self.robots.get(res.robot_name)
        if record is None or robot is None:
            raise TemotoError(ErrorCode.RESOURCE_FAILED, SUB, 'robot %s: %s' % (
                res.robot_name, 'the journal has no record of its parts' if record is None
                else 'it is not described any more'))
        with self._lock:
            self._loaded[load_id] = {k: record[k] for k in ('robot', 'features', 'parts')}
            self._held[load_id] = [int(local_id) for local_id in record.get('held', [])]
            for local_id in record.get('held', []):
                self._robot_of_part[int(local_id)] = robot.name
        kept = record.get('obstacles')
        if kept is not None and robot.navigation is not None:
            source = next((s for s in robot.navigation.obstacle_sources if s.label == kept['source']), None)
            served = Served(robot.name, tuple(robot.navigation.obstacle_sources), source, int(kept['local_id']),
                            kept['topic'], kept['sensor'])
            if served.local_id:
                with self._lock:
                    self._robot_of_part[served.local_id] = robot.name
            self.obstacles.adopt(load_id, served)
        rospy.loginfo('%s: took robot %s back after a restart (load %d): %s', NAME, robot.name, load_id,
                      ', '.join(sorted(record['parts'])))

    def owner_topic(self, robot: str) -> str:
        """The latched topic that the motion nodes of ``robot`` subscribe to: its connection's end tells them
        this manager is gone (``goal_holders.py``)."""
        return '/%s/%s/%s/owner' % (self.namespace, NAME, robot)

    def source_topic(self, robot: str) -> str:
        """The latched topic on which the navigator of ``robot`` hears which obstacle topic to read."""
        return '/%s/%s/%s/obstacle_source' % (self.namespace, NAME, robot)

    def _announce_source(self, load_id: int, served: Served) -> None:
        """Tell the navigator of ``served.robot`` its new obstacle topic; journal the load's new source."""
        robot, topic = served.robot, served.topic
        with self._lock:
            pub = self._source_topics.get(robot)
            if pub is None:
                pub = self._source_topics[robot] = rospy.Publisher(self.source_topic(robot), String, queue_size=1,
                                                                   latch=True)
        pub.publish(String(topic))
        self._keep_load(load_id)

    def _tell(self, load_id: int, code: int, message: str) -> None:
        """A status of a loaded robot to its holders (the obstacle failover's steps)."""
        rospy.loginfo('%s: robot %d: %s', NAME, load_id, message)
        try:
            self.rr.send_status(load_id, code, message)
        except (KeyError, TemotoError) as err:       # unloaded meanwhile: nobody to tell
            rospy.logwarn('%s: robot %d is gone; not told: %s (%s)', NAME, load_id, message, err)

    def _start_source(self, source: ObstacleSource) -> tuple:
        resp = self.rr.call(SENSOR_MANAGER, START_SENSOR, START_SENSOR_TYPE._request_class(
            sensor_type=source.sensor_type, package_name=source.package, executable=source.executable,
            output_topics=[KeyValue(source.output_topic, '')]), link=False)
        topic = dict((kv.key, kv.value) for kv in resp.output_topics).get(source.output_topic, '')
        return resp.trr.resource_id, resp.sensor_name, topic

    def _navigation(self, robot: RobotDescription, load_id: int, held: List[int]) -> List[KeyValue]:
        nav = robot.navigation
        parts = [self._part(robot, 'navigation.driver', nav.driver, nav.odom_topic, held)]
        served = self.obstacles.take(load_id, robot.name, nav.obstacle_sources)
        with self._lock:
            self._robot_of_part[served.local_id] = robot.name
        parts.append(KeyValue('navigation.obstacles', served.summary))
        if nav.controller is not None:
            # no obstacle topic among its arguments: it hears the source on the robot's latched topic (announced
            # above), so that every load of the robot asks for the same navigator and shares it. With the topic,
            # two loads on different sources (one of them failed over) asked for two navigators of one base, and
            # the second was refused: "node name /chaos/vaultbot_navigator is already in use" (chaos, history 7)
            args = ' '.join(a for a in (nav.controller.args, '_description:=%s' % robot.path, '_robot:=%s' % robot.name,
                                        '_obstacle_source_topic:=%s' % self.source_topic(robot.name),
                                        '_halt_topic:=%s' % halt_topic(self.namespace)) if a)
            parts.append(self._part(robot, 'navigation.controller', dataclasses.replace(nav.controller, args=args),
                                    'move_base/status', held))
        return parts

    def _part(self, robot: RobotDescription, label: str, part: Part, topic: str, held: List[int]) -> KeyValue:
        """Start ``part`` through the ER Manager (linked), or check that it runs; raises naming the part."""
        if part.running:
            if topic and not self._published(topic):
                raise TemotoError(ErrorCode.RESOURCE_FAILED, SUB, '%s of %s: nothing publishes %s after %.0f s; it '
                                  'should run with the robot (%s %s)' % (label, robot.name, rospy.resolve_name(topic),
                                                                          RUNNING_CHECK_S, part.package,
                                                                          part.executable))
            return KeyValue(label, 'runs with the robot (%s %s)' % (part.package, part.executable))
        try:
            resp = self.rr.call(ER_MANAGER, LOAD_PROCESS, LOAD_PROCESS_TYPE._request_class(
                action='ros_execute', package_name=part.package, executable=part.executable, args=part.args))
        except TemotoError as err:
            raise err.extended(ErrorCode.RESOURCE_FAILED, SUB, '%s of %s could not start' % (label, robot.name),
                               self.rr.prefix) from None
        with self._lock:
            self._robot_of_part[resp.trr.resource_id] = robot.name
        held.append(resp.trr.resource_id)
        if topic and not self._published(topic):
            raise TemotoError(ErrorCode.RESOURCE_FAILED, SUB, '%s of %s started (pid %d) but nothing publishes %s '
                              'after %.0f s' % (label, robot.name, resp.pid, rospy.resolve_name(topic),
                                                RUNNING_CHECK_S))
        return KeyValue(label, 'process %d (%s %s %s)' % (resp.pid, part.package, part.executable, part.args))

    @staticmethod
    def _published(topic: str) -> bool:
        """Whether ``topic`` has a publisher at the master, within a bound."""
        name = rospy.resolve_name(topic)
        master = rosgraph.Master(rospy.get_name())
        deadline = time.monotonic() + RUNNING_CHECK_S
        while True:
            try:
                if any(t == name for t, _ in master.getPublishedTopics('')):
                    return True
            except (rosgraph.MasterException, OSError):
                pass
            if time.monotonic() >= deadline:
                return False
            time.sleep(CHECK_PERIOD_S)

    # -- status ----------------------------------------------------------------------------------------------
    def _on_part_status(self, event: StatusEvent) -> None:
        """A part's FAILED: its robot is less reliable. A linked part's has reached the holders already
        (the registrar forwards it); an obstacle source's is failed over instead (``obstacle_failover.py``)."""
        if not event.failed:
            return
        with self._lock:
            robot = self._robot_of_part.pop(event.resource_id, None)
        if robot is not None:
            self.reliability[robot].failure()
            self._keep_reliabilities()
            rospy.logwarn('%s: a part of %s failed: %s', NAME, robot, event.message)
        self.obstacles.failed(event.resource_id, event.message)

    # -- introspection -----------------------------------------------------------------------------------------
    def info_json(self) -> str:
        with self._lock:
            loaded = list(self._loaded.values())
        return json.dumps({'robots': [{
            'name': r.name, 'description': r.description, 'features': r.features,
            'reliability': round(self.reliability[r.name].value, 3),
            'places': sorted(r.navigation.places) if r.navigation else [],
            'place_poses': {k: list(v) for k, v in r.navigation.places.items()} if r.navigation else {},
            'base_frame': r.navigation.base_frame if r.navigation else '',
            # the navigator's node, whose private topics (plan, scene) the operator's scene shows
            'navigator': r.navigation.controller.node_name if r.navigation and r.navigation.controller else '',
            'arms': {a.name: sorted(a.named_poses) for a in r.manipulation.values()},
            'arm_frames': {a.name: {'base_frame': a.base_frame, 'tool_frame': a.tool_frame}
                           for a in r.manipulation.values()},
            'gripper': {'action': r.gripper.command_action, 'arm': r.gripper.arm, 'positions': r.gripper.positions}
            if r.gripper else None,
            # where the robot's relative topic names live (move_base, <arm>/servo_target): the manager's own
            # ROS namespace, as its parts are started by the ER Manager next to it
            'ros_namespace': rospy.get_namespace(),
            'loaded': [dict(entry, features=list(entry['features'])) for entry in loaded if entry['robot'] == r.name],
        } for r in self.robots.values()], 'problems': self.problems}, sort_keys=True)

    def shutdown(self) -> None:
        self.obstacles.close()
        self.rr.shutdown()
