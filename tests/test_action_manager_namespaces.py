"""An action finds a manager that runs under another TeMoto namespace (a robot's, on another host) from its
config's ``manager_namespaces``; a bad entry is refused by name. The run across two hosts is in test_demo."""
import pytest

from temoto_action_engine.action_base import ActionBase, ActionContext, ActionError
from temoto_action_engine.umrf import ActionDescriptor, Grounding, ParamSpec


class RecordingInterface:
    """Stands in for a manager interface class: records what it was bound to."""

    def __init__(self, rr, namespace=None):
        self.rr, self.namespace = rr, namespace


def action(config):
    descriptor = ActionDescriptor('show_environment', 'test', 'asynchronous', 'm', 'C', {}, {}, Grounding())
    context = ActionContext(descriptor=descriptor, instance_id=0, graph_name='g', inputs={}, uid='1',
                            config=config, rr_factory=lambda name: 'rr:' + name,
                            interface_factories={'sensor_manager': RecordingInterface,
                                                 'output_manager': RecordingInterface})
    return ActionBase(context)


def test_a_manager_named_in_manager_namespaces_is_asked_there_and_the_others_in_the_engines():
    act = action({'manager_namespaces': {'sensor_manager': '/vaultbot'}})
    assert act.sensor_manager.namespace == 'vaultbot'
    assert act.output_manager.namespace is None           # the registrar's own namespace
    assert act.sensor_manager.rr == act.output_manager.rr  # one registrar per action, wherever it asks


def test_an_empty_entry_means_the_engines_own_namespace():
    assert action({'manager_namespaces': {'sensor_manager': ''}}).sensor_manager.namespace is None


@pytest.mark.parametrize('config, named', [
    ({'manager_namespaces': {'sensor_manager': 'a/b'}}, "manager_namespaces.sensor_manager is 'a/b'"),
    ({'manager_namespaces': {'sensor_manager': 3}}, 'manager_namespaces.sensor_manager is 3'),
    ({'manager_namespaces': ['vaultbot']}, "manager_namespaces must map a manager to a TeMoto namespace, got "
                                           "['vaultbot']"),
])
def test_a_bad_manager_namespace_is_refused_by_name_and_binds_nothing(config, named):
    act = action(config)
    with pytest.raises(ActionError) as err:
        act.sensor_manager
    assert named in str(err.value)
    assert act._interfaces == {}


def robot_action(robot, config=None):
    descriptor = ActionDescriptor('show_environment', 'test', 'asynchronous', 'm', 'C',
                                  {'robot': ParamSpec('robot', 'string', required=False)}, {}, Grounding())
    context = ActionContext(descriptor=descriptor, instance_id=0, graph_name='g', inputs={'robot': robot}, uid='1',
                            config=config or {}, rr_factory=lambda name: 'rr:' + name,
                            interface_factories={'sensor_manager': RecordingInterface,
                                                 'output_manager': RecordingInterface})
    return ActionBase(context)


def test_a_robot_named_in_the_instruction_is_asked_over_the_config():
    act = robot_action('vaultbot_2', {'manager_namespaces': {'sensor_manager': 'vaultbot_1'}})
    assert act.sensor_manager.namespace == 'vaultbot_2'
    assert act.output_manager.namespace is None           # the station's own: the robot has none
    assert robot_action('').sensor_manager.namespace is None


def test_a_robot_that_is_not_a_namespace_is_refused_by_name():
    act = robot_action('vault bot')
    with pytest.raises(ActionError) as err:
        act.sensor_manager
    assert "robot 'vault bot' is not a TeMoto namespace" in str(err.value)
    assert act._interfaces == {}
