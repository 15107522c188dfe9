"""Registrar concurrency: coalescing across processes, unload racing a load, and a randomised soak."""
import concurrent.futures
import random
import time

import pytest

from temoto_testing import wait_for
from rr_helpers import RegistrarNode, registry_empty


@pytest.fixture(scope='module')
def fleet(rospy_client, module_procs):
    """One server registrar and five client processes."""
    server = RegistrarNode(module_procs, 'rr_srv')
    clients = [RegistrarNode(module_procs, 'rr_cli%d' % i) for i in range(5)]
    return server, clients


def test_fifty_concurrent_equal_requests_from_five_processes_load_once(fleet):
    server, clients = fleet
    params = [('delay', '0.8')]   # every request arrives while the first is still loading
    with concurrent.futures.ThreadPoolExecutor(50) as pool:
        futures = [pool.submit(clients[i % 5].call, 'rr_srv', 'burst', params) for i in range(50)]
        results = [f.result(timeout=60) for f in futures]
    assert all('error' not in r for r in results), results
    assert {r['payload'] for r in results} == {'payload of burst from /rr_srv'}   # full, identical responses
    assert len({(i % 5, r['id']) for i, r in enumerate(results)}) == 50         # every call its own id
    assert server.counts()['loads'] == {'burst': 1}
    consumers = server.registry()['server_queries'][0]['consumers']
    assert len(consumers) == 5                                   # one remote reference per client process
    for i, r in enumerate(results):
        assert clients[i % 5].unload(r['id']) == {}
    assert server.counts()['unloads'] == {'burst': 1}
    for node in (server, *clients):
        assert registry_empty(node), node.registry()


def test_unload_while_another_consumer_loads_an_equal_request(fleet):
    server, clients = fleet
    a, b = clients[0], clients[1]
    held = a.call('rr_srv', 'race')
    assert server.counts()['loads'].get('race') == 1
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        loading = pool.submit(b.call, 'rr_srv', 'race')
        unloading = pool.submit(a.unload, held['id'])
        got, _ = loading.result(timeout=30), unloading.result(timeout=30)
    assert 'error' not in got
    counts = server.counts()
    # either B shared A's resource (1 load, 0 unloads) or A's went first (2 loads, 1 unload): never early, never leaked
    assert counts['loads']['race'] - counts['unloads'].get('race', 0) == 1
    reg = server.registry()['server_queries']
    assert len(reg) == 1 and len(reg[0]['consumers']) == 1 and reg[0]['state'] == 'active'
    b.unload(got['id'])
    assert server.counts()['loads']['race'] == server.counts()['unloads']['race']
    assert registry_empty(server)


def test_randomised_soak_keeps_the_invariants(fleet, procs):
    """500 operations: load, unload, fail, kill a consumer; invariants checked after every step."""
    server, clients = fleet
    rng = random.Random(20181026)
    names = ['s%d' % i for i in range(4)]
    held = {i: [] for i in range(len(clients))}          # client index -> [(id, name, generation)]
    generation = {name: 0 for name in names}             # a FAILED resource is never shared again
    for step in range(500):
        op = 'kill' if step == 250 else rng.choices(['load', 'unload', 'fail'], [5, 4, 1])[0]
        if op == 'load':
            ci, name = rng.randrange(len(clients)), rng.choice(names)
            res = clients[ci].call('rr_srv', name)
            assert 'error' not in res, (step, res)
            held[ci].append((res['id'], name, generation[name]))
        elif op == 'unload':
            pool = [ci for ci in held if held[ci]]
            if not pool:
                continue
            ci = rng.choice(pool)
            rid, _, _ = held[ci].pop(rng.randrange(len(held[ci])))
            assert clients[ci].unload(rid) == {}, step
        elif op == 'fail':
            live = {name for ci in held for _, name, gen in held[ci] if gen == generation[name]}
            if not live:
                continue
            name = rng.choice(sorted(live))
            before = {ci: len(clients[ci].events()) for ci in held}
            server.fail(name)
            holders = {ci for ci in held if any(n == name and g == generation[name] for _, n, g in held[ci])}
            generation[name] += 1
            # every holder of the failed resource hears about it
            for ci in holders:
                wait_for(lambda: len(clients[ci].events()) > before[ci], 10, 'FAILED at client %d (step %d)' % (ci, step))
        elif op == 'kill':
            doomed = RegistrarNode(procs, 'rr_doomed', check_period=0.5)
            res = doomed.call('rr_srv', 'doomed_res')
            assert 'error' not in res
            import os
            import signal
            os.killpg(doomed.process.pid, signal.SIGKILL)
            # the server releases the dead consumer's reference within the documented bound
            wait_for(lambda: server.counts()['unloads'].get('doomed_res') == 1, 2.0 + 1.0 + 5.0,
                     'release of the killed consumer')
        check_invariants(server, clients, held, step)
    for ci, entries in held.items():
        for rid, _, _ in entries:
            assert clients[ci].unload(rid) == {}
    for node in (server, *clients):
        assert registry_empty(node), node.registry()
    counts = server.counts()
    assert counts['loads'] == counts['unloads']


def check_invariants(server, clients, held, step):
    reg = server.registry()
    # server side: every consumer reference belongs to a live client query, counts match
    refs = {}
    for q in reg['server_queries']:
        assert q['state'] in ('active', 'failed'), (step, q)
        assert q['consumers'], ('dangling server entry without consumers', step, q)
        for c in q['consumers']:
            refs[c['resource_id']] = q
    remote_ids = set()
    for ci, client in enumerate(clients):
        creg = client.registry()
        local = sorted(i for q in creg['client_queries'] for i in q['local_ids'])
        assert local == sorted(rid for rid, _, _ in held[ci]), (step, ci, creg, client.command(op='events'))
        for q in creg['client_queries']:
            assert q['local_ids'], ('client query without holders', step)
            remote_ids.add(q['external_id'])
    assert remote_ids == set(refs), ('server references != client queries', step)


def test_calls_to_one_server_of_different_resources_run_in_parallel(fleet):
    server, clients = fleet
    t0 = time.monotonic()
    with concurrent.futures.ThreadPoolExecutor(4) as pool:
        futures = [pool.submit(clients[i].call, 'rr_srv', 'par%d' % i, [('delay', '1.0')]) for i in range(4)]
        results = [f.result(timeout=30) for f in futures]
    elapsed = time.monotonic() - t0
    assert all('error' not in r for r in results)
    assert elapsed < 3.5, 'four 1 s loads took %.1f s: loads of different resources are serialised' % elapsed
    for i, r in enumerate(results):
        clients[i].unload(r['id'])
