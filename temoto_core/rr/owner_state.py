"""What a registrar's owner keeps across its own crash, indexed by the resource it belongs to.

A key ``<kind>/<internal id>`` (the ER Manager's ``pid/17``) belongs to served
resource 17 and travels with that resource's record to its consumers
(``backup.py``); any other key (a sensor's reliability history) is only in the
journal. The record is built for every load a journaling registrar answers, so
the keys of one resource are found by its id, not by a scan of every key: with
ten thousand processes under one ER Manager, a scan of every key cost 1.4 ms per load.

The owner writes its state from its own threads while service threads build
records, so every access takes the mapping's lock.
"""
import threading
from typing import Dict, Optional, Set


def resource_of(key: str) -> Optional[int]:
    """The internal id a key ``<kind>/<internal id>`` belongs to; None for a key of no resource."""
    _, _, tail = key.rpartition('/')
    return int(tail) if tail.isdigit() else None


class OwnerState:
    """A ``str -> str`` mapping that also knows the keys of each resource."""

    def __init__(self, items: Optional[Dict[str, str]] = None) -> None:
        self._lock = threading.Lock()
        self._values: Dict[str, str] = {}
        self._by_resource: Dict[int, Set[str]] = {}
        for key, value in (items or {}).items():
            self[key] = value

    def __setitem__(self, key: str, value: str) -> None:
        resource = resource_of(key)
        with self._lock:
            self._values[key] = value
            if resource is not None:
                self._by_resource.setdefault(resource, set()).add(key)

    def pop(self, key: str) -> Optional[str]:
        resource = resource_of(key)
        with self._lock:
            value = self._values.pop(key, None)
            keys = self._by_resource.get(resource) if resource is not None else None
            if keys is not None:
                keys.discard(key)
                if not keys:
                    del self._by_resource[resource]
        return value

    def __contains__(self, key: object) -> bool:
        with self._lock:
            return key in self._values

    def __len__(self) -> int:
        with self._lock:
            return len(self._values)

    def as_dict(self) -> Dict[str, str]:
        with self._lock:
            return dict(self._values)

    def of_resource(self, internal_id: int) -> Dict[str, str]:
        """The keys of served resource ``internal_id``, with their values."""
        with self._lock:
            return {key: self._values[key] for key in sorted(self._by_resource.get(internal_id, ()))}
