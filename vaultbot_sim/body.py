"""The robot's moving parts as the simulation owns them: the base's motors and body, the arms' joint motors,
and their contacts with the world. No ROS: ``sim_node.py`` feeds it commands and publishes what it says.

Contacts are checked in a private pybullet copy of the robot and the world (``scene.Scene``), posed, never
stepped. A base pose that touches the world is not entered (``base.BasePlant``). An arm that touches it is
put back where it was and its setpoint dropped, as a UR arm's protective stop does. Either way one touch is one
contact, however long it is pushed: a touch lasts until the robot is ``CONTACT_MARGIN`` clear of the object.
The gripper's fingers meeting an object are a grasp, not a contact: they stop there (``gripper.GripperPlant``).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

from vaultbot_sim.arm import ArmPlant
from vaultbot_sim.base import BISECTIONS, BasePlant, Contact, wheel_speeds
from vaultbot_sim.gripper import GripperPlant
from vaultbot_sim.scene import Scene
from vaultbot_sim.spec import BASE_JOINTS, GRIPPER_JOINTS, WHEEL_JOINTS

CONTACT_MARGIN = 0.01
IDLE_WAIT_S = 0.5


@dataclass
class Step:
    """What one step of the body gives: the joints it owns, and the touches that began."""
    names: List[str]
    positions: List[float]
    velocities: List[float]
    contacts: List[Tuple[Contact, float]] = field(default_factory=list)     # (contact, speed of the part)


class Body:
    def __init__(self, collider: Scene, base: BasePlant, arms: Mapping[str, ArmPlant],
                 gripper: Optional[GripperPlant] = None) -> None:
        self.collider = collider
        self.base = base
        self.arms = dict(arms)              # 'left_arm', 'right_arm'
        self.gripper = gripper if gripper is not None else GripperPlant()
        self._finger_links = {j.replace('_joint', '_link') for j in GRIPPER_JOINTS}
        # held by every call; notified by every command (the command timeout's thread waits)
        self.lock = threading.Condition()
        self.contacts = 0
        self.touching: set = set()          # (robot link, world link) pairs within CONTACT_MARGIN now
        self._checks = 0                    # collision checks in the step under way

    # --- commands (any thread) -------------------------------------------------------------------
    def command_base(self, left: float, right: float, now: float) -> bool:
        """The wheels' command; True when it makes the commanded velocity zero now (a stop's moment)."""
        with self.lock:
            moving = self.base.commanded != (0.0, 0.0)
            self.base.command(left, right, now)
            self.lock.notify()
            return moving and self.base.commanded == (0.0, 0.0)

    def command_arm(self, arm: str, setpoint: Mapping[str, Tuple[float, float]], now: float,
                    sent: float = 0.0) -> bool:
        """An arm's setpoint (``sent``: its stamp); True when it makes the commanded joint speed zero now (a hold's
        moment)."""
        with self.lock:
            plant = self.arms[arm]
            moving = plant.setpoint is not None and any(v != 0.0 for _, v in plant.setpoint.values())
            if not plant.command(setpoint, now, sent):
                return False
            self.lock.notify()
            return moving and all(v == 0.0 for _, v in plant.setpoint.values())

    def stop_arm(self, arm: str, now: float) -> bool:
        """An arm's stop; False when nobody holds the arm (the stop is moot: ``Arm.stop``)."""
        with self.lock:
            taken = self.arms[arm].stop(now)
            self.lock.notify()
            return taken

    def command_gripper(self, gap: float, speed: float, now: float) -> None:
        with self.lock:
            self.gripper.command(gap, speed, now)
            self.lock.notify()

    def stop_gripper(self, now: float) -> None:
        with self.lock:
            self.gripper.stop(now)
            self.lock.notify()

    # --- the motors' command timeout (its own thread) -----------------------------------------------------
    def drop_stale(self, now: float) -> List[str]:
        """The parts whose stale command was dropped now: 'base', arm names and 'gripper'."""
        with self.lock:
            tripped = ['base'] if self.base.drop_stale(now) else []
            tripped += [name for name, arm in self.arms.items() if arm.drop_stale(now)]
            return tripped + (['gripper'] if self.gripper.drop_stale(now) else [])

    def wait_for_deadline(self, now: float) -> None:
        """Sleep until the earliest command could go stale, or until a command arrives."""
        with self.lock:
            deadlines = []
            if self.base.command_at is not None and self.base.commanded != (0.0, 0.0):
                deadlines.append(self.base.command_at + self.base.motor_timeout)
            deadlines += [a.command_at + a.motor_timeout for a in list(self.arms.values()) + [self.gripper]
                          if a.setpoint is not None and a.command_at is not None]
            wait = IDLE_WAIT_S if not deadlines else max(0.0, min(deadlines) - now) + 0.0005
            self.lock.wait(min(wait, IDLE_WAIT_S))

    # --- a step of the simulation -------------------------------------------------------------------
    def step(self, now: float, hold: Mapping[str, float]) -> Step:
        """Move every part to ``now``. ``hold``: the joints the simulation sets itself (the stowed pose, the sweep);
        an arm's joints come from its motors once someone holds it."""
        with self.lock:
            cfg = dict(hold)
            for arm in self.arms.values():
                if arm.held:
                    cfg.update(arm.position)
                else:                         # follows the stowed pose and the sweep until someone holds it
                    arm.position.update({j: hold[j] for j in arm.joints if j in hold})
            out = Step([], [], [])
            speed = abs(self.base.velocity[0])
            touched: Dict[Tuple[str, str], None] = {}      # pairs within the margin, in what was checked
            contact = self.base.step(now, lambda pose: self._blocked(dict(cfg, **dict(zip(BASE_JOINTS, pose))),
                                                                     pose, touched))
            if contact is not None:
                out.contacts.append((contact, speed))
            cfg.update(zip(BASE_JOINTS, self.base.pose))
            cfg.update(self._fingers(self.gripper.gap))
            for name, arm in self.arms.items():
                if not arm.held:
                    continue
                before = (dict(arm.position), dict(arm.velocity))
                arm.step(now)
                if arm.at_rest and arm.position == before[0]:
                    continue
                after = dict(arm.position)
                hit = self._blocked(dict(cfg, **after), self.base.pose, touched)
                if hit is not None:           # protective stop where it touched: at rest, setpoint dropped
                    arm.position.update(self._last_free(cfg, before[0], after, touched))
                    arm.velocity.update({j: 0.0 for j in arm.joints})
                    arm.setpoint = None
                    out.contacts.append((hit, max(abs(v) for v in before[1].values())))
                cfg.update(arm.position)
            self.gripper.step(now, lambda gap: self._fingers_blocked(dict(cfg, **self._fingers(gap))))
            checked = bool(self._checks)
            self._checks = 0
            # A touch begins at an overlap while no touch lasts, and lasts until whatever moved is clear of
            # every object by the margin: one touch is one contact, however long it is pushed.
            began = out.contacts[:1] if out.contacts and not self.touching else []
            if out.contacts:
                self.touching = set(touched)
            elif checked and not touched:
                self.touching = set()
            out.contacts = began
            self.contacts += len(out.contacts)
            out.names, out.positions, out.velocities = self._joints()
            return out

    def _last_free(self, cfg: Dict[str, float], start: Dict[str, float], end: Dict[str, float],
                   touched: Dict) -> Dict[str, float]:
        """The arm's last free configuration between ``start`` (free) and ``end`` (touching), by bisection to
        a 64th of the step: the arm stops where it touched, not a whole step back (a push then goes on as one
        touch, within the margin)."""
        free, lo, hi = start, 0.0, 1.0
        for _ in range(BISECTIONS):
            mid = (lo + hi) / 2
            q = {j: start[j] + (end[j] - start[j]) * mid for j in start}
            if self._blocked(dict(cfg, **q), self.base.pose, touched) is None:
                free, lo = q, mid
            else:
                hi = mid
        return free

    def _blocked(self, cfg: Dict[str, float], pose, touched: Dict) -> Optional[Contact]:
        """A configuration's overlap with the world, if any; records what is within the margin in ``touched``."""
        self._checks += 1
        self.collider.set_robot(cfg)
        near = self.collider.contacts(margin=CONTACT_MARGIN)
        touched.update({(a, b): None for a, b, _ in near})
        overlap = [(a, b) for a, b, d in near if d <= 0.0]
        return Contact(overlap[0][0], overlap[0][1], pose[0], pose[1]) if overlap else None

    @staticmethod
    def _fingers(gap: float) -> Dict[str, float]:
        """The finger joints for a gap between the pads: each finger moves half of it."""
        return {j: gap / 2 for j in GRIPPER_JOINTS}

    def _fingers_blocked(self, cfg: Dict[str, float]) -> bool:
        """Whether a finger overlaps the world in ``cfg`` (a grasp: not recorded as a touch)."""
        self.collider.set_robot(cfg)
        return any(d <= 0.0 and a in self._finger_links for a, _, d in self.collider.contacts())

    def _joints(self) -> Tuple[List[str], List[float], List[float]]:
        """The base's virtual joints, the wheels and the held arms' joints: names, positions, velocities."""
        base = self.base
        (x, y, yaw), (v, w) = base.pose, base.velocity
        left, right = base.wheels
        wheel_v = wheel_speeds(v, w)
        names = list(BASE_JOINTS) + list(WHEEL_JOINTS)
        pos = [x, y, yaw] + [left if 'left' in n else right for n in WHEEL_JOINTS]
        vel = [v * math.cos(yaw), v * math.sin(yaw), w] + [wheel_v[0] if 'left' in n else wheel_v[1]
                                                            for n in WHEEL_JOINTS]
        for arm in self.arms.values():
            if arm.held:
                names += arm.joints
                pos += [arm.position[j] for j in arm.joints]
                vel += [arm.velocity[j] for j in arm.joints]
        names += list(GRIPPER_JOINTS)
        pos += [self.gripper.gap / 2] * len(GRIPPER_JOINTS)
        vel += [self.gripper.velocity / 2] * len(GRIPPER_JOINTS)
        return names, pos, vel

    def arm_speeds(self, arm: str) -> Tuple[float, float]:
        """(commanded, actual): the largest |velocity| of an arm's setpoint (0 without one) and of its joints."""
        with self.lock:
            plant = self.arms[arm]
            commanded = max((abs(v) for _, v in plant.setpoint.values()), default=0.0) if plant.setpoint else 0.0
            return commanded, max(abs(v) for v in plant.velocity.values())


def joint_names(sides: Sequence[str], joints: Sequence[str]) -> Dict[str, List[str]]:
    """{'left_arm': ['left_shoulder_pan_joint', ...], ...}."""
    return {'%s_arm' % side: ['%s_%s_joint' % (side, j) for j in joints] for side in sides}
