"""The motion invariants' rules alone: the ground truth's spans (motion_truth.py) and the ledger that holds
them against the clients' journals and the faults (motion_checker.py). ``tests/test_chaos.py`` runs them
against the real robot."""
import math

import pytest

from temoto_chaos.motion_checker import ALLOWANCE_S, CUT_ALLOWANCE_S, JUDGE_AFTER_S, MotionLedger, stop_bound
from temoto_chaos.motion_truth import (BASE, GRIPPER, LEARNT_TOLERANCE_S, LEFT_ARM, RIGHT_ARM, SAMPLES_LOST_S, GroundTruth,
                                      blind_after)

SICK = 'sick/scan'


def drive(truth, t0, t1, speed=0.4, dt=0.02, scans=True):
    """Base samples from t0 to t1 at ``speed``, then one at rest; the SICK heard at every sample."""
    t = t0
    while t < t1:
        if scans:
            truth.obstacle(t, SICK)
        truth.base(t, speed, 0.0)
        t += dt
    truth.obstacle(t1, SICK)
    truth.base(t1, 0.0, 0.0)


def spans(truth):
    return [e for e in truth.since(0)['events'] if e['type'] == 'span']


def test_a_span_runs_from_the_first_moving_sample_to_the_first_at_rest_with_its_peak():
    truth = GroundTruth({SICK: 0.04})
    truth.base(0.0, 0.0, 0.0)
    drive(truth, 1.0, 2.0)
    [span] = spans(truth)
    assert (span['part'], span['start'], span['end'], span['peak']) == (BASE, 1.0, 2.0, 0.4)
    assert truth.since(span['seq'])['events'] == []


def test_an_arm_nobody_holds_sweeps_as_the_sims_own_motion_and_makes_no_span():
    truth = GroundTruth({})
    for i in range(10):
        truth.arm(i * 0.02, RIGHT_ARM, False, 1.57)
    truth.arm(0.5, LEFT_ARM, True, 0.3)
    truth.arm(0.6, LEFT_ARM, True, 0.0)
    assert [(s['part'], s['start'], s['end']) for s in spans(truth)] == [(LEFT_ARM, 0.5, 0.6)]


def test_a_span_whose_samples_stop_closes_at_its_last_sample():
    truth = GroundTruth({SICK: 0.04})
    truth.obstacle(0.0, SICK)
    truth.base(0.0, 0.3, 0.0)
    truth.base(0.1, 0.3, 0.0)
    truth.tick(0.1 + SAMPLES_LOST_S / 2)
    assert spans(truth) == [] and BASE in truth.since(0)['moving']
    truth.tick(0.1 + SAMPLES_LOST_S * 1.5)
    [span] = spans(truth)
    assert span['end'] == 0.1 and span['lost']


def test_the_base_moving_past_its_sources_freshness_and_braking_drives_blind():
    truth = GroundTruth({SICK: 0.04})
    truth.obstacle(0.0, SICK)
    limit = blind_after(0.04)
    truth.base(limit - 0.01, 0.3, 0.0)        # braking, still within the bound
    truth.base(limit + 0.01, 0.3, 0.0)        # blind
    truth.base(limit + 0.2, 0.3, 0.0)
    truth.obstacle(limit + 0.25, SICK)
    truth.base(limit + 0.3, 0.3, 0.0)         # fresh again
    [blind] = [e for e in truth.since(0)['events'] if e['type'] == 'blind']
    assert math.isclose(blind['start'], limit + 0.01) and math.isclose(blind['end'], limit + 0.2)


def test_a_base_with_no_source_ever_heard_drives_blind_at_once():
    truth = GroundTruth({SICK: 0.04})
    truth.base(0.0, 0.2, 0.0)
    truth.base(0.1, 0.0, 0.0)
    assert sorted(e['type'] for e in truth.since(0)['events']) == ['blind', 'span']


# -- the ledger -------------------------------------------------------------------------------------------------
def ledger_with(truth, *records):
    ledger = MotionLedger()
    ledger.journal(records)
    ledger.truth(truth.since(0))
    return ledger


def goal(mid, t, part=BASE, kind='goal'):
    return [{'id': mid, 'ev': 'sent', 'part': part, 'kind': kind, 't': t, 'what': 'x'},
            {'id': mid, 'ev': 'accepted', 't': t + 0.01}]


def test_motion_within_a_live_hold_and_its_allowance_keeps_the_invariant():
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 3.0 + ALLOWANCE_S[BASE] - 0.05)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9), {'id': '/c_0#1', 'ev': 'ended', 't': 3.0, 'state': 'SUCCEEDED'})
    assert ledger.check(10.0) == []


def test_motion_past_the_holds_end_and_its_allowance_is_a_violation_naming_the_hold():
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 3.0 + ALLOWANCE_S[BASE] + 0.5)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9), {'id': '/c_0#1', 'ev': 'ended', 't': 3.0, 'state': 'SUCCEEDED'})
    [v] = ledger.check(10.0)
    assert 'the base moved' in v and 'no live holder for 0.5' in v and '/c_0#1' in v
    assert ledger.check(11.0) == []            # said once


def test_a_gripper_goal_cancelled_during_a_link_cut_may_finish_its_stroke_within_the_cut_bound():
    """A cancel sent while the link is down never reaches the gripper's controller, which finds its client cut
    off as the navigator does (nothing acknowledged for 0.4 s): the stroke may go on up to that bound."""
    def closing(until):
        truth = GroundTruth({SICK: 0.04})
        t = 1.0
        while t < until:
            truth.gripper(t, 0.14)
            t += 0.02
        truth.gripper(until, 0.0)
        ledger = ledger_with(truth, *goal('/c_0#6', 0.98, part=GRIPPER, kind='grip'),
                             {'id': '/c_0#6', 'ev': 'ended', 't': 1.04, 'cause': 'cancelled', 'state': 'CANCELLED',
                              'reason': 'cancelled by its client'})
        ledger.link(False, 1.0)
        ledger.link(True, 3.0)
        return ledger
    assert closing(1.62).check(10.0) == []               # the 0.62 s stroke, 0.58 s after the cancel
    assert CUT_ALLOWANCE_S[GRIPPER] >= stop_bound('link_cut', GRIPPER) > 0.58
    [v] = closing(1.04 + stop_bound('link_cut', GRIPPER) + 0.3).check(10.0)
    assert 'the gripper moved' in v and '/c_0#6' in v


def test_motion_after_a_cancel_with_the_link_up_is_allowed_the_braking_and_the_ends_way_only():
    """Mutation: the base went on 1.0 s after its client cancelled, the link up. The old allowance (the longest
    stop case's, 1.5 s) excused it; a cancel that reaches the robot allows the braking and the end's way."""
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 3.0 + 1.0)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9), {'id': '/c_0#1', 'ev': 'ended', 't': 3.0, 'cause': 'cancelled',
                                                       'state': 'CANCELLED', 'reason': 'cancelled by its client'})
    [v] = ledger.check(10.0)
    assert 'the base moved' in v and 'no live holder for %.3f' % (1.0 - ALLOWANCE_S[BASE]) in v, v
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9), {'id': '/c_0#1', 'ev': 'ended', 't': 3.0, 'cause': 'cancelled',
                                                       'state': 'CANCELLED', 'reason': 'cancelled by its client'})
    ledger.link(False, 2.5)                              # the same, the link down: the cancel could not cross
    assert ledger.check(10.0) == []


def test_a_span_is_judged_only_once_the_journals_have_had_time_to_say_its_holds_end():
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 5.0)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9))
    assert ledger.check(5.0 + JUDGE_AFTER_S / 2) == []
    ledger.journal([{'id': '/c_0#1', 'ev': 'ended', 't': 2.0, 'state': 'SUCCEEDED'}])
    [v] = ledger.check(5.0 + JUDGE_AFTER_S + 0.1)
    assert 'no live holder' in v


def test_a_refused_goal_holds_nothing_and_motion_meanwhile_is_laid_to_it():
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 2.0)
    ledger = ledger_with(truth, {'id': '/c_0#1', 'ev': 'sent', 'part': BASE, 'kind': 'goal', 't': 0.99, 'what': 'x'},
                         {'id': '/c_0#1', 'ev': 'refused', 't': 1.0, 'state': 'REJECTED', 'reason': 'in an obstacle'})
    [v] = ledger.check(10.0)
    assert 'a refused goal, /c_0#1' in v


def test_a_refusal_or_a_failure_without_a_reason_is_a_violation():
    ledger = MotionLedger()
    ledger.journal(goal('/c_0#1', 1.0) + [{'id': '/c_0#1', 'ev': 'ended', 't': 2.0, 'state': 'ABORTED', 'reason': ''}]
                   + [{'id': '/c_0#2', 'ev': 'sent', 'part': BASE, 'kind': 'goal', 't': 3.0},
                      {'id': '/c_0#2', 'ev': 'refused', 't': 3.0, 'state': 'REJECTED', 'reason': ''}])
    out = ledger.check(10.0)
    assert any('ended ABORTED with no reason' in v for v in out) and any('refused with no reason' in v for v in out)


def test_a_goal_that_never_ends_is_a_violation_past_its_bound():
    ledger = MotionLedger()
    ledger.journal(goal('/c_0#1', 0.0, GRIPPER_PART, 'grip'))
    assert ledger.check(5.0) == []
    [v] = ledger.check(11.0)
    assert 'has not ended' in v


GRIPPER_PART = 'gripper'


def test_a_killed_clients_part_must_come_to_rest_within_the_cases_bound():
    truth = GroundTruth({SICK: 0.04})
    bound = stop_bound('client_killed', BASE)
    drive(truth, 1.0, 2.0 + bound - 0.1)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9))
    ledger.killed('/c_0', 2.0, step=7)
    assert ledger.check(10.0) == []
    [row] = ledger.figures()['stop_cases'].values()
    assert row['measured'] == 1 and row['worst_s'] == pytest.approx(bound - 0.1)

    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 2.0 + bound + 0.2)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9))
    ledger.killed('/c_0', 2.0, step=7)
    out = ledger.check(10.0)
    assert any('still moving' in v and 'step 7' in v and 'client killed' in v for v in out), out


def test_a_killed_clients_stop_is_not_owed_while_another_client_holds_the_part():
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 6.0)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9), *goal('/c_1#1', 1.5))
    ledger.killed('/c_0', 2.0, step=7)
    assert ledger.check(20.0) == []
    assert ledger.figures()['stop_cases']['client_killed/base']['held'] == 1


def test_a_controller_fault_holds_the_part_to_its_bound_whoever_holds_it_and_a_new_goal_excuses_nothing():
    """Mutation: a fault still in force (a controller stalled, a source unplugged) was dropped as "restarted" when
    any new goal came within its bound (5 of 10 obstacle unplugs in run AG). No goal may move a part through it."""
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 4.0)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9))
    ledger.fault('controller_stalled', 2.0, BASE, step=3)
    [v] = ledger.check(20.0)
    assert 'still moving 2.000 s after step 3 (controller stalled' in v

    for case in ('controller_stalled', 'obstacle_unplugged'):
        ledger = ledger_with(truth, *goal('/c_0#1', 0.9), *goal('/c_1#1', 2.1))
        ledger.fault(case, 2.0, BASE, step=3)
        assert any('still moving' in v for v in ledger.check(20.0)), case


def arm_moves(truth, t0, t1, arm=LEFT_ARM, speed=0.5, dt=0.02):
    t = t0
    while t < t1:
        truth.arm(t, arm, True, speed)
        t += dt
    truth.arm(t1, arm, True, 0.0)


def test_a_halt_holds_every_moving_part_to_its_bound_and_a_goal_sent_after_it_may_move_again():
    """Mutation (history 6): an arm still running its trajectory past the halt's bound is caught; one at rest within
    it is not; a goal sent after the halt moves the arm again, which the halt does not forbid."""
    bound = stop_bound('halted', LEFT_ARM)
    for late, caught in ((-0.1, False), (0.3, True)):
        truth = GroundTruth({})
        arm_moves(truth, 1.0, 2.0 + bound + late)
        ledger = ledger_with(truth, *goal('/c_0#1', 0.9, LEFT_ARM, 'arm_goal'))
        ledger.fault('halted', 2.0, LEFT_ARM, step=5)
        out = ledger.check(20.0)
        assert any('still moving' in v and '(halted' in v for v in out) == caught, (late, out)
    truth = GroundTruth({})
    arm_moves(truth, 1.0, 4.0)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9, LEFT_ARM, 'arm_goal'), *goal('/c_1#1', 2.05, LEFT_ARM, 'arm_goal'))
    ledger.fault('halted', 2.0, LEFT_ARM, step=5)
    assert ledger.check(20.0) == []
    assert ledger.figures()['stop_cases']['halted/left_arm']['restarted'] == 1


def test_a_killed_manipulator_holds_its_arm_to_its_bound_and_a_new_goal_excuses_nothing():
    """Mutation (history 6): the manipulator SIGKILLed mid-trajectory once left the arm running the trajectory to its
    end; a new goal cannot excuse it (the dead manipulator serves none)."""
    truth = GroundTruth({})
    arm_moves(truth, 1.0, 3.5)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9, LEFT_ARM, 'arm_goal'), *goal('/c_1#1', 2.05, LEFT_ARM, 'arm_goal'))
    ledger.fault('manipulator_killed', 2.0, LEFT_ARM, step=9)
    [v] = ledger.check(20.0)
    assert 'still moving 1.500 s after step 9 (manipulator killed' in v, v


def test_a_client_killed_while_another_sends_a_goal_is_a_restart():
    """A killed client's fault ends with it: a new goal of another client may move the part at once."""
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 4.0)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9), *goal('/c_1#1', 2.1))
    ledger.killed('/c_0', 2.0, step=3)
    assert ledger.check(20.0) == []
    assert ledger.figures()['stop_cases']['client_killed/base']['restarted'] == 1


def test_a_fault_while_the_part_was_at_rest_is_counted_as_such():
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.0, 2.0)
    ledger = ledger_with(truth, *goal('/c_0#1', 0.9))
    ledger.fault('obstacle_unplugged', 5.0, BASE, step=3)
    assert ledger.check(5.0 + JUDGE_AFTER_S + 0.1) == []
    assert ledger.figures()['stop_cases']['obstacle_unplugged/base']['was_at_rest'] == 1


def test_a_contact_and_a_blind_drive_are_violations():
    truth = GroundTruth({SICK: 0.04})
    truth.contact(1.0, 'base_link', 'table', 0.3)
    truth.base(2.0, 0.3, 0.0)
    out = ledger_with(truth).check(2.1)
    assert any('a contact: base_link touched table' in v for v in out)
    assert not any('blind' in v for v in out)          # still under way: said when it ends
    truth.obstacle(2.5, SICK)
    truth.base(2.5, 0.3, 0.0)
    ledger = ledger_with(truth)
    assert any('moved blind' in v for v in ledger.check(2.6))


def test_a_cloud_is_held_to_its_own_pace_and_a_silent_one_leaves_the_base_blind():
    """A cloud declares no period: the contract holds it to the 90th percentile of its last intervals (a
    camera rendered on a busy machine), as the navigator does; silent past three of them, it is stale."""
    cloud = 'd435/depth_registered/points'
    truth = GroundTruth({cloud: None})
    for i in range(10):
        truth.obstacle(i * 0.3, cloud)              # 3.3 Hz
    last, bound = 2.7, blind_after(0.3) + LEARNT_TOLERANCE_S
    truth.base(last + bound - 0.01, 0.3, 0.0)     # slow, but fresh by its own pace
    truth.base(last + bound + 0.01, 0.3, 0.0)     # silent past it: blind
    truth.base(last + bound + 0.1, 0.0, 0.0)
    [blind] = [e for e in truth.since(0)['events'] if e['type'] == 'blind']
    assert math.isclose(blind['start'], last + bound + 0.01)
    assert blind['since_heard'][cloud][1] == pytest.approx(0.3)


def test_a_goal_whose_acceptance_never_reached_its_client_still_holds_the_part():
    """Chaos seed 17, step 407 (two hosts): the link was cut as a drive began; the robot drove (and stopped,
    its client out of reach), the client heard neither the acceptance nor the end, and let go at its robot's
    FAILED. Sent and not refused, the goal held the base all along."""
    truth = GroundTruth({SICK: 0.04})
    drive(truth, 1.2, 1.6)
    ledger = ledger_with(truth, {'id': '/c_0#1', 'ev': 'sent', 'part': BASE, 'kind': 'goal', 't': 1.0, 'what': 'x'},
                         {'id': '/c_0#1', 'ev': 'ended', 't': 1.8, 'cause': 'robot_failed', 'state': 'FAILED',
                          'reason': 'cut off'})
    assert ledger.check(10.0) == []


def test_the_watch_learns_a_clouds_pace_as_the_navigator_does_from_its_stamps():
    """The navigator and the watch each receive a cloud when their own threads get a CPU; learnt from arrivals
    alone their periods differed by 80 ms (seed 17, step 2299). Both take the shorter of the arrivals' and the
    stamps' intervals, each with code of its own, so both learn the camera's own pace."""
    cloud = 'd435/depth_registered/points'
    truth = GroundTruth({SICK: 0.04, cloud: None})
    t = 0.0
    for k in range(21):
        t += 0.34
        truth.obstacle(t + (0.16 if k % 4 == 1 else 0.0), cloud, stamp=100.0 + t)
    assert truth.sources[cloud].period() == pytest.approx(0.34)


def test_an_unplugged_obstacle_source_is_held_to_its_own_period_not_the_sicks():
    """Seed 17, step 2445 (two hosts): the stitched Hokuyo cloud, the active source, was stalled; the base
    stopped 0.841 s later, within the cloud's own contract (3 of its periods), but the case held it to the
    SICK's 0.64 s. The watch says each source's stale bound; a fault given it is held to it."""
    cloud = 'laser_stitcher/cloud'
    truth = GroundTruth({SICK: 0.04, cloud: None})
    for i in range(25):                               # the cloud at 10 Hz
        truth.obstacle(0.1 * i, cloud)
    stale = truth.since(0)['stale_after']
    assert stale[SICK] == pytest.approx(0.14), 'a declared period: 3 of its 40 ms and 20 ms'
    assert stale[cloud] == pytest.approx(3 * 0.1 + 0.02 + LEARNT_TOLERANCE_S)

    stop = 2.4 + stale[cloud] + 0.45                  # past the SICK's bound, within the cloud's
    assert stop - 2.4 > stop_bound('obstacle_unplugged', BASE)
    drive(truth, 1.0, stop, scans=False)
    for detection, violated in ((stale[cloud], False), (None, True)):
        ledger = ledger_with(truth, *goal('/c_0#1', 0.9))
        ledger.fault('obstacle_unplugged', 2.4, BASE, step=9, detection=detection)
        out = ledger.check(20.0)
        assert any('still moving' in v and 'obstacle unplugged' in v for v in out) == violated, (detection, out)
    row = ledger.figures()['stop_cases']['obstacle_unplugged/base']
    assert row['bound_s'] == pytest.approx(stop_bound('obstacle_unplugged', BASE), abs=1e-3)
    assert row['worst_of_bound'] > 1.0


def test_the_base_driving_on_a_silent_active_source_is_blind_though_another_source_flows():
    """Mutation (the issue's probe): the SICK silent, a D435 cloud flowing, the base driving for 4 s. The old rule
    passed if any source was fresh; the navigator drove on the SICK, and only its freshness counts."""
    cloud = 'd435/depth_registered/points'

    def blind_drives(active):
        truth = GroundTruth({SICK: 0.04, cloud: 1 / 30.0})
        truth.navigator_reads([active])
        truth.obstacle(0.0, SICK)                  # the SICK's last scan; the cloud flows all along
        t = 0.0
        while t < 4.0:
            truth.obstacle(t, cloud)
            truth.base(t, 0.4, 0.0)
            t += 0.03
        truth.base(4.0, 0.0, 0.0)
        return [e for e in truth.since(0)['events'] if e['type'] == 'blind']
    [blind] = blind_drives(SICK)
    assert blind['active'] == SICK and blind['start'] == pytest.approx(blind_after(0.04), abs=0.03)
    assert blind_drives(cloud) == [], 'the navigator on the cloud: not blind'


def test_a_source_is_held_to_its_declared_rate_unless_it_runs_slower():
    """The catalogue's rate is the contract: a D435 declared at 30 Hz that delivers at 30 Hz is stale 3 periods
    and 20 ms after its last frame; one that delivers at 10 Hz is held to its own pace."""
    cloud = 'd435/depth_registered/points'
    truth = GroundTruth({cloud: 1 / 30.0})
    for i in range(21):
        truth.obstacle(i / 30.0, cloud)
    assert truth.since(0)['stale_after'][cloud] == pytest.approx(3 / 30.0 + 0.02)
    truth = GroundTruth({cloud: 1 / 30.0})
    for i in range(21):
        truth.obstacle(i * 0.1, cloud)
    assert truth.since(0)['stale_after'][cloud] == pytest.approx(0.3 + 0.02 + LEARNT_TOLERANCE_S)


def test_the_watchs_declared_rates_are_the_sensor_catalogues():
    """The checker reckons from the robot's declared rates: its table must say what the catalogue says."""
    import os
    import yaml
    from temoto_chaos.motion_truth import OBSTACLE_SOURCES
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'temoto_sensor_manager',
                        'config', 'vaultbot.yaml')
    with open(path) as f:
        sensors = yaml.safe_load(f)['sensors']
    rates = {}
    for sensor in sensors:
        for output in sensor['output_topics'].values():
            rates[output['topic']] = output.get('rate', sensor.get('rate'))
    for topic, period in OBSTACLE_SOURCES.items():
        assert rates[topic] is not None and period == pytest.approx(1.0 / rates[topic]), topic


def test_a_switch_to_a_silent_source_keeps_the_braking_its_predecessor_gave_and_no_more():
    """Seed 17, history 7, step 6229: the SICK died mid-drive, the navigator switched to a cloud silent for 12 s,
    and the base, braking from the SICK's stop, was judged blind on the cloud's clock. The cover the SICK gave
    stands through the switch; a base still moving past it, on the silent cloud, is blind."""
    cloud = 'laser_stitcher/cloud'
    truth = GroundTruth({SICK: 0.04, cloud: 0.1})
    for i in range(12):
        truth.obstacle(i * 0.1, cloud)             # the cloud, heard long ago
    truth.navigator_reads([SICK])
    t = 10.0
    for i in range(10):
        truth.obstacle(t + i * 0.04, SICK)
        truth.base(t + i * 0.04, 0.5, 0.0)
    last = t + 9 * 0.04
    truth.base(last + 0.1, 0.4, 0.0)
    truth.navigator_reads([cloud])                 # the switch, mid-braking
    truth.base(last + blind_after(0.04) - 0.01, 0.1, 0.0)
    assert not [e for e in truth.since(0)['events'] if e['type'] == 'blind'], 'braking from a stop in time'
    truth.base(last + blind_after(0.04) + 0.02, 0.1, 0.0)   # past the SICK's cover, on the silent cloud
    truth.base(last + blind_after(0.04) + 0.1, 0.0, 0.0)
    [blind] = [e for e in truth.since(0)['events'] if e['type'] == 'blind']
    assert blind['active'] == cloud and blind['start'] == pytest.approx(last + blind_after(0.04) + 0.02)
