"""The RViz host: a real librviz VisualizationFrame embedded in this process.

Every method of :class:`RvizHost` touches RViz and must run on the Qt main
thread; :class:`MainThreadCaller` carries calls there from
rospy's service threads. The ROS side (services, event topic) is in
host_node.py; this class only knows RViz and Qt.

Settings that keep it light on 2 cores: anti-aliasing off
(ctypes call before ``frame.initialize()``), Frame Rate capped. Image displays
are never deleted (each delete leaks ~7 MB): removed ones are disabled and
kept in a pool for the next Image display.
"""
from __future__ import annotations

import ctypes
import logging
import re
import threading
import time
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Tuple

from python_qt_binding import QtCore, QtWidgets
from rviz import bindings as rviz

from temoto_core.master_reach import MasterReach
from temoto_core.rr.messages import legal_name

from . import display_config
from .display_types import PROBED_CLASSES, check_rviz_class, installed_rviz_classes, topic_property
from .first_frame import FirstFrameWatch, received_count
from .framing import OPERATOR_VIEW, OrbitView, robot_view

log = logging.getLogger('temoto_output_manager.rviz_host')

IMAGE_CLASS = 'rviz/Image'
VISIBLE = 'Visible'     # not an RViz property: the host's own, in add_display's and configure_display's config
ALPHA = 'Alpha'
BUILTIN_GRID = 'Grid'
BUILTIN_ROBOT = 'RobotModel'


class HostError(ValueError):
    """A request the host refuses; the message says what was wrong. Nothing was changed."""


class MainThreadCaller(QtCore.QObject):
    """Runs a callable on the Qt main thread; the calling thread waits for its result.

    A queued signal posts the job to the main thread's event loop. A job whose
    caller gave up waiting is cancelled and never runs late.
    """
    _job = QtCore.Signal(object)

    def __init__(self):
        super().__init__()
        self._main = threading.current_thread()
        self._job.connect(self._run, QtCore.Qt.QueuedConnection)

    @staticmethod
    def _run(job):
        fn, fut = job
        if not fut.set_running_or_notify_cancel():
            return
        try:
            fut.set_result(fn())
        except BaseException as e:  # handed to the waiting thread
            fut.set_exception(e)

    def call(self, fn: Callable[[], Any], timeout: float = 10.0) -> Any:
        if threading.current_thread() is self._main:
            return fn()
        fut: Future = Future()
        self._job.emit((fn, fut))
        try:
            return fut.result(timeout)
        except FutureTimeout:
            fut.cancel()
            raise HostError('the RViz main thread did not answer within %.1f s' % timeout) from None


@dataclass
class HostedDisplay:
    name: str
    cls: str
    topic: str
    handle: Any                      # rviz.Display; never touched after deleteLater()
    watch: FirstFrameWatch
    added_at: float
    builtin: bool = False
    defaults: Optional[list] = None  # Image displays: property values to restore when pooled
    probe: Any = None                # classes without a message count: a subscriber that sees the data
    probe_seen: threading.Event = field(default_factory=threading.Event)
    hidden_alpha: Optional[float] = None   # hidden (drawn with Alpha 0, still subscribed): the Alpha to restore

    @property
    def visible(self) -> bool:
        return self.hidden_alpha is None


@dataclass(frozen=True)
class RobotDrawn:
    """A robot model RViz draws: the parameter holding its URDF, and the prefix of its frames in a TF tree
    shared by several robots ('' for none)."""
    description: str = 'robot_description'
    tf_prefix: str = ''


def _pop_flag(config: Dict[str, Any], key: str, default: Optional[bool] = True) -> Optional[bool]:
    """Take the boolean ``key`` out of ``config``; ``default`` when it is absent."""
    value = config.pop(key, default)
    if value is not default and not isinstance(value, bool):
        raise HostError("property '%s' expects true or false, got %r" % (key, value))
    return value


def robots_from_names(text: str) -> List[RobotDrawn]:
    """The robots named in ``text`` (separated by commas or spaces), each drawn as ``robot.launch robot:=<name>
    frame_prefix:=<name>/`` publishes it: its URDF in ``/<name>/robot_description``, its frames prefixed
    ``<name>/``. ValueError names a name that is not one."""
    robots = []
    for name in re.split(r'[,\s]+', text.strip()):
        if not name:
            continue
        if not legal_name(name, base=True):
            raise ValueError('robot name %r: it must be a ROS base name (a letter, then letters, digits or _)'
                             % name)
        robots.append(RobotDrawn('/%s/robot_description' % name, name + '/'))
    if len({r.description for r in robots}) != len(robots):
        raise ValueError('robot names %r: a robot is named twice' % text)
    return robots


@dataclass
class HostSettings:
    fixed_frame: str = 'base_link'
    frame_rate: int = 15
    width: int = 960
    height: int = 600
    robot_description: str = 'robot_description'
    robot_tf_prefix: str = ''         # the robot's frame prefix, when robots share the TF tree (vaultbot_2/)
    robots: List[RobotDrawn] = field(default_factory=list)   # several robots: these, not the two above
    show_robot: bool = True
    show_grid: bool = True
    initial_view: Dict[str, Any] = field(default_factory=lambda: dict(OPERATOR_VIEW))   # {}: frame the robot
    watch_period_ms: int = 5          # sampling period while a display waits for its first frame

    def drawn_robots(self) -> List[RobotDrawn]:
        """The robot models shown: ``robots`` if set, else the one robot of ``robot_description``."""
        return list(self.robots) or [RobotDrawn(self.robot_description, self.robot_tf_prefix)]


def robot_model_config(robot: RobotDrawn) -> Dict[str, Any]:
    """A robot model's RViz properties: where its URDF is, and the prefix of its frames in a TF tree shared
    by several robots (RViz adds the '/' itself)."""
    config: Dict[str, Any] = {'Robot Description': robot.description}
    prefix = robot.tf_prefix.strip('/')
    if prefix:
        config['TF Prefix'] = prefix
    return config


def robot_model_name(robot: RobotDrawn, several: bool) -> str:
    """The display's name: RobotModel, or with the robot's prefix when several robots are drawn."""
    return '%s %s' % (BUILTIN_ROBOT, robot.tf_prefix.strip('/') or robot.description) if several else BUILTIN_ROBOT


EventSink = Callable[[str, str, str, str, int, float], None]   # event, name, class, topic, frame_count, seconds
ProbeFactory = Callable[[str, Callable[[], None]], Any]        # (topic, on_message) -> object with unregister()


class RvizHost:
    """Owns the VisualizationFrame and the displays in it."""

    def __init__(self, app: QtWidgets.QApplication, settings: HostSettings, on_event: EventSink,
                 get_urdf: Callable[[], Optional[str]] = lambda: None, probe_factory: Optional[ProbeFactory] = None,
                 master_reach: Optional[MasterReach] = None):
        self.app = app
        # None: the master is never asked about (a host without ROS, in the unit tests)
        self.master_reach = master_reach
        self.probe_factory = probe_factory
        self.settings = settings
        self.on_event = on_event
        self.get_urdf = get_urdf
        self.known_classes = installed_rviz_classes()
        self.displays: Dict[str, HostedDisplay] = {}
        self._image_pool: List[Tuple[Any, list]] = []   # (disabled rviz/Image display, its default values)
        self.retired: List[HostedDisplay] = []   # removed while the master was out of reach: drawn transparent
        self._pool_serial = 0
        self.frame = None
        self.manager = None
        self._render_panel = None
        self._watch_timer = None

    # ---------------------------------------------------------------- start / stop
    def start(self) -> None:
        # static rviz::RenderSystem::disableAntiAliasing(); not exposed by the sip bindings
        ctypes.CDLL('librviz.so.7d')._ZN4rviz12RenderSystem19disableAntiAliasingEv()
        frame = rviz.VisualizationFrame()
        frame.setSplashPath('')
        frame.initialize()
        cfg = rviz.Config()
        rviz.YamlConfigReader().readString(cfg, '')
        frame.load(cfg)                      # empty config: no side panels
        frame.menuBar().hide()               # NOT setMenuBar(None): segfaults once a pane opens
        frame.statusBar().hide()
        frame.setHideButtonVisibility(False)
        for tb in frame.findChildren(QtWidgets.QToolBar):
            tb.hide()
        frame.setWindowTitle('TeMoto - RViz')
        frame.resize(self.settings.width, self.settings.height)
        frame.show()
        self.frame = frame
        self.manager = frame.getManager()
        self._render_panel = self._find_render_panel()
        root = self.manager.getRootDisplayGroup()
        display_config.resolve(root, ('Global Options', 'Frame Rate')).setValue(int(self.settings.frame_rate))
        self.manager.setFixedFrame(self.settings.fixed_frame)
        if self.settings.show_grid:
            self._add_builtin('rviz/Grid', BUILTIN_GRID, {})
        if self.settings.show_robot:
            robots = self.settings.drawn_robots()
            for robot in robots:
                self._add_builtin('rviz/RobotModel', robot_model_name(robot, len(robots) > 1),
                                  robot_model_config(robot))
        if self.settings.initial_view:
            self.apply_view(self.settings.initial_view)     # looking at the data, not at the robot
        else:
            self.frame_robot()
        self._watch_timer = QtCore.QTimer()
        self._watch_timer.timeout.connect(self._sample_first_frames)
        self._watch_timer.start(self.settings.watch_period_ms)

    def _find_render_panel(self):
        # The main 3D view is the only RenderPanel before any Image pane exists.
        for w in self.frame.findChildren(QtWidgets.QWidget):
            if w.metaObject().className() == 'rviz::RenderPanel':
                return w
        raise RuntimeError('rviz render panel not found')

    def shutdown(self) -> None:
        if self.frame is None:
            return
        if self._watch_timer is not None:
            self._watch_timer.stop()
        for hd in self.displays.values():
            self._detach_probe(hd)
        self.manager.removeAllDisplays()
        self.displays.clear()
        self.retired.clear()
        self._image_pool.clear()
        # RViz asks "save changes?" in a modal dialog when its config counts as modified (a display changed
        # after it had drawn a while). Nobody answers it headless: the host sat in it until its supervisor's
        # SIGTERM, 3 s after the SIGINT (gdb: QDialog::exec in VisualizationFrame::prepareToExit).
        self.frame.setWindowModified(False)
        self.frame.close()
        self.frame = None
        self.manager = None

    def frame_count(self) -> int:
        return int(self.manager.getFrameCount())

    # ---------------------------------------------------------------- displays
    def _add_builtin(self, cls: str, name: str, config: Dict[str, Any]) -> None:
        d = self.manager.createDisplay(cls, name, True)
        display_config.apply_config(d, config)
        self.displays[name] = HostedDisplay(name, cls, '', d, FirstFrameWatch(False, self.frame_count()),
                                            time.monotonic(), builtin=True)

    def add_display(self, cls: str, name: str, topic: str, config: Dict[str, Any]) -> str:
        """Create (or take from the Image pool) a display; all-or-nothing."""
        check_rviz_class(cls, self.known_classes)
        config = dict(config)
        if not name:
            name = '%s %s' % (cls.split('/')[-1], topic) if topic else cls.split('/')[-1]
        if name in self.displays:
            raise HostError("a display named '%s' already exists" % name)
        topic_label = topic_property(cls)
        if topic_label is None and topic:
            raise HostError('%s takes no topic (got %s)' % (cls, topic))
        enabled = _pop_flag(config, 'Enabled')
        visible = _pop_flag(config, VISIBLE)
        defaults = None
        if cls == IMAGE_CLASS and self._image_pool:
            d, defaults = self._image_pool.pop()
            d.setName(name)
        else:
            d = self.manager.createDisplay(cls, name, False)   # disabled: subscribe only once, to the right topic
            if cls == IMAGE_CLASS:
                defaults = display_config.snapshot(d)
        try:
            if topic_label and topic:
                display_config.resolve(d, (topic_label,)).setValue(topic)
            display_config.apply_config(d, config)
        except display_config.DisplayConfigError as e:
            self._discard(cls, d, defaults)
            raise HostError(str(e)) from None
        fc = self.frame_count()
        probed = cls in PROBED_CLASSES and bool(topic)
        hd = HostedDisplay(name, cls, topic, d, FirstFrameWatch(bool(topic_label), fc, margin=1 if probed else 0),
                           time.monotonic(), defaults=defaults)
        if not visible:
            try:
                self._hide(hd)
            except HostError:
                self._discard(cls, d, defaults)
                raise
        d.setValue(enabled)
        self.displays[name] = hd
        if probed:
            self._attach_probe(hd)
        self.on_event('added', name, cls, topic, fc, 0.0)
        if topic:
            self.on_event('topic', name, cls, topic, fc, 0.0)
        self._ensure_watching()
        return name

    def _attach_probe(self, hd: HostedDisplay) -> None:
        self._detach_probe(hd)
        hd.probe_seen.clear()
        if self.probe_factory is not None:
            hd.probe = self.probe_factory(hd.topic, hd.probe_seen.set)

    @staticmethod
    def _detach_probe(hd: HostedDisplay) -> None:
        if hd.probe is not None:
            hd.probe.unregister()
            hd.probe = None

    def _discard(self, cls: str, d, defaults) -> None:
        """Undo a half-made display: pool an Image display, delete anything else."""
        if cls == IMAGE_CLASS:
            self._to_pool(d, defaults)
        else:
            self.manager.getRootDisplayGroup().takeDisplay(d)
            d.deleteLater()

    def _to_pool(self, d, defaults) -> None:
        d.setValue(False)                               # unsubscribes and hides its pane
        if defaults:
            display_config.restore(d, defaults)
        self._pool_serial += 1
        d.setName('(unused image %d)' % self._pool_serial)
        self._image_pool.append((d, defaults))

    def remove_display(self, name: str) -> None:
        hd = self._get(name)
        del self.displays[name]
        self._detach_probe(hd)
        if hd.cls == IMAGE_CLASS:
            self._to_pool(hd.handle, hd.defaults)
        elif self._master_down() and self._can_hide(hd):
            # destroying it would unsubscribe, and roscpp asks the master on this thread, the one that renders:
            # seconds per call with the master across a cut link. It is drawn transparent now, and destroyed
            # once the master answers again.
            if hd.visible:
                self._hide(hd)
            self.retired.append(hd)
            self._ensure_watching()
        else:
            self._destroy(hd)
        self.on_event('removed', name, hd.cls, hd.topic, self.frame_count(), 0.0)

    def _destroy(self, hd: HostedDisplay) -> None:
        self.manager.getRootDisplayGroup().takeDisplay(hd.handle)
        hd.handle.deleteLater()      # the subscription goes at the next event-loop pass

    def _master_down(self) -> bool:
        return self.master_reach is not None and self.master_reach.unreachable_now()

    def refuse_without_master(self, topic: str) -> None:
        """A subscription needs the master, and roscpp waits for it on the thread that renders: a display
        shown while the master was away (the robot rebooting, a cut link to it) froze the whole view until it
        came back, while the display's own request ran out. Refused at once instead, naming it. Asked by the
        node's service thread before it hands a display with a topic to the main thread."""
        if topic and self._master_down():
            raise HostError('the master at %s:%d does not answer: subscribing to %s would wait for it, and the '
                            'view would freeze until it is back' % (self.master_reach.address + (topic,)))

    @staticmethod
    def _can_hide(hd: HostedDisplay) -> bool:
        try:
            display_config.resolve(hd.handle, (ALPHA,))
            return True
        except display_config.DisplayConfigError:
            return False

    def _destroy_retired(self) -> None:
        """The displays removed during a partition, destroyed once the master answers (checked off this thread)."""
        if self.retired and self.master_reach is not None and self.master_reach.last():
            retired, self.retired = self.retired, []
            for hd in retired:
                self._destroy(hd)

    def configure_display(self, name: str, topic: str, config: Dict[str, Any]) -> List[str]:
        hd = self._get(name)
        changed: List[str] = []
        label = topic_property(hd.cls)
        if topic and label is None:
            raise HostError('%s takes no topic (got %s)' % (hd.cls, topic))
        config = dict(config)
        visible = _pop_flag(config, VISIBLE, default=None)
        if not hd.visible and ALPHA in config:       # a hidden display keeps Alpha 0: the new value waits
            alpha = config.pop(ALPHA)
            if not isinstance(alpha, (int, float)) or isinstance(alpha, bool) or not 0.0 <= alpha <= 1.0:
                raise HostError("property '%s' expects a number from 0 to 1, got %r" % (ALPHA, alpha))
            hd.hidden_alpha = float(alpha)
            changed.append(ALPHA)
        if config:
            try:
                changed += display_config.apply_config(hd.handle, config)
            except display_config.DisplayConfigError as e:
                raise HostError(str(e)) from None
        fc = self.frame_count()
        if visible is False and hd.visible:
            self._hide(hd)
            changed.append(VISIBLE)
            self.on_event('hidden', name, hd.cls, hd.topic, fc, 0.0)
        elif visible and not hd.visible:
            self._reveal(hd, fc)
            changed.append(VISIBLE)
        if topic and topic != hd.topic:
            display_config.resolve(hd.handle, (label,)).setValue(topic)
            hd.topic = topic
            hd.watch.restart(fc)
            hd.added_at = time.monotonic()
            if hd.cls in PROBED_CLASSES:
                self._attach_probe(hd)
            self.on_event('topic', name, hd.cls, topic, fc, 0.0)
            self._ensure_watching()
        if changed:
            self.on_event('configured', name, hd.cls, hd.topic, fc, 0.0)
        return changed

    def _hide(self, hd: HostedDisplay) -> None:
        """Draw ``hd`` fully transparent. Unchecking 'Enabled' would unsubscribe it, and showing it again
        would then wait for a new TCPROS connection and the next message: a hidden display keeps both."""
        try:
            alpha = display_config.resolve(hd.handle, (ALPHA,))
        except display_config.DisplayConfigError:
            raise HostError('%s has no %s property, so it cannot be hidden while it stays subscribed'
                            % (hd.cls, ALPHA)) from None
        hd.hidden_alpha = float(alpha.getValue())
        alpha.setValue(0.0)

    def _reveal(self, hd: HostedDisplay, fc: int) -> None:
        """Give ``hd`` its Alpha back. Its first frame is then the next one rendered with its data: the
        data it already holds, so no blank frame between the switch and the picture."""
        # read before the Alpha goes back: the count of what it holds is the display's own word (first_frame.py);
        # read only after, at the watch's next sample, a reveal once waited 10 s for a first frame (CI, twice)
        holding = bool(self.messages_received(hd)) if hd.watch.needs_data else False
        display_config.resolve(hd.handle, (ALPHA,)).setValue(hd.hidden_alpha)
        hd.hidden_alpha = None
        hd.watch.restart(fc, holding=holding)
        hd.added_at = time.monotonic()
        self.on_event('shown', hd.name, hd.cls, hd.topic, fc, 0.0)
        self._ensure_watching()

    def _get(self, name: str) -> HostedDisplay:
        hd = self.displays.get(name)
        if hd is None:
            raise HostError("no display named '%s'; displays: %s" % (name, ', '.join(sorted(self.displays)) or 'none'))
        return hd

    def status_lines(self, d) -> List[Tuple[str, str]]:
        status = None
        for i in range(d.numChildren()):
            c = d.childAt(i)
            if c.getName().startswith('Status'):
                status = c
                break
        if status is None:
            return []
        return [(status.childAt(i).getName(), str(status.childAt(i).getValue())) for i in range(status.numChildren())]

    def messages_received(self, hd: HostedDisplay) -> Optional[int]:
        if hd.cls in PROBED_CLASSES:
            return 1 if hd.probe_seen.is_set() else None
        counts = [received_count(text) for _, text in self.status_lines(hd.handle)]
        counts = [c for c in counts if c is not None]
        return max(counts) if counts else None

    def list_displays(self) -> List[Dict[str, Any]]:
        out = []
        for hd in self.displays.values():
            out.append({'name': hd.name, 'display_class': hd.cls, 'topic': hd.topic,
                        'enabled': bool(hd.handle.getValue()), 'visible': hd.visible,
                        'drawn': hd.visible and hd.watch.drawn,
                        'status': '; '.join('%s: %s' % kv for kv in self.status_lines(hd.handle)),
                        'builtin': hd.builtin})
        return out

    # ---------------------------------------------------------------- first frame drawn
    def _ensure_watching(self) -> None:
        if self._watch_timer is not None and not self._watch_timer.isActive():
            self._watch_timer.start(self.settings.watch_period_ms)

    def _sample_first_frames(self) -> None:
        self._destroy_retired()
        fc = self.frame_count()
        pending = bool(self.retired)
        for hd in list(self.displays.values()):
            if hd.watch.drawn or not hd.visible:     # a hidden display's first frame comes once it is shown
                continue
            msgs = self.messages_received(hd) if hd.watch.needs_data else None
            if hd.watch.observe(fc, msgs):
                self._detach_probe(hd)
                self.on_event('first_frame', hd.name, hd.cls, hd.topic, fc, time.monotonic() - hd.added_at)
            pending = pending or not hd.watch.drawn
        if not pending:
            self._watch_timer.stop()    # nothing to wait for: no sampling cost

    # ---------------------------------------------------------------- view
    def frame_robot(self) -> OrbitView:
        view = robot_view(self.get_urdf(), self.settings.fixed_frame)
        self.apply_view({'Distance': view.distance, 'Yaw': view.yaw, 'Pitch': view.pitch,
                         'Focal Point': list(view.focal_point)})
        return view

    def apply_view(self, config: Dict[str, Any]) -> List[str]:
        vc = self.manager.getViewManager().getCurrent()
        try:
            return display_config.apply_config(vc, dict(config))
        except display_config.DisplayConfigError as e:
            raise HostError(str(e)) from None

    # ---------------------------------------------------------------- screenshot
    def screenshot(self, what: str = 'view') -> Tuple[bytes, int, int]:
        """PNG bytes of the X framebuffer (QWidget.grab() would give a black 3D view)."""
        if what in ('', 'view'):
            widget = self._render_panel
        elif what == 'window':
            widget = self.frame
        else:
            raise HostError("screenshot 'what' must be 'view' or 'window', got '%s'" % what)
        pixmap = self.app.primaryScreen().grabWindow(int(widget.winId()))
        buf = QtCore.QBuffer()
        buf.open(QtCore.QIODevice.WriteOnly)
        if not pixmap.save(buf, 'PNG'):
            raise HostError('could not encode the screenshot as PNG')
        return bytes(buf.data()), pixmap.width(), pixmap.height()
