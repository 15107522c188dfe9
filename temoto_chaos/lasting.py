"""A fault that lasts, going on in a thread of its own: a cut link, a manager SIGSTOPped for a while, or a
manager SIGKILLed until its next incarnation answers.

In a concurrent history the runner does not sit out such a fault. It queues the clients' next steps
meanwhile, as Jepsen's nemesis runs beside its clients, so the calls made during the fault meet it. The
fault ends on its own clock (the link is plugged back, the manager gets SIGCONT or is respawned) whatever
the runner does.
No check runs while it lasts: the registries it cuts off could not answer, and a check would only wait.
The runner ends the fault before the next fault or check, and checks at once what it left (logged at the
fault's step).
"""
from __future__ import annotations

import threading
from typing import Callable, Optional


class LastingFault:
    """``body`` is the whole fault (do it, wait it out, undo it) and returns what was done, a sentence."""

    def __init__(self, entry: dict, body: Callable[[], str]) -> None:
        self.entry = entry                       # the fault's step in the run's log
        self._body = body
        self._did = ''
        self._error: Optional[BaseException] = None
        self._thread = threading.Thread(target=self._run, daemon=True, name='chaos-fault-%d' % entry['step'])
        self._thread.start()

    def _run(self) -> None:
        try:
            self._did = self._body()
        except BaseException as err:        # raised again in end(), to the runner, as a step it could not do
            self._error = err

    def done(self) -> bool:
        return not self._thread.is_alive()

    def end(self, timeout: float) -> str:
        """Wait for the fault to end on its own clock; what it did. Raises what the fault raised, or
        TimeoutError if it has not ended within ``timeout`` (its own bounds are shorter)."""
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise TimeoutError('the fault of step %d did not end within %.0f s' % (self.entry['step'], timeout))
        if self._error is not None:
            raise self._error
        return self._did
