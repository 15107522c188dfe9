"""TeMoto for Python and ROS 1.

Every top-level package is both a ROS package (package.xml, found through
ROS_PACKAGE_PATH) and a Python package. Message modules are generated into the
packages by tools/gen_msgs.py. Versions of third-party packages are pinned in
requirements.txt only.
"""
from setuptools import setup

PACKAGES = [
    'temoto_core',
    'temoto_er_manager',
    'temoto_sensor_manager',
    'temoto_output_manager',
    'temoto_context_manager',
    'temoto_action_engine',
    'temoto_speech',
    'temoto_testing',
    'vaultbot_sim',
    'temoto_demo',
    'temoto_chaos',
    'temoto_bringup',
]

setup(
    name='temoto',
    version='0.1.0',
    description='TeMoto: supervisory teleoperation with a Resource Registrar, for ROS 1 in Python',
    python_requires='>=3.11',
    packages=[],   # development install: the repository root is put on sys.path
    py_modules=[],
    entry_points={'console_scripts': ['temoto = temoto_bringup.cli:main'],
                  # the fixtures, for every pytest run in an environment where TeMoto is installed
                  'pytest11': ['temoto = temoto_testing.pytest_plugin']},
)
