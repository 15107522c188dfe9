"""A display's `config`: RViz properties as YAML, applied all-or-nothing.

The keys are the property labels of the RViz GUI, exactly as they appear in a
saved .rviz file (``Color``, ``Size (Pixels)``, ``Decay Time``...). A nested
mapping addresses sub-properties (``Autocompute Value Bounds: {Max Value: 2}``)
and its ``Value`` key sets the parent's own value. Colours and vectors may be
given as lists (``[255, 0, 0]``) or as RViz strings (``"255; 0; 0"``).

RViz never complains: an unknown property name returns a silent "failure"
property and a bad value is often ignored. So every key is looked up among the
real children first, values are type-checked against the current value, and if
any step fails the properties already changed are restored.

Works on anything with the rviz.Property interface (numChildren, childAt,
getName, getValue, setValue), so it is testable without RViz.
"""
from __future__ import annotations

from numbers import Real
from typing import Any, Dict, List, Optional, Tuple

import yaml


class DisplayConfigError(ValueError):
    """Bad config YAML, an unknown property, or a value the property refuses."""


def parse_config(text: str) -> Dict[str, Any]:
    """YAML text → mapping of property label → value. Empty text is an empty config."""
    if text is None or not text.strip():
        return {}
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise DisplayConfigError('config is not valid YAML: %s' % str(e).replace('\n', ' ')) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise DisplayConfigError('config must be a YAML mapping of RViz property names to values, got %s'
                                 % type(data).__name__)
    return data


def with_defaults(defaults: Dict[str, Any], text: str) -> str:
    """``text``'s config over ``defaults``, as YAML text: the request's own properties win."""
    merged = dict(defaults)
    merged.update(parse_config(text))
    return yaml.safe_dump(merged, default_flow_style=True, sort_keys=False).strip() if merged else ''


def flatten(config: Dict[str, Any], prefix: Tuple[str, ...] = ()) -> List[Tuple[Tuple[str, ...], Any]]:
    """Nested mapping → [(property path, value)] in the given order."""
    items = []
    for key, value in config.items():
        if not isinstance(key, str) or not key:
            raise DisplayConfigError('config keys must be property names (strings), got %r' % (key,))
        if key == 'Value' and prefix:
            items.append((prefix, value))
        elif isinstance(value, dict):
            items.extend(flatten(value, prefix + (key,)))
        else:
            items.append((prefix + (key,), value))
    return items


def to_property_value(value: Any) -> Any:
    """YAML value → what rviz.Property.setValue accepts (lists become "a; b; c")."""
    if isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (list, tuple)) and value and all(
            isinstance(v, Real) and not isinstance(v, bool) for v in value):
        return ';'.join('%g' % v for v in value)
    raise DisplayConfigError('unsupported value %r: use a number, a boolean, a string or a list of numbers'
                             % (value,))


def child(prop, name: str):
    """The child property called ``name`` or None. (rviz's subProp logs an ERROR for a miss.)"""
    for i in range(prop.numChildren()):
        c = prop.childAt(i)
        if c is not None and c.getName() == name:
            return c
    return None


def child_names(prop) -> List[str]:
    names = []
    for i in range(prop.numChildren()):
        n = prop.childAt(i).getName()
        if not n.startswith('Status'):
            names.append(n)
    return names


def resolve(root, path: Tuple[str, ...]):
    prop = root
    for depth, name in enumerate(path):
        nxt = child(prop, name)
        if nxt is None:
            where = '/'.join(path[:depth]) or 'the display'
            raise DisplayConfigError("unknown property '%s' in %s; known: %s"
                                     % ('/'.join(path[:depth + 1]), where, ', '.join(child_names(prop))))
        prop = nxt
    return prop


def _check_type(path: Tuple[str, ...], current: Any, value: Any) -> None:
    label = '/'.join(path)
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise DisplayConfigError("property '%s' expects true or false, got %r" % (label, value))
    elif isinstance(current, Real):
        if isinstance(value, bool) or not isinstance(value, Real):
            raise DisplayConfigError("property '%s' expects a number, got %r" % (label, value))


def same_value(a: Any, b: Any) -> bool:
    """RViz stores floats as float32 and formats lists with "; ": compare loosely."""
    if isinstance(a, Real) and isinstance(b, Real) and not isinstance(a, bool) and not isinstance(b, bool):
        return abs(float(a) - float(b)) <= 1e-5 * max(1.0, abs(float(b)))
    if isinstance(a, str) and isinstance(b, str):
        pa, pb = a.split(';'), b.split(';')
        if len(pa) == len(pb) > 1:
            try:
                return all(same_value(float(x), float(y)) for x, y in zip(pa, pb))
            except ValueError:
                pass
        return a.replace(' ', '') == b.replace(' ', '')
    return a == b


def apply_config(root, config: Dict[str, Any], display_value_key: str = 'Enabled') -> List[str]:
    """Apply ``config`` to the property tree under ``root``; all-or-nothing.

    ``Enabled`` (the display's own check box) is accepted at the top level.
    Returns the labels that were set.
    """
    items = flatten(config)
    plan = []
    for path, raw in items:          # validate everything before touching anything
        prop = root if path == (display_value_key,) else resolve(root, path)
        value = to_property_value(raw)
        _check_type(path, prop.getValue(), value)
        plan.append((path, prop, value))
    undo = []
    try:
        for path, prop, value in plan:
            old = prop.getValue()
            if not prop.setValue(value) and not same_value(prop.getValue(), value):
                raise DisplayConfigError("property '%s' refused value %r" % ('/'.join(path), value))
            undo.append((prop, old))
    except DisplayConfigError:
        for prop, old in reversed(undo):
            prop.setValue(old)
        raise
    return ['/'.join(p) for p, _, _ in plan]


def snapshot(root, max_depth: int = 3) -> List[Tuple[Tuple[str, ...], Any]]:
    """Every (path, value) below ``root`` with a plain value; used to reset a reused display."""
    out: List[Tuple[Tuple[str, ...], Any]] = []

    def walk(prop, path, depth):
        for i in range(prop.numChildren()):
            c = prop.childAt(i)
            name = c.getName()
            if name.startswith('Status'):
                continue
            value = c.getValue()
            if isinstance(value, (bool, int, float, str)):
                out.append((path + (name,), value))
            if depth < max_depth:
                walk(c, path + (name,), depth + 1)

    walk(root, (), 1)
    return out


def restore(root, values: List[Tuple[Tuple[str, ...], Any]]) -> None:
    for path, value in values:
        try:
            prop = resolve(root, path)
        except DisplayConfigError:
            continue
        if prop.getValue() != value:
            prop.setValue(value)
