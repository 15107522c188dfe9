"""The External Resource Manager on the wire: its registrar, its server, its service type and its equality.

Its server and every client (``interface.py``, other managers) import this
module, never each other, so both sides name and compare requests by one rule.
Process requests use the default equality: every field but the ``trr`` header.
"""
from temoto_er_manager.srv import LoadProcess

RR_NAME = 'temoto_er_manager'
LOAD_PROCESS = 'load_process'
LOAD_PROCESS_TYPE = LoadProcess
