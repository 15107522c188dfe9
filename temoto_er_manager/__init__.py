"""TeMoto External Resource Manager: processes as shared resources.

Modules, one idea each:
- ``policy``     what may run (allowlists, field validation) and the manager's tunables;
- ``resolve``    a validated request -> a plan of argvs (rosrun / roslaunch rules, never a shell);
- ``launchfile`` a ``.launch`` file -> its parameters and one process per node (roslaunch's loader only);
- ``resource``   the processes of one resource, which start, fail and stop together;
- ``supervisor`` start, watch (event-driven), stop and reap child processes; ROS-free;
- ``zygote``     the optional fork server that starts Python nodes with their imports done (``preload``: its client);
- ``master``     ROS master look-ups used to decide that a node "really started";
- ``manager``    the node's logic: the Resource Registrar server ``load_process``;
- ``interface``  ``ERManagerInterface`` for other managers and actions;
- ``cli``        ``temoto ps``.

Kept import-light: Debian's ROS tools import ``temoto_er_manager.srv`` through it.
"""
