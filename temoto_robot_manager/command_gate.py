"""One actuator's command gate: the only writer of its command, with inputs in a declared priority and a guard for
every rule that a command must pass. No ROS.

Before it, the base's ``cmd_vel`` was written from six places (the control loop, the teleop stream, its deadman,
the staleness watch, the halt, the controller watch), each with its own copy of the rules. A rule missed in one of
them was a robot that moved when it should not. Here every command goes through :meth:`CommandGate.offer`, and
every zero through :meth:`CommandGate.stop` or a guard; adding a safety rule is adding a guard.

- **Inputs** (:class:`Input`), as twist_mux declares them: a name, a priority and a timeout. An input is *live*
  from its command until its timeout, or until it is released (a goal's input has no timeout: the goal ends it).
  A command of an input is refused while an input of a higher priority is live; a command of a higher input takes
  the actuator from a lower one at once. The last live input's silence past its timeout is the deadman: zero, once.
- **Guards**: each has ``check(now) -> Optional[StopReason]`` (``guards.py``). A command passes only when every
  guard holds; otherwise the gate sends zero and says HELD with the guard's reason. :meth:`enforce` re-checks the
  guards between commands, at a guard's deadline, so a stale source zeroes the actuator at that moment and not at
  the next command.
- **Stops**: :meth:`stop` (the operator's halt, a dead controller, a goal that ended) sends zero, ends every input,
  and says STOPPED with the reason. Nothing moves again until an input's next command, and a command *decided*
  before the stop (its ``now``) is refused: a servo step computed while the stop came, or a goal planned then,
  must not follow the stop's zero. A stream (an input with a timeout) that goes on after a stop is not taken up
  again: it must fall silent for its timeout first, so that a stop ends a stream whose sender did not hear it
  (a hand that drives on), and only a new stream moves the actuator.

What it says is a :class:`Status` (the typed ``temoto_core/MotionStatus``), given to ``report`` when the state or
its reason changes. The gate is not thread-safe by itself: its owner calls it under the one lock that also guards
what the inputs decide from, so a zero is never overtaken by a command decided before it.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Callable, Dict, Generic, Optional, Sequence, TypeVar

from temoto_robot_manager.guards import StopCode, StopReason

Command = TypeVar('Command')


class State(enum.IntEnum):
    """``temoto_core/MotionStatus``'s states, by the same numbers."""
    IDLE = 0          # nothing commands it
    MOVING = 1        # commands pass
    HELD = 2          # held at zero by a guard; the input's motion waits for it to pass
    STOPPED = 3       # stopped for good: a new command moves it


@dataclass(frozen=True)
class Input:
    """One source of commands. ``timeout``: seconds after its last command that it lapses (None: until released)."""
    name: str
    priority: int
    timeout: Optional[float] = None

    def __post_init__(self) -> None:
        if self.timeout is not None and not self.timeout > 0:
            raise ValueError('input %s: timeout %r must be above 0 (or None: until released)'
                             % (self.name, self.timeout))


@dataclass(frozen=True)
class Status:
    state: State
    reason: Optional[StopCode]
    text: str


class Refused(ValueError):
    """A command the gate does not take: a higher input holds the actuator. The message names it."""


class CommandGate(Generic[Command]):
    def __init__(self, actuator: str, inputs: Sequence[Input], guards: Sequence, send: Callable[[Command], None],
                 zero: Command, report: Callable[[Status], None] = lambda status: None) -> None:
        names = [i.name for i in inputs]
        if len(set(names)) != len(names) or not names:
            raise ValueError('%s: inputs %r must be one or more, each named once' % (actuator, names))
        priorities = [i.priority for i in inputs]
        if len(set(priorities)) != len(priorities):
            raise ValueError('%s: inputs %r need distinct priorities, or which one wins is not said'
                             % (actuator, names))
        self.actuator = actuator
        self.inputs: Dict[str, Input] = {i.name: i for i in inputs}
        self.guards = list(guards)
        self._send, self._zero, self._report = send, zero, report
        self._until: Dict[str, float] = {}        # each live input: when it lapses (inf: until released)
        self._stopped_at = float('-inf')          # the last stop: a command decided before it is refused
        self._latched: Dict[str, float] = {}      # a stream stopped and going on: its last command, refused
        self.owner: Optional[str] = None          # the input whose command the actuator has now
        self.moving = False                       # the last command sent was not zero
        self.status = Status(State.IDLE, None, 'nothing commands the %s' % actuator)
        report(self.status)

    # -- what inputs do --------------------------------------------------------------------------------------------
    def offer(self, name: str, command: Command, now: float, moving: bool = True,
              held: Optional[StopReason] = None, why: str = '') -> Status:
        """A command of input ``name`` at ``now`` (monotonic): sent when every guard holds, else zero. ``moving``:
        whether the command moves the actuator (a zero does not). ``held``: the input's own reason for a zero (a
        goal waiting for an obstacle to clear). Raises :class:`Refused` when a higher input is live; a refused
        command changes nothing."""
        source = self.inputs[name]
        if now <= self._stopped_at:
            raise Refused('decided %.0f ms before the %s was stopped' % ((self._stopped_at - now) * 1e3,
                                                                        self.actuator))
        if name in self._latched:
            if now - self._latched[name] < source.timeout:
                self._latched[name] = now
                raise Refused('the %s was stopped: this stream must pause %.0f ms before it moves it again'
                              % (self.actuator, source.timeout * 1e3))
            del self._latched[name]                # silent for its timeout: a new stream
        self._lapse(now)
        higher = [i for i in self._until if self.inputs[i].priority > source.priority]
        if higher:
            raise Refused('the %s is held by %s, which comes first' % (self.actuator, higher[0]))
        for lower in [i for i in self._until if i != name]:
            del self._until[lower]                 # a higher input takes the actuator from a lower one at once
        self._until[name] = now + source.timeout if source.timeout is not None else float('inf')
        self.owner = name
        stop = self.check(now)
        if stop is not None:
            self._put(self._zero, False)
            return self._say(State.HELD, stop.code, stop.text)
        self._put(command, moving)
        if held is not None:
            return self._say(State.HELD, held.code, held.text)
        return self._say(State.MOVING, None, why or '%s commands the %s' % (name, self.actuator))

    def release(self, name: str, reason: StopReason) -> None:
        """Input ``name`` is done (its goal ended, its holder gone): zero if it had the actuator, STOPPED."""
        self._until.pop(name, None)
        if self.owner == name:
            self.owner = None
            self._put(self._zero, False)
            self._say(State.STOPPED, reason.code, reason.text)

    def stop(self, reason: StopReason, now: float) -> None:
        """Zero now, whoever commands, and every input ended: the operator's halt, a dead controller. A command
        decided at ``now`` or before is refused after it."""
        self._stopped_at = max(self._stopped_at, now)
        # every stream is latched off until it pauses for its timeout, from now
        self._latched = {i.name: now for i in self.inputs.values() if i.timeout is not None}
        self._until.clear()
        self.owner = None
        self._put(self._zero, False)
        self._say(State.STOPPED, reason.code, reason.text)

    def refused(self, reason: StopReason) -> None:
        """A command refused before it reached the gate (late, bad): said when no input moves the actuator (a goal
        that drives is not stopped by a stray stream's refusal), nothing sent."""
        if self.owner is None:
            self._say(State.STOPPED, reason.code, reason.text)

    # -- between commands --------------------------------------------------------------------------------------------
    def check(self, now: float) -> Optional[StopReason]:
        """Why a guard forbids motion now (a final reason first), or None."""
        reasons = [r for r in (g.check(now) for g in self.guards) if r is not None]
        return next((r for r in reasons if r.final), reasons[0] if reasons else None)

    def deadline(self) -> Optional[float]:
        """The earliest moment a live input lapses; None when none can."""
        finite = [t for t in self._until.values() if t != float('inf')]
        return min(finite) if finite else None

    def enforce(self, now: float) -> Optional[StopReason]:
        """Lapse the inputs whose timeout passed (the deadman), and hold a moving actuator at zero if a guard trips
        now. Returns the reason when it sent a zero, else None."""
        lapsed = self._lapse(now)
        if lapsed is not None:
            return lapsed
        if self.owner is None or not self.moving:
            return None
        stop = self.check(now)
        if stop is not None:
            self._put(self._zero, False)
            self._say(State.HELD, stop.code, stop.text)
        return stop

    # -- inside ----------------------------------------------------------------------------------------------------
    def _lapse(self, now: float) -> Optional[StopReason]:
        """End the inputs whose timeout passed; the deadman's reason when the one that had the actuator did."""
        lapsed = None
        for name, until in list(self._until.items()):
            if now < until:
                continue
            del self._until[name]
            if self.owner == name:
                self.owner = None
                lapsed = StopReason(StopCode.DEADMAN, 'no %s command for %.0f ms'
                                    % (name, self.inputs[name].timeout * 1e3))
                self._put(self._zero, False)
                self._say(State.STOPPED, lapsed.code, lapsed.text)
        return lapsed

    def _put(self, command: Command, moving: bool) -> None:
        self._send(command)
        self.moving = moving

    def _say(self, state: State, reason: Optional[StopCode], text: str) -> Status:
        if (state, reason) != (self.status.state, self.status.reason):
            self.status = Status(state, reason, text)
            self._report(self.status)
        return self.status
