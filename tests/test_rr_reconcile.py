"""The journal checked against the neighbours' copies at a restart (backup.reconcile): pure logic; the
cross-process cases are in test_rr_recovery.py."""
from temoto_core.rr.backup import NO_PARENT, Kept, parse_record, reconcile
from temoto_core.rr.journal import JournalContents, JournaledConsumer, JournaledHold, JournaledServed

A, B, C = '/temoto/rr_a/status', '/temoto/rr_b/status', '/temoto/rr_c/status'


def consumer(ext, topic, uri='http://old:1/'):
    return JournaledConsumer(ext, topic, '/node_' + topic.split('/')[2], 'temoto', uri, 1)


def served(internal_id, *consumers):
    return JournaledServed(internal_id, 'load_test', 'active', 'temoto_core/LoadTestResourceRequest', b'q', b'r',
                           list(consumers))


def hold(local_id, external_id, parent):
    return JournaledHold(local_id, ('temoto', 'rr_z', 'load_test'), external_id, 'temoto_core/LoadTestResourceRequest',
                         b'q', b'r', parent)


def test_a_consumer_that_answered_and_holds_nothing_is_stale_one_that_did_not_answer_stays():
    journal = JournalContents([served(1, consumer(11, A), consumer(12, B), consumer(13, C))], [])
    kept = Kept(JournalContents([served(1, consumer(11, A, uri='http://new:2/'))], []), {}, {A, B})
    out = reconcile(journal, kept)
    assert out.stale == [('load_test', 12)]                      # B answered without it
    by_ext = {c.external_id: c for c in out.contents.served[0].consumers}
    assert set(by_ext) == {11, 12, 13}                           # the stale one stays, for the recovery to release
    assert by_ext[11].uri == 'http://new:2/'                     # the neighbour's record is the fresher one
    assert by_ext[13].uri == 'http://old:1/'                     # C did not answer: the journal's word stands


def test_what_the_journal_lacks_comes_back_from_the_neighbours_and_nothing_is_doubled():
    journal = JournalContents([served(1, consumer(11, A))], [hold(5, 50, 1)])
    kept = Kept(JournalContents([served(1, consumer(11, A), consumer(14, B)), served(2, consumer(21, A))],
                                [hold(5, 50, 1), hold(6, 60, 2), hold(99, 90, NO_PARENT)]), {}, {A, B})
    out = reconcile(journal, kept)
    assert [e.internal_id for e in out.contents.served] == [1, 2]
    assert sorted(c.external_id for c in out.contents.served[0].consumers) == [11, 14]
    assert sorted(h.external_id for h in out.contents.holds) == [50, 60, 90]
    assert (out.added_served, out.added_holds, out.stale) == (1, 2, [])


def test_a_recovering_neighbour_is_not_asked_to_judge():
    journal = JournalContents([served(1, consumer(11, A))], [])
    out = reconcile(journal, Kept(JournalContents([], []), {}, set()))
    assert out.stale == [] and out.contents.served[0].consumers[0].external_id == 11


def test_a_hold_whose_link_the_journal_lacks_takes_the_parent_the_record_names():
    # held with link=False, then linked: the SIGKILL came between the two commits
    journal = JournalContents([], [hold(5, 50, None), hold(7, 70, None)])
    kept = Kept(JournalContents([served(1, consumer(11, A))], [hold(5, 50, 1)]), {}, {A})
    out = reconcile(journal, kept)
    assert {h.local_id: h.parent for h in out.contents.holds} == {5: 1, 7: None}   # 7 is on its own account
    assert out.added_holds == 0


Z = ('temoto', 'rr_z', 'load_test')


def test_a_link_nobody_gives_back_fails_its_resource_unless_the_journal_has_it():
    journal = JournalContents([], [hold(5, 50, 1)])
    kept = Kept(JournalContents([served(1, consumer(11, A)), served(2, consumer(21, A))], []), {}, {A},
                unfound=[(1, Z, 50), (2, Z, 60)])
    out = reconcile(journal, kept)
    assert list(out.lost) == [2]                                 # 50 is in the journal: resource 1 is whole
    assert '/temoto/rr_z/load_test 60' in out.lost[2] and 'could not be recovered' in out.lost[2]


def test_a_record_from_the_wire_is_checked_before_it_is_used():
    good = '{"v":2,"internal_id":7,"links":[{"local_id":3,"target":["temoto","rr_z","load_test"],"external_id":9}],' \
           '"owner_state":{"pid/7":"100"}}'
    assert parse_record(good, A) == (7, [(3, Z, 9)], {'pid/7': '100'})
    assert parse_record('', A) == (None, [], {})
    for bad in ('not json', '[1]', '{"internal_id": true}', '{"internal_id": -4}',
                '{"internal_id": 7, "links": [{"local_id": "3", "target": ["a", "b", "c"], "external_id": 9}]}',
                '{"internal_id": 7, "links": [{"local_id": 3, "target": ["a", "b"], "external_id": 9}]}',
                '{"internal_id": 7, "links": [{"target": ["a", "b", "c"], "external_id": 9}]}'):
        assert parse_record(bad, A) == (None, [], {}), bad
