"""The motion invariants, held against the simulation's ground truth (``motion_truth.py``).

Three accounts meet here, none of them a manager's:
- the ground truth: each part's spans of motion, contacts, blind drives (the watch on the robot's host);
- the holds: each client's journal of its motion goals (sent, accepted or refused, ended), written before
  the robot could act on them, so a SIGKILL loses nothing the robot saw;
- the faults: when the runner killed a client, and when it did each fault that stops motion (a stop case).

The invariants (docs/chaos.md):
1. nothing moves unless a live client holds a motion goal for that part: every moment of a span of motion
   lies within some hold of the part, from its goal's sending to its end plus the *stop allowance* of how it
   ended: a goal that ended or was let go, the part's braking and the end's way to the robot
   (``END_LATENCY_S``); a client killed, that stop case's bound; a hold that ended while the link was cut
   (the cancel could not cross), the cut's bound. An ended, cancelled or replaced goal excuses nothing more;
2. after a stop-case fault, a part that was moving is at rest within that case's bound (its detection
   bound, docs/robots.md, plus the braking), unless a hold of that part begins meanwhile (a new goal). A
   fault that stays in force (``PERSISTENT``: a source unplugged, a controller down) is no such excuse: no
   new goal may move the part through it;
3. no contact;
4. no base motion while no obstacle source is fresh (``motion_truth.blind_after``);
5. a refused goal moved nothing: it is no hold, so motion it caused would break 1, and is said so;
6. every goal ends, within its kind's bound; one that did not succeed says why.

Time is the wall clock everywhere (the simulation's stamps, the journals, the runner's faults): the hosts
of a two-host run are network namespaces of one machine.
"""
from __future__ import annotations

import collections
import dataclasses
import math
from typing import Deque, Dict, Iterable, List, Optional, Sequence, Tuple

from .motion_truth import BASE, GRIPPER, LEFT_ARM, RIGHT_ARM

BRAKING_S = {BASE: 0.5, LEFT_ARM: 0.4, RIGHT_ARM: 0.4, GRIPPER: 0.1}    # from top speed (docs/robots.md)
# the stop cases (issue 41's table, docs/robots.md): what detects each, within what, before the braking
DETECTION_S = {
    'client_killed': 0.3,        # a goal's client dies: its connection's end of file (servo: the stream's 0.1 s
                                 # timeout and the controller's 0.1 s deadman, within the same 0.3 s)
    'manager_killed': 0.3,       # the Robot Manager dies during a drive: the navigator's latched topic closes
    'controller_killed': 0.05,   # a controller dies or stalls: the motors' command timeout (40 ms) and a period
    'controller_stalled': 0.05,
    # the active obstacle source goes stale: 3 of its periods + 20 ms (the SICK's here; the runner gives each
    # case its source's own, as the watch learns it: the stitched Hokuyo cloud and the D435's are slower)
    'obstacle_unplugged': 0.14,
    'hand_unplugged': 0.04,      # the hand source goes stale while an arm follows it: 2 periods + 20 ms
    'halted': 0.05,              # the operator's stop: every motion node commands zero (docs/robots.md: 50 ms)
    # an arm's manipulator killed: its controller sees its trajectory's client gone (its connection's end of
    # file), or a servo stream's commands stop and the controller's 0.1 s deadman holds the arm
    'manipulator_killed': 0.15,
    'link_cut': 0.2,             # the servo stream is cut: the stream's 0.1 s timeout, the controller's deadman
    # a drive's client is cut off: the kernel drops the navigator's unacknowledged status after 0.4 s
    # (goal_holders.py), at its retransmission timer's next firing (up to 0.4 s more), then the next tick
    ('link_cut', BASE): 1.0,
    # the gripper's controller finds a cut-off client the same way: a cancel sent during the cut never
    # reaches it (seed 17, step 2032: the fingers finished their 0.62 s stroke 0.56 s after the cancel)
    ('link_cut', GRIPPER): 1.0,
}
# a goal's end: the longest a goal of each kind may run before it ends by itself (a drive across the lab at
# the navigator's speed, with replanning; a gripper's stroke and its 1 s; a stream's own length is its end)
GOAL_BOUND_S = {'goal': 120.0, 'grip': 10.0, 'servo': 30.0, 'arm_goal': 30.0}
# s after a span's end before it is judged: the journals' lines that bear on it have been written by then
JUDGE_AFTER_S = 2.0
MAX_JUDGED = 5000        # judged spans kept for the stop cases still open (a few minutes of motion)
TOLERANCE_S = 0.03       # an uncovered sliver shorter than this is the samples' own period (50 Hz), not motion


# the stop cases whose fault stays in force after it is done: a new goal cannot excuse motion through them
PERSISTENT = frozenset(('obstacle_unplugged', 'controller_killed', 'controller_stalled', 'hand_unplugged',
                        'manipulator_killed'))
# s from a client's end of a hold (it heard the goal end, or sent its cancel) to the robot's knowing it, at most,
# on a loaded machine: the cancel's message on its way and the motion node's next look
END_LATENCY_S = 0.3


def stop_bound(case: str, part: str) -> float:
    return DETECTION_S.get((case, part), DETECTION_S[case]) + BRAKING_S[part]


# motion allowed after a hold's end, by how it ended: let go or ended (the braking and the end's way), its client
# killed (that case's bound), or during a cut link (the cut's bound: the cancel could not cross)
ALLOWANCE_S = {part: BRAKING_S[part] + END_LATENCY_S for part in BRAKING_S}
KILLED_ALLOWANCE_S = {part: stop_bound('client_killed', part) for part in BRAKING_S}
CUT_ALLOWANCE_S = {part: stop_bound('link_cut', part) for part in BRAKING_S}


@dataclasses.dataclass
class Hold:
    id: str
    part: str
    kind: str
    sent: float
    accepted: bool = False               # its acceptance reached the client (it may not: a cut link)
    refused: Optional[float] = None      # when, for a goal refused
    end: Optional[float] = None          # when the client let go (the goal ended, or it cancelled, or died)
    cause: str = ''
    state: str = ''
    reason: str = ''
    what: str = ''

    def until(self) -> float:
        return math.inf if self.end is None else self.end

    @property
    def holds(self) -> bool:
        """Whether the robot may act on it: any goal not refused, whether its acceptance reached the client
        or not (a link cut right after the goal went out: the robot drives, the client hears nothing)."""
        return self.refused is None


@dataclasses.dataclass
class StopCase:
    case: str
    t: float
    part: str
    step: int
    # the holds the fault takes away (a killed client's, those that follow the hand); another live hold of the
    # part still moves it, and the stop is not owed. Empty: the fault stops the part whoever holds it
    affected: Tuple[str, ...] = ()
    measured: Optional[float] = None     # s from the fault to the part at rest
    outcome: str = 'open'                # open | at rest | was at rest | restarted | held | VIOLATION
    detection: Optional[float] = None    # this fault's detection bound, when not its case's (DETECTION_S)

    @property
    def bound(self) -> float:
        return stop_bound(self.case, self.part) if self.detection is None else self.detection + BRAKING_S[self.part]


class MotionLedger:
    def __init__(self) -> None:
        self.holds: Dict[str, Hold] = {}
        self.spans: List[dict] = []                  # closed spans not judged yet
        self.judged: Deque[dict] = collections.deque(maxlen=MAX_JUDGED)   # for the stop cases still open
        self.moving: Dict[str, dict] = {}            # part -> its span under way (the watch's last answer)
        self.stale_after: Dict[str, Optional[float]] = {}   # obstacle source -> its stale bound (the same)
        self.rest_since: Dict[str, float] = {}       # part -> its last sample, when at rest
        self.cases: List[StopCase] = []
        self.seq = 0                                 # the last ground-truth event read
        self.counts = collections.Counter()
        self.worst_uncovered = 0.0
        self.reported: set = set()
        self.finding: List[str] = []                 # violations found and not yet returned
        self.cuts: List[List[float]] = []            # [cut, healed] of the link (healed inf while it is down)

    # -- what comes in -----------------------------------------------------------------------------------------
    def journal(self, records: Iterable[dict]) -> None:
        for r in records:
            ev, mid = r.get('ev'), r.get('id', '')
            if ev == 'sent':
                self.holds[mid] = Hold(mid, r['part'], r['kind'], r['t'], what=r.get('what', ''))
                self.counts['goals %s' % r['kind']] += 1
                continue
            hold = self.holds.get(mid)
            if hold is None:
                continue
            if ev == 'accepted':
                hold.accepted = True
            elif ev == 'refused':
                hold.refused = hold.end = r['t']
                hold.state, hold.reason = r.get('state', ''), r.get('reason', '')
                self.counts['refused %s' % hold.kind] += 1
                if not hold.reason:
                    self.finding.append('motion: %s (%s, %s) was refused with no reason' % (mid, hold.kind, hold.what))
            elif ev == 'ended' and hold.end is None:
                hold.end, hold.cause, hold.state, hold.reason = r['t'], r.get('cause', ''), r.get('state', ''), \
                    r.get('reason', '')
                self.counts['ended %s %s' % (hold.kind, hold.state or hold.cause)] += 1
                if hold.state not in ('SUCCEEDED', 'PREEMPTED', 'CANCELLED', 'RELEASED', '') and not hold.reason:
                    self.finding.append('motion: %s (%s, %s) ended %s with no reason' % (mid, hold.kind, hold.what,
                                                                                       hold.state))

    def killed(self, node: str, t: float, step: int) -> None:
        """A client incarnation died at ``t``: its holds end then, and each part it moved is a stop case."""
        prefix = node.rstrip('/') + '#'
        parts = set()
        mine = tuple(h.id for h in self.holds.values() if h.id.startswith(prefix))
        for hold in self.holds.values():
            if hold.id.startswith(prefix) and hold.end is None:
                hold.end, hold.cause = t, 'client killed'
                if hold.holds:
                    parts.add(hold.part)
        for part in sorted(parts):
            self.fault('client_killed', t, part, step, mine)

    def link(self, up: bool, t: float) -> None:
        """The link between the hosts cut (``up`` False) or plugged back at ``t``."""
        if not up:
            self.cuts.append([t, math.inf])
        elif self.cuts and self.cuts[-1][1] == math.inf:
            self.cuts[-1][1] = t

    def allowance(self, hold: Hold) -> float:
        """How long after ``hold``'s end its part may still move (``ALLOWANCE_S``, by how it ended)."""
        if hold.end is None:
            return 0.0
        if hold.cause == 'client killed':
            return KILLED_ALLOWANCE_S[hold.part]
        if any(cut <= hold.end <= healed for cut, healed in self.cuts):
            return CUT_ALLOWANCE_S[hold.part]
        return ALLOWANCE_S[hold.part]

    def fault(self, case: str, t: float, part: str, step: int, affected: Tuple[str, ...] = (),
              detection: Optional[float] = None) -> None:
        self.cases.append(StopCase(case, t, part, step, tuple(affected), detection=detection))

    def truth(self, answer: dict) -> None:
        """The watch's answer to ``since(self.seq)``."""
        if answer.get('oldest', 0) > self.seq + 1 and self.seq:
            self.finding.append('motion: the watch dropped ground-truth events %d to %d before they were read'
                                % (self.seq + 1, answer['oldest'] - 1))
        for e in answer['events']:
            if e['type'] == 'span':
                self.spans.append(e)
            elif e['type'] == 'contact':
                self.counts['contacts'] += 1
                self.finding.append('motion: a contact: %s touched %s at %.2f m/s (t %.3f)'
                                    % (e['robot_link'], e['object_link'], e['speed'], e['t']))
            elif e['type'] == 'blind':
                self.counts['blind drives'] += 1
                self.finding.append('motion: the base moved blind from t %.3f to %.3f: no obstacle source fresh '
                                    '(each source: s since it was heard, its period: %s)' % (e['start'], e['end'], e['since_heard']))
        self.seq = answer['seq']
        self.stale_after = answer.get('stale_after', {})
        self.moving = answer['moving']
        self.rest_since = {p: t for p, t in answer['last'].items() if p not in self.moving}

    # -- judging -----------------------------------------------------------------------------------------------
    def check(self, now: float, live_nodes: Sequence[str] = ()) -> List[str]:
        out, self.finding = self.finding, []
        keep = []
        for span in self.spans:
            if now - span['end'] < JUDGE_AFTER_S:
                keep.append(span)
                continue
            out += self._judge_span(span['part'], span['start'], span['end'], span['peak'])
            self.judged.append(span)
        self.spans = keep
        for part, span in self.moving.items():                  # a span under way: judged up to a while ago
            upto = min(span['last'], now - JUDGE_AFTER_S)
            if upto > span['start']:
                out += self._judge_span(part, span['start'], upto, span['peak'])
        out += self._judge_cases(now)
        for hold in self.holds.values():
            if hold.end is None and now - hold.sent > GOAL_BOUND_S[hold.kind] and hold.id not in self.reported:
                self.reported.add(hold.id)
                out.append('motion: %s (%s, %s) has not ended %.0f s after it was sent (its bound: %.0f s)'
                           % (hold.id, hold.kind, hold.what, now - hold.sent, GOAL_BOUND_S[hold.kind]))
        self._forget(now)
        return out

    def _judge_span(self, part: str, start: float, end: float, peak: float) -> List[str]:
        covers = sorted((h.sent, h.until() + self.allowance(h)) for h in self.holds.values()
                        if h.part == part and h.holds)
        gaps = _uncovered(start, end, covers)
        gaps = [(a, b) for a, b in gaps if b - a > TOLERANCE_S]
        if not gaps:
            return []
        key = (part, round(start, 3))
        if key in self.reported:
            return []
        self.reported.add(key)
        a, b = gaps[0]
        self.worst_uncovered = max(self.worst_uncovered, sum(y - x for x, y in gaps))
        refused = [h for h in self.holds.values() if h.part == part and h.refused is not None
                   and h.sent <= b and h.refused + KILLED_ALLOWANCE_S[part] >= a]
        near = sorted(self.holds.values(), key=lambda h: abs(h.until() - a))[:3]
        return ['motion: the %s moved (up to %.2f) from t %.3f to %.3f with no live holder for %.3f s of it%s; '
                'the nearest holds: %s' % (
                    part, peak, start, end, sum(y - x for x, y in gaps),
                    ' (a refused goal, %s, was sent meanwhile: it moved the robot)' % refused[0].id if refused else '',
                    '; '.join('%s %s %s sent %.3f ended %s (%s)' % (h.id, h.kind, h.part, h.sent,
                                                                    '%.3f' % h.end if h.end else 'no', h.cause)
                              for h in near) or 'none')]

    def _judge_cases(self, now: float) -> List[str]:
        out = []
        for case in self.cases:
            if case.outcome != 'open':
                continue
            bound = case.bound
            moving_at = self._span_at(case.part, case.t)
            if moving_at is None:
                if now - case.t > JUDGE_AFTER_S:
                    case.outcome = 'was at rest'
                continue
            started = case.case not in PERSISTENT and [h for h in self.holds.values() if h.part == case.part
                                                       and h.holds and case.t < h.sent <= case.t + bound]
            held = case.affected and [h for h in self.holds.values() if h.part == case.part and h.holds
                                      and h.sent <= case.t < h.until() and h.id not in case.affected]
            end = moving_at.get('end')
            if held:
                case.outcome = 'held'          # another client drives it: the killed one's stop is not owed
            elif started:
                case.outcome = 'restarted'
            elif end is not None:
                case.measured = end - case.t
                case.outcome = 'at rest' if case.measured <= bound else 'VIOLATION'
            elif now - case.t > bound + JUDGE_AFTER_S:
                case.measured = now - case.t
                case.outcome = 'VIOLATION'
            if case.outcome == 'VIOLATION':
                out.append('motion: the %s was still moving %.3f s after step %d (%s; its bound: %.3f s)'
                           % (case.part, case.measured, case.step, case.case.replace('_', ' '), bound))
        return out

    def _span_at(self, part: str, t: float) -> Optional[dict]:
        """The span of ``part`` that holds ``t`` (closed or under way), if the part was moving then."""
        for span in list(self.spans) + list(self.judged):
            if span['part'] == part and span['start'] <= t <= span['end']:
                return span
        span = self.moving.get(part)
        if span is not None and span['start'] <= t:
            return {'part': part, 'start': span['start'], 'end': None}
        return None

    def _forget(self, now: float) -> None:
        """Bounded over any length of history: ended holds and judged cases older than any span still judged."""
        horizon = now - 10 * JUDGE_AFTER_S - max(GOAL_BOUND_S.values())
        self.holds = {k: h for k, h in self.holds.items() if h.end is None or h.end > horizon}

    # -- figures -----------------------------------------------------------------------------------------------
    def figures(self) -> dict:
        worst: Dict[str, dict] = {}
        for case in self.cases:
            row = worst.setdefault('%s/%s' % (case.case, case.part), {
                'bound_s': 0.0, 'measured': 0, 'worst_s': 0.0, 'worst_of_bound': 0.0, 'was_at_rest': 0,
                'restarted': 0, 'held': 0, 'open': 0})
            row['bound_s'] = round(max(row['bound_s'], case.bound), 3)      # the widest, when a case's varies
            if case.measured is not None and case.outcome in ('at rest', 'VIOLATION'):
                row['measured'] += 1
                row['worst_s'] = round(max(row['worst_s'], case.measured), 3)
                row['worst_of_bound'] = round(max(row['worst_of_bound'], case.measured / case.bound), 3)
            elif case.outcome == 'was at rest':
                row['was_at_rest'] += 1
            elif case.outcome in ('restarted', 'held'):
                row[case.outcome] += 1
            else:
                row['open'] += 1
        return {'stop_cases': worst, 'counts': dict(self.counts),
                'worst_uncovered_s': round(self.worst_uncovered, 3)}


def _uncovered(start: float, end: float, covers: Sequence[Tuple[float, float]]) -> List[Tuple[float, float]]:
    """The parts of [start, end] that no interval of ``covers`` (sorted by start) holds."""
    gaps, at = [], start
    for a, b in covers:
        if b <= at:
            continue
        if a > at:
            gaps.append((at, min(a, end)))
        at = max(at, b)
        if at >= end:
            break
    if at < end:
        gaps.append((at, end))
    return [(a, b) for a, b in gaps if b > a]
