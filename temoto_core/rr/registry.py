"""A registrar's registry as plain data: what ``registry()`` returns, what the
``/<ns>/<rr>/registry`` service sends as JSON, and what ``temoto registry`` prints.

Requests and responses are kept both as readable YAML-ish dicts (for people)
and as their serialised bytes in base64 (so a snapshot can be turned back into
the exact messages, which is what a later backup or recovery needs).
"""
import base64
import dataclasses
import io
import json
from typing import Dict, List, Optional

import genpy


def encode_message(msg: genpy.Message) -> Dict[str, str]:
    buf = io.BytesIO()
    msg.serialize(buf)
    return {'type': msg._type, 'data': base64.b64encode(buf.getvalue()).decode('ascii')}


def decode_message(encoded: Dict[str, str], msg_class) -> genpy.Message:
    msg = msg_class()
    msg.deserialize(base64.b64decode(encoded['data']))
    return msg


def readable(msg: genpy.Message) -> dict:
    """A JSON-friendly dict of a message, for display only."""
    out = {}
    for slot in msg.__slots__:
        value = getattr(msg, slot)
        if isinstance(value, genpy.Message):
            out[slot] = readable(value)
        elif isinstance(value, (list, tuple)):
            out[slot] = [readable(v) if isinstance(v, genpy.Message) else v for v in value]
        elif isinstance(value, (genpy.Time, genpy.Duration)):
            out[slot] = value.to_sec()
        elif isinstance(value, bytes):
            out[slot] = '<%d bytes>' % len(value)
        else:
            out[slot] = value
    return out


@dataclasses.dataclass
class ConsumerEntry:
    resource_id: int          # the consumer's external id
    status_topic: str
    client_name: str
    namespace: str
    client_uri: str = ''      # the consumer node's XML-RPC URI: with client_name, its incarnation


@dataclasses.dataclass
class ServerEntry:
    server: str
    internal_id: int
    state: str                # loading | active | failed | unloading
    consumers: List[ConsumerEntry]
    links: List[int]          # local ids of sub-resources loaded for this resource
    request: Dict[str, str]   # encode_message()
    response: Optional[Dict[str, str]]
    summary: dict             # readable() of request fields other than trr
    details: dict             # readable() of response fields other than trr (pid, topics, ...)
    failure: str = ''
    record: str = ''          # the owner's record its consumers keep (P2P backup, ``rr/backup.py``)


@dataclasses.dataclass
class ClientEntry:
    target: str               # /<ns>/<rr>/<server>
    external_id: int
    state: str                # loading | active | failed
    local_ids: List[int]
    linked_to: List[int]      # internal ids of this registrar's server queries that link it
    request: Dict[str, str]
    response: Optional[Dict[str, str]]
    summary: dict


@dataclasses.dataclass
class RegistrySnapshot:
    name: str
    namespace: str
    node: str
    servers: List[str]
    server_queries: List[ServerEntry]
    client_queries: List[ClientEntry]
    recovering: bool = False  # a restarted registrar that has not finished taking its registry back
    incarnation: int = 0      # the registrar's incarnation (0: it keeps no journal)
    # loads being served right now, per consumer incarnation: [client name, client URI, how many]
    calls_in_flight: List[list] = dataclasses.field(default_factory=list)

    def to_json(self, indent: Optional[int] = None) -> str:
        return json.dumps(dataclasses.asdict(self), indent=indent, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> 'RegistrySnapshot':
        raw = json.loads(text)
        raw['server_queries'] = [ServerEntry(**dict(q, consumers=[ConsumerEntry(**c) for c in q['consumers']]))
                                 for q in raw['server_queries']]
        raw['client_queries'] = [ClientEntry(**q) for q in raw['client_queries']]
        return cls(**raw)

    def is_empty(self) -> bool:
        return not self.server_queries and not self.client_queries
