"""The Robot Manager on the wire: its registrar, its server, its service type and its equality.

Its server and every client (``interface.py``) import this module, never each other.
"""
from temoto_core.rr.deadlines import register_deadlines
from temoto_core.rr.keys import register_key
from temoto_robot_manager.srv import LoadRobot

RR_NAME = 'temoto_robot_manager'
LOAD_ROBOT = 'load_robot'
LOAD_ROBOT_TYPE = LoadRobot
ROBOTS = 'robots'                  # a GetRegistry service: the described robots, their features and holders (JSON)


def robot_key(request) -> tuple:
    """Two requests share a loaded robot when they name the same robot and the same features (in any order)."""
    return request.robot_name.strip(), tuple(sorted({f.strip() for f in request.features}))


register_key(LoadRobot._request_class, robot_key)
# The longest a load may take (deadlines.py): each part's process start (15 s each, one after another) and the
# obstacle sensor's first data (40 s at most).
register_deadlines(LoadRobot._request_class, load=90.0, unload=30.0)
