"""TeMoto External Resource Manager: processes as shared resources.

Modules, one idea each:
- ``policy``     what may run (allowlists, field validation) and the manager's tunables;
- ``resolve``    a validated request -> an argv (rosrun / roslaunch rules, never a shell);
- ``supervisor`` start, watch (event-driven), stop and reap child processes; ROS-free;
- ``master``     ROS master look-ups used to decide that a node "really started";
- ``launch_runner`` runs a launch file and exits as soon as any of its nodes dies;
- ``manager``    the node's logic: the Resource Registrar server ``load_process``;
- ``interface``  ``ERManagerInterface`` for other managers and actions;
- ``cli``        ``temoto ps``.

Kept import-light: Debian's ROS tools import ``temoto_er_manager.srv`` through it.
"""
