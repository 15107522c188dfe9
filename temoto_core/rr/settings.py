"""A registrar's settings, read and checked once, before any part is built.

Each setting comes from the constructor's argument when given, else from the node's private parameter
of the same name. A bad value is refused here, naming it, before the journal is opened (opening it
starts a new incarnation) and before any thread starts.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Optional

import rospkg
import rospy

from temoto_core.params import ParamError, number_param, seconds_param, text_param
from temoto_core.rr import owners
from temoto_core.rr.core import DEFAULT_NAMESPACE
from temoto_core.rr.deadlines import DEFAULT_DEADLINE
from temoto_core.rr.recorder import COMMIT_PAUSE, MAX_COMMIT_PAUSE

DEFAULT_RECOVERY_GRACE = 10.0
DEFAULT_CONSUMER_CHECK_PERIOD = 2.0


def default_journal_path() -> str:
    """Where ``~journal: auto`` keeps a node's journal: under the ROS home, one file per node name."""
    return os.path.join(rospkg.get_ros_home(), 'temoto', 'journal', rospy.get_name().strip('/').replace('/', '.')
                        + '.sqlite')


def journal_param() -> str:
    """The journal path the node's ``~journal`` parameter asks for ('' for none, ``auto`` for the default)."""
    journal = text_param(rospy.get_param('~journal', ''), 'journal')
    return default_journal_path() if journal == 'auto' else journal


@dataclass(frozen=True)
class RegistrarSettings:
    namespace: str                  # the TeMoto namespace the registrar's services live in
    journal: str                    # the journal's path; '' for none
    recovery_grace: float           # s a dead journaling consumer's resources are kept for its return
    call_deadline: float            # s, for a call whose request type declares none
    journal_pause: float            # s the journal's writer waits between two commits under a burst
    consumer_check_period: float    # s between two checks that the consumers are alive; 0: never
    owner_check_period: float       # s between two checks that the owners answer
    owner_liveness_bound: float     # s an owner may not answer before what it serves fails
    owner_busy_bound: float         # s an owner that answers "busy" is waited for

    @classmethod
    def read(cls, namespace: Optional[str] = None, journal: Optional[str] = None,
             recovery_grace: Optional[float] = None, call_deadline: Optional[float] = None,
             journal_pause: Optional[float] = None,
             consumer_check_period: Optional[float] = None) -> 'RegistrarSettings':
        """The settings: each argument given, else its private parameter, else its default. Raises
        ParamError naming the first bad one."""
        def given(value, name: str, default):
            return value if value is not None else rospy.get_param('~' + name, default)
        deadline = number_param(given(call_deadline, 'call_deadline', DEFAULT_DEADLINE), 'call_deadline', above=0)
        return cls(
            namespace=text_param(given(namespace, 'temoto_namespace', DEFAULT_NAMESPACE), 'temoto_namespace'),
            journal=journal if journal is not None else journal_param(),
            recovery_grace=seconds_param(given(recovery_grace, 'recovery_grace', DEFAULT_RECOVERY_GRACE),
                                         'recovery_grace'),
            call_deadline=deadline,
            journal_pause=number_param(given(journal_pause, 'journal_pause', COMMIT_PAUSE), 'journal_pause',
                                       minimum=0, maximum=MAX_COMMIT_PAUSE),
            consumer_check_period=seconds_param(given(consumer_check_period, 'consumer_check_period',
                                                      DEFAULT_CONSUMER_CHECK_PERIOD), 'consumer_check_period'),
            owner_check_period=number_param(rospy.get_param('~owner_check_period', owners.DEFAULT_PERIOD),
                                            'owner_check_period', above=0),
            owner_liveness_bound=number_param(rospy.get_param('~owner_liveness_bound', owners.DEFAULT_BOUND),
                                              'owner_liveness_bound', above=0),
            owner_busy_bound=number_param(rospy.get_param('~owner_busy_bound', owners.DEFAULT_BUSY_BOUND),
                                          'owner_busy_bound', above=0))


__all__ = ['ParamError', 'RegistrarSettings', 'default_journal_path', 'journal_param']
