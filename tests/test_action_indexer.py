"""Indexing action plugins: valid ones load, each kind of broken one is reported, the rest survive."""
import json
import os

import pytest

from temoto_action_engine import indexer
from temoto_action_engine.action_base import ActionBase
from temoto_action_engine.indexer import ActionIndex
from temoto_testing.action_engine import write_plugin
from temoto_action_engine.umrf import UmrfError, parse_descriptor

GOOD = '''
from temoto_action_engine.action_base import ActionBase

class Good(ActionBase):
    def execute(self):
        self.set_output('answer', 42)
'''


def good(root, name='good_one', **kw):
    return write_plugin(str(root), name, GOOD, outputs={'answer': {'pvf_type': 'number'}},
                        grounding={'verbs': ['answer'], 'subjects': ['question']}, **kw)


def index_of(*paths):
    return ActionIndex([str(p) for p in paths], include_bundled=False).reindex()


def only_problem(idx):
    assert len(idx.problems) == 1, idx.problems
    return idx.problems[0]


def test_valid_plugin_is_indexed_with_its_class_and_descriptor(tmp_path):
    good(tmp_path)
    idx = index_of(tmp_path)
    assert list(idx) == ['good_one'] and idx.problems == []
    a = idx.action('good_one')
    assert issubclass(a.cls, ActionBase) and a.cls.__name__ == 'Good'
    d = a.descriptor
    assert d.effect == 'synchronous' and d.outputs['answer'].pvf_type == 'number'
    assert d.grounding.verbs == ('answer',) and d.grounding.subjects == ('question',)


def test_bundled_actions_index_cleanly():
    idx = ActionIndex([]).reindex()
    assert idx.problems == []
    assert set(idx) == {'show_environment', 'track_object', 'show', 'stop', 'navigate', 'gripper', 'follow_hand', 'dial'}
    assert idx.get('show_environment').asynchronous and not idx.get('stop').asynchronous


def test_bad_json_is_reported_and_the_others_still_load(tmp_path):
    good(tmp_path)
    write_plugin(str(tmp_path), 'broken', GOOD, descriptor='{"name": "broken", "effect": ')
    idx = index_of(tmp_path)
    p = only_problem(idx)
    assert p.kind == indexer.BAD_JSON and p.path.endswith('broken.umrf.json')
    assert 'JSON' in p.message
    assert list(idx) == ['good_one']


@pytest.mark.parametrize('change, words', [
    ({'effect': 'sometimes'}, ['effect', 'sometimes']),
    ({'name': 'Bad Name'}, ['name']),
    ({'description': ''}, ['description']),
    ({'input_parameters': {'x': {'pvf_type': 'colour'}}}, ['input_parameters.x.pvf_type', 'colour']),
    ({'input_parameters': {'x': {'pvf_type': 'number', 'pvf_value': 'three'}}}, ['pvf_value', 'three']),
    ({'input_parameters': {'x': {'a': {'pvf_type': 'number'}}}}, ['nested']),
    ({'grounding': {'verbs': []}}, ['grounding.verbs']),
    ({'grounding': {'verbs': ['go'], 'parameters': {'nope': {'any': True}}}}, ['nope', 'not an input']),
    ({'grounding': {'verbs': ['two words']}}, ['single lower-case word']),
    ({'colour': 'red'}, ['unknown field', 'colour']),
])
def test_schema_violations_name_the_field(tmp_path, change, words):
    good(tmp_path)
    desc = {'name': 'bad_one', 'description': 'x', 'effect': 'synchronous',
            'grounding': {'verbs': ['bad']}}
    desc.update(change)
    write_plugin(str(tmp_path), 'bad_one', GOOD, descriptor=desc)
    idx = index_of(tmp_path)
    p = only_problem(idx)
    assert p.kind == indexer.SCHEMA
    for w in words:
        assert w in p.message, p.message
    assert list(idx) == ['good_one']


def test_every_schema_problem_is_listed_at_once():
    with pytest.raises(UmrfError) as e:
        parse_descriptor({'name': 'x', 'effect': 'maybe', 'grounding': {'verbs': []}}, 'x.umrf.json')
    assert len(e.value.problems) == 3      # description, effect, verbs
    assert str(e.value).startswith('x.umrf.json')


@pytest.mark.parametrize('code, words', [
    ('import no_such_module_here\n', ['ModuleNotFoundError', 'no_such_module_here', 'line 1']),
    ('def broken(:\n    pass\n', ['SyntaxError', 'line 1']),
    ('x = 1\nraise RuntimeError("plugin exploded")\n', ['RuntimeError', 'plugin exploded', 'line 2']),
    ('import sys\nsys.exit(3)\n', ['SystemExit']),
])
def test_import_errors_are_reported_with_the_line(tmp_path, code, words):
    good(tmp_path)
    write_plugin(str(tmp_path), 'crashy', code)
    idx = index_of(tmp_path)
    p = only_problem(idx)
    assert p.kind == indexer.IMPORT_ERROR and p.path.endswith('crashy.py')
    for w in words:
        assert w in p.message, p.message
    assert list(idx) == ['good_one']


def test_missing_module_file_is_an_import_error(tmp_path):
    write_plugin(str(tmp_path), 'lonely', GOOD, module='other.py')   # descriptor expects lonely.py
    p = only_problem(index_of(tmp_path))
    assert p.kind == indexer.IMPORT_ERROR and 'lonely.py does not exist' in p.message


@pytest.mark.parametrize('code, class_name, words', [
    ('x = 1\n', '', ['no class derived from ActionBase']),
    (GOOD, 'Missing', ["'Missing'", 'not defined']),
    ('class NotAnAction:\n    pass\n', 'NotAnAction', ['not a class derived from ActionBase']),
    (GOOD + '\nclass Other(Good):\n    pass\n', '', ['several', 'Good', 'Other', 'class_name']),
    ('from temoto_action_engine.action_base import ActionBase\nclass Lazy(ActionBase):\n    pass\n', '',
     ['synchronous', 'execute']),
])
def test_missing_class_is_reported(tmp_path, code, class_name, words):
    extra = {'class_name': class_name} if class_name else {}
    write_plugin(str(tmp_path), 'classy', code, **extra)
    p = only_problem(index_of(tmp_path))
    assert p.kind == indexer.MISSING_CLASS
    for w in words:
        assert w in p.message, p.message


def test_duplicate_names_keep_the_first_and_report_the_second(tmp_path):
    good(tmp_path / 'a', name='same')
    good(tmp_path / 'b', name='same')
    idx = index_of(tmp_path / 'a', tmp_path / 'b')
    p = only_problem(idx)
    assert p.kind == indexer.DUPLICATE and str(tmp_path / 'a') in p.message
    assert idx.get('same').source.startswith(str(tmp_path / 'a'))


def test_missing_folder_is_reported(tmp_path):
    good(tmp_path)
    idx = index_of(tmp_path, tmp_path / 'nowhere')
    p = only_problem(idx)
    assert p.kind == indexer.MISSING_FOLDER and list(idx) == ['good_one']


def test_scan_depth_is_bounded(tmp_path):
    good(tmp_path / 'level1', name='shallow')
    good(tmp_path / 'level1' / 'level2' / 'level3', name='deep')
    assert list(index_of(tmp_path)) == ['shallow']


def test_reindex_picks_up_new_and_fixed_plugins(tmp_path):
    write_plugin(str(tmp_path), 'later', 'raise ImportError("not yet")\n')
    idx = index_of(tmp_path)
    assert list(idx) == [] and only_problem(idx).kind == indexer.IMPORT_ERROR
    write_plugin(str(tmp_path), 'later', GOOD.replace('42', '43'), outputs={'answer': {'pvf_type': 'number'}})
    good(tmp_path, name='fresh')
    idx.reindex()
    assert list(idx) == ['fresh', 'later'] and idx.problems == []
    assert idx.to_json()['errors'] == []
    assert json.loads(json.dumps(idx.to_json()))['actions'][0]['name'] == 'fresh'
    assert os.path.isdir(idx.paths[0])
