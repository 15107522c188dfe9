"""Other hosts' clocks, learnt from their messages' stamps and arrivals (``temoto_core/clocks.py``). Across
processes, a station whose clock runs ahead or behind is in ``tests/test_navigation_link.py``."""
import pytest

from temoto_core.clocks import MAX_SKEW_S, RISE_S_PER_S, PeerClocks

HOSTS = {'/station_a': 'station', '/station_b': 'station', '/robot_node': 'robot', '/nobody': None}


def clocks():
    return PeerClocks(HOSTS.get, 'robot')


@pytest.mark.parametrize('skew', [0.5, -0.5, 0.0])
def test_a_skewed_station_is_judged_on_time_and_a_held_message_late_by_exactly_its_hold(skew):
    c = clocks()
    t = 1000.0
    for k in range(50):                                   # a 50 Hz stream, 2 to 6 ms on the way
        arrival = t + 0.02 * k + 0.002 + 0.004 * (k % 2)
        local = c.observe('/station_a', t + 0.02 * k + skew, arrival)
        assert 0.0 <= arrival - local <= 0.0041
    held = t + 2.0                                        # sent then, delivered 0.4 s later
    local = c.observe('/station_a', held + skew, held + 0.402)
    assert (held + 0.402) - local == pytest.approx(0.4, abs=0.02), 'late by the hold, less the offset\'s rise'


def test_a_hosts_nodes_share_its_clock_and_this_hosts_own_need_no_learning():
    c = clocks()
    c.observe('/station_a', 100.5, 100.002)               # the station 0.5 s ahead
    # a new node of that host, whose very first message a link held 0.3 s: judged late at once
    assert 101.3 - c.observe('/station_b', 101.5, 101.3) == pytest.approx(0.3, abs=0.02)
    assert c.observe('/robot_node', 150.0, 150.3) == 150.0, 'one clock: the stamp as it is'
    assert c.observe('/nobody', 150.0, 150.3) == 150.0, 'a host not known: the stamp as it is'


def test_the_offset_may_rise_slowly_so_a_clock_stepped_back_is_forgiven_and_a_hold_is_not():
    c = clocks()
    c.observe('/station_a', 100.0, 100.0)
    assert c.observe('/station_a', 102.0, 102.5) == pytest.approx(102.0 + 2.5 * RISE_S_PER_S), 'held 0.5 s: late'
    # the station's clock stepped back 0.5 s for good: its messages look late at first, then less and less
    lateness = [(100 + t + 0.5) - c.observe('/station_a', 100 + t, 100 + t + 0.5) for t in (10, 30, 60)]
    assert lateness[0] > lateness[1] > lateness[2] == pytest.approx(0.0)


def test_a_stamp_that_would_skew_the_clocks_past_the_bound_teaches_nothing():
    c = clocks()
    c.observe('/station_a', 100.0, 100.0)
    assert c.observe('/station_a', 100.0 + 2 * MAX_SKEW_S, 100.1) == 100.0 + 2 * MAX_SKEW_S
    assert c.offset('/station_a') == pytest.approx(0.0, abs=0.01), 'the wrong stamp left the offset alone'
