"""How an action that keeps a view up fails over, fails back and treats a flapping source.

Plain data and arithmetic, no ROS: ``show_environment`` (and any action with a priority list of
sources) reads a :class:`FailoverConfig` from its configuration and its request, and asks a
``temoto_core.backoff.Backoff`` per source when it may try that source again (the Robot Manager's
obstacle fail-back asks the same rule).

Standby policies, the paper's power argument kept as a choice:

- ``cold``: nothing runs ahead of need. A failover starts the next driver, then its display.
- ``warm``: the next source's driver runs (its data flows, nobody shows it). A failover only adds
  the display, which waits for RViz to connect to the running driver.
- ``hot``: the next source also streams into a hidden display. A failover is one visibility change:
  the spare's latest frame is on screen at the next render, with no new connection.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any, Mapping, Optional


class Standby(str, enum.Enum):
    COLD = 'cold'
    WARM = 'warm'
    HOT = 'hot'

    @classmethod
    def parse(cls, value: Any, where: str) -> 'Standby':
        try:
            return cls(str(value).strip().lower())
        except ValueError:
            raise ValueError('%s must be one of %s, got %r' % (where, ', '.join(p.value for p in cls), value)) from None


@dataclass(frozen=True)
class FailoverConfig:
    standby: Standby = Standby.COLD
    failback: bool = True           # return to a better-ranked source once it works again
    failback_hold_s: float = 2.0    # a returned source must run this long without a FAILED before the switch
    failback_check_s: float = 2.0   # first wait before a better source is tried again; doubles per failure
    failback_max_s: float = 8.0     # the longest wait between two tries of a source
    quarantine_after: int = 3       # this many flaps in a row (up, then FAILED within a hold) ...
    quarantine_s: float = 60.0      # ... keep the source out of fail-back this long
    retry_initial_s: float = 2.0    # every source failed: the first wait before the list is tried again
    retry_max_s: float = 30.0

    @classmethod
    def from_config(cls, config: Mapping[str, Any], standby_override: Optional[str] = None) -> 'FailoverConfig':
        """Read and check the action's configuration; ``standby_override`` is the request's own policy.

        Raises ValueError naming the first bad key.
        """
        def number(key: str, low: float, high: float) -> float:
            value = config.get(key, getattr(cls, key))
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or not low <= value <= high:
                raise ValueError('%s must be a number from %g to %g, got %r' % (key, low, high, value))
            return float(value)
        failback = config.get('failback', cls.failback)
        if not isinstance(failback, bool):
            raise ValueError('failback must be true or false, got %r' % (failback,))
        standby = Standby.parse(config.get('standby', cls.standby.value), 'standby')
        if standby_override:
            standby = Standby.parse(standby_override, "the request's standby")
        out = cls(standby=standby, failback=failback,
                  failback_hold_s=number('failback_hold_s', 0.0, 600.0),
                  failback_check_s=number('failback_check_s', 0.05, 600.0),
                  failback_max_s=number('failback_max_s', 0.05, 3600.0),
                  quarantine_after=int(number('quarantine_after', 1, 1000)),
                  quarantine_s=number('quarantine_s', 0.0, 86400.0),
                  retry_initial_s=number('retry_initial_s', 0.01, 600.0),
                  retry_max_s=number('retry_max_s', 0.01, 3600.0))
        if out.failback_max_s < out.failback_check_s:
            raise ValueError('failback_max_s (%g) must not be under failback_check_s (%g)'
                             % (out.failback_max_s, out.failback_check_s))
        if out.retry_max_s < out.retry_initial_s:
            raise ValueError('retry_max_s (%g) must not be under retry_initial_s (%g)'
                             % (out.retry_max_s, out.retry_initial_s))
        return out
