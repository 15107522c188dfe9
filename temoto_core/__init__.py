"""TeMoto core: the Resource Registrar (RR) and what every subsystem shares.

Kept import-light on purpose: Debian's ROS tools import ``temoto_core.msg``
through this package, so nothing heavy may run here.
"""
