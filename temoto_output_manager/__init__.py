"""TeMoto Output Manager: what the operator sees.

Displays in a real RViz are shared resources of the Resource Registrar; the RViz
host (``nodes/rviz_host``) embeds librviz and runs headless under its own Xvfb
when there is no DISPLAY. Kept import-light: ROS tools import ``.msg``/``.srv``
through this package.
"""
