"""What the ER Manager may run, and its tunables.

ROS 1 has no authentication: anyone who reaches the master can call
``load_process``. So every field is validated here before anything touches the
file system, ``sys_execute`` is off unless the config names the command, and an
optional package allowlist narrows ``ros_execute``. A refusal is a
:class:`RequestRefused` whose message names the field and the rule.
"""
from __future__ import annotations

import os
import re
import shlex
import signal
from dataclasses import dataclass, field, fields
from typing import Any

from temoto_core.errors import ErrorCode, Subsystem, TemotoError

ROS_EXECUTE = 'ros_execute'
SYS_EXECUTE = 'sys_execute'
ACTIONS = (ROS_EXECUTE, SYS_EXECUTE)

_PACKAGE_RE = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
_FILE_RE = re.compile(r'^[A-Za-z0-9_][A-Za-z0-9_.+-]*$')          # a base name, no path, no leading dot
_NS_SEGMENT_RE = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
_MAX_FIELD = 4096
# remappings that would take the node out of the manager's control or off this master
_FORBIDDEN_SPECIAL = ('__ns:=', '__master:=', '__ip:=', '__hostname:=', '__log:=')


class RequestRefused(TemotoError):
    """A request that is invalid, not allowed, or names something that does not exist.

    ``kind`` is the name of a :class:`temoto_core.errors.ErrorCode`.
    """

    def __init__(self, kind: str, message: str):
        super().__init__(ErrorCode[kind], Subsystem.ER_MANAGER, message)
        self.kind = kind


@dataclass
class ERConfig:
    """The node's parameters (config/er_manager.yaml). Durations in seconds."""
    sys_allowlist: list = field(default_factory=list)        # commands sys_execute may run; empty: none
    package_allowlist: list = field(default_factory=list)    # packages ros_execute may use; empty: all
    registration_timeout: float = 10.0   # a node must register with the master within this
    ready_poll_interval: float = 0.02    # master look-up period while waiting for registration
    sys_settle_time: float = 0.2         # a sys_execute command must stay alive this long to count as started
    sigint_grace: float = 3.0            # unload: SIGINT, wait this, then SIGTERM
    sigterm_grace: float = 2.0           # ... wait this, then SIGKILL
    death_signal: str = 'SIGKILL'        # without a journal: sent to children if the manager dies
    adoption_bound: float = 30.0         # with a journal: how long children wait for a restarted manager
    log_dir: str = ''                    # per-process logs; empty: <ROS log dir>/temoto_er_manager
    log_tail_lines: int = 20             # lines of output quoted in a FAILED status
    preload_python: bool = False         # fork Python node scripts from a zygote that has imported preload_modules
    preload_modules: list = field(default_factory=lambda: ['rospy', 'numpy', 'std_msgs.msg', 'sensor_msgs.msg'])

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> 'ERConfig':
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ValueError('unknown ER Manager parameter(s): %s (known: %s)'
                             % (', '.join(unknown), ', '.join(sorted(known))))
        cfg = cls(**values)
        if not isinstance(cfg.preload_python, bool):
            raise ValueError('preload_python must be true or false, got %r' % (cfg.preload_python,))
        v = cfg.preload_modules
        if not isinstance(v, (list, tuple)) or not all(isinstance(x, str) and re.match(
                r'^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$', x) for x in v):
            raise ValueError('preload_modules must be a list of dotted module names, got %r' % (v,))
        cfg.preload_modules = list(v)
        for name in ('sys_allowlist', 'package_allowlist'):
            v = getattr(cfg, name)
            if not isinstance(v, (list, tuple)) or not all(isinstance(x, str) and x for x in v):
                raise ValueError('%s must be a list of non-empty strings, got %r' % (name, v))
            setattr(cfg, name, list(v))
        for name in ('registration_timeout', 'ready_poll_interval', 'sys_settle_time', 'sigint_grace',
                     'sigterm_grace', 'adoption_bound'):
            v = getattr(cfg, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or v < 0:
                raise ValueError('%s must be a number >= 0, got %r' % (name, v))
            setattr(cfg, name, float(v))
        if cfg.death_signal:
            cfg.death_signal_number()                # raises on a bad name
        return cfg

    def death_signal_number(self) -> int:
        if not self.death_signal:
            return 0
        try:
            return int(signal.Signals[self.death_signal])
        except KeyError:
            raise ValueError('death_signal must be a signal name such as SIGKILL or SIGTERM, got %r'
                             % self.death_signal) from None


@dataclass(frozen=True)
class LoadRequest:
    """A validated ``LoadProcess`` request; ``argv_args`` is ``args`` split by shlex."""
    action: str
    ros_namespace: str          # absolute, normalised ('/' for the root)
    package_name: str
    executable: str
    args: str
    argv_args: tuple


def _check_text(name: str, value: Any) -> str:
    if not isinstance(value, str):
        raise RequestRefused('BAD_REQUEST', '%s must be a string' % name)
    if '\x00' in value:
        raise RequestRefused('BAD_REQUEST', '%s contains a NUL character' % name)
    if len(value) > _MAX_FIELD:
        raise RequestRefused('BAD_REQUEST', '%s is longer than %d characters' % (name, _MAX_FIELD))
    return value


def normalise_namespace(ns: str, base_ns: str) -> str:
    """``ns`` made absolute against ``base_ns`` (empty: ``base_ns``); ``~`` names are refused."""
    if ns in ('', '.'):
        ns = base_ns or '/'
    elif not ns.startswith('/'):
        if ns.startswith('~'):
            raise RequestRefused('BAD_REQUEST', 'ros_namespace %r: private (~) names are not allowed' % ns)
        ns = (base_ns.rstrip('/') if base_ns else '') + '/' + ns
    segments = [s for s in ns.split('/') if s]
    if '//' in ns.rstrip('/') or any(not _NS_SEGMENT_RE.match(s) for s in segments):
        raise RequestRefused('BAD_REQUEST',
                             'ros_namespace %r is not a legal ROS namespace (segments must match '
                             '[A-Za-z][A-Za-z0-9_]*)' % ns)
    return '/' + '/'.join(segments)


def check_package_allowed(package: str, allowlist: list, what: str = 'package_name') -> None:
    """Refuse an illegal package name, or one outside a non-empty ``allowlist``.

    Applied to the request's package and to the package of every node of a launch file."""
    if not isinstance(package, str) or not _PACKAGE_RE.match(package):
        raise RequestRefused('BAD_REQUEST', '%s %r is not a legal ROS package name' % (what, package))
    if allowlist and package not in allowlist:
        raise RequestRefused('NOT_ALLOWED', '%s %r is not in this manager\'s package_allowlist (%s)'
                             % (what, package, ', '.join(allowlist)))


def validate_request(action: str, ros_namespace: str, package_name: str, executable: str, args: str,
                     config: ERConfig, base_ns: str = '/') -> LoadRequest:
    """Check every field and the allowlists; return the normalised request or raise RequestRefused."""
    for name, value in (('action', action), ('ros_namespace', ros_namespace),
                        ('package_name', package_name), ('executable', executable), ('args', args)):
        _check_text(name, value)
    if action not in ACTIONS:
        raise RequestRefused('BAD_REQUEST', 'action %r is not one of %s' % (action, ', '.join(ACTIONS)))
    ns = normalise_namespace(ros_namespace, base_ns)
    try:
        argv_args = tuple(shlex.split(args))
    except ValueError as e:
        raise RequestRefused('BAD_REQUEST', 'args %r cannot be split: %s' % (args, e)) from None
    if not executable:
        raise RequestRefused('BAD_REQUEST', 'executable is empty')

    if action == SYS_EXECUTE:
        if executable not in config.sys_allowlist:
            raise RequestRefused('NOT_ALLOWED',
                                 'sys_execute of %r refused: the command is not in this manager\'s '
                                 'sys_allowlist (%s)' % (executable, ', '.join(config.sys_allowlist) or
                                                         'empty: sys_execute is disabled'))
        if package_name:
            raise RequestRefused('BAD_REQUEST', 'sys_execute takes no package_name (got %r)' % package_name)
        return LoadRequest(action, ns, '', executable, args, argv_args)

    check_package_allowed(package_name, config.package_allowlist)
    if not _FILE_RE.match(executable) or os.sep in executable:
        raise RequestRefused('BAD_REQUEST',
                             'executable %r must be a plain file name inside the package (no path, no '
                             'leading dot)' % executable)
    for a in argv_args:
        for special in _FORBIDDEN_SPECIAL:
            if a.startswith(special):
                raise RequestRefused('BAD_REQUEST', 'args may not set %s (use the request fields)'
                                     % special.rstrip(':='))
    return LoadRequest(action, ns, package_name, executable, args, argv_args)
