"""The External Resource Manager on the wire: its registrar, its server, its service type and its equality.

Its server and every client (``interface.py``, other managers) import this
module, never each other, so both sides name and compare requests by one rule.
Process requests use the default equality: every field but the ``trr`` header.
"""
from temoto_core.rr.deadlines import register_deadlines
from temoto_er_manager.srv import LoadProcess

RR_NAME = 'temoto_er_manager'
LOAD_PROCESS = 'load_process'
LOAD_PROCESS_TYPE = LoadProcess

# The longest a load and an unload may take (deadlines.py): a node's registration (10 s by default), and the
# SIGINT and SIGTERM graces of a stop (3 s + 2 s), with room to spare.
register_deadlines(LoadProcess._request_class, load=15.0, unload=10.0)
