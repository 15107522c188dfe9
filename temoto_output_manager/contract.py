"""The Output Manager on the wire: its registrar, its server and its service type.

Its server and every client (``interface.py``) import this module, never each
other. Display requests use the default equality: every field but the ``trr``
header.
"""
from temoto_core.rr.deadlines import register_deadlines
from temoto_output_manager.srv import LoadRvizPlugin

RR_NAME = 'temoto_output_manager'
LOAD_RVIZ_PLUGIN = 'load_rviz_plugin'
LOAD_RVIZ_PLUGIN_TYPE = LoadRvizPlugin

# The longest a display load may take (deadlines.py): RViz's host started up to twice (20 s each by default)
# before the display is added; an unload stops the host's process.
register_deadlines(LoadRvizPlugin._request_class, load=60.0, unload=15.0)
