"""Status channels, their logic alone: rospy's Publisher is replaced by a recorder whose making can be held,
as rospy holds it while the master is away (its registration loop). Across processes, with a master
really stopped: test_master_rejoin.py."""
import threading

import pytest

from temoto_core.rr import channels as channels_module
from temoto_core.rr.channels import MasterAway, StatusChannels
from temoto_core.msg import ResourceStatus
from temoto_testing import wait_for

HANG = 10.0


class HeldPublisher:
    """Records what is published; making one for a topic in ``held`` waits until ``release`` is set."""
    held: set = set()
    release = threading.Event()
    made: list = []
    by_topic: dict = {}

    def __init__(self, topic, data_class, **kwargs):
        HeldPublisher.made.append(topic)
        if topic in HeldPublisher.held:
            assert HeldPublisher.release.wait(3 * HANG), 'the test never released the publisher'
        self.topic, self.sent = topic, []
        HeldPublisher.by_topic[topic] = self

    def publish(self, msg):
        self.sent.append(msg)

    def get_num_connections(self):
        return 1

    def unregister(self):
        pass


@pytest.fixture
def channels(monkeypatch, rospy_client):           # rospy's clock stamps every status
    HeldPublisher.held, HeldPublisher.made, HeldPublisher.by_topic = set(), [], {}
    HeldPublisher.release = threading.Event()
    monkeypatch.setattr(channels_module.rospy, 'Publisher', HeldPublisher)
    yield StatusChannels('owner', connect_timeout=1.0)
    HeldPublisher.release.set()


def test_a_status_on_an_open_channel_does_not_wait_for_a_channel_being_made(channels):
    channels.acquire('/temoto/a/status')
    HeldPublisher.held.add('/temoto/b/status')
    making = threading.Thread(target=channels.acquire, args=('/temoto/b/status',), daemon=True)
    making.start()
    wait_for(lambda: '/temoto/b/status' in HeldPublisher.made, HANG, 'the second channel to be under way')
    status = ResourceStatus(server_name='srv', resource_id=7, status_code=1, message='failed')
    sent = threading.Thread(target=lambda: channels.publisher('/temoto/a/status').publish(status), daemon=True)
    sent.start()
    sent.join(HANG)
    assert not sent.is_alive(), 'a status to an open channel waited for another channel to be made'
    assert [(m.resource_id, m.message) for m in HeldPublisher.by_topic['/temoto/a/status'].sent] == [(7, 'failed')]
    HeldPublisher.release.set()
    making.join(HANG)
    assert not making.is_alive()


def test_two_loads_that_need_the_same_new_channel_make_one_publisher(channels):
    HeldPublisher.held.add('/temoto/c/status')
    loads = [threading.Thread(target=channels.acquire, args=('/temoto/c/status',), daemon=True) for _ in range(2)]
    for load in loads:
        load.start()
    wait_for(lambda: '/temoto/c/status' in HeldPublisher.made, HANG, 'the channel to be under way')
    HeldPublisher.release.set()
    for load in loads:
        load.join(HANG)
        assert not load.is_alive()
    assert HeldPublisher.made.count('/temoto/c/status') == 1


class Away:
    address = ('127.0.0.1', 9)

    def probe(self):
        return False


def test_a_new_channel_is_refused_naming_the_master_when_it_does_not_answer(monkeypatch):
    HeldPublisher.held, HeldPublisher.made = set(), []
    monkeypatch.setattr(channels_module.rospy, 'Publisher', HeldPublisher)
    channels = StatusChannels('owner', connect_timeout=1.0, master_reach=Away())
    channels.acquire('/temoto/open/status')          # opened before: needs no master
    channels.acquire('/temoto/open/status', master_needed=True)
    with pytest.raises(MasterAway, match=r'the master at 127\.0\.0\.1:9 does not answer.*/temoto/new/status'):
        channels.acquire('/temoto/new/status', master_needed=True)
    assert HeldPublisher.made == ['/temoto/open/status']
