"""Device "cables": which simulated sensors are plugged in, and what their drivers do when not.

Pure logic shared by the sim (which owns the table), the drivers (which obey it)
and the CLI (which validates before calling the service).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from vaultbot_sim.spec import DEVICES, MODES, STATES


class DeviceError(ValueError):
    """Bad device, state or mode; the message names what was wrong and the valid choices."""


@dataclass(frozen=True)
class Cable:
    name: str
    plugged: bool = True
    mode: str = 'crash'


def validate(device: str, state: str, mode: str) -> tuple[str, bool, str]:
    """Check one request; returns (device, plugged, mode). An empty mode means crash."""
    if device not in DEVICES:
        raise DeviceError(f'unknown device {device!r}: use one of {", ".join(DEVICES)}')
    if state not in STATES:
        raise DeviceError(f'unknown state {state!r}: use one of {", ".join(STATES)}')
    mode = mode or 'crash'
    if mode not in MODES:
        raise DeviceError(f'unknown mode {mode!r}: use one of {", ".join(MODES)}')
    return device, state == 'plugged', mode


class DeviceTable:
    """The state of every cable. Invalid requests raise DeviceError and change nothing."""

    def __init__(self, devices: Iterable[str] = DEVICES):
        self._cables = {d: Cable(d) for d in devices}

    def set(self, device: str, state: str, mode: str = '') -> Cable:
        device, plugged, mode = validate(device, state, mode)
        cable = Cable(device, plugged, mode)
        self._cables[device] = cable
        return cable

    def get(self, device: str) -> Cable:
        return self._cables[device]

    def all(self) -> list[Cable]:
        return [self._cables[d] for d in sorted(self._cables)]


class CableWatch:
    """What a driver should do given the latest states message: 'run', 'crash' or 'stall'.

    A stalled driver stays stalled even if the cable is plugged back in, like a real
    driver whose device vanished under it; a newly started driver works again.
    """

    def __init__(self, device: str):
        if device not in DEVICES:
            raise DeviceError(f'unknown device {device!r}: use one of {", ".join(DEVICES)}')
        self.device = device
        self.verdict: str | None = None   # None until the first states message

    def update(self, cables: Iterable[Cable]) -> str:
        for c in cables:
            if c.name == self.device:
                if self.verdict == 'stall':
                    return self.verdict
                self.verdict = 'run' if c.plugged else c.mode
                return self.verdict
        # A states message that does not list our device: treat as no device found.
        if self.verdict is None:
            self.verdict = 'crash'
        return self.verdict
