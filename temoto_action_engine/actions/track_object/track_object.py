"""track_object: ask the Context Manager to track an object; output the topic with its pose."""
from temoto_action_engine.action_base import ActionBase, ActionError


def _topic_of(result) -> str:
    """The tracker's output topic, whatever shape the Context Manager interface returns."""
    if isinstance(result, str):
        return result
    for attr in ('topic', 'output_topic', 'object_topic'):
        value = getattr(result, attr, None)
        if isinstance(value, str) and value:
            return value
    topics = getattr(result, 'output_topics', None)
    if isinstance(topics, dict) and topics:
        return next(iter(topics.values()))
    raise ActionError('the Context Manager answered without a topic: %r' % (result,))


class TrackObject(ActionBase):
    def on_start(self):
        obj = self.input('object')
        result = self.context_manager.track_object(obj)
        topic = _topic_of(result)
        self.set_output('topic', topic)
        self.event('tracking', object=obj, topic=topic)
        self.feedback('tracking the %s on %s' % (obj, topic))
