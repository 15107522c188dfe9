"""A host cut off from the master still reaches its own nodes' services: the URIs the master gave are
remembered, and a sibling's URI stands for a service of the same node (``temoto_core/service_uris.py``).
Across processes this is the two-host demo's partition stage (test_demo)."""
import time

import pytest

from temoto_core import service_uris


@pytest.fixture
def no_master(monkeypatch):
    """A master URI on which nothing listens: every look-up fails at once with a refused connection."""
    monkeypatch.setenv('ROS_MASTER_URI', 'http://127.0.0.1:9/')
    monkeypatch.setattr(service_uris, '_uris', {})


def test_with_no_master_and_nothing_known_the_lookup_fails_within_its_deadline(no_master):
    t0 = time.monotonic()
    with pytest.raises(OSError):
        service_uris.lookup('/ns/node/load', time.monotonic() + 2.0)
    assert time.monotonic() - t0 < 2.0 + 1.0


def test_with_no_master_a_known_uri_and_a_siblings_are_used(no_master):
    service_uris.remember('/ns/node/load', 'rosrpc://198.18.0.2:4000')
    assert service_uris.lookup('/ns/node/load', time.monotonic() + 1.0) == 'rosrpc://198.18.0.2:4000'
    # never looked up, but served by the same node
    assert service_uris.lookup('/ns/node/unload', time.monotonic() + 1.0) == 'rosrpc://198.18.0.2:4000'
    with pytest.raises(OSError):
        service_uris.lookup('/ns/other/unload', time.monotonic() + 1.0)


def test_a_global_service_has_no_sibling(no_master):
    service_uris.remember('/a', 'rosrpc://198.18.0.2:4000')
    with pytest.raises(OSError):
        service_uris.lookup('/b', time.monotonic() + 1.0)
