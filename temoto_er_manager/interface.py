"""``ERManagerInterface``: how other managers and actions start processes.

    er = ERManagerInterface()                     # or ERManagerInterface(rr=self.rr) inside a manager
    resp = er.load('my_pkg', 'driver_node', args='_rate:=10')
    ...                                           # resp.pid, resp.log_path, resp.trr.resource_id
    er.unload(resp.trr.resource_id)

Called inside another registrar's load callback (with that registrar passed as
``rr``), the process becomes a linked sub-resource: it is unloaded in cascade and
its FAILED is forwarded to that resource's consumers automatically.

Failure policy: pass ``on_status`` with a request to decide yourself what its
FAILED means; otherwise ``register_update_callback`` (the original's
``registerUpdateCallback``) gets it, and by default (the base class) a FAILED
process is unloaded and the same request is loaded again, i.e. the process is
restarted.
"""
from __future__ import annotations

from typing import Callable, Optional

from temoto_core.errors import Subsystem
from temoto_core.interface import ManagerInterface
from temoto_core.rr import StatusEvent

from temoto_er_manager.contract import LOAD_PROCESS, LOAD_PROCESS_TYPE, RR_NAME
from temoto_er_manager.policy import ROS_EXECUTE, SYS_EXECUTE


class ERManagerInterface(ManagerInterface):
    MANAGER = RR_NAME
    SUBSYSTEM = Subsystem.ER_MANAGER
    SERVER = LOAD_PROCESS

    def load(self, package: str, executable: str, args: str = '', ros_namespace: str = '',
             on_status: Optional[Callable[[StatusEvent], None]] = None):
        """Start a node or a ``*.launch`` file of ``package`` (``ros_execute``); returns the LoadProcess response
        once the process runs and its node(s) registered. Raises TemotoError otherwise."""
        return self._load(self.SERVER, self._request(ROS_EXECUTE, package, executable, args, ros_namespace),
                          on_status)

    def load_command(self, executable: str, args: str = '', ros_namespace: str = '',
                     on_status: Optional[Callable[[StatusEvent], None]] = None):
        """``sys_execute`` of a command the manager's ``sys_allowlist`` names."""
        return self._load(self.SERVER, self._request(SYS_EXECUTE, '', executable, args, ros_namespace), on_status)

    def unload(self, resource_id: int) -> None:
        """Release this interface's reference; the process stops when its last consumer leaves."""
        self._unload(resource_id)

    @staticmethod
    def _request(action, package, executable, args, ros_namespace):
        return LOAD_PROCESS_TYPE._request_class(action=action, package_name=package, executable=executable, args=args,
                                          ros_namespace=ros_namespace)
