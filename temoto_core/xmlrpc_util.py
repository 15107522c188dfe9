"""XML-RPC to the master and to nodes, with a timeout.

``xmlrpc.client`` waits forever by default, and a node that is SIGSTOPped or
wedged would then hang whoever asks it (a liveness check, a registration
check). Every XML-RPC call the project makes goes through :func:`proxy`.
"""
import xmlrpc.client


class TimeoutTransport(xmlrpc.client.Transport):
    """An HTTP transport whose connections time out after ``timeout`` seconds."""

    def __init__(self, timeout: float) -> None:
        super().__init__()
        self._timeout = timeout

    def make_connection(self, host):
        conn = super().make_connection(host)
        conn.timeout = self._timeout
        return conn


def proxy(uri: str, timeout: float) -> xmlrpc.client.ServerProxy:
    return xmlrpc.client.ServerProxy(uri, transport=TimeoutTransport(timeout), allow_none=True)
