# The fixtures (ros_master, procs, rospy_client, ...) come from temoto_testing.pytest_plugin, which pytest
# loads through its pytest11 entry point (setup.py) in every environment where TeMoto is installed.
