"""Every node's parameters, read through one typed reader.

A node that reads ``float(rospy.get_param('~rate', 50))`` and is given ``_rate:=fast`` dies with
"could not convert string to float", which names neither the parameter nor what was expected; one
given ``_rate:=-5`` runs with it. Here each read says what it expects, and a value that does not fit
raises :class:`ParamError` naming the parameter, the value and the expectation. A node lets it end
the node (its main catches nothing), so a bad value stops the node at start, with that line in its log.

The checks themselves (``seconds_param``, ``list_param``, ...) take a value and a name, so a value
that arrives another way (a launch argument, a service field) is checked by the same rules.
"""
from __future__ import annotations

import math
from typing import List, Optional, Sequence

import rospy


class ParamError(ValueError):
    """A parameter whose value the node cannot use."""


def _shown(name: str) -> str:
    return name if name.startswith('/') else '~' + name


def _fail(name: str, value, expected: str) -> ParamError:
    return ParamError('parameter %s: %r is not %s' % (_shown(name), value, expected))


def _get(name: str, default):
    return rospy.get_param(name if name.startswith('/') else '~' + name, default)


def list_param(value, name: str, separator: str = ',') -> List[str]:
    """A list parameter that may also be given as one ``separator``-separated string (from a launch file's
    argument or the command line): ``'robot,hey'`` and ``['robot', 'hey']`` are the same list. Raises
    ParamError naming ``~name`` for anything else."""
    if value in (None, ''):
        return []
    if isinstance(value, str):
        return [v.strip() for v in value.split(separator) if v.strip()]
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return value
    raise _fail(name, value, 'a list of strings (or one %r-separated string)' % separator)


def seconds_param(value, name: str) -> float:
    """A duration parameter in seconds, 0 meaning off. Raises ParamError naming ``name`` for anything else
    (a negative number, a bool, a string)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise _fail(name, value, 'a number of seconds (0 for off)')
    return float(value)


def number_param(value, name: str, minimum: Optional[float] = None, maximum: Optional[float] = None,
                 above: Optional[float] = None, integer: bool = False) -> float:
    """A number within bounds: ``minimum`` and ``maximum`` inclusive, ``above`` exclusive; ``integer``: a
    whole number (returned as int). A bool is no number, though Python counts it as one."""
    kinds = (int,) if integer else (int, float)
    fits = not isinstance(value, bool) and isinstance(value, kinds) and math.isfinite(value)
    if fits and ((minimum is not None and value < minimum) or (maximum is not None and value > maximum)
                 or (above is not None and value <= above)):
        fits = False
    if not fits:
        bounds = [b for b in ('> %g' % above if above is not None else '',
                              '>= %g' % minimum if minimum is not None else '',
                              '<= %g' % maximum if maximum is not None else '') if b]
        raise _fail(name, value, ('a whole number' if integer else 'a number') +
                    (' ' + ' and '.join(bounds) if bounds else ''))
    return int(value) if integer else float(value)


def flag_param(value, name: str) -> bool:
    """true or false (a launch file's ``value="true"`` arrives as a bool; the command line's ``_x:=true`` too)."""
    if not isinstance(value, bool):
        raise _fail(name, value, 'true or false')
    return value


def text_param(value, name: str, choices: Sequence[str] = (), empty: bool = True) -> str:
    """A string; one of ``choices`` when given; not empty unless ``empty``."""
    if not isinstance(value, str) or (choices and value not in choices) or (not empty and not value):
        expected = 'one of %s' % ', '.join(repr(c) for c in choices) if choices else \
            'a string' + ('' if empty else ', not empty')
        raise _fail(name, value, expected)
    return value


def seconds(name: str, default: float) -> float:
    """The private (``~name``) or global (``/name``) parameter ``name``, as :func:`seconds_param`."""
    return seconds_param(_get(name, default), name)


def number(name: str, default: float, minimum: Optional[float] = None, maximum: Optional[float] = None,
           above: Optional[float] = None, integer: bool = False) -> float:
    """The parameter ``name``, as :func:`number_param`."""
    return number_param(_get(name, default), name, minimum, maximum, above, integer)


def flag(name: str, default: bool) -> bool:
    return flag_param(_get(name, default), name)


def text(name: str, default: str, choices: Sequence[str] = (), empty: bool = True) -> str:
    return text_param(_get(name, default), name, choices, empty)


def strings(name: str, default, separator: str = ',') -> List[str]:
    return list_param(_get(name, default), name, separator)
