"""``OutputManagerInterface``: how actions put things on the operator's screen.

    om = OutputManagerInterface()                       # or OutputManagerInterface(rr=self.rr) inside a manager
    shown = om.show_in_rviz('point cloud', '/d435/points', config='{Size (Pixels): 3}')
    ...
    om.hide(shown)

Like the original's ``showInRviz``; ``hide`` takes the id ``show_in_rviz``
returned. A display whose RViz host crashes gets FAILED: the request's own
``on_status`` policy hears it, or, by default (base class), the display is
unloaded and requested again, which starts a new host.
"""
from __future__ import annotations

from typing import Callable, Optional

from temoto_core.errors import Subsystem
from temoto_core.interface import ManagerInterface
from temoto_core.rr import StatusEvent
from temoto_output_manager.contract import LOAD_RVIZ_PLUGIN, LOAD_RVIZ_PLUGIN_TYPE, RR_NAME


class OutputManagerInterface(ManagerInterface):
    MANAGER = RR_NAME
    SUBSYSTEM = Subsystem.OUTPUT_MANAGER
    SERVER = LOAD_RVIZ_PLUGIN

    def show_in_rviz(self, type: str, topic: str = '', name: str = '', config: str = '',
                     on_status: Optional[Callable[[StatusEvent], None]] = None) -> int:
        """Show ``topic`` as a display of abstract ``type``; returns this interface's resource id.

        ``on_status``: this request's failure policy (a crash of the RViz host reaches it as FAILED).
        """
        return self.show(type, topic, name, config, on_status).trr.resource_id

    def show(self, type: str, topic: str = '', name: str = '', config: str = '',
             on_status: Optional[Callable[[StatusEvent], None]] = None):
        """Like show_in_rviz, returning the whole response (``display_name`` included)."""
        req = LOAD_RVIZ_PLUGIN_TYPE._request_class(type=type, name=name, topic=topic, config=config)
        return self._load(self.SERVER, req, on_status)

    def hide(self, resource_id: int) -> None:
        self._unload(resource_id)
