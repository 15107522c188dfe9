"""The Output Manager on the wire: its registrar, its server and its service type.

Its server and every client (``interface.py``) import this module, never each
other. Display requests use the default equality: every field but the ``trr``
header.
"""
from temoto_output_manager.srv import LoadRvizPlugin

RR_NAME = 'temoto_output_manager'
LOAD_RVIZ_PLUGIN = 'load_rviz_plugin'
LOAD_RVIZ_PLUGIN_TYPE = LoadRvizPlugin
