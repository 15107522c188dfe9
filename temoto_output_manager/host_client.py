"""Client of the RViz host's services, used by the Output Manager, the CLI and tests.

Every call raises :class:`RvizHostError` with the host's message when the host
refuses, so callers never have to inspect ``ok`` fields.
"""
from __future__ import annotations

from typing import List, Optional

import rospy

from temoto_output_manager.srv import (AddDisplay, ConfigureDisplay, ListDisplays, RemoveDisplay, Screenshot,
                                       SetView)


class RvizHostError(RuntimeError):
    """The RViz host refused a request or could not be reached."""


def host_node_name(temoto_namespace: str = 'temoto') -> str:
    """Where the Output Manager runs its host: /<ns>/rviz_host."""
    return '/%s/rviz_host' % temoto_namespace.strip('/')


class RvizHostClient:
    def __init__(self, node_name: Optional[str] = None, timeout: float = 15.0):
        self.node_name = (node_name or host_node_name()).rstrip('/')
        self.timeout = timeout
        self._proxies = {}

    def _srv(self, name: str, srv_type):
        proxy = self._proxies.get(name)
        if proxy is None:
            proxy = self._proxies[name] = rospy.ServiceProxy('%s/%s' % (self.node_name, name), srv_type)
        return proxy

    def wait_ready(self, timeout: Optional[float] = None) -> None:
        try:
            rospy.wait_for_service('%s/list_displays' % self.node_name, timeout=timeout or self.timeout)
        except rospy.ROSException:
            raise RvizHostError('RViz host %s did not come up within %.0f s'
                                % (self.node_name, timeout or self.timeout)) from None

    def _call(self, service: str, srv_type, *args, **kwargs):
        try:
            resp = self._srv(service, srv_type)(*args, **kwargs)
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

    def set_view(self, config: str = '', frame_robot: bool = False) -> None:
        self._call('set_view', SetView, frame_robot=frame_robot, config=config)

    def screenshot(self, what: str = 'view', path: str = ''):
        """The Screenshot response (``png`` bytes, ``width``, ``height``, ``frame_count``)."""
        return self._call('screenshot', Screenshot, what=what, path=path)

    def list_displays(self):
        return self._call('list_displays', ListDisplays)

    def display_names(self) -> List[str]:
        return [d.name for d in self.list_displays().displays]
