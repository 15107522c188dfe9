"""show_environment: the paper's demo. Keep the operator seeing the surroundings.

This plugin is glue, and a model for an action that keeps something up through failures:
- what to show, in order, is the configuration's ``sensor_priority`` list
  (``temoto_action_engine.view_sources``; default: the VaultBot's, from the paper's section 4);
- what happens on a FAILED, which source is shown, held ready or failed back to, is the state
  machine ``temoto_action_engine.view_failover``; this file only starts and stops sensors and
  displays for it, through the Sensor and Output Managers' interfaces;
- every request states this action's own failure policy (``on_status=self.post``): a FAILED of a
  sensor or of its display comes to the run loop as an item, never to an interface's default
  reload, and the run loop hands it to the machine;
- the display is asked for on the topic the sensor will most likely get while the sensor starts
  (``temoto_action_engine.speculative_display``; parameter ``speculative_display``, default true);
- the standby and fail-back policy (``failover_policy``) comes from the configuration, or from the
  request ("... with a hot standby").
"""
from __future__ import annotations

from typing import Any

from temoto_action_engine.action_base import ActionBase, ActionError
from temoto_action_engine.failover_policy import FailoverConfig
from temoto_action_engine.speculative_display import SpeculativeDisplay
from temoto_action_engine.view_failover import Held, ViewFailover
from temoto_action_engine.view_sources import DEFAULT_PRIORITY, SensorChoice, parse_priority

CATALOGUE_TIMEOUT_S = 0.5

__all__ = ['ShowEnvironment', 'DEFAULT_PRIORITY', 'parse_priority']


class ShowEnvironment(ActionBase):
    def on_start(self):
        self.priority = parse_priority(self.config.get('sensor_priority', DEFAULT_PRIORITY))
        try:
            policy = FailoverConfig.from_config(self.config, self.input('standby'))
        except ValueError as e:
            raise ActionError(str(e)) from None
        self.speculative = bool(self.config.get('speculative_display', True))
        self.view = ViewFailover(self.priority, policy, self)
        self.view.start()       # sets the output 'topic' when a sensor is up (children start after this)

    def execute(self):
        while self.action_ok():
            item = self.next_item(self.view.wait_s())
            if not self.action_ok():
                break
            self.view.handle(item)

    def on_stop(self):
        self.view.stop(drain=lambda: self.next_item(0.0))

    # ------------------------------------------------------------------ the machine's port
    def activate(self, index: int) -> Held:
        """Entry ``index``: its sensor, then its display; raises (after rolling back) when either fails."""
        choice = self.priority[index]
        guess = SpeculativeDisplay(choice.label, lambda: self.likely_topic(choice),
                                   lambda topic: self.display(choice, topic),
                                   lambda did: self.hide_display(did, choice.label),
                                   self.log_info) if self.speculative else None
        try:
            result = self.sensors_of(choice).start_sensor(
                choice.sensor_type, output_topics={k: '' for k in choice.output_topics}, on_status=self.post)
        except Exception as e:
            if guess is not None:
                guess.discard()
            self.event('sensor_unavailable', sensor_type=choice.sensor_type, label=choice.label,
                       priority_index=index, message=str(e))
            raise
        topic = dict(result.output_topics).get(choice.display_key, '')
        display_id = guess.take(topic) if guess is not None else None
        try:
            if not topic:
                raise ActionError('the sensor gave no %r topic' % choice.display_key)
            if display_id is None:
                display_id = self.display(choice, topic)
        except Exception as e:
            self.event('display_failed', sensor_name=result.sensor_name, label=choice.label,
                       priority_index=index, message=str(e))
            self.stop_resource(choice, result.resource_id)
            raise
        return Held(index, choice, result.sensor_name, result.resource_id, topic, display_id)

    def hold(self, index: int, hidden: bool, avoid: frozenset) -> Held:
        """Entry ``index``'s sensor, running, and (``hidden``) its display, subscribed but not drawn.

        The device must not be one in ``avoid`` (those the view already holds): the manager would answer a
        spare's request with the device on screen when it ranks first for both entries, and a spare on the
        same device fails with it. So the best other device is asked for by package and executable.
        """
        choice = self.priority[index]
        keys = list(choice.output_topics)
        sensors = self.sensors_of(choice)
        rows = [r for r in sensors.ranked_sensors(choice.sensor_type, keys, CATALOGUE_TIMEOUT_S)
                if r.get('name') not in avoid]
        if not rows:
            raise ActionError('no %s with %s other than %s' % (choice.sensor_type, ', '.join(keys),
                                                               ', '.join(sorted(avoid)) or 'none'))
        result = sensors.start_sensor(choice.sensor_type, output_topics={k: '' for k in keys},
                                      package_name=str(rows[0].get('package', '')),
                                      executable=str(rows[0].get('executable', '')), on_status=self.post)
        topic = dict(result.output_topics).get(choice.display_key, '')
        display_id = None
        try:
            if result.sensor_name in avoid:
                raise ActionError('the manager gave %s, which the view holds already' % result.sensor_name)
            if not topic:
                raise ActionError('the sensor gave no %r topic' % choice.display_key)
            if hidden:
                display_id = self.display(choice, topic, hidden=True)
        except Exception:
            self.stop_resource(choice, result.resource_id)
            raise
        return Held(index, choice, result.sensor_name, result.resource_id, topic, display_id)

    def show(self, held: Held, hidden: bool = False) -> Any:
        return self.display(held.choice, held.topic, hidden)

    def set_visible(self, display_id: Any, visible: bool) -> None:
        self.output_manager.set_visible(display_id, visible)

    def hide_display(self, display_id: Any, what: str) -> None:
        try:
            self.output_manager.hide(display_id)
        except Exception as e:
            self.log_warn('hiding the display of %s: %s' % (what, e))

    def stop_sensor(self, held: Held) -> None:
        self.stop_resource(held.choice, held.resource_id)

    def shown_topic(self, topic: str) -> None:
        self.set_output('topic', topic)       # the topic shown now (list_graphs reports it)

    # ------------------------------------------------------------------ the managers
    def display(self, choice: SensorChoice, topic: str, hidden: bool = False) -> Any:
        """A display of ``topic`` whose failures come to this action's run loop."""
        return self.output_manager.show_in_rviz(choice.display_type, topic, name=self.display_name(choice),
                                                config=choice.display_config, on_status=self.post, hidden=hidden)

    def display_name(self, choice: SensorChoice) -> str:
        """The entry's label, and the robot's name when the view is of a named robot: one station shows
        several robots, and RViz's display names must differ (the Output Manager refuses a taken name)."""
        robot = self.input('robot')
        return '%s (%s)' % (choice.label, robot.strip('/')) if isinstance(robot, str) and robot.strip('/') \
            else choice.label

    def likely_topic(self, choice: SensorChoice) -> str:
        """The topic ``choice``'s display will most likely show: the Sensor Manager's catalogue ranking."""
        topics = self.sensors_of(choice).likely_topics(choice.sensor_type, list(choice.output_topics),
                                                       CATALOGUE_TIMEOUT_S)
        return (topics or {}).get(choice.display_key, '')

    def sensors_of(self, choice: SensorChoice):
        """The Sensor Manager interface that serves ``choice``: the robot's or the station's."""
        return self.station_sensor_manager if choice.station else self.sensor_manager

    def stop_resource(self, choice: SensorChoice, resource_id: Any) -> None:
        try:
            self.sensors_of(choice).stop_sensor(resource_id)
        except Exception as e:
            self.log_warn('stopping sensor resource %s: %s' % (resource_id, e))
