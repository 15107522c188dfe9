"""Turn a validated request into a :class:`Plan`: the rosrun and roslaunch rules, no shell.

- ``ros_execute`` of a node: the package is found through ``ROS_PACKAGE_PATH``
  (rospkg); the executable is the unique file of that name below the package
  directory (``build/`` and hidden directories skipped, like ``rosrun``) that has
  the executable bit. argv = ``[path] + shlex.split(args) + [__name:=, __ns:=]``.
  ``__name`` is always set so the manager knows which node must register.
- ``ros_execute`` of ``*.launch``: the file below the package directory (the
  ``roslaunch`` rule), loaded with roslaunch's loader into parameters and one
  process per node (:mod:`temoto_er_manager.launchfile`); the request's namespace
  is the launch's root namespace.
- ``sys_execute``: the allowlisted command looked up in ``PATH``.

A plan is one resource: one or more processes that live and die together.
"""
from __future__ import annotations

import itertools
import os
import re
import shutil
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import rospkg

from .launchfile import plan_launch
from .policy import SYS_EXECUTE, ERConfig, LoadRequest, RequestRefused
from .supervisor import ProcessSpec

_NAME_RE = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
_seq = itertools.count(1)


@dataclass
class Plan:
    """One resource to start: parameters to set first, then its processes (all must start, all stop together)."""
    label: str                          # "pkg/executable", "pkg/file.launch" or the command
    log_path: str                       # every process of the resource appends its output here
    specs: list[ProcessSpec]
    command: str                        # for listings: the argv of a single process, or the launch file and args
    params: dict[str, Any] = field(default_factory=dict)
    clear_params: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def is_launch(self) -> bool:
        return self.label.endswith('.launch')


def default_log_dir() -> str:
    return os.path.join(rospkg.get_log_dir(), 'temoto_er_manager')


def node_base_name(executable: str) -> str:
    """A legal node name from an executable: ``my-node.py`` -> ``my_node``."""
    stem = executable.split('.', 1)[0] if not executable.startswith('.') else executable
    name = re.sub(r'[^A-Za-z0-9_]', '_', stem)
    return name if name[:1].isalpha() else 'n_' + name


def join_name(ns: str, name: str) -> str:
    return ns.rstrip('/') + '/' + name


def interpreter_argv(path: str) -> list[str]:
    """Python node scripts run under the manager's interpreter (the venv, which can load ROS),
    whatever their ``#!/usr/bin/env python3`` would find in PATH; anything else runs as itself."""
    try:
        with open(path, 'rb') as f:
            first = f.readline(200)
    except OSError:
        return [path]
    if first.startswith(b'#!') and b'python' in first:
        return [sys.executable, path]
    return [path]


def is_python_script_argv(argv: list) -> bool:
    """``argv`` is what :func:`interpreter_argv` makes of a Python script (so the zygote may start it)."""
    return len(argv) >= 2 and argv[0] == sys.executable and os.path.isabs(argv[1])


def find_in_package(pkg_dir: str, filename: str) -> list[str]:
    """Every path named ``filename`` below ``pkg_dir``; skips hidden dirs and ``build``, no symlinked dirs."""
    found = []
    for root, dirs, files in os.walk(pkg_dir):
        dirs[:] = sorted(d for d in dirs if not d.startswith('.') and not (root == pkg_dir and d == 'build'))
        if filename in files:
            found.append(os.path.join(root, filename))
    return found


class Resolver:
    """Resolves requests against the manager's environment (``env``: its ROS variables and PATH)."""

    def __init__(self, config: ERConfig, env: Optional[dict] = None):
        self.config = config
        self.env = dict(os.environ if env is None else env)
        self._rospack = rospkg.RosPack(rospkg.get_ros_paths(env=self.env))
        self.log_dir = config.log_dir or default_log_dir()

    def package_dir(self, package: str) -> str:
        try:
            return self._rospack.get_path(package)
        except rospkg.ResourceNotFound:
            # packages may have appeared since the last crawl: look once more with a fresh cache
            self._rospack = rospkg.RosPack(rospkg.get_ros_paths(env=self.env))
            try:
                return self._rospack.get_path(package)
            except rospkg.ResourceNotFound:
                raise RequestRefused('PACKAGE_NOT_FOUND', 'package %r not found in ROS_PACKAGE_PATH (%s)'
                                     % (package, self.env.get('ROS_PACKAGE_PATH', ''))) from None

    def resolve(self, req: LoadRequest, name_taken: Callable[[str], bool] = lambda n: False) -> Plan:
        env = dict(self.env)
        env['ROS_NAMESPACE'] = req.ros_namespace
        env['PYTHONUNBUFFERED'] = '1'       # so a crash's last lines are in the log
        if req.action == SYS_EXECUTE:
            return self._single(self._sys(req, env))
        pkg_dir = self.package_dir(req.package_name)
        if req.executable.endswith('.launch'):
            return self._launch(req, pkg_dir, env)
        return self._single(self._node(req, pkg_dir, env, name_taken))

    @staticmethod
    def _single(spec: ProcessSpec) -> Plan:
        return Plan(label=spec.label, log_path=spec.log_path, specs=[spec], command=spec.command)

    def find_executable(self, package: str, executable: str, pkg_dir: Optional[str] = None) -> str:
        """The rosrun rule: the unique file ``executable`` below the package, with the executable bit."""
        pkg_dir = pkg_dir or self.package_dir(package)
        matches = find_in_package(pkg_dir, executable)
        execs = [p for p in matches if os.path.isfile(p) and os.access(p, os.X_OK)]
        if not execs:
            if matches:
                raise RequestRefused('EXECUTABLE_NOT_FOUND',
                                     'executable %r in package %r is not an executable file: %s'
                                     % (executable, package, ', '.join(matches)))
            raise RequestRefused('EXECUTABLE_NOT_FOUND', 'no executable %r in package %r (%s)'
                                 % (executable, package, pkg_dir))
        if len(execs) > 1:
            raise RequestRefused('EXECUTABLE_NOT_FOUND', 'executable %r is not unique in package %r: %s'
                                 % (executable, package, ', '.join(execs)))
        return execs[0]

    def _log_path(self, req: LoadRequest) -> str:
        parts = [p for p in (req.package_name, req.executable) if p]
        label = re.sub(r'[^A-Za-z0-9_.-]', '_', '-'.join(parts))[:80]
        return os.path.join(self.log_dir, '%s-%d-%d-%s.log'
                            % (time.strftime('%Y%m%d-%H%M%S'), os.getpid(), next(_seq), label))

    def _sys(self, req: LoadRequest, env: dict) -> ProcessSpec:
        path = req.executable if os.path.isabs(req.executable) else shutil.which(req.executable,
                                                                                  path=env.get('PATH'))
        if not path or not os.access(path, os.X_OK) or not os.path.isfile(path):
            raise RequestRefused('EXECUTABLE_NOT_FOUND', 'sys_execute: command %r not found or not executable'
                                 % req.executable)
        return ProcessSpec(argv=[path, *req.argv_args], env=env, log_path=self._log_path(req),
                           label=req.executable)

    def _node(self, req: LoadRequest, pkg_dir: str, env: dict, name_taken) -> ProcessSpec:
        exe = self.find_executable(req.package_name, req.executable, pkg_dir)
        args = list(req.argv_args)
        named = [a.split(':=', 1)[1] for a in args if a.startswith('__name:=')]
        if named:
            name = named[-1]
            if not _NAME_RE.match(name):
                raise RequestRefused('BAD_REQUEST', '__name:=%s is not a legal node base name' % name)
        else:
            base = name = node_base_name(req.executable)
            # two different requests for the same executable in one namespace must not kick each
            # other off the master (a duplicate name makes the master shut the older node down)
            for i in range(2, 1000):
                if not name_taken(join_name(req.ros_namespace, name)):
                    break
                name = '%s_%d' % (base, i)
            args.append('__name:=' + name)
        args.append('__ns:=' + req.ros_namespace)
        argv = interpreter_argv(exe)
        return ProcessSpec(argv=argv + args, env=env, log_path=self._log_path(req),
                           cwd=os.path.dirname(exe), label='%s/%s' % (req.package_name, req.executable),
                           node_names=[join_name(req.ros_namespace, name)], preloadable=is_python_script_argv(argv))

    def _launch(self, req: LoadRequest, pkg_dir: str, env: dict) -> Plan:
        matches = [p for p in find_in_package(pkg_dir, req.executable) if os.path.isfile(p)]
        if not matches:
            raise RequestRefused('EXECUTABLE_NOT_FOUND', 'no launch file %r in package %r (%s)'
                                 % (req.executable, req.package_name, pkg_dir))
        if len(matches) > 1:
            raise RequestRefused('EXECUTABLE_NOT_FOUND', 'launch file %r is not unique in package %r: %s'
                                 % (req.executable, req.package_name, ', '.join(matches)))
        for a in req.argv_args:
            if ':=' not in a or a.startswith('__'):
                raise RequestRefused('BAD_REQUEST', 'launch file args must be name:=value, got %r' % a)
        label = '%s/%s' % (req.package_name, req.executable)
        log_path = self._log_path(req)
        launch = plan_launch(matches[0], list(req.argv_args), req.ros_namespace, env=env, log_path=log_path,
                             label=label, find_executable=self.find_executable,
                             package_allowlist=self.config.package_allowlist,
                             sys_allowlist=self.config.sys_allowlist, interpreter_argv=interpreter_argv)
        command = ' '.join([matches[0], *req.argv_args] + (['(ns %s)' % req.ros_namespace]
                                                         if req.ros_namespace != '/' else []))
        return Plan(label=label, log_path=log_path, specs=launch.nodes, command=command, params=launch.params,
                    clear_params=launch.clear_params, warnings=launch.warnings)
