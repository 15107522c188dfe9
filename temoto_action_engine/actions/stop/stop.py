"""stop: halt the robot, or stop running actions by name or by the words that started them.

"stop", "stop stop", "stop the robot": every motion stops at once. The engine has already published the
halt when it grounded the words (``ActionEngine.is_halt``), before this graph started; this action halts
again (for a graph sent as JSON, which was not grounded) and then stops every action that moves the robot,
so that none of them sends one more command. The view and the other actions go on.

"stop showing the environment", "stop everything": the actions the words name best are stopped; their
resources are released, and a motion among them stops with its holder.
"""
from temoto_action_engine.action_base import ActionBase, ActionError
from temoto_action_engine.engine import ActionEngine


class Stop(ActionBase):
    def execute(self):
        target = self.input('action') or ''
        if ActionEngine.is_halt_target(target):
            self.engine.halt('stop: %s' % (target or 'the robot'))
            stopped = self.engine.stop_actions(target, exclude_graph=self.context.graph_name, motion_only=True)
            if any(w in target.lower().split() for w in ('everything', 'all')):
                stopped += self.engine.stop_actions(target, exclude_graph=self.context.graph_name)
            self.set_output('stopped', stopped)
            self.feedback('the robot is halted%s' % ('; stopped %s' % ', '.join(stopped) if stopped else ''))
            return
        stopped = self.engine.stop_actions(target, exclude_graph=self.context.graph_name)
        if not stopped:
            running = self.engine.running_actions(exclude_graph=self.context.graph_name)
            raise ActionError('nothing running matches "%s" (running: %s)'
                              % (target, ', '.join(running) if running else 'nothing'))
        self.set_output('stopped', stopped)
        self.feedback('stopped %s' % ', '.join(stopped))
