"""stop: stop running actions by name or by the words that started them."""
from temoto_action_engine.action_base import ActionBase, ActionError


class Stop(ActionBase):
    def execute(self):
        target = self.input('action')
        stopped = self.engine.stop_actions(target, exclude_graph=self.context.graph_name)
        if not stopped:
            running = self.engine.running_actions(exclude_graph=self.context.graph_name)
            raise ActionError('nothing running matches "%s" (running: %s)'
                              % (target, ', '.join(running) if running else 'nothing'))
        self.set_output('stopped', stopped)
        self.feedback('stopped %s' % ', '.join(stopped))
