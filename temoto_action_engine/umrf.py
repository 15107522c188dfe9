"""UMRF descriptors and graphs: an explicit validator and the plain data they become.

The original engine read ``*.umrf.json`` files with a hand-written converter that
checked every field (``umrf_json_converter.h``); this module does the same for
the Python port, without a schema library, so that a broken plugin or graph is
rejected with a message naming the file, the field and what was wrong.

Action descriptor (one per plugin folder, ``<name>.umrf.json``)::

    {
      "name": "track_object",                  # identifier, unique in the index
      "description": "Track an object ...",
      "effect": "asynchronous",                # or "synchronous"
      "module": "track_object.py",             # optional, default "<name>.py"
      "class_name": "TrackObject",             # optional, default: the one ActionBase subclass
      "input_parameters":  {"object": {"pvf_type": "string"}},
      "output_parameters": {"topic":  {"pvf_type": "string"}},
      "grounding": {
        "verbs": ["track", "follow"],          # the verb and its aliases
        "subjects": ["object"],                # words naming what the action is about
        "parameters": {"object": {"words": ["hand", "ball"], "any": true}}
      }
    }

Graph (``StartGraph`` and the grounder's output)::

    {"graph_name": "g", "graph_description": "...",
     "actions": [{"name": "track_object", "instance_id": 0,
                  "input_parameters": {"object": {"pvf_type": "string", "pvf_value": "hand"}},
                  "children": [{"name": "show", "instance_id": 1}]},
                 {"name": "show", "instance_id": 1,
                  "parents": [{"name": "track_object", "instance_id": 0, "required": true}]}]}
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from typing import Any

SYNC = 'synchronous'
ASYNC = 'asynchronous'
EFFECTS = (SYNC, ASYNC)

# PVF types of the ROS 1-era UMRF plus the plural forms added later.
SCALAR_TYPES = {'string': (str,), 'number': (int, float), 'bool': (bool,)}
PLURAL_TYPES = {'strings': 'string', 'numbers': 'number', 'bools': 'bool'}
PVF_TYPES = tuple(SCALAR_TYPES) + tuple(PLURAL_TYPES)
PVF_FIELDS = ('pvf_type', 'pvf_value', 'pvf_example', 'pvf_required', 'pvf_updatable',
              'pvf_allowed_values', 'pvf_description')

NAME_RE = re.compile(r'^[a-z][a-z0-9_]{0,62}$')
PARAM_RE = re.compile(r'^[A-Za-z][A-Za-z0-9_]{0,62}$')
WORD_RE = re.compile(r'^[a-z0-9][a-z0-9_\-]*$')

DESCRIPTOR_FIELDS = {'name', 'description', 'effect', 'module', 'class_name', 'input_parameters',
                     'output_parameters', 'grounding', 'motion'}
# Fields of the original UMRF format that mean nothing for a descriptor file; tolerated, ignored.
IGNORED_UMRF_FIELDS = {'package_name', 'notation', 'library_path', 'state', 'id', 'execute_first',
                       'parents', 'children', 'instance_id', 'type', 'actor', 'gui_attributes'}
GROUNDING_FIELDS = {'verbs', 'aliases', 'subjects', 'parameters', 'bare'}
GROUNDING_PARAM_FIELDS = {'words', 'any', 'pattern'}

GRAPH_FIELDS = {'graph_name', 'graph_description', 'graph_state', 'actions', 'umrf_actions'}
NODE_FIELDS = {'name', 'instance_id', 'id', 'input_parameters', 'output_parameters', 'parents',
               'children', 'description', 'effect', 'type', 'state'}
RELATION_FIELDS = {'name', 'instance_id', 'id', 'required', 'stop_when_received'}


class UmrfError(ValueError):
    """A descriptor or graph that does not follow the schema. ``problems`` lists every finding."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = list(problems)
        super().__init__('%s: %s' % (source, '; '.join(self.problems)))


def type_matches(pvf_type: str, value: Any) -> bool:
    """True when ``value`` is a valid ``pvf_type`` value (bool is not a number)."""
    if pvf_type in PLURAL_TYPES:
        return isinstance(value, list) and all(type_matches(PLURAL_TYPES[pvf_type], v) for v in value)
    if pvf_type == 'number':
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    return isinstance(value, SCALAR_TYPES.get(pvf_type, ()))


@dataclass(frozen=True)
class ParamSpec:
    """One typed parameter (a UMRF PVF leaf)."""
    name: str
    pvf_type: str
    required: bool = True
    default: Any = None
    allowed_values: tuple = ()
    description: str = ''

    def check(self, value: Any) -> str | None:
        """None when ``value`` fits, else a message saying why not."""
        if not type_matches(self.pvf_type, value):
            return 'parameter %r expects %s, got %s %r' % (self.name, self.pvf_type,
                                                          type(value).__name__, value)
        if self.allowed_values and value not in self.allowed_values:
            return 'parameter %r must be one of %s, got %r' % (self.name, list(self.allowed_values), value)
        return None

    def to_json(self) -> dict:
        d = {'pvf_type': self.pvf_type, 'pvf_required': self.required}
        if self.default is not None:
            d['pvf_value'] = self.default
        if self.allowed_values:
            d['pvf_allowed_values'] = list(self.allowed_values)
        if self.description:
            d['pvf_description'] = self.description
        return d


@dataclass(frozen=True)
class GroundingParam:
    """How words of a clause fill one input parameter."""
    words: tuple = ()          # listed words fill the parameter (+2 each in scoring)
    any_word: bool = False     # any leftover content word may fill it (+1)
    pattern: str = ''          # a token matching this regex fills it (+2), e.g. a topic name


@dataclass(frozen=True)
class Grounding:
    verbs: tuple = ()
    subjects: tuple = ()
    parameters: dict = field(default_factory=dict)   # param name -> GroundingParam
    bare: bool = False          # the verb alone is enough ("Robot please go"), though it takes words


@dataclass(frozen=True)
class ActionDescriptor:
    name: str
    description: str
    effect: str
    module: str
    class_name: str
    inputs: dict          # name -> ParamSpec
    outputs: dict         # name -> ParamSpec
    grounding: Grounding
    source: str = ''      # the descriptor file
    # it moves the robot: an instruction that asks for it must open with the motion wake phrase when it
    # comes from chatter (speech), and ``stop`` halts it (docs/teleoperation.md)
    motion: bool = False

    @property
    def asynchronous(self) -> bool:
        return self.effect == ASYNC

    def to_json(self) -> dict:
        g = self.grounding
        return {
            'name': self.name, 'description': self.description, 'effect': self.effect,
            'module': self.module, 'class_name': self.class_name, 'source': self.source, 'motion': self.motion,
            'input_parameters': {k: p.to_json() for k, p in self.inputs.items()},
            'output_parameters': {k: p.to_json() for k, p in self.outputs.items()},
            'grounding': {'verbs': list(g.verbs), 'subjects': list(g.subjects),
                          'parameters': {k: {'words': list(p.words), 'any': p.any_word,
                                             'pattern': p.pattern}
                                         for k, p in g.parameters.items()},
                          'bare': g.bare},
        }


# --------------------------------------------------------------------------- descriptors

def _word_list(value, where: str, problems: list[str]) -> tuple:
    if not isinstance(value, list) or not all(isinstance(w, str) for w in value):
        problems.append('%s must be a list of strings' % where)
        return ()
    out = []
    for w in value:
        w = w.strip().lower()
        if not WORD_RE.match(w):
            problems.append('%s: %r is not a single lower-case word' % (where, w))
        else:
            out.append(w)
    return tuple(out)


def _params(value, where: str, problems: list[str], inputs: bool) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        problems.append('%s must be an object mapping parameter names to PVF objects' % where)
        return {}
    out = {}
    for name, pvf in value.items():
        here = '%s.%s' % (where, name)
        if not PARAM_RE.match(name):
            problems.append('%s: %r is not a valid parameter name' % (where, name))
            continue
        if not isinstance(pvf, dict):
            problems.append('%s must be a PVF object like {"pvf_type": "string"}' % here)
            continue
        unknown = sorted(set(pvf) - set(PVF_FIELDS))
        if unknown:
            problems.append('%s: unknown field(s) %s (nested parameters are not supported; PVF fields '
                            'are %s)' % (here, unknown, list(PVF_FIELDS)))
            continue
        ptype = pvf.get('pvf_type')
        if ptype not in PVF_TYPES:
            problems.append('%s.pvf_type must be one of %s, got %r' % (here, list(PVF_TYPES), ptype))
            continue
        default = pvf.get('pvf_value')
        if default is not None and not type_matches(ptype, default):
            problems.append('%s.pvf_value %r is not a %s' % (here, default, ptype))
            continue
        required = pvf.get('pvf_required', inputs and default is None)
        if not isinstance(required, bool):
            problems.append('%s.pvf_required must be true or false' % here)
            continue
        allowed = pvf.get('pvf_allowed_values', [])
        if not isinstance(allowed, list) or not all(type_matches(ptype, a) for a in allowed):
            problems.append('%s.pvf_allowed_values must be a list of %s' % (here, ptype))
            continue
        desc = pvf.get('pvf_description', '')
        out[name] = ParamSpec(name, ptype, required, default, tuple(allowed), str(desc))
    return out


def _grounding(value, inputs: dict, problems: list[str]) -> Grounding:
    if value is None:
        return Grounding()
    if not isinstance(value, dict):
        problems.append('grounding must be an object with "verbs", "subjects", "parameters"')
        return Grounding()
    unknown = sorted(set(value) - GROUNDING_FIELDS)
    if unknown:
        problems.append('grounding: unknown field(s) %s; allowed: %s' % (unknown, sorted(GROUNDING_FIELDS)))
    verbs = _word_list(value.get('verbs', []), 'grounding.verbs', problems)
    verbs += _word_list(value.get('aliases', []), 'grounding.aliases', problems)
    if not verbs:
        problems.append('grounding.verbs must name at least one verb (the action cannot be said otherwise)')
    subjects = _word_list(value.get('subjects', []), 'grounding.subjects', problems)
    params = {}
    raw = value.get('parameters', {})
    if not isinstance(raw, dict):
        problems.append('grounding.parameters must be an object keyed by input parameter name')
        raw = {}
    for pname, spec in raw.items():
        here = 'grounding.parameters.%s' % pname
        if pname not in inputs:
            problems.append('%s: %r is not an input parameter (inputs: %s)' % (here, pname, sorted(inputs)))
            continue
        if not isinstance(spec, dict) or set(spec) - GROUNDING_PARAM_FIELDS:
            problems.append('%s must be an object with fields from %s' % (here, sorted(GROUNDING_PARAM_FIELDS)))
            continue
        if inputs[pname].pvf_type != 'string':
            problems.append('%s: only string parameters can be filled from words' % here)
            continue
        words = _word_list(spec.get('words', []), here + '.words', problems)
        any_word = spec.get('any', False)
        if not isinstance(any_word, bool):
            problems.append('%s.any must be true or false' % here)
            any_word = False
        pattern = spec.get('pattern', '')
        if not isinstance(pattern, str):
            problems.append('%s.pattern must be a string' % here)
            pattern = ''
        elif pattern:
            try:
                re.compile(pattern)
            except re.error as e:
                problems.append('%s.pattern is not a valid regular expression: %s' % (here, e))
                pattern = ''
        if not (words or any_word or pattern):
            problems.append('%s needs "words", "any" or "pattern"' % here)
            continue
        params[pname] = GroundingParam(words, any_word, pattern)
    bare = value.get('bare', False)
    if not isinstance(bare, bool):
        problems.append('grounding.bare must be true or false')
        bare = False
    return Grounding(verbs, subjects, params, bare)


def parse_descriptor(data: Any, source: str = '<descriptor>') -> ActionDescriptor:
    """Validate a decoded ``*.umrf.json`` and return its descriptor; raise UmrfError listing every problem."""
    problems: list[str] = []
    if not isinstance(data, dict):
        raise UmrfError(source, ['the descriptor must be a JSON object, got %s' % type(data).__name__])
    unknown = sorted(set(data) - DESCRIPTOR_FIELDS - IGNORED_UMRF_FIELDS)
    if unknown:
        problems.append('unknown field(s) %s; allowed: %s' % (unknown, sorted(DESCRIPTOR_FIELDS)))
    name = data.get('name')
    if not isinstance(name, str) or not NAME_RE.match(name):
        problems.append('"name" must be a lower-case identifier like "show_environment", got %r' % (name,))
        name = str(name)
    description = data.get('description')
    if not isinstance(description, str) or not description.strip():
        problems.append('"description" must be a non-empty string')
    effect = data.get('effect')
    if effect not in EFFECTS:
        problems.append('"effect" must be "synchronous" or "asynchronous", got %r' % (effect,))
    module = data.get('module', '%s.py' % name)
    if not isinstance(module, str) or not re.match(r'^[A-Za-z_][A-Za-z0-9_]*\.py$', module):
        problems.append('"module" must be a Python file name in the plugin folder, got %r' % (module,))
    class_name = data.get('class_name', '')
    if not isinstance(class_name, str) or (class_name and not class_name.isidentifier()):
        problems.append('"class_name" must be a Python class name, got %r' % (class_name,))
    inputs = _params(data.get('input_parameters'), 'input_parameters', problems, inputs=True)
    outputs = _params(data.get('output_parameters'), 'output_parameters', problems, inputs=False)
    grounding = _grounding(data.get('grounding'), inputs, problems)
    motion = data.get('motion', False)
    if not isinstance(motion, bool):
        problems.append('"motion" must be true or false, got %r' % (motion,))
    if problems:
        raise UmrfError(source, problems)
    return ActionDescriptor(name, description.strip(), effect, module, class_name, inputs, outputs,
                            grounding, source, motion)


# --------------------------------------------------------------------------- graphs

@dataclass
class NodeSpec:
    """One action instance of a graph."""
    name: str
    instance_id: int
    inputs: dict                                   # name -> value given in the graph
    parents: dict = field(default_factory=dict)    # key -> required (bool)
    children: list = field(default_factory=list)   # keys

    @property
    def key(self) -> str:
        return node_key(self.name, self.instance_id)


@dataclass
class GraphSpec:
    name: str
    description: str
    nodes: dict            # key -> NodeSpec, in the order given

    def to_json(self, index=None) -> dict:
        actions = []
        for n in self.nodes.values():
            desc = index.get(n.name) if index is not None else None
            inputs = {}
            for k, v in n.inputs.items():
                ptype = desc.inputs[k].pvf_type if desc and k in desc.inputs else _guess_type(v)
                inputs[k] = {'pvf_type': ptype, 'pvf_value': v}
            actions.append({
                'name': n.name, 'instance_id': n.instance_id, 'input_parameters': inputs,
                'parents': [dict(zip(('name', 'instance_id'), split_key(p)), required=r)
                            for p, r in n.parents.items()],
                'children': [dict(zip(('name', 'instance_id'), split_key(c))) for c in n.children],
            })
        return {'graph_name': self.name, 'graph_description': self.description, 'actions': actions}


def _guess_type(v) -> str:
    for t in ('bool', 'number', 'string', 'bools', 'numbers', 'strings'):
        if type_matches(t, v):
            return t
    return 'string'


def node_key(name: str, instance_id: int) -> str:
    return '%s_%d' % (name, instance_id)


def split_key(key: str) -> tuple:
    name, _, iid = key.rpartition('_')
    return name, int(iid)


def _relation(rel, where: str, problems: list[str]):
    if not isinstance(rel, dict) or 'name' not in rel:
        problems.append('%s must be an object {"name", "instance_id", "required"}' % where)
        return None
    unknown = sorted(set(rel) - RELATION_FIELDS)
    if unknown:
        problems.append('%s: unknown field(s) %s' % (where, unknown))
        return None
    iid = rel.get('instance_id', rel.get('id', 0))
    required = rel.get('required', True)
    if not isinstance(rel['name'], str) or not isinstance(iid, int) or isinstance(iid, bool) \
            or not isinstance(required, bool):
        problems.append('%s: name must be a string, instance_id an integer, required a bool' % where)
        return None
    return node_key(rel['name'], iid), required


def parse_graph(data: Any, index, source: str = '<graph>') -> GraphSpec:
    """Validate a decoded UMRF graph against the action index (a mapping name -> ActionDescriptor).

    Relations may be given on either side (a parent's ``children`` or a child's ``parents``);
    both are merged. Unknown actions, unknown or badly typed parameters, dangling relations and
    cycles are all reported at once.
    """
    if isinstance(data, str):
        try:
            data = json.loads(data)
        except ValueError as e:
            raise UmrfError(source, ['not valid JSON: %s' % e]) from None
    problems: list[str] = []
    if not isinstance(data, dict):
        raise UmrfError(source, ['a graph must be a JSON object with "graph_name" and "actions"'])
    unknown = sorted(set(data) - GRAPH_FIELDS)
    if unknown:
        problems.append('unknown field(s) %s; allowed: %s' % (unknown, sorted(GRAPH_FIELDS)))
    gname = data.get('graph_name', 'graph')
    if not isinstance(gname, str) or not re.match(r'^[A-Za-z][A-Za-z0-9_]{0,80}$', gname):
        problems.append('"graph_name" must be an identifier, got %r' % (gname,))
        gname = 'graph'
    desc = data.get('graph_description', '')
    if not isinstance(desc, str):
        problems.append('"graph_description" must be a string')
        desc = ''
    actions = data.get('actions', data.get('umrf_actions'))
    if not isinstance(actions, list) or not actions:
        raise UmrfError(source, problems + ['"actions" must be a non-empty list of action nodes'])
    nodes: dict = {}
    relations = []
    for i, a in enumerate(actions):
        where = 'actions[%d]' % i
        if not isinstance(a, dict):
            problems.append('%s must be an object' % where)
            continue
        unknown = sorted(set(a) - NODE_FIELDS)
        if unknown:
            problems.append('%s: unknown field(s) %s' % (where, unknown))
        name = a.get('name')
        d = index.get(name) if isinstance(name, str) else None
        if d is None:
            problems.append('%s: unknown action %r (indexed: %s)' % (where, name, sorted(index)))
            continue
        iid = a.get('instance_id', a.get('id', i))
        if not isinstance(iid, int) or isinstance(iid, bool) or iid < 0:
            problems.append('%s: instance_id must be a non-negative integer' % where)
            continue
        key = node_key(name, iid)
        if key in nodes:
            problems.append('%s: duplicate node %s' % (where, key))
            continue
        inputs = {}
        raw = a.get('input_parameters', {}) or {}
        if not isinstance(raw, dict):
            problems.append('%s.input_parameters must be an object' % where)
            raw = {}
        for pname, pv in raw.items():
            spec = d.inputs.get(pname)
            if spec is None:
                problems.append('%s: action %r has no input parameter %r (inputs: %s)'
                                % (where, name, pname, sorted(d.inputs)))
                continue
            if isinstance(pv, dict):
                if 'pvf_type' in pv and pv['pvf_type'] != spec.pvf_type:
                    problems.append('%s.%s: pvf_type %r differs from the action\'s %r'
                                    % (where, pname, pv['pvf_type'], spec.pvf_type))
                    continue
                if 'pvf_value' not in pv:
                    continue        # declared only; filled by a parent at run time
                pv = pv['pvf_value']
            err = spec.check(pv)
            if err:
                problems.append('%s: %s' % (where, err))
                continue
            inputs[pname] = pv
        nodes[key] = NodeSpec(name, iid, inputs)
        for field_name in ('parents', 'children'):
            rels = a.get(field_name, []) or []
            if not isinstance(rels, list):
                problems.append('%s.%s must be a list' % (where, field_name))
                continue
            for j, r in enumerate(rels):
                rel = _relation(r, '%s.%s[%d]' % (where, field_name, j), problems)
                if rel:
                    relations.append((field_name, key, rel[0], rel[1]))
    for kind, key, other, required in relations:
        if key not in nodes:
            continue
        if other not in nodes:
            problems.append('%s lists %s %s, which is not a node of the graph' % (key, kind[:-1], other))
            continue
        parent, child = (other, key) if kind == 'parents' else (key, other)
        if parent == child:
            problems.append('%s cannot be its own parent' % key)
            continue
        if kind == 'parents':
            nodes[child].parents[parent] = required       # the child's side says whether it waits
        elif parent not in nodes[child].parents:
            nodes[child].parents[parent] = True
        if child not in nodes[parent].children:
            nodes[parent].children.append(child)
    if not problems:
        cycle = _find_cycle(nodes)
        if cycle:
            problems.append('the graph has a cycle: %s' % ' -> '.join(cycle))
    if problems:
        raise UmrfError(source, problems)
    return GraphSpec(gname, desc, nodes)


def _find_cycle(nodes: dict) -> list | None:
    state: dict = {}

    def visit(k, path):
        state[k] = 1
        for c in nodes[k].children:
            if state.get(c) == 1:
                return path + [k, c]
            if c not in state:
                found = visit(c, path + [k])
                if found:
                    return found
        state[k] = 2
        return None

    for k in nodes:
        if k not in state:
            found = visit(k, [])
            if found:
                return found
    return None
