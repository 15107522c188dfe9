"""The action index: plugin folders scanned into descriptors and classes.

The original TaskManager scanned directories (depth 2) for descriptors and loaded
each task's shared library with class_loader. Here a plugin is a folder holding
``<name>.umrf.json`` and a Python module; the module is loaded with importlib
under a fresh module name on every (re)index, so an edited plugin is picked up
by ``reindex`` while graphs already running keep the class they started with.

A broken plugin never stops the indexing of the others: each problem becomes a
:class:`PluginProblem` naming the file and what was wrong.
"""
from __future__ import annotations

import importlib.util
import inspect
import itertools
import json
import os
import sys
import threading
import traceback
from dataclasses import dataclass

from .action_base import ActionBase
from .umrf import ActionDescriptor, UmrfError, parse_descriptor

BUNDLED_ACTIONS = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'actions')
DESCRIPTOR_SUFFIX = '.umrf.json'
MAX_DEPTH = 2          # as the original indexTasks(dir, depth=2)

# Kinds of plugin problems, in the order they can happen.
MISSING_FOLDER = 'missing_folder'
BAD_JSON = 'bad_json'
SCHEMA = 'schema'
IMPORT_ERROR = 'import_error'
MISSING_CLASS = 'missing_class'
DUPLICATE = 'duplicate'

_module_counter = itertools.count(1)


@dataclass(frozen=True)
class PluginProblem:
    path: str
    kind: str
    message: str

    def __str__(self):
        return '%s [%s]: %s' % (self.path, self.kind, self.message)

    def to_json(self) -> dict:
        return {'path': self.path, 'kind': self.kind, 'message': self.message}


@dataclass(frozen=True)
class IndexedAction:
    descriptor: ActionDescriptor
    cls: type

    @property
    def name(self) -> str:
        return self.descriptor.name


def find_descriptors(root: str, depth: int = MAX_DEPTH) -> list[str]:
    """Every ``*.umrf.json`` in ``root`` or in its sub-folders down to ``depth`` levels, sorted."""
    found = []
    root = os.path.abspath(root)
    base_depth = root.rstrip(os.sep).count(os.sep)
    for dirpath, dirnames, filenames in os.walk(root):
        if dirpath.count(os.sep) - base_depth >= depth:
            dirnames[:] = []
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(('.', '__')))
        found.extend(os.path.join(dirpath, f) for f in sorted(filenames) if f.endswith(DESCRIPTOR_SUFFIX))
    return found


def _import_module(path: str, action_name: str):
    mod_name = 'temoto_action_plugins.%s_%d' % (action_name, next(_module_counter))
    spec = importlib.util.spec_from_file_location(mod_name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module       # dataclasses and pickling look modules up here
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(mod_name, None)
        raise
    return module


def _describe_exception(exc: BaseException, path: str) -> str:
    """One line: the exception and the deepest frame inside the plugin file."""
    line = ''
    if isinstance(exc, SyntaxError) and exc.lineno:
        line = ' (line %d)' % exc.lineno
    else:
        for fr in traceback.extract_tb(exc.__traceback__):
            if os.path.abspath(fr.filename) == os.path.abspath(path):
                line = ' (line %d)' % fr.lineno
    return '%s: %s%s' % (type(exc).__name__, exc, line)


def load_plugin(descriptor_path: str) -> tuple[IndexedAction | None, PluginProblem | None]:
    """Load one plugin; exactly one of the two results is None."""
    try:
        with open(descriptor_path, encoding='utf-8') as f:
            data = json.load(f)
    except (OSError, ValueError) as e:
        return None, PluginProblem(descriptor_path, BAD_JSON, 'cannot read JSON: %s' % e)
    try:
        desc = parse_descriptor(data, descriptor_path)
    except UmrfError as e:
        return None, PluginProblem(descriptor_path, SCHEMA, '; '.join(e.problems))
    module_path = os.path.join(os.path.dirname(descriptor_path), desc.module)
    if not os.path.isfile(module_path):
        return None, PluginProblem(descriptor_path, IMPORT_ERROR, 'module file %s does not exist' % module_path)
    try:
        module = _import_module(module_path, desc.name)
    except BaseException as e:    # a plugin may raise anything at import time, even SystemExit
        if isinstance(e, KeyboardInterrupt):
            raise
        return None, PluginProblem(module_path, IMPORT_ERROR, _describe_exception(e, module_path))
    if desc.class_name:
        cls = getattr(module, desc.class_name, None)
        if cls is None:
            return None, PluginProblem(module_path, MISSING_CLASS,
                                       'class %r named by %s is not defined in the module'
                                       % (desc.class_name, os.path.basename(descriptor_path)))
        if not (inspect.isclass(cls) and issubclass(cls, ActionBase)):
            return None, PluginProblem(module_path, MISSING_CLASS,
                                       '%r is not a class derived from ActionBase' % desc.class_name)
    else:
        candidates = [c for _, c in inspect.getmembers(module, inspect.isclass)
                      if issubclass(c, ActionBase) and c is not ActionBase and c.__module__ == module.__name__]
        if len(candidates) != 1:
            what = 'no class derived from ActionBase' if not candidates else \
                'several ActionBase classes (%s); set "class_name" in the descriptor' % \
                ', '.join(sorted(c.__name__ for c in candidates))
            return None, PluginProblem(module_path, MISSING_CLASS, 'the module defines %s' % what)
        cls = candidates[0]
    if desc.asynchronous is False and cls.execute is ActionBase.execute:
        return None, PluginProblem(module_path, MISSING_CLASS,
                                   'synchronous action %r must override execute()' % desc.name)
    return IndexedAction(desc, cls), None


class ActionIndex:
    """Indexed actions by name, plus the problems found while indexing. Thread-safe."""

    def __init__(self, paths: list[str], include_bundled: bool = True):
        self.paths = ([BUNDLED_ACTIONS] if include_bundled else []) + \
            [os.path.abspath(os.path.expanduser(p)) for p in paths if p]
        self._lock = threading.Lock()
        self._actions: dict[str, IndexedAction] = {}
        self._problems: list[PluginProblem] = []

    def reindex(self) -> 'ActionIndex':
        actions: dict[str, IndexedAction] = {}
        problems: list[PluginProblem] = []
        for root in self.paths:
            if not os.path.isdir(root):
                problems.append(PluginProblem(root, MISSING_FOLDER, 'action folder does not exist'))
                continue
            for path in find_descriptors(root):
                action, problem = load_plugin(path)
                if problem:
                    problems.append(problem)
                elif action.name in actions:
                    problems.append(PluginProblem(path, DUPLICATE, 'action %r is already defined by %s; '
                                                  'this one is ignored'
                                                  % (action.name, actions[action.name].descriptor.source)))
                else:
                    actions[action.name] = action
        with self._lock:
            self._actions, self._problems = actions, problems
        return self

    # Mapping-style access used by the grounder and the graph parser (name -> descriptor).
    def get(self, name: str) -> ActionDescriptor | None:
        with self._lock:
            a = self._actions.get(name)
        return a.descriptor if a else None

    def __contains__(self, name) -> bool:
        with self._lock:
            return name in self._actions

    def __iter__(self):
        with self._lock:
            return iter(sorted(self._actions))

    def __len__(self) -> int:
        with self._lock:
            return len(self._actions)

    def action(self, name: str) -> IndexedAction | None:
        with self._lock:
            return self._actions.get(name)

    def descriptors(self) -> dict[str, ActionDescriptor]:
        with self._lock:
            return {k: a.descriptor for k, a in sorted(self._actions.items())}

    @property
    def problems(self) -> list[PluginProblem]:
        with self._lock:
            return list(self._problems)

    def to_json(self) -> dict:
        return {'paths': list(self.paths),
                'actions': [d.to_json() for d in self.descriptors().values()],
                'errors': [p.to_json() for p in self.problems]}
