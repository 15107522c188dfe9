"""``OutputManagerInterface``: how actions put things on the operator's screen.

    om = OutputManagerInterface()                       # or OutputManagerInterface(rr=self.rr) inside a manager
    shown = om.show_in_rviz('point cloud', '/d435/points', config='{Size (Pixels): 3}')
    ...
    om.hide(shown)

Like the original's ``showInRviz``; ``hide`` takes the id ``show_in_rviz``
returned. A display requested with ``hidden=True`` is drawn transparent but stays
subscribed, so that ``set_visible(shown, True)`` puts its latest data on screen at
the next frame, with no new connection (a hot standby's display). A display whose RViz host crashes gets FAILED: the request's own
``on_status`` policy hears it, or, by default (base class), the display is
unloaded and requested again, which starts a new host.
"""
from __future__ import annotations

import threading
from typing import Callable, Dict, Optional

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_core.interface import ManagerInterface
from temoto_core.rr import StatusEvent
from temoto_output_manager import display_config
from temoto_output_manager.contract import LOAD_RVIZ_PLUGIN, LOAD_RVIZ_PLUGIN_TYPE, RR_NAME
from temoto_output_manager.host_client import RvizHostClient, RvizHostError, host_node_name

# A visibility change is one property set on RViz's main thread: it answers within milliseconds, or the host hangs.
SET_VISIBLE_TIMEOUT = 2.0
HIDDEN = '{Visible: false}'


class OutputManagerInterface(ManagerInterface):
    MANAGER = RR_NAME
    SUBSYSTEM = Subsystem.OUTPUT_MANAGER
    SERVER = LOAD_RVIZ_PLUGIN

    def __init__(self, rr=None, namespace: Optional[str] = None) -> None:
        super().__init__(rr=rr, namespace=namespace)
        self._names: Dict[int, str] = {}      # resource id -> display name in the RViz host
        self._names_lock = threading.Lock()
        self._host: Optional[RvizHostClient] = None

    def show_in_rviz(self, type: str, topic: str = '', name: str = '', config: str = '',
                     on_status: Optional[Callable[[StatusEvent], None]] = None, hidden: bool = False) -> int:
        """Show ``topic`` as a display of abstract ``type``; returns this interface's resource id.

        ``on_status``: this request's failure policy (a crash of the RViz host reaches it as FAILED).
        ``hidden``: draw it transparent until ``set_visible(id, True)``; it subscribes and receives meanwhile.
        """
        return self.show(type, topic, name, config, on_status, hidden).trr.resource_id

    def show(self, type: str, topic: str = '', name: str = '', config: str = '',
             on_status: Optional[Callable[[StatusEvent], None]] = None, hidden: bool = False):
        """Like show_in_rviz, returning the whole response (``display_name`` included)."""
        if hidden:
            # part of the request, so a hidden display is never shared with a visible one of the same topic
            try:
                config = display_config.with_defaults(display_config.parse_config(config), HIDDEN)
            except display_config.DisplayConfigError as e:
                raise TemotoError(ErrorCode.BAD_REQUEST, self.SUBSYSTEM, str(e)) from None
        req = LOAD_RVIZ_PLUGIN_TYPE._request_class(type=type, name=name, topic=topic, config=config)
        response = self._load(self.SERVER, req, on_status)
        with self._names_lock:
            self._names[response.trr.resource_id] = response.display_name
        return response

    def hide(self, resource_id: int) -> None:
        with self._names_lock:
            self._names.pop(resource_id, None)
        self._unload(resource_id)

    def set_visible(self, resource_id: int, visible: bool) -> None:
        """Show a display requested ``hidden`` (or hide one again), through the RViz host directly: a hot
        standby's switch is this one call. Raises TemotoError (DISPLAY_FAIL) naming the display on failure."""
        with self._names_lock:
            name = self._names.get(resource_id)
            if name is not None and self._host is None:
                self._host = RvizHostClient(host_node_name(self.namespace or self.rr.namespace),
                                            call_timeout=SET_VISIBLE_TIMEOUT)
            host = self._host
        if name is None:
            raise TemotoError(ErrorCode.RESOURCE_NOT_FOUND, self.SUBSYSTEM,
                              'this output manager interface holds no display %d' % resource_id)
        try:
            host.set_visible(name, visible)
        except RvizHostError as e:
            raise TemotoError(ErrorCode.DISPLAY_FAIL, self.SUBSYSTEM,
                              "could not %s display '%s': %s" % ('show' if visible else 'hide', name, e)) from None
