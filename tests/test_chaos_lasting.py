"""A lasting fault on its own (temoto_chaos/lasting.py): it ends on its own clock, and what it did, or what it
raised, reaches the runner at its end. (The runner's use of it, against the real managers: test_chaos.py.)"""
import threading

import pytest

from temoto_chaos.lasting import LastingFault


def test_the_fault_goes_on_while_the_runner_does_other_things_and_tells_what_it_did_at_its_end():
    release = threading.Event()
    fault = LastingFault({'step': 7}, lambda: 'waited' if release.wait(10) else 'never released')
    assert not fault.done()                  # it runs beside the caller
    release.set()
    assert fault.end(10) == 'waited' and fault.done()


def test_what_the_fault_raised_reaches_the_runner_at_its_end():
    def body():
        raise OSError('the link would not come back')
    fault = LastingFault({'step': 3}, body)
    with pytest.raises(OSError, match='would not come back'):
        fault.end(10)


def test_a_fault_past_its_bound_is_named_and_not_waited_for_forever():
    release = threading.Event()
    fault = LastingFault({'step': 12}, lambda: str(release.wait(10)))
    try:
        with pytest.raises(TimeoutError, match='step 12 did not end within 0 s'):
            fault.end(0.05)
    finally:
        release.set()
        assert fault.end(10) == 'True'
