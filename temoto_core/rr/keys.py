"""Request equality for sharing: every field except the ``trr`` header.

genpy messages compare every slot, header included, so two consumers asking for
the same sensor from different status topics would never share it. The key
below leaves ``trr`` out and compares ``diagnostic_msgs/KeyValue`` lists as
multisets, because topic maps are unordered in meaning.
"""
from typing import Any, Callable, Dict, Hashable

import genpy

HEADER_FIELD = 'trr'
KEYVALUE_TYPE = 'diagnostic_msgs/KeyValue'


def _value_key(value: Any) -> Hashable:
    if isinstance(value, genpy.Message):
        return message_key(value)
    if isinstance(value, (list, tuple)):
        if value and all(getattr(v, '_type', None) == KEYVALUE_TYPE for v in value):
            # what message_key gives each KeyValue, built directly: this list is in nearly every request
            return ('multiset',) + tuple(sorted((KEYVALUE_TYPE, v.key, v.value) for v in value))
        return tuple([_value_key(v) for v in value])
    if isinstance(value, (genpy.Time, genpy.Duration)):
        return (value.secs, value.nsecs)
    if isinstance(value, bytearray):
        return bytes(value)
    return value


_PLAIN = (str, int, float, bool, bytes)
_SLOTS: dict = {}


def message_key(msg: genpy.Message, skip: str = '') -> Hashable:
    """A hashable key of ``msg``'s fields, leaving out the field named ``skip``.

    This runs twice per load (client and server side), so plain fields, the
    common case, take a fast path.
    """
    cls = type(msg)
    slots = _SLOTS.get((cls, skip))
    if slots is None:
        slots = _SLOTS[(cls, skip)] = tuple(s for s in cls.__slots__ if s != skip)
    key = [msg._type]
    for slot in slots:
        value = getattr(msg, slot)
        key.append(value if type(value) in _PLAIN else _value_key(value))
    return tuple(key)


def request_key(request: genpy.Message) -> Hashable:
    """The default equality of resource requests (docs/architecture.md)."""
    return message_key(request, skip=HEADER_FIELD)


_KEYS: Dict[type, Callable[[genpy.Message], Hashable]] = {}


def register_key(request_class: type, key: Callable[[genpy.Message], Hashable]) -> None:
    """Make ``key`` the equality of every request of ``request_class``, on both sides of the wire.

    A manager's contract module calls this at import; its server and every client
    interface import that module, so the server shares exactly what a client
    shares (one rule, not two that drift apart). Registering a second, different
    key for one type is a bug, and raises.
    """
    known = _KEYS.get(request_class)
    if known is not None and known is not key:
        raise ValueError('request type %s already has the equality %s' % (request_class._type, known.__name__))
    _KEYS[request_class] = key


def key_of(request: genpy.Message) -> Hashable:
    """The equality key of ``request``: its type's registered key, else every field but the header."""
    key = _KEYS.get(type(request))
    return key(request) if key is not None else message_key(request, skip=HEADER_FIELD)


def key_function(request_class: type) -> Callable[[genpy.Message], Hashable]:
    """The key function that ``key_of`` uses for ``request_class``."""
    return _KEYS.get(request_class, request_key)
