"""What the registrar's sides tell its journal: one call per change of the registry.

Without a journal every call is a no-op, so the sides never ask whether there is
one. Calls are made with the registrar's lock held, so the journal sees changes
in the order the registry made them.
"""
import io
from typing import Optional

from temoto_core.rr.journal import Journal, JournaledConsumer
from temoto_core.rr.query import ClientQuery, Consumer, ServerQuery


def serialized(msg) -> bytes:
    buf = io.BytesIO()
    msg.serialize(buf)
    return buf.getvalue()


def journaled(consumer: Consumer, external_id: int) -> JournaledConsumer:
    return JournaledConsumer(external_id, consumer.status_topic, consumer.client_name, consumer.namespace,
                             consumer.uri, consumer.incarnation)


class Recorder:
    def __init__(self, journal: Optional[Journal] = None) -> None:
        self.journal = journal

    def attached(self, query: ServerQuery, external_id: int, consumer: Consumer) -> None:
        if self.journal is None:
            return
        if len(query.consumers) == 1:
            self.journal.serve(query.internal_id, query.server.name, query.request._type, serialized(query.request),
                               serialized(query.response), external_id, journaled(consumer, external_id))
        else:
            self.journal.attach(query.server.name, query.internal_id, journaled(consumer, external_id))

    def reattached(self, query: ServerQuery, external_id: int, consumer: Consumer) -> None:
        """A consumer's new incarnation took its resource back (new URI, status topic, incarnation)."""
        if self.journal is not None:
            self.journal.attach(query.server.name, query.internal_id, journaled(consumer, external_id))

    def detached(self, server_name: str, external_id: int) -> None:
        if self.journal is not None:
            self.journal.detach(server_name, external_id)

    def failed(self, query: ServerQuery) -> None:
        if self.journal is not None:
            self.journal.mark(query.internal_id, query.state.value)

    def gone(self, query: ServerQuery) -> None:
        if self.journal is not None:
            self.journal.unserve(query.internal_id)

    def held(self, local_id: int, query: ClientQuery, parent: Optional[ServerQuery]) -> None:
        if self.journal is not None:
            self.journal.hold(local_id, query.target, query.external_id, query.request._type,
                              serialized(query.request), serialized(query.response),
                              parent.internal_id if parent is not None else None)

    def linked(self, local_id: int, parent: ServerQuery) -> None:
        if self.journal is not None:
            self.journal.link(local_id, parent.internal_id)

    def released(self, local_id: int) -> None:
        if self.journal is not None:
            self.journal.release(local_id)
