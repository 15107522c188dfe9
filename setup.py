"""TeMoto for Python and ROS 1.

Every top-level package is both a ROS package (package.xml, found through
ROS_PACKAGE_PATH) and a Python package. Message modules are generated into the
packages by tools/gen_msgs.py (``make setup``), before an install copies them.
Versions of third-party packages are pinned in requirements.txt only.

``make setup`` installs the checkout in development mode (env.sh puts the
repository on PYTHONPATH and ROS_PACKAGE_PATH). ``pip install .`` copies every
package, with what ROS needs of it (package.xml, launch files, configurations,
node scripts, message definitions, the robot's URDFs), into site-packages;
``temoto`` then finds them there (docs/commands.md, "Installed").
"""
from setuptools import find_packages, setup

PACKAGES = [
    'control_msgs',             # upstream's definitions (control_msgs/README.md); Debian has no package of them
    'temoto_core',
    'temoto_er_manager',
    'temoto_sensor_manager',
    'temoto_output_manager',
    'temoto_context_manager',
    'temoto_robot_manager',
    'temoto_operator',
    'temoto_action_engine',
    'temoto_speech',
    'temoto_testing',
    'vaultbot_sim',
    'temoto_demo',
    'temoto_chaos',
    'temoto_bringup',
]

# what ROS (rospack, roslaunch, rosrun) and the nodes read beside the Python code, per package
ROS_FILES = ['package.xml', 'launch/*.launch', 'config/*.yaml', 'nodes/*', 'msg/*.msg', 'srv/*.srv', 'action/*.action']
EXTRA_FILES = {'vaultbot_sim': ['urdf/*.urdf'], 'temoto_action_engine': ['actions/*/*.py', 'actions/*/*.json']}

setup(
    name='temoto',
    version='0.1.0',
    description='TeMoto: supervisory teleoperation with a Resource Registrar, for ROS 1 in Python',
    python_requires='>=3.11',
    packages=find_packages(include=[p + suffix for p in PACKAGES for suffix in ('', '.*')]),
    package_data={p: ROS_FILES + EXTRA_FILES.get(p, []) for p in PACKAGES},
    entry_points={'console_scripts': ['temoto = temoto_bringup.cli:main'],
                  # the fixtures, for every pytest run in an environment where TeMoto is installed
                  'pytest11': ['temoto = temoto_testing.pytest_plugin']},
)
