"""Turn a validated request into a :class:`ProcessSpec`: the rosrun and roslaunch rules, no shell.

- ``ros_execute`` of a node: the package is found through ``ROS_PACKAGE_PATH``
  (rospkg); the executable is the unique file of that name below the package
  directory (``build/`` and hidden directories skipped, like ``rosrun``) that has
  the executable bit. argv = ``[path] + shlex.split(args) + [__name:=, __ns:=]``.
  ``__name`` is always set so the manager knows which node must register.
- ``ros_execute`` of ``*.launch``: the file below the package directory (the
  ``roslaunch`` rule). argv = ``[python, launch_runner.py, ..., file, arg:=value...]``;
  the namespace goes in ``ROS_NAMESPACE``, which roslaunch uses as the root.
- ``sys_execute``: the allowlisted command looked up in ``PATH``.
"""
from __future__ import annotations

import itertools
import os
import re
import socket
import sys
import time
from typing import Callable, Optional

import rospkg

from .policy import SYS_EXECUTE, ERConfig, LoadRequest, RequestRefused
from .supervisor import ProcessSpec

LAUNCH_RUNNER = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'launch_runner.py')
_NAME_RE = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
_seq = itertools.count(1)


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

    def resolve(self, req: LoadRequest, name_taken: Callable[[str], bool] = lambda n: False) -> ProcessSpec:
        env = dict(self.env)
        env['ROS_NAMESPACE'] = req.ros_namespace
        env['PYTHONUNBUFFERED'] = '1'       # so a crash's last lines are in the log
        if req.action == SYS_EXECUTE:
            return self._sys(req, env)
        pkg_dir = self.package_dir(req.package_name)
        if req.executable.endswith('.launch'):
            return self._launch(req, pkg_dir, env)
        return self._node(req, pkg_dir, env, name_taken)

    def _log_path(self, req: LoadRequest) -> str:
        parts = [p for p in (req.package_name, req.executable) if p]
        label = re.sub(r'[^A-Za-z0-9_.-]', '_', '-'.join(parts))[:80]
        return os.path.join(self.log_dir, '%s-%d-%d-%s.log'
                            % (time.strftime('%Y%m%d-%H%M%S'), os.getpid(), next(_seq), label))

    def _sys(self, req: LoadRequest, env: dict) -> ProcessSpec:
        import shutil
        path = req.executable if os.path.isabs(req.executable) else shutil.which(req.executable,
                                                                                  path=env.get('PATH'))
        if not path or not os.access(path, os.X_OK) or not os.path.isfile(path):
            raise RequestRefused('EXECUTABLE_NOT_FOUND', 'sys_execute: command %r not found or not executable'
                                 % req.executable)
        return ProcessSpec(argv=[path, *req.argv_args], env=env, log_path=self._log_path(req),
                           label=req.executable)

    def _node(self, req: LoadRequest, pkg_dir: str, env: dict, name_taken) -> ProcessSpec:
        matches = find_in_package(pkg_dir, req.executable)
        execs = [p for p in matches if os.path.isfile(p) and os.access(p, os.X_OK)]
        if not execs:
            if matches:
                raise RequestRefused('EXECUTABLE_NOT_FOUND',
                                     'executable %r in package %r is not an executable file: %s'
                                     % (req.executable, req.package_name, ', '.join(matches)))
            raise RequestRefused('EXECUTABLE_NOT_FOUND', 'no executable %r in package %r (%s)'
                                 % (req.executable, req.package_name, pkg_dir))
        if len(execs) > 1:
            raise RequestRefused('EXECUTABLE_NOT_FOUND', 'executable %r is not unique in package %r: %s'
                                 % (req.executable, req.package_name, ', '.join(execs)))
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
        return ProcessSpec(argv=interpreter_argv(execs[0]) + args, env=env, log_path=self._log_path(req),
                           cwd=os.path.dirname(execs[0]), label='%s/%s' % (req.package_name, req.executable),
                           node_names=[join_name(req.ros_namespace, name)])

    def _launch(self, req: LoadRequest, pkg_dir: str, env: dict) -> ProcessSpec:
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
        node_names = launch_node_names(matches[0], list(req.argv_args), req.ros_namespace)
        argv = [sys.executable, LAUNCH_RUNNER, '--sigint-timeout', str(self.config.sigint_grace),
                '--sigterm-timeout', str(self.config.sigterm_grace),
                '--death-signal', self.config.death_signal, matches[0], *req.argv_args]
        return ProcessSpec(argv=argv, env=env, log_path=self._log_path(req), cwd=os.path.dirname(matches[0]),
                           label='%s/%s' % (req.package_name, req.executable), node_names=node_names)


def launch_node_names(path: str, args: list[str], ns: str) -> list[str]:
    """The full names of the launch file's nodes under namespace ``ns``.

    Anonymous names (``$(anon x)``) differ in every roslaunch process, so they
    cannot be checked and are left out. A ``<group ns="/absolute">`` is also
    placed under ``ns`` here (roslaunch would not): a documented approximation.
    """
    import roslaunch.config
    import roslaunch.core
    try:
        cfg = roslaunch.config.load_config_default([(path, args)], None, verbose=False)
    except (roslaunch.core.RLException, Exception) as e:     # XML errors are not all RLException
        raise RequestRefused('BAD_REQUEST', 'launch file %s cannot be loaded: %s' % (path, e)) from None
    anon = re.compile(r'_%s_%d_\d+$' % (re.escape(re.sub(r'[.\-]', '_', socket.gethostname())), os.getpid()))
    names = []
    for node in cfg.nodes:
        if not node.name or anon.search(node.name):
            continue
        names.append(join_name(ns, (node.namespace + node.name).lstrip('/')))
    return names
