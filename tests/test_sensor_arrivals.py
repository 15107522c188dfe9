"""Stall detection from a stream's own rhythm (temoto_core/stall/arrivals.py): pure logic. A real
stall caught with the adaptive limit, across processes, is in test_sensor_manager.py."""
import random

import pytest

from temoto_core.stall import arrivals
from temoto_core.stall.arrivals import ArrivalModel
from temoto_sensor_manager.catalogue import parse_entry


def fed(gaps):
    model = ArrivalModel()
    for gap in gaps:
        model.add(gap)
    return model


def test_the_catalogue_limit_holds_until_enough_gaps_are_seen():
    model = fed([1 / 30.0] * (arrivals.WARMUP - 1))
    assert model.limit(0.5, 1 / 30.0) == 0.5
    model.add(1 / 30.0)
    assert model.limit(0.5, 1 / 30.0) < 0.5


def test_a_steady_30_hz_stream_is_watched_within_three_periods_and_never_below_the_floor():
    rng = random.Random(3)
    model = fed([1 / 30.0 + rng.gauss(0, 0.002) for _ in range(600)])
    limit = model.limit(0.5, 1 / 30.0)
    assert arrivals.FLOOR_PERIODS / 30.0 <= limit <= 3 / 30.0, limit
    # perfectly regular: the floor (2.5 periods), not the mean plus a vanishing spread
    assert fed([0.04] * 100).limit(1.0, 0.04) == pytest.approx(arrivals.FLOOR_PERIODS * 0.04)


def test_a_fast_regular_stream_is_not_called_stalled_by_a_scheduling_gap():
    """A 100 Hz hand source, regular for its first second: its limit learnt 2.5 periods (25 ms), and a 48 ms
    gap on a loaded machine was called a stall (a CI run's virtual hand). The floor in seconds is above it."""
    model = fed([0.01] * arrivals.WARMUP)
    assert model.limit(0.2, 0.01) >= 0.048 * 1.5
    assert model.limit(0.2, 0.01) == pytest.approx(arrivals.FLOOR_S)
    assert fed([0.01] * arrivals.WARMUP).limit(0.05, 0.01) == 0.05, 'the catalogue\'s own limit still caps it'


def test_a_jittery_stream_gets_a_longer_limit_and_the_cap_bounds_it():
    rng = random.Random(4)
    steady = fed([1 / 30.0 + rng.gauss(0, 0.002) for _ in range(300)]).limit(0.5, 1 / 30.0)
    jittery = fed([abs(1 / 30.0 + rng.gauss(0, 0.015)) for _ in range(300)]).limit(0.5, 1 / 30.0)
    assert jittery > steady
    assert fed([0.2, 0.01] * 100).limit(0.3, 0.1) == 0.3


def test_a_long_gap_raises_the_limit_until_it_leaves_the_history():
    model = fed([0.033] * 200 + [0.150] + [0.033] * 50)
    assert model.limit(0.5, 1 / 30.0) >= arrivals.MAX_GAP_MARGIN * 0.150
    for _ in range(arrivals.BUCKET * (arrivals.HISTORY_BUCKETS - 1)):
        model.add(0.033)
    assert model.limit(0.5, 1 / 30.0) >= arrivals.MAX_GAP_MARGIN * 0.150, 'still within the history'
    for _ in range(arrivals.BUCKET):
        model.add(0.033)
    assert model.limit(0.5, 1 / 30.0) < 0.150


def test_the_running_sums_do_not_drift_over_a_long_run():
    model = fed([0.001 * (i % 7) + 0.03 for i in range(50 * arrivals.WINDOW + 17)])
    window = [0.001 * (i % 7) + 0.03 for i in range(50 * arrivals.WINDOW + 17)][-arrivals.WINDOW:]
    assert model.mean() == pytest.approx(sum(window) / len(window), rel=1e-12)


def test_stall_detection_is_adaptive_unless_the_catalogue_says_fixed():
    base = {'name': 'a', 'type': 't', 'package': 'p', 'executable': 'e', 'rate': 30}
    assert parse_entry(dict(base, output_topics={'d': '/d'})).output_topics['d'].adaptive
    entry = parse_entry(dict(base, stall_detection='fixed',
                             output_topics={'d': '/d', 'e': {'topic': '/e', 'stall_detection': 'adaptive'}}))
    assert not entry.output_topics['d'].adaptive and entry.output_topics['e'].adaptive
    with pytest.raises(ValueError, match="stall_detection must be one of adaptive, fixed, got 'smart'"):
        parse_entry(dict(base, stall_detection='smart', output_topics={'d': '/d'}))
    with pytest.raises(ValueError, match='output_topics.d.stall_detection must be one of'):
        parse_entry(dict(base, output_topics={'d': {'topic': '/d', 'stall_detection': 3}}))


def test_a_rhythm_learnt_in_an_earlier_load_is_the_limit_until_this_load_learns_its_own():
    earlier = ArrivalModel()
    for _ in range(arrivals.WARMUP):
        earlier.add(0.025)
    fresh = ArrivalModel()
    assert fresh.limit(0.3, 0.025) == 0.3                      # nothing learnt: the catalogue's limit
    fresh.seed(earlier.rhythm())
    assert fresh.limit(0.3, 0.025) < 0.1                       # 2.5 periods, not 12
    fresh.add(0.2)                                             # a long gap in this load still widens it
    assert fresh.limit(0.3, 0.025) >= 0.3 - 1e-9
    fresh.seed((float('nan'), 0.0, 0.0))                       # a journal's garbage is ignored
    assert ArrivalModel().rhythm() is None
