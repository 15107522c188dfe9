"""Owner liveness: the registrars this one holds resources from, or is calling, are watched, so that a
partition, a dead host or a stopped process is found within a bound and reported, never waited out.

An owner is a node incarnation: its name, its XML-RPC URI and its incarnation, as
every response says (``RMPResponse.owner_*``; for a call still in flight, from the
connection: rospy's TCPROS header names the node serving the service). One thread
per owner asks it ``getPid`` every ``period`` (the consumer side's
``liveness.ConsumerWatch`` does the same for consumers):

- it answers: alive;
- no answer for ``bound`` seconds, and its host does not take a connection (a
  partition, a dead host): **lost**; if its host does (the process holds its
  port: busy, or SIGSTOPped), lost after ``busy_bound`` seconds;
- its connection is refused (its host answers, the process is gone): an owner
  that keeps a journal (incarnation > 0) is being respawned and takes its
  registry back (``recovery.py``), so it is given ``grace`` seconds, and is
  followed to its new URI when the master has one that answers. One that keeps
  no journal lost everything it served: **lost** at once. One that has not
  answered this side yet (only called, or owed an unload) may keep a journal:
  it is handled as one that does.

**Lost** means: every call in flight to that owner is cut (``deadlines.py``), and
every resource held from it is handled as a FAILED arriving from it, so that the
holders' policies run (a failover, or the action ending FAILED). A resource that
failed stays failed until it is requested again.

An unload that could not reach its owner is *owed*: the owner stays watched, and
the unload is sent again as soon as the owner answers (after a partition heals,
or once a respawned owner is back), so that no reference leaks at the owner. An
owner that says it no longer knows the resource has settled the debt too.

An owner may also hold references this side never learnt of: a load it answered
after the caller's deadline had cut the call, or anything from before a
partition. Such an owner is *suspect*; once it answers and no call to it is in
flight, its registry is read, and whatever it says this node incarnation holds
that this side does not know of is released (``ClientSide.reconcile_with``). So is an owner that comes
back as a new incarnation; and whatever its registry says has FAILED for this node, while this side never
heard the status, is handled as that FAILED arriving now (a status is a topic message, and one sent before
this node could connect to the new incarnation is lost).
"""
import http.client
import threading
import time
import xmlrpc.client
from typing import Callable, Dict, List, Optional, Set, Tuple

import rosgraph
import rospy

from temoto_core.rr.core import RegistrarCore
from temoto_core.rr.deadlines import WATCH
from temoto_core.rr.liveness import accepts, ping
from temoto_core.rr.query import ACTIVE, Target, target_name
from temoto_core.xmlrpc_util import proxy as xmlrpc_proxy

DEFAULT_PERIOD = 0.15
DEFAULT_BOUND = 0.7
# an owner whose node still accepts connections (its host is up, its process holds its port) but does not
# answer is busy (a node with ten thousand resources and a thousand new consumers was silent for 0.8 s) or
# stopped: it is given this long before it is lost
DEFAULT_BUSY_BOUND = 3.0
# how long a connect to a silent owner may take; a cut link takes it all (detection must stay within 1 s)
ACCEPT_TIMEOUT = 0.1
# an owner that answers, while this node holds something from it, and whose statuses have had no way here
# (no connection from it on this node's status topic) for this long: see OwnerWatch._hear
UNHEARD_BOUND = 1.0
UNHEARD_RETRY_S = 2.0      # seconds between two attempts to hear an owner again
RECONCILE_SPACING = 0.5    # seconds between two reads of a suspect owner's registry
# a request whose caller gave up may still reach its owner this long after: TCP sends a request caught in
# a cut link again with a growing backoff (after a 3 s cut, up to about 6 s after it was first sent), and a
# stopped owner reads it when it runs again. The owner's registry is read again until then (chaos seed 17,
# step 2437: a tracker load arrived after the one read that found nothing, and leaked)
LATE_REQUEST_S = 10.0


class _SharedVerdicts:
    """The last verdict on each owner URI, shared by every registrar of this process.

    Each registrar watches its own owners; a process with many registrars (an
    action engine, a benchmark with a thousand consumers) would otherwise ask the
    same owner once per registrar per period, and a thousand asks every 0.15 s
    filled the owner's listen backlog (128), so that it looked cut off. A verdict
    younger than ``max_age`` is reused, and while one ask of an owner is under
    way, every other registrar waits for its answer instead of asking too.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._verdicts: Dict[Tuple[str, str], Tuple[float, object]] = {}
        self._asking: Dict[Tuple[str, str], threading.Event] = {}

    def get(self, kind: str, uri: str, max_age: float, ask: Callable[[], object], wait: float,
            default: object) -> object:
        """The verdict of ``kind`` on ``uri``: a fresh one, the one under way (waited for at most ``wait``
        seconds, ``default`` if it takes longer), or ``ask()``."""
        key = (kind, uri)
        with self._lock:
            known = self._verdicts.get(key)
            if known is not None and time.monotonic() - known[0] < max_age:
                return known[1]
            under_way = self._asking.get(key)
            if under_way is None:
                self._asking[key] = threading.Event()
        if under_way is not None:
            if not under_way.wait(wait):
                return default
            with self._lock:
                known = self._verdicts.get(key)
            return known[1] if known is not None else default
        verdict = default
        try:
            verdict = ask()
        finally:
            with self._lock:
                self._verdicts[key] = (time.monotonic(), verdict)
                self._asking.pop(key).set()
                if len(self._verdicts) > 4096:                  # old URIs of nodes long gone
                    cutoff = time.monotonic() - 60.0
                    self._verdicts = {k: v for k, v in self._verdicts.items() if v[0] > cutoff}
        return verdict


_SHARED = _SharedVerdicts()


class Owner:
    """What is known of one owner incarnation (guarded by the watch's lock)."""
    __slots__ = ('node', 'uri', 'incarnation', 'last_ok', 'refused_since', 'lost', 'calls', 'owed', 'started',
                 'noticed', 'registrars', 'suspect', 'next_reconcile', 'recheck_until', 'unheard_since',
                 'next_hear_again')

    def __init__(self, node: str, uri: str, incarnation: Optional[int]) -> None:
        self.node = node
        self.uri = uri
        # None until it answers: an owner only called (or owed an unload) may keep a journal, and a load it
        # served for a call this side gave up on comes back with its next incarnation (chaos seed 17, step 6429)
        self.incarnation = incarnation
        self.last_ok = time.monotonic()
        self.refused_since: Optional[float] = None
        self.lost = ''                 # why it was found lost ('' while it answers)
        self.calls = 0                 # calls in flight to it
        self.owed: List[Tuple[Target, int]] = []    # unloads that did not reach it
        self.started = 0               # calls ever started to it: a reconciliation runs only between calls
        self.noticed = 0               # responses from it, each counted once the resource it gave is held
        self.registrars: Set[Tuple[str, str]] = set()   # its registrars this one has called
        self.suspect = False           # it may hold references this side does not know of: reconcile
        self.next_reconcile = 0.0      # not before (a reconciliation reads the owner's whole registry)
        self.recheck_until = 0.0       # a request given up on may still arrive: read again until then
        self.unheard_since: Optional[float] = None   # since when its statuses have had no way to this node
        self.next_hear_again = 0.0     # not before (see OwnerWatch._hear)


class OwnerWatch:
    def __init__(self, core: RegistrarCore, holds_from: Callable[[str], bool],
                 held_from: Callable[[str], List[Tuple[Target, int]]],
                 on_lost: Callable[[Target, int, str], None], send_unload: Callable[[Target, int], bool],
                 reconcile: Callable[[Tuple[str, str], Callable[[], bool]], bool],
                 period: float = DEFAULT_PERIOD, bound: float = DEFAULT_BOUND, grace: float = 10.0,
                 busy_bound: float = DEFAULT_BUSY_BOUND, hears_from: Optional[Callable[[str], bool]] = None,
                 hear_again: Optional[Callable[[], None]] = None) -> None:
        """``holds_from(node)``: whether anything active is held from ``node``; ``held_from(node)``: the
        (target, external id) of those resources;
        ``on_lost``: handle one of them as failed; ``send_unload``: send one unload again, True once the
        owner has answered (whatever it said), False if it could not be reached;
        ``hears_from(node)``: whether this node's status subscriber is connected to ``node``;
        ``hear_again()``: ask the master again for the publishers of that subscriber (raises when it cannot)."""
        if not 0 < period < bound:
            raise ValueError('owner liveness: the check period (%r s) must be positive and shorter than the '
                             'bound (%r s)' % (period, bound))
        self._core = core
        self._holds_from = holds_from
        self._held_from = held_from
        self._on_lost = on_lost
        self._send_unload = send_unload
        self._reconcile = reconcile
        self._hears_from = hears_from
        self._hear_again = hear_again
        if busy_bound < bound:
            raise ValueError('owner liveness: the bound for a busy owner (%r s) must not be shorter than the '
                             'bound (%r s)' % (busy_bound, bound))
        self.period, self.bound, self.grace, self.busy_bound = period, bound, grace, busy_bound
        self._me = rospy.get_name()
        self._owners: Dict[str, Owner] = {}
        self._node_of: Dict[Tuple[str, str], str] = {}     # registrar -> the node last found serving it
        # node -> the URI it last answered at, or a response named: a watch that starts while the master is
        # away (the robot rebooting) still reaches an owner it has met (the calls to it found its services)
        self._last_uri: Dict[str, str] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()

    # ------------------------------------------------------------------------------------------ what depends
    def notice(self, node: str, uri: str, incarnation: int) -> None:
        """An owner named by a response: watch it while anything is held from it."""
        if node and node != self._me:
            with self._lock:
                owner = self._owner(node, uri, incarnation)
                if owner.incarnation is not None and incarnation < owner.incarnation:
                    return               # an answer from an older incarnation: fenced
                if uri and uri != owner.uri:
                    owner.uri, owner.last_ok, owner.lost, owner.refused_since = uri, time.monotonic(), '', None
                if uri:
                    self._last_uri[node] = uri
                owner.incarnation = incarnation
                owner.noticed += 1

    def calling(self, node: str, registrar: Tuple[str, str]) -> Optional[Owner]:
        """A call to ``registrar`` of ``node`` starts; ``done_calling`` must follow."""
        if not node or node == self._me:
            return None
        with self._lock:
            owner = self._owner(node, '', None)
            owner.calls += 1
            owner.started += 1
            owner.registrars.add(registrar)
            self._node_of[registrar] = node
            return owner

    def serving(self, registrar: Tuple[str, str]) -> str:
        """The node last found serving ``registrar`` ('' if none yet): a call is counted before it connects."""
        with self._lock:
            return self._node_of.get(registrar, '')

    def done_calling(self, owner: Optional[Owner], answered: bool) -> None:
        """``answered``: false if the call was cut or expired, and the owner may have served it anyway."""
        if owner is not None:
            with self._lock:
                owner.calls -= 1
                if not answered:
                    owner.suspect = True
                    owner.recheck_until = time.monotonic() + LATE_REQUEST_S

    def owe(self, node: str, target: Target, external_id: int) -> None:
        """An unload of ``target``'s ``external_id`` did not reach ``node``: send it again when it answers."""
        if node and node != self._me and not self._stop.is_set():
            with self._lock:
                self._owner(node, '', None).owed.append((target, external_id))

    def unreachable(self, registrar: Tuple[str, str]) -> str:
        """Why ``registrar``'s node is lost, or '' if it is not known to be: a call need not try it."""
        with self._lock:
            for owner in self._owners.values():
                if owner.lost and registrar in owner.registrars:
                    return owner.lost
        return ''

    def recheck(self, registrar: Tuple[str, str], timeout: float) -> str:
        """Why ``registrar``'s node is lost, after asking it once more (within ``timeout``); '' if it is not
        known lost, or answers now: a call right after a partition heals need not wait for the next check."""
        with self._lock:
            owner = next((o for o in self._owners.values() if o.lost and registrar in o.registrars), None)
            if owner is None:
                return ''
            uri, why = owner.uri, owner.lost
        if uri and ping(uri, timeout, self._core.prefix)[0]:
            with self._lock:
                if owner.uri == uri:
                    owner.last_ok, owner.refused_since, owner.lost, owner.suspect = time.monotonic(), None, '', True
            return ''
        return why

    def owed(self) -> List[Tuple[str, Target, int]]:
        with self._lock:
            return [(o.node, t, e) for o in self._owners.values() for t, e in o.owed]

    def stop(self) -> None:
        self._stop.set()

    def _owner(self, node: str, uri: str, incarnation: Optional[int]) -> Owner:
        """The record of ``node``, made (and its thread started) on first sight (lock held)."""
        owner = self._owners.get(node)
        if owner is None:
            owner = self._owners[node] = Owner(node, uri, incarnation)
            threading.Thread(target=self._watch, args=(owner,), daemon=True,
                             name='rr-%s-owner' % self._core.name).start()
        return owner

    # ------------------------------------------------------------------------------------------ the watch
    def _watch(self, owner: Owner) -> None:
        while not self._stop.is_set():
            with self._lock:
                seen = (owner.started, owner.noticed)
            held = self._holds_from(owner.node)       # before the watch's lock: it takes the registrar's
            with self._lock:
                # a load answered while ``held`` was read is held now but not in ``held``: it was noticed (or its
                # call started) meanwhile, and the owner stays watched (the chaos history of seed 17 found a
                # client whose watch had ended under a fresh load, so a partition never failed it)
                if not (held or owner.calls or owner.owed or owner.suspect) and seen == (owner.started, owner.noticed):
                    del self._owners[owner.node]
                    return
            if not owner.uri:
                looked_up = self._lookup(owner.node)
                with self._lock:
                    # a response may have named the URI while the master was asked: it is the newer word;
                    # the master's is newer than the one last met, which serves while the master is away
                    if not owner.uri:
                        owner.uri = looked_up or self._last_uri.get(owner.node, '')
            verdict = None
            if owner.uri:
                silent = time.monotonic() - owner.last_ok
                limit = self.bound if silent < self.bound else self.busy_bound
                timeout = max(0.05, min(self.bound, limit - silent))
                verdict, _pid = _SHARED.get('ping', owner.uri, self.period / 2,
                                            lambda: ping(owner.uri, timeout, self._core.prefix), timeout + 0.1,
                                            (None, 0))
            now = time.monotonic()
            if verdict:
                with self._lock:
                    self._last_uri[owner.node] = owner.uri
                    if owner.lost:         # back after a partition: what it holds for this side is checked
                        owner.suspect = True
                        owner.recheck_until = now + LATE_REQUEST_S
                owner.last_ok, owner.refused_since, owner.lost = now, None, ''
                if held:
                    self._hear(owner, now)
                self._settle(owner)
            elif verdict is None:
                silent = now - owner.last_ok
                if silent >= self.bound and not owner.uri:
                    self._lose(owner, 'no address for %s for %.1f s: the master (%s) does not name it, and this '
                                      'node never met it' % (owner.node, silent, rosgraph.get_master_uri()))
                elif silent >= self.bound:
                    if not _SHARED.get('accepts', owner.uri, self.period / 2,
                                       lambda: accepts(owner.uri, ACCEPT_TIMEOUT), ACCEPT_TIMEOUT + 0.1, True):
                        self._lose(owner, 'no answer from %s for %.1f s: its host is cut off or down'
                                   % (owner.node, silent))
                    elif silent >= self.busy_bound:
                        self._lose(owner, 'no answer from %s for %.1f s: it accepts connections, so the process '
                                          'is stopped or wedged' % (owner.node, silent))
            else:
                self._gone(owner, now)
            self._stop.wait(self.period)

    def _hear(self, owner: Owner, now: float) -> None:
        """An owner that answers, of which something is held here: its statuses must have a way to this node.

        A status channel is connected when the master tells this node of the owner's new publisher. That
        update can be lost (the master sent it across a link that went down a moment later: chaos seed 17,
        step 3914, a display's FAILED never reached its client), and then nothing the owner says arrives, for
        good. So once it has had no way here for ``UNHEARD_BOUND``, the master is asked again for the
        publishers, and the owner's registry is read, so that a FAILED sent meanwhile is handled now."""
        if self._hears_from is None or self._hears_from(owner.node):
            owner.unheard_since = None
            return
        if owner.unheard_since is None:
            owner.unheard_since = now
        if now - owner.unheard_since < UNHEARD_BOUND or now < owner.next_hear_again:
            return
        owner.next_hear_again = now + UNHEARD_RETRY_S
        rospy.logwarn('%s: no status from %s can reach this node (no connection from it on its status topic for '
                      '%.1f s): asking the master for its publishers again, and reading its registry',
                      self._core.prefix, owner.node, now - owner.unheard_since)
        if self._hear_again is not None:
            try:
                self._hear_again()
            except (OSError, xmlrpc.client.Error, http.client.HTTPException) as err:
                # the master is away or answered garbage: the owner's registry is read anyway
                rospy.logwarn('%s: could not ask the master for the publishers of %s: %s', self._core.prefix,
                              owner.node, err)
        with self._lock:
            owner.suspect = True

    def _gone(self, owner: Owner, now: float) -> None:
        """Nobody answers at the owner's URI any more: follow it to a new incarnation, or lose it."""
        uri = self._lookup(owner.node)
        if uri and uri != owner.uri and ping(uri, self.bound, self._core.prefix)[0]:
            if owner.incarnation != 0:
                rospy.loginfo('%s: owner %s is back at %s', self._core.prefix, owner.node, uri)
                owner.uri, owner.last_ok, owner.refused_since, owner.lost = uri, now, None, ''
                # its new incarnation rebuilt its registry and sent a FAILED for what it could not vouch for,
                # which is lost if this node was not connected to it yet (after a power loss of the robot,
                # before this node joined the new master): its registry is read (chaos seed 17, step 543)
                with self._lock:
                    owner.suspect = True
                self._settle(owner)
                return
            self._lose(owner, '%s restarted without a journal: what it served is gone' % owner.node, dead=True)
            owner.uri = uri
            return
        if owner.incarnation != 0:
            if owner.refused_since is None:
                owner.refused_since = now
            if now - owner.refused_since < self.grace:
                return
            self._lose(owner, '%s died and did not come back within %.0f s' % (owner.node, self.grace), dead=True)
        else:
            self._lose(owner, '%s died (it keeps no journal: what it served is gone)' % owner.node, dead=True)

    def _lose(self, owner: Owner, why: str, dead: bool = False) -> None:
        """``dead``: the owner's process is gone for good, with what it served: nothing is owed to it."""
        if dead:
            with self._lock:
                owner.owed, owner.suspect = [], False
        cut = WATCH.abort(owner.node, why)
        held = self._held_from(owner.node)
        if owner.lost == why and not cut and not held:
            return
        owner.lost = why
        if held or cut:
            rospy.logwarn('%s: %s; %d held resource(s) failed, %d call(s) cut', self._core.prefix, why, len(held),
                          cut)
        for target, external_id in held:
            self._on_lost(target, external_id, '%s: %s' % (target_name(target), why))

    def _settle(self, owner: Owner) -> None:
        with self._lock:
            owed, owner.owed = owner.owed, []
        unsent = [(target, external_id) for target, external_id in owed if not self._send_unload(target, external_id)]
        if unsent:
            with self._lock:
                owner.owed.extend(unsent)
            return
        with self._lock:
            if not owner.suspect or owner.calls or time.monotonic() < owner.next_reconcile:
                return
            started, registrars = owner.started, sorted(owner.registrars)
            owner.suspect = False
            owner.next_reconcile = time.monotonic() + RECONCILE_SPACING

        def quiet() -> bool:
            with self._lock:
                return owner.calls == 0 and owner.started == started
        for registrar in registrars:
            if not self._reconcile(registrar, quiet):
                with self._lock:
                    owner.suspect = True       # not read, or a call started meanwhile: next time
        with self._lock:
            if time.monotonic() < owner.recheck_until:
                owner.suspect = True           # a request given up on may still arrive there

    def _lookup(self, node: str) -> str:
        try:
            code, _, uri = xmlrpc_proxy(rosgraph.get_master_uri(), min(self.bound, 0.5)).lookupNode(
                self._core.prefix, node)
        except (OSError, xmlrpc.client.Error):
            return ''
        return uri if code == 1 else ''


def owned_by(query, node: str) -> bool:
    """Whether held ``query`` is active and owned by ``node`` (its response names the owner)."""
    return query.state is ACTIVE and query.response is not None and query.response.trr.owner_node == node
