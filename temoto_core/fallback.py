"""Try ranked candidates until one works: the one loop behind every failover in TeMoto.

The Sensor Manager tries sensors, the Context Manager tries trackers and detection
methods, and an action tries its own priority list. Each is the same loop, modelled
on py_trees' ``Selector``: candidates are tried in priority order; the first that
works wins; one that fails is rolled back, loses reliability (when the failure is
its own fault, not, say, a manager being away), and the next is tried. When none
works, the error names every candidate and why it failed, once each.

The loop knows nothing of ROS: an ``attempt`` is any callable that returns a result
or raises.
"""
from __future__ import annotations

import dataclasses
from typing import Callable, Generic, Iterable, List, Optional, Sequence, Tuple, TypeVar

from temoto_core.errors import ErrorCode, TemotoError
from temoto_core.reliability import Reliability

C = TypeVar('C')
R = TypeVar('R')


@dataclasses.dataclass
class Tried(Generic[C]):
    """One candidate that failed, and why."""
    candidate: C
    name: str
    error: BaseException

    @property
    def reason(self) -> str:
        """The candidate's own failure, said once: where it started, not every hop it took."""
        if isinstance(self.error, TemotoError):
            return self.error.origin.message
        return str(self.error) or type(self.error).__name__


class NoCandidateLeft(TemotoError):
    """Every candidate failed; ``tried`` lists them in the order they were tried."""

    def __init__(self, code: int, subsystem: int, message: str, tried: Sequence[Tried]) -> None:
        super().__init__(code, subsystem, message)
        self.tried = list(tried)


def first_that_works(candidates: Iterable[C], attempt: Callable[[C], R], *, what: str, subsystem: int,
                     code: int = ErrorCode.RESOURCE_FAILED, name: Callable[[C], str] = str,
                     reliability: Optional[Callable[[C], Reliability]] = None,
                     counts_against: Callable[[BaseException], bool] = lambda err: True,
                     rollback: Optional[Callable[[C, BaseException], None]] = None,
                     on_failure: Optional[Callable[[Tried], None]] = None,
                     keep_going: Callable[[], bool] = lambda: True,
                     errors: Tuple[type, ...] = (TemotoError,)) -> Tuple[C, R]:
    """Return ``(candidate, attempt(candidate))`` for the first candidate whose attempt does not raise.

    - ``reliability(c)``: the candidate's reliability, raised on success and lowered on a failure
      that ``counts_against`` it;
    - ``rollback(c, err)``: undo what a failed attempt left behind (never raises into the loop);
    - ``on_failure(tried)``: report a failure (a log line, an event);
    - ``keep_going()``: checked before each candidate (an action being stopped says False);
    - ``errors``: the exceptions that mean "this candidate failed"; anything else propagates.

    Raises :class:`NoCandidateLeft` (``code``) naming ``what`` and every candidate tried.
    """
    tried: List[Tried] = []
    for candidate in candidates:
        if not keep_going():
            break
        try:
            result = attempt(candidate)
        except errors as err:
            failure = Tried(candidate, name(candidate), err)
            tried.append(failure)
            if rollback is not None:
                try:
                    rollback(candidate, err)
                except Exception as rollback_err:      # reported with the failure, never raised over it
                    failure.error = TemotoError(ErrorCode.UNSPECIFIED, subsystem, '%s (and rolling it back failed: '
                                                '%s)' % (failure.reason, rollback_err))
            if reliability is not None and counts_against(err):
                reliability(candidate).failure()
            if on_failure is not None:
                on_failure(failure)
            continue
        if reliability is not None:
            reliability(candidate).success()
        return candidate, result
    if not tried:
        raise NoCandidateLeft(code, subsystem, 'no candidate for %s was tried%s'
                              % (what, '' if keep_going() else ' (stopped)'), tried)
    raise NoCandidateLeft(code, subsystem, 'no candidate left for %s: every one failed (%s)'
                          % (what, '; '.join('%s: %s' % (t.name, t.reason) for t in tried)), tried)
