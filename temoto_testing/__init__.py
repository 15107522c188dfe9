"""rostest-style helpers for pytest: a private roscore, node and launch-file
subprocesses that are registered before a test goes on, bag recording, and a
process census that proves nothing outlives a test session.

Everything started here carries the environment variable
``TEMOTO_TEST_SESSION=<token>``. Children inherit it, and so do the processes
*they* start (an ER Manager's children, RViz's Xvfb), which is what lets
:func:`leftover_processes` find a leak at any depth by scanning ``/proc``.
"""
from temoto_core.master import RosMaster, free_port, master_proxy
from temoto_core.processes import LoggedChild, ProcessGroupLauncher, leftover_processes, SESSION_ENV
from temoto_testing.bag import BagRecorder
from temoto_testing.connections import wait_receiving
from temoto_core.wait import wait_for
from temoto_testing.interfaces import made_interfaces
from temoto_testing.status import FirstFailure

__all__ = ['RosMaster', 'free_port', 'master_proxy', 'LoggedChild', 'ProcessGroupLauncher',
           'leftover_processes', 'SESSION_ENV', 'BagRecorder', 'wait_for', 'made_interfaces', 'FirstFailure',
           'wait_receiving']
