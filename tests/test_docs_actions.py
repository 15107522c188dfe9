"""docs/actions.md says which descriptor fields are required, and the engine agrees: a descriptor without a
field the page calls required is refused naming it, and one without an optional field loads. (The page
never said that ``description`` is required, and a user's first plugin was refused for it.)"""
import copy
import os
import re

import pytest

from temoto_action_engine.umrf import UmrfError, parse_descriptor

DOC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'docs', 'actions.md')
FULL = {'name': 'wave', 'description': 'Wave an arm at the operator.', 'effect': 'asynchronous',
        'module': 'wave.py', 'class_name': 'Wave',
        'input_parameters': {'arm': {'pvf_type': 'string', 'pvf_required': False}},
        'output_parameters': {'topic': {'pvf_type': 'string'}},
        'grounding': {'verbs': ['wave'], 'subjects': ['operator']}, 'motion': True}


def documented_fields() -> dict:
    """field -> True if the page's table calls it required."""
    with open(DOC, encoding='utf-8') as f:
        rows = re.findall(r'^\| `(\w+)` \| (\*\*required\*\*|optional) \|', f.read(), re.M)
    return {field: kind != 'optional' for field, kind in rows}


def test_the_page_lists_every_field_the_engine_knows():
    assert set(documented_fields()) == set(FULL)
    parse_descriptor(copy.deepcopy(FULL))          # the full example is valid


@pytest.mark.parametrize('field', sorted(FULL))
def test_a_descriptor_without_a_field_is_refused_exactly_when_the_page_says_required(field):
    data = copy.deepcopy(FULL)
    del data[field]
    required = documented_fields()[field]
    if required:
        with pytest.raises(UmrfError) as err:
            parse_descriptor(data)
        assert '"%s"' % field in str(err.value), str(err.value)
    else:
        parse_descriptor(data)
