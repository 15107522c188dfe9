"""The owner state a registrar keeps across its crash, indexed by resource (rr/owner_state.py), and the
record a consumer keeps of a resource (backup.record): pure logic; the cross-process recovery that uses
both is in test_er_recovery.py and test_manager_recovery.py."""
import json
import threading

from temoto_core.rr.backup import record
from temoto_core.rr.owner_state import OwnerState, resource_of
from temoto_core.rr.query import ACTIVE, ClientQuery, Server, ServerQuery
from temoto_core.srv import LoadTestResource

Req, Res = LoadTestResource._request_class, LoadTestResource._response_class


def test_only_a_key_ending_in_an_id_belongs_to_a_resource():
    assert resource_of('pid/17') == 17
    assert resource_of('pid/start/17') == 17
    assert resource_of('reliability/front_camera') is None
    assert resource_of('pid/-3') is None
    assert resource_of('17') == 17


def test_the_keys_of_one_resource_are_found_and_forgotten_with_it():
    state = OwnerState({'pid/1': '100', 'start/1': '5.0', 'pid/11': '101', 'reliability/cam': '0.9'})
    assert state.of_resource(1) == {'pid/1': '100', 'start/1': '5.0'}      # not pid/11: ids are not suffixes
    assert state.of_resource(11) == {'pid/11': '101'}
    state['pid/1'] = '200'
    assert state.of_resource(1)['pid/1'] == '200'
    assert state.pop('pid/1') == '200' and state.pop('start/1') == '5.0'
    assert state.of_resource(1) == {}
    assert state.pop('pid/1') is None                                       # gone already: no error
    assert state.as_dict() == {'pid/11': '101', 'reliability/cam': '0.9'}
    assert 'reliability/cam' in state and len(state) == 2


def test_records_are_built_while_the_owner_writes_its_state():
    state = OwnerState()
    errors = []

    def writer():
        try:
            for i in range(20000):
                state['pid/%d' % (i % 50)] = str(i)
                if i % 3 == 0:
                    state.pop('pid/%d' % (i % 50))
        except Exception as err:      # pragma: no cover - the failure this test looks for
            errors.append(err)
    thread = threading.Thread(target=writer)
    thread.start()
    for _ in range(20000):
        state.of_resource(7)
        if not thread.is_alive():
            break
    thread.join(30)
    assert not thread.is_alive() and errors == []


def _active_client_query(external_id: int, name: str) -> ClientQuery:
    request = Req(name=name)
    request.trr.client_name = '/rr_b'
    query = ClientQuery(('temoto', 'rr_c', 'load_test'), name, request)
    query.response = Res(payload='from c')
    query.response.trr.resource_id = external_id
    query.external_id = external_id
    query.move(ACTIVE)
    return query


def test_a_record_carries_its_links_and_only_its_own_owner_state():
    server = Server('load_test', LoadTestResource, lambda req, res: None, lambda req, res: None, lambda req: req.name)
    served = ServerQuery(server, 'k', 7, Req(name='top'))
    held = _active_client_query(5, 'below')
    served.links = [11, 12]                                   # 12 is gone meanwhile: left out
    state = OwnerState({'pid/7': '100', 'pid/70': '200', 'reliability/x': '1'})
    out = json.loads(record(served, {11: held}, state))
    assert out['internal_id'] == 7
    assert out['owner_state'] == {'pid/7': '100'}
    assert [(link['local_id'], link['external_id'], link['target']) for link in out['links']] == \
        [(11, 5, ['temoto', 'rr_c', 'load_test'])]
    assert set(out['links'][0]) == {'local_id', 'target', 'external_id'}, \
        'a link is named: its request and response are at its own owner'
