"""Parameters that nodes share the shape of."""
from __future__ import annotations

from typing import List


def list_param(value, name: str, separator: str = ',') -> List[str]:
    """A list parameter that may also be given as one ``separator``-separated string (from a launch file's
    argument or the command line): ``'robot,hey'`` and ``['robot', 'hey']`` are the same list. Raises
    ValueError naming ``~name`` for anything else."""
    if value in (None, ''):
        return []
    if isinstance(value, str):
        return [v.strip() for v in value.split(separator) if v.strip()]
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return value
    raise ValueError('parameter ~%s must be a list of strings, got %r' % (name, value))


def seconds_param(value, name: str) -> float:
    """A duration parameter in seconds, 0 meaning off. Raises ValueError naming ``name`` for anything else
    (a negative number, a bool, a string)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
        raise ValueError('%s %r: it must be a number of seconds, 0 for off' % (name, value))
    return float(value)
