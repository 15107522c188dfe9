"""gripper: "open the gripper", "close the gripper".

Holds the robot's gripper through the Robot Manager for one command and sends it to the gripper's controller
(``control_msgs/GripperCommand``): the gap is the description's named position (``open``, ``closed``). It
ends FINISHED when the fingers reach the gap, or stop on an object (a grasp: the gap is the object's width);
FAILED with the controller's reason. "stop" cancels the command: the fingers stop where they are.
"""
from actionlib_msgs.msg import GoalStatus
from control_msgs.msg import GripperCommand, GripperCommandAction, GripperCommandGoal

from temoto_action_engine.action_base import ActionError
from temoto_action_engine.robot_action import RobotAction

POSITIONS = {'open': 'open', 'release': 'open', 'close': 'closed', 'grip': 'closed', 'grasp': 'closed'}
COMMAND_TIMEOUT_S = 30.0


class Gripper(RobotAction):
    def on_start(self):
        command = (self.input('command') or '').strip().lower()
        if command not in POSITIONS:
            raise ActionError('gripper command "%s": say one of %s' % (command, ', '.join(sorted(POSITIONS))))
        info = self.claim_robot('gripper')
        gripper = info.get('gripper') or {}
        positions = gripper.get('positions') or {}
        self.position = POSITIONS[command]
        if self.position not in positions:
            raise ActionError('%s\'s gripper has no position "%s" (its positions: %s)'
                              % (info['name'], self.position, ', '.join(sorted(positions)) or 'none'))
        self.gap = float(positions[self.position])
        self.client = self.client(gripper['action'], GripperCommandAction)

    def execute(self):
        self.event('gripper', position=self.position, gap=self.gap)
        state, text, result = self.run_goal(
            self.client, GripperCommandGoal(command=GripperCommand(position=self.gap, max_effort=0.0)),
            'the gripper\'s %s' % self.position, COMMAND_TIMEOUT_S)
        if not self.action_ok():
            return
        if state != GoalStatus.SUCCEEDED or result is None:
            raise ActionError('the gripper did not %s: %s' % ({'open': 'open', 'closed': 'close'}[self.position],
                                                             text or self.state_name(state)))
        self.set_output('gap', float(result.position))
        if result.stalled:
            self.event('grasped', width=round(result.position, 4))
            self.feedback('holding an object %.1f mm wide' % (1000 * result.position))
        else:
            self.event('gripper_reached', position=self.position, gap=round(result.position, 4))
            self.feedback('%s: %.1f mm' % (self.position, 1000 * result.position))
