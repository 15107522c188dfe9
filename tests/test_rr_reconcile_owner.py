"""A consumer that follows its owner to a new incarnation reads the owner's registry for the FAILEDs it never
heard (client_side.reconcile_with): the logic alone, the owner's registry given as its JSON (or its read
failing). The cross-process case is test_rr_recovery.py."""
import json
import logging
from types import SimpleNamespace

from temoto_core.errors import ErrorCode, Subsystem
from temoto_core.msg import RMPRequest
from temoto_core.rr.client_side import ClientSide
from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.query import ACTIVE, ClientQuery, HeldQueries
from temoto_core.srv import GetRegistryResponse

TARGET = ('chaos', 'temoto_context_manager', 'track_object')
ME = RMPRequest(client_name='/chaos_client_2', client_uri='http://station:1/')


def side_holding(external_id, registry):
    heard = []
    lost = SimpleNamespace(lost=lambda target, external_id, message: heard.append((target, external_id, message)))
    side = ClientSide(RegistrarCore('rr_t', 'chaos', Subsystem.CORE), None, HeldQueries(), ME, None, lost)
    query = ClientQuery(TARGET, 'hand', None)
    query.external_id, query.state = external_id, ACTIVE
    side.by_external[(TARGET, external_id)] = query
    side.invoke = lambda service, request, seconds, watched=True: GetRegistryResponse(json=json.dumps(registry))
    return side, heard


def registry(recovering):
    """While it recovers, the entry is back as it was (active); once its sub-resource is found lost, failed."""
    return {'recovering': recovering, 'server_queries': [
        {'server': 'track_object', 'state': 'active' if recovering else 'failed',
         'failure': '' if recovering else 'its tracker could not be recovered',
         'consumers': [{'client_name': ME.client_name, 'client_uri': ME.client_uri, 'resource_id': 7}]}]}


def test_a_failed_entry_of_an_owner_still_recovering_is_read_again_later_and_then_delivered():
    """Seed 17, two hosts, step 4778: the robot lost power; the Context Manager's new incarnation gave the
    tracked object back (a neighbour's copy), then found its tracker lost and sent the FAILED before the client
    had joined the new master. The client had read the registry a moment before, while it was still being
    rebuilt, found nothing failed, and never read it again."""
    side, heard = side_holding(7, registry(recovering=True))
    assert side.reconcile_with(('chaos', 'temoto_context_manager'), lambda: True) is False     # later
    assert heard == []
    side.invoke = lambda service, request, seconds, watched=True: GetRegistryResponse(json=json.dumps(registry(False)))
    assert side.reconcile_with(('chaos', 'temoto_context_manager'), lambda: True) is True
    assert heard == [(TARGET, 7, '/chaos/temoto_context_manager/track_object: FAILED at its owner (its tracker could '
                                 'not be recovered); its status never reached this node')]


def test_a_registry_that_cannot_be_read_is_a_warning_and_read_again_later(rospy_client, caplog):
    """Seed 17, two hosts, step 6429: a stray reference stayed at the Context Manager after a cut call, and
    the client's log said nothing of its reconciliation, whose failed reads were debug lines. (A node: the
    warning is throttled on ROS time.)"""
    side, heard = side_holding(7, registry(recovering=False))

    def unreadable(service, request, seconds, watched=True):
        raise side._core.error(ErrorCode.SERVICE_REQ_FAIL, 'service %s is not tried: it is lost' % service)
    side.invoke = unreadable
    with caplog.at_level(logging.WARNING, logger='rosout'):
        assert side.reconcile_with(('chaos', 'temoto_context_manager'), lambda: True) is False     # later
    assert heard == []
    assert 'could not read /chaos/temoto_context_manager/registry to reconcile with it: service ' \
           '/chaos/temoto_context_manager/registry is not tried: it is lost' in caplog.text, caplog.text


def test_a_stray_whose_release_does_not_reach_the_owner_leaves_the_owner_to_be_read_again(rospy_client):
    """A stray found in the owner's registry is released by an unload; an owner that died or was cut off
    between the read and the unload has not let it go, so the reconciliation is not done."""
    snapshot = {'server_queries': [{'server': 'track_object', 'state': 'active', 'failure': '', 'consumers': [
        {'client_name': ME.client_name, 'client_uri': ME.client_uri, 'resource_id': 8}]}]}
    side, heard = side_holding(7, snapshot)
    sent = []

    def unload(target, external_id):
        sent.append((target, external_id))
        return len(sent) > 1                   # the first unload does not reach the owner; the second does
    side.resend_unload = unload
    assert side.reconcile_with(('chaos', 'temoto_context_manager'), lambda: True) is False     # read again
    assert side.reconcile_with(('chaos', 'temoto_context_manager'), lambda: True) is True
    assert sent == [(TARGET, 8), (TARGET, 8)] and heard == []
