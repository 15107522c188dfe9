"""track_object: ask the Context Manager to track an object; output the topic with its pose.

The request carries this action's own failure policy. A failure anywhere below (the tracker's
algorithm, the camera, the camera's driver) reaches it as FAILED. The action then asks once more;
the Context Manager's ranking now prefers another detection method or tracker. When nothing can
track the object any more, or the new tracker's pose topic is not the one this graph's later
actions were given, the action ends FAILED with the reason (and its graph with it), rather than
stay RUNNING with nothing behind it.
"""
from temoto_action_engine.action_base import ActionBase


class TrackObject(ActionBase):
    def on_start(self):
        self.object_name = self.input('object')
        self.tracked = self.context_manager.track_object(self.object_name, on_status=self.post)
        self.set_output('topic', self.tracked.topic)
        self.event('tracking', object=self.object_name, topic=self.tracked.topic,
                   tracker=self.tracked.tracker_name, detection_method=self.tracked.detection_method)
        self.feedback('tracking the %s on %s' % (self.object_name, self.tracked.topic))

    def execute(self):
        while self.action_ok():
            ev = self.next_item(3600.0)
            if ev is None or not self.action_ok():
                continue
            if ev.resource_id != self.tracked.resource_id:
                self.log_info('status %s for resource %s, which is not in use any more; ignored'
                              % (ev.code.name, ev.resource_id))
            elif ev.failed:
                self.track_again(ev)
            else:
                self.log_info('status %s of the tracker: %s' % (ev.code.name, ev.message))

    def track_again(self, ev) -> None:
        failed = self.tracked
        self.event('tracker_failed', object=self.object_name, tracker=failed.tracker_name, message=ev.message,
                   origin=ev.origin)
        try:
            self.context_manager.stop(failed.resource_id)
        except Exception as e:          # its owner may be gone with it; what it held is released in cascade
            self.log_warn('releasing the failed tracker: %s' % e)
        try:
            self.tracked = self.context_manager.track_object(self.object_name, on_status=self.post)
        except Exception as e:
            self.fail('lost track of the %s (%s), and nothing else can track it: %s'
                      % (self.object_name, ev.origin, e))
            return
        if self.tracked.topic != failed.topic:
            self.fail('lost track of the %s (%s); it is tracked again on %s, but this graph shows %s'
                      % (self.object_name, ev.origin, self.tracked.topic, failed.topic))
            return
        self.event('tracking', object=self.object_name, topic=self.tracked.topic,
                   tracker=self.tracked.tracker_name, detection_method=self.tracked.detection_method)
        self.feedback('the tracker of the %s failed (%s); tracking it again with %s'
                      % (self.object_name, ev.origin, self.tracked.tracker_name))
