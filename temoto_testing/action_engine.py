"""Helpers for tests of the action engine: plugin folders written on the fly, a fake registrar."""
from __future__ import annotations

import json
import os
import textwrap
import threading


def write_plugin(root: str, name: str, code: str, effect: str = 'synchronous', inputs: dict | None = None,
                 outputs: dict | None = None, grounding: dict | None = None, descriptor: dict | str | None = None,
                 module: str | None = None, **extra) -> str:
    """Write ``root/<name>/<name>.umrf.json`` and its module; returns the plugin folder.

    ``descriptor`` replaces the generated JSON entirely (a str is written verbatim, for bad JSON).
    """
    folder = os.path.join(root, name)
    os.makedirs(folder, exist_ok=True)
    if descriptor is None:
        descriptor = {'name': name, 'description': 'test action %s' % name, 'effect': effect,
                      'input_parameters': inputs or {}, 'output_parameters': outputs or {},
                      'grounding': grounding or {'verbs': [name.split('_')[0]]}}
        descriptor.update(extra)
    with open(os.path.join(folder, '%s.umrf.json' % name), 'w') as f:
        f.write(descriptor if isinstance(descriptor, str) else json.dumps(descriptor, indent=1))
    with open(os.path.join(folder, module or '%s.py' % name), 'w') as f:
        f.write(textwrap.dedent(code))
    return folder


class FakeRegistrar:
    """Stands in for temoto_core.rr.ResourceRegistrar where only the lifetime matters."""

    def __init__(self, name: str):
        self.name = name
        self.held: list = []
        self.shut_down = False

    def shutdown(self):
        self.held.clear()
        self.shut_down = True


class FakeRegistrarFactory:
    def __init__(self):
        self.made: list[FakeRegistrar] = []
        self._lock = threading.Lock()

    def __call__(self, name: str) -> FakeRegistrar:
        rr = FakeRegistrar(name)
        with self._lock:
            self.made.append(rr)
        return rr
