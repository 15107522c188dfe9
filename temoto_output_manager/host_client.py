"""Client of the RViz host's services, used by the Output Manager, the CLI and tests.

Every call raises :class:`RvizHostError` with the host's message when the host
refuses, so callers never have to inspect ``ok`` fields.
"""
from __future__ import annotations

import socket
import threading
import time
from typing import Callable, List, Optional

import rosgraph.network
import rospy

from temoto_core import rospy_internals, service_uris
from temoto_core.service_uris import ServiceProxy
from temoto_output_manager.srv import (AddDisplay, ConfigureDisplay, ListDisplays, RemoveDisplay, Screenshot,
                                       SetView)


class RvizHostError(RuntimeError):
    """The RViz host refused a request or could not be reached."""


def host_node_name(temoto_namespace: str = 'temoto') -> str:
    """Where the Output Manager runs its host: /<ns>/rviz_host."""
    return '/%s/rviz_host' % temoto_namespace.strip('/')


class RvizHostClient:
    def __init__(self, node_name: Optional[str] = None, timeout: float = 15.0, call_timeout: Optional[float] = None):
        self.node_name = (node_name or host_node_name()).rstrip('/')
        self.timeout = timeout
        self.call_timeout = self.CALL_TIMEOUT if call_timeout is None else call_timeout
        self._proxies = {}

    def _srv(self, name: str, srv_type):
        proxy = self._proxies.get(name)
        if proxy is None:
            proxy = self._proxies[name] = ServiceProxy('%s/%s' % (self.node_name, name), srv_type)
        return proxy

    def wait_ready(self, timeout: Optional[float] = None,
                   failed: Callable[[], Optional[str]] = lambda: None, poll: float = 0.05) -> None:
        """Return once the host's services answer; raise at once when ``failed()`` gives a reason.

        Not rospy.wait_for_service: it retries every 0.3 s, logs a warning per
        attempt, and keeps knocking on the registration a crashed host left at
        the master until the timeout. A host that died while starting should
        fail its request with the reason (its log tail) within a poll period.
        """
        timeout = timeout or self.timeout
        service = rospy.resolve_name('%s/list_displays' % self.node_name)
        deadline = time.monotonic() + timeout
        while True:
            reason = failed()
            if reason:
                raise RvizHostError('RViz host %s failed while starting: %s' % (self.node_name, reason))
            left = deadline - time.monotonic()
            if left <= 0:
                raise RvizHostError('RViz host %s did not come up within %.0f s' % (self.node_name, timeout))
            if _service_answers(service, min(1.0, left)):
                return
            time.sleep(min(poll, max(0.0, deadline - time.monotonic())))

    # rospy's service calls have no timeout. A call that got no answer is abandoned after this long (the
    # host answers within ~0.1 s, or within its own 10 s main-thread timeout); calls that only read or set
    # view state are then tried once more on a fresh connection.
    CALL_TIMEOUT = 20.0
    REPEATABLE = ('screenshot', 'list_displays', 'set_view')

    def _bounded(self, service: str, srv_type, args, kwargs):
        box = {}

        def run():
            try:
                box['resp'] = self._srv(service, srv_type)(*args, **kwargs)
            except BaseException as e:   # handed to the caller
                box['error'] = e
        worker = threading.Thread(target=run, daemon=True, name='rviz host call %s' % service)
        worker.start()
        worker.join(self.call_timeout)
        if worker.is_alive():
            self._proxies.pop(service, None)
            raise TimeoutError('no answer within %.1f s' % self.call_timeout)
        if 'error' in box:
            raise box['error']
        return box['resp']

    def _call(self, service: str, srv_type, *args, **kwargs):
        attempts = 2 if service in self.REPEATABLE else 1
        for attempt in range(1, attempts + 1):
            try:
                resp = self._bounded(service, srv_type, args, kwargs)
                break
            except TimeoutError as e:
                if attempt < attempts:
                    rospy.logwarn('RViz host %s: %s: %s; trying again', self.node_name, service, e)
                    continue
                raise RvizHostError('RViz host %s: %s failed: %s' % (self.node_name, service, e)) from None
            except (rospy.ServiceException, rospy.ROSException) as e:
                self._proxies.pop(service, None)
                raise RvizHostError('RViz host %s: %s failed: %s' % (self.node_name, service, e)) from None
        if hasattr(resp, 'ok') and not resp.ok:
            raise RvizHostError(resp.message)
        return resp

    def add_display(self, display_class: str, topic: str = '', name: str = '', config: str = '') -> str:
        return self._call('add_display', AddDisplay, display_class=display_class, name=name, topic=topic,
                          config=config).name

    def remove_display(self, name: str) -> None:
        self._call('remove_display', RemoveDisplay, name=name)

    def configure_display(self, name: str, topic: str = '', config: str = '') -> str:
        return self._call('configure_display', ConfigureDisplay, name=name, topic=topic, config=config).message

    def set_visible(self, name: str, visible: bool) -> None:
        """Hide a display (drawn transparent, still subscribed) or show it again."""
        self.configure_display(name, config='{Visible: %s}' % ('true' if visible else 'false'))

    def set_view(self, config: str = '', frame_robot: bool = False) -> None:
        self._call('set_view', SetView, frame_robot=frame_robot, config=config)

    def screenshot(self, what: str = 'view', path: str = ''):
        """The Screenshot response (``png`` bytes, ``width``, ``height``, ``frame_count``)."""
        return self._call('screenshot', Screenshot, what=what, path=path)

    def list_displays(self):
        return self._call('list_displays', ListDisplays)

    def display_names(self) -> List[str]:
        return [d.name for d in self.list_displays().displays]


def _service_answers(service: str, timeout: float) -> bool:
    """True when ``service`` is registered and its server accepts a connection (the same probe as rospy's).
    Found as every call of this client finds it: with the master away, at the address last known (a host
    that runs was taken for one that never came up, and every display shown meanwhile failed so)."""
    try:
        uri = service_uris.lookup(service, time.monotonic() + timeout)
        host, port = rospy_internals.parse_rosrpc_uri(uri)
    except Exception:           # not registered yet, master busy, or a malformed URI: not ready
        return False
    try:
        with socket.create_connection((host, port), timeout=timeout) as s:
            rosgraph.network.write_ros_handshake_header(s, {'probe': '1', 'md5sum': '*', 'service': service,
                                                            'callerid': rospy.get_name()})
        return True
    except OSError:             # a registration left by a host that is gone: refused
        return False
