"""YAML with the line of every value: configuration errors name the line a user must fix.

``load(text)`` gives the document as plain Python values (``yaml.safe_load``) and a
:class:`Lines` that answers the line of any path in it, ``('robots', 0, 'navigation', 'places')``,
from the same document composed as nodes. A path that is not in the document answers the line of
its nearest ancestor that is (a missing key is reported where its mapping starts).
"""
from __future__ import annotations

from typing import Any, Dict, Hashable, Tuple

import yaml

Path = Tuple[Hashable, ...]


class Lines:
    def __init__(self, lines: Dict[Path, int]) -> None:
        self._lines = lines

    def of(self, path: Path) -> int:
        """The 1-based line where ``path`` is written, or that of its nearest ancestor in the document."""
        for end in range(len(path), -1, -1):
            line = self._lines.get(tuple(path[:end]))
            if line is not None:
                return line
        return 1


def _walk(node: yaml.Node, path: Path, out: Dict[Path, int]) -> None:
    out[path] = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            child = path + (key.value,)
            _walk(value, child, out)
            out[child] = key.start_mark.line + 1     # a key's line is where a reader looks for it
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _walk(item, path + (i,), out)


def load(text: str) -> Tuple[Any, Lines]:
    """The document and its lines; raises ``yaml.YAMLError`` (with ``problem_mark``) when it is not YAML."""
    data = yaml.safe_load(text)
    root = yaml.compose(text)
    lines: Dict[Path, int] = {}
    if root is not None:
        _walk(root, (), lines)
    return data, Lines(lines)
