"""ROS face of the RViz host: services, the display-event topic, start-up and shutdown.

Service handlers run in rospy threads. They validate what they can without
RViz (class name, topic name and type at the master, YAML), then hand the
RViz part to the Qt main thread through :class:`MainThreadCaller` and wait.

Services (private names of the host node, e.g. /temoto/rviz_host/add_display):
add_display, remove_display, configure_display, set_view, screenshot,
list_displays. Events: /<ns>/temoto_output_manager/display_events.
"""
from __future__ import annotations

import os
import signal
import sys
import time
from typing import Optional

import rosgraph
import rospy
from std_msgs.msg import Header
from temoto_core import master_rejoin, params, rospy_internals
from temoto_core.master_reach import MasterReach
from temoto_core.node import after_init_node
from temoto_core.xmlrpc_util import proxy

from temoto_output_manager.msg import DisplayEvent, DisplayInfo
from temoto_output_manager.srv import (AddDisplay, AddDisplayResponse, ConfigureDisplay, ConfigureDisplayResponse,
                                       ListDisplays, ListDisplaysResponse, RemoveDisplay, RemoveDisplayResponse,
                                       Screenshot, ScreenshotResponse, SetView, SetViewResponse)

from . import display_config
from .display_types import MESSAGE_TYPE, UnknownDisplayType, check_rviz_class, check_topic_name, needs_topic
from .framing import OPERATOR_VIEW
from .rviz_host import HostError, HostSettings, MainThreadCaller, RvizHost, robots_from_names

SERVICE_NAMES = ('add_display', 'remove_display', 'configure_display', 'set_view', 'screenshot', 'list_displays')


def events_topic(temoto_namespace: str) -> str:
    return '/%s/temoto_output_manager/display_events' % temoto_namespace.strip('/')


class RvizHostNode:
    """Binds an :class:`RvizHost` to ROS services and the event topic."""

    def __init__(self, host: RvizHost, caller: MainThreadCaller, temoto_namespace: str = 'temoto',
                 call_timeout: float = 10.0):
        self.host = host
        self.caller = caller
        self.call_timeout = call_timeout
        self.events = rospy.Publisher(events_topic(temoto_namespace), DisplayEvent, queue_size=100)
        self._services = [
            rospy.Service('~add_display', AddDisplay, self._add),
            rospy.Service('~remove_display', RemoveDisplay, self._remove),
            rospy.Service('~configure_display', ConfigureDisplay, self._configure),
            rospy.Service('~set_view', SetView, self._set_view),
            rospy.Service('~screenshot', Screenshot, self._screenshot),
            rospy.Service('~list_displays', ListDisplays, self._list),
        ]

    def publish_event(self, event: str, name: str, cls: str, topic: str, frame_count: int, seconds: float) -> None:
        msg = DisplayEvent(header=Header(stamp=rospy.Time.now()), event=event, display_name=name,
                           display_class=cls, topic=topic, frame_count=frame_count, seconds_since_added=seconds)
        if not rospy.is_shutdown():
            self.events.publish(msg)
        if event == 'first_frame':
            rospy.loginfo("display '%s' drew its first frame of %s %.3f s after it was added (frame %d)",
                          name, topic, seconds, frame_count)
        else:
            rospy.loginfo("display %s: '%s' (%s %s)", event, name, cls, topic)

    def shutdown(self) -> None:
        for s in self._services:
            s.shutdown('rviz host stopping')

    # ------------------------------------------------------------ validation without RViz
    def _check_topic_type(self, cls: str, topic: str) -> None:
        """Refuse a topic that carries another message type than the display reads, and any topic while the
        master does not answer (asked with a bound: rospy's own question has none, and a master across a cut
        link held this service thread until the Output Manager's call ran out)."""
        resolved = rospy.resolve_name(topic)
        self.host.refuse_without_master(resolved)
        expected = MESSAGE_TYPE.get(cls)
        if not expected:
            return
        try:
            code, message, published = proxy(rosgraph.get_master_uri(), MASTER_TIMEOUT).getPublishedTopics(
                rospy.get_name(), '')
            if code != 1:
                raise RuntimeError(message)
        except Exception as e:   # the master went away meanwhile: RViz would not get data either
            raise HostError('cannot check topic %s at the master: %s' % (resolved, e)) from None
        published = dict(published)
        actual = published.get(resolved)
        if actual and actual != expected:
            raise HostError('topic %s carries %s but %s displays %s' % (resolved, actual, cls, expected))

    def _run(self, fn):
        return self.caller.call(fn, timeout=self.call_timeout)

    # ------------------------------------------------------------ handlers
    def _add(self, req):
        try:
            cls = check_rviz_class(req.display_class.strip(), self.host.known_classes)
            topic = req.topic.strip()
            if needs_topic(cls):
                if not topic:
                    raise HostError('%s needs a topic; none was given' % cls)
                topic = rospy.resolve_name(check_topic_name(topic))
                self._check_topic_type(cls, topic)
            config = display_config.parse_config(req.config)
            name = self._run(lambda: self.host.add_display(cls, req.name.strip(), topic, config))
            return AddDisplayResponse(ok=True, message='', name=name)
        except (HostError, UnknownDisplayType, display_config.DisplayConfigError, ValueError) as e:
            rospy.logwarn('add_display refused: %s', e)
            return AddDisplayResponse(ok=False, message=str(e), name='')

    def _remove(self, req):
        try:
            self._run(lambda: self.host.remove_display(req.name))
            return RemoveDisplayResponse(ok=True, message='')
        except HostError as e:
            return RemoveDisplayResponse(ok=False, message=str(e))

    def _configure(self, req):
        try:
            topic = req.topic.strip()
            if topic:
                topic = rospy.resolve_name(check_topic_name(topic))
            config = display_config.parse_config(req.config)
            cls = self._run(lambda: self.host._get(req.name).cls)
            if topic:
                self._check_topic_type(cls, topic)
            changed = self._run(lambda: self.host.configure_display(req.name, topic, config))
            return ConfigureDisplayResponse(ok=True, message='changed: %s' % ', '.join(changed) if changed else '')
        except (HostError, display_config.DisplayConfigError, ValueError) as e:
            return ConfigureDisplayResponse(ok=False, message=str(e))

    def _set_view(self, req):
        try:
            config = display_config.parse_config(req.config)

            def apply():
                if req.frame_robot:
                    self.host.frame_robot()
                return self.host.apply_view(config)
            self._run(apply)
            return SetViewResponse(ok=True, message='')
        except (HostError, display_config.DisplayConfigError, ValueError) as e:
            return SetViewResponse(ok=False, message=str(e))

    def _screenshot(self, req):
        try:
            png, w, h = self._run(lambda: self.host.screenshot(req.what.strip()))
            fc = self._run(self.host.frame_count)
            if req.path:
                with open(req.path, 'wb') as f:
                    f.write(png)
            return ScreenshotResponse(ok=True, message=req.path, png=png, width=w, height=h, frame_count=fc)
        except (HostError, OSError) as e:
            return ScreenshotResponse(ok=False, message=str(e))

    def _list(self, req):
        def snapshot():
            return self.host.list_displays(), self.host.frame_count(), str(self.host.manager.getFixedFrame())
        displays, fc, fixed = self._run(snapshot)
        infos = [DisplayInfo(name=d['name'], display_class=d['display_class'], topic=d['topic'],
                             enabled=d['enabled'], visible=d['visible'], drawn=d['drawn'], status=d['status']) for d in displays]
        return ListDisplaysResponse(displays=infos, fixed_frame=fixed, frame_count=fc,
                                    frame_rate=float(self.host.settings.frame_rate))


def _get_urdf(param: str):
    def read() -> Optional[str]:
        try:
            return rospy.get_param(param if param.startswith('/') else '/' + param, None)
        except Exception:
            return None
    return read


def _probe(topic: str, on_message):
    """A subscriber that only notes that data arrived (no deserialisation)."""
    return rospy.Subscriber(topic, rospy.AnyMsg, lambda _msg: on_message(), queue_size=1)


STARTUP_FRAMES = 3              # rendered frames before the host offers its services
STARTUP_RENDER_TIMEOUT = 20.0
MASTER_TIMEOUT = 2.0            # s for a question to the master that answers (it answers in ~1 ms)


def _render_first_frames(app, host: RvizHost, frames: int, timeout: float) -> bool:
    """Run the Qt event loop until RViz has rendered ``frames`` frames (True) or ``timeout`` passed (False)."""
    from python_qt_binding import QtCore    # lazy: Qt only once the X display is up (main)
    deadline = time.monotonic() + timeout
    loop = QtCore.QEventLoop()
    check = QtCore.QTimer()
    check.timeout.connect(lambda: loop.quit() if host.frame_count() >= frames or time.monotonic() > deadline
                          else None)
    check.start(5)
    loop.exec_()
    check.stop()
    return host.frame_count() >= frames


def _initial_view(value) -> dict:
    """``~initial_view``: 'operator' (behind and above the robot, looking ahead: the default), 'robot' (frame
    the whole robot), or a mapping of view properties."""
    if value == 'operator':
        return dict(OPERATOR_VIEW)
    if value == 'robot':
        return {}
    if isinstance(value, dict):
        return dict(value)
    raise SystemExit("~initial_view must be 'operator', 'robot' or a mapping of view properties, got %r" % (value,))


def _robots(value) -> list:
    try:
        return robots_from_names(str(value or ''))
    except ValueError as err:
        raise SystemExit('~robots: %s' % err)


def _adopt_librviz_node() -> None:
    """librviz's roscpp node carries the robot's transforms (and every display's data) to the screen, and
    roscpp never registers again with a master that restarted: after the robot's reboot RViz would not hear
    the new robot's /tf, and every display in its frames would lose its transform while listed as shown. The
    master check registers it again with this node (temoto_core/master_rejoin.py)."""
    rejoin = master_rejoin.ensure_started()
    if rejoin is None:
        return                           # ~master_check_period 0: the user turned the check off
    try:
        nodes = master_rejoin.nodes_of_processes([os.getpid()])
    except master_rejoin.XMLRPC_ERRORS as err:
        raise SystemExit('the master did not say which node librviz started: %s' % err)
    if not nodes:
        raise SystemExit("the master knows no other node of this process: librviz's roscpp node could not be "
                         'registered again after a restart of the master')
    for node in nodes:
        rejoin.adopt(node)
        rospy.loginfo('librviz runs roscpp node %s; registered again with a new master along with this one',
                      node.name)


def main(argv=None) -> int:
    """Entry point of nodes/rviz_host: headless by default, RViz on the Qt main thread."""
    from .xvfb import ensure_display        # lazy: with Qt, only in the host process
    xvfb = ensure_display()              # before Qt: a private X server when there is no DISPLAY
    rc = 1
    try:
        from python_qt_binding import QtCore, QtWidgets    # lazy: Qt needs the display started above
        app = QtWidgets.QApplication([sys.argv[0]])
        rospy_internals.install_bounded_handshake()
        rospy_internals.install_shutdown_guard()
        rospy.init_node('rviz_host', argv=argv, disable_signals=True)
        # the station's screen outlives a master on the robot that lost power: the new master learns its
        # services again (a host with no registrar has no other way back); its logging must not wait for the
        # master, and a wedged host kills itself so that the Output Manager fails its displays (node.py)
        after_init_node()
        try:
            settings = HostSettings(
                fixed_frame=params.text('fixed_frame', 'base_link', empty=False),
                frame_rate=params.number('frame_rate', 15, minimum=1, maximum=60, integer=True),
                width=params.number('width', 960, minimum=64, maximum=8192, integer=True),
                height=params.number('height', 600, minimum=64, maximum=8192, integer=True),
                robot_description=params.text('robot_description', 'robot_description', empty=False),
                robot_tf_prefix=params.text('robot_tf_prefix', ''),
                robots=_robots(rospy.get_param('~robots', '')),
                show_robot=params.flag('show_robot', True),
                show_grid=params.flag('show_grid', True),
                initial_view=_initial_view(rospy.get_param('~initial_view', 'operator')))
            namespace = params.text('temoto_namespace', 'temoto', empty=False)
        except params.ParamError as err:
            raise SystemExit(str(err))
        caller = MainThreadCaller()
        node: Optional[RvizHostNode] = None

        def on_event(*args):
            if node is not None:
                node.publish_event(*args)
        host = RvizHost(app, settings, on_event, get_urdf=_get_urdf(settings.drawn_robots()[0].description),
                        probe_factory=_probe, master_reach=MasterReach())
        stop = []       # set by SIGINT/SIGTERM/rospy shutdown, also while the host is still starting

        def request_stop(*_):
            stop.append(True)
            app.quit()  # leaves every running Qt event loop, the start-up one included
        # Python runs signal handlers only between bytecodes; the tick gives it a chance while Qt waits.
        signal.signal(signal.SIGINT, request_stop)
        signal.signal(signal.SIGTERM, request_stop)
        tick = QtCore.QTimer()
        tick.timeout.connect(lambda: None)
        tick.start(100)
        rospy.on_shutdown(request_stop)
        host.start()
        # librviz's roscpp node (ros::init inside frame.initialize()) installs its own SIGINT handler, which
        # only shuts roscpp down and leaves Qt running: a host then ignored SIGINT until SIGKILL. Ours again.
        signal.signal(signal.SIGINT, request_stop)
        signal.signal(signal.SIGTERM, request_stop)
        _adopt_librviz_node()
        # Offer the services only once RViz has rendered: under CPU load Mesa's llvmpipe (22.3) now and then
        # segfaults in the first frames (about 1 start in 15 with both cores busy). A host that dies there never
        # looked ready, so the Output Manager sees a failed start it can retry, not a display lost just after add.
        if not _render_first_frames(app, host, STARTUP_FRAMES, STARTUP_RENDER_TIMEOUT) and not stop:
            raise SystemExit('RViz rendered %d frames in %.0f s of starting, %d needed'
                             % (host.frame_count(), STARTUP_RENDER_TIMEOUT, STARTUP_FRAMES))
        node = RvizHostNode(host, caller, namespace)
        node.publish_event('host_started', '', '', '', host.frame_count(), 0.0)
        rospy.loginfo('rviz host ready on DISPLAY=%s (%s), fixed frame %s, %d fps cap',
                      os.environ.get('DISPLAY'), 'private Xvfb' if xvfb else 'given', settings.fixed_frame,
                      settings.frame_rate)
        if not stop:
            app.exec_()
        node.publish_event('host_stopping', '', '', '', host.frame_count(), 0.0)
        node.shutdown()
        host.shutdown()
        rospy.signal_shutdown('rviz host stopped')
        rc = 0
    finally:
        if xvfb is not None:
            xvfb.stop()
        sys.stdout.flush()
        sys.stderr.flush()
    # Skip interpreter teardown: librviz/Ogre globals are destroyed in an order that can crash at exit.
    os._exit(rc)
