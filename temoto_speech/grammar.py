"""The recognition grammar (JSGF), built from the indexed actions' descriptors.

A new plugin's phrases are understood as soon as it is indexed, with no training: its verbs, subject
words and parameter words become a rule of their own. A free grammar (any verb, then any words) lets the
decoder pad a short utterance into words nobody said ("show an hot"), so each action's rule asks for an
object the grounder can use:

- its subject words ("show the environment");
- else the words of its parameters ("track the hand");
- else, for an action whose parameter takes any words (``stop``), "everything" or another action's clause
  in its -ing form ("stop tracking the hand");
- an action with a required input no word can fill (``show``'s topic) takes its parent's output, so its
  rule is the verb and a pronoun ("show it on the screen");
- at most one prepositional phrase: "with a hot standby" for a parameter whose pattern lists words.

An utterance is an optional wake word, then one clause, or two joined by "and" or "then" (the grounder's
separators). An action that moves the robot (``motion`` in its descriptor) has no clause of its own: it is
said only after the motion wake phrase ("robot please go", "robot please close the gripper"), which the
engine also demands of what speech hears, and which the recogniser holds to a stricter margin. An
action whose verb alone grounds it (``bare``: "stop", "go") may be said with no object. Words outside the recogniser's dictionary get espeak-ng's pronunciation (``phonemes.py``);
words that cannot be said (topic names, robot names with digits) are left out, and listed.
"""
from __future__ import annotations

import dataclasses
import re
from typing import Dict, Iterable, List, Optional, Sequence, Set

from temoto_action_engine.grounding import inflections

DETERMINERS = ('the', 'a')
POSSESSIVE = 'my'
PRONOUNS = ('it', 'them')
LOCATIVES = ('on', 'in')
EVERYTHING = ('everything', 'all')
JOINERS = ('and', 'then')
POLITE = 'please'
BARE_PLACES = ('home', 'there')        # said with no article: "go home", "go there"
MOTION_WAKE = ('robot', 'please')      # the paper's "Robot please go"; the action engine's default too
SAYABLE = re.compile(r'[a-z]+$')
ENUM_PATTERN = re.compile(r'^\^?\(?([a-z]+(?:\|[a-z]+)+)\)?\$?$')     # "cold|warm|hot", "^(a|b)$"


@dataclasses.dataclass
class Grammar:
    jsgf: str
    words: Set[str]                    # every word the grammar can produce
    actions: List[str]                 # the actions that have a rule
    left_out: Dict[str, List[str]]     # action -> what could not be said (and why)


def _sayable(words: Iterable[str], unsayable: Set[str] = frozenset()) -> List[str]:
    return sorted({w.lower() for w in words if SAYABLE.match(w.lower()) and w.lower() not in unsayable})


def _alt(words: Sequence[str]) -> str:
    return '(%s)' % ' | '.join(words)


def _enum_words(pattern: Optional[str]) -> List[str]:
    m = ENUM_PATTERN.match(pattern or '')
    return m.group(1).split('|') if m else []


def gerund(verb: str) -> str:
    """The -ing form: show -> showing, locate -> locating, stop -> stopping, tie -> tying."""
    if verb.endswith('ie'):
        return verb[:-2] + 'ying'
    if verb.endswith('e') and not verb.endswith('ee'):
        return verb[:-1] + 'ing'
    doubled = verb + verb[-1] + 'ing'
    return doubled if doubled in inflections(verb) else verb + 'ing'


class _ActionWords:
    """What can be said of one action, from its descriptor's JSON (``ActionDescriptor.to_json``)."""

    def __init__(self, action: dict, unsayable: Set[str]) -> None:
        self.name = str(action['name'])
        self.unsayable = unsayable
        grounding = action.get('grounding') or {}
        self.verbs = _sayable(grounding.get('verbs', []), unsayable)
        # "my" as a subject word ("follow my hand") is said as a determiner, before the object
        said = _sayable(grounding.get('subjects', []), unsayable)
        self.possessive = POSSESSIVE in said
        self.subjects = [w for w in said if w != POSSESSIVE]
        self.param_words: List[str] = []
        self.any_words = False
        self.enums: Dict[str, List[str]] = {}
        self.phrases: Dict[str, List[str]] = {}      # parameter -> its words, said after the subject
        self.left_out: List[str] = []
        self.motion = bool(action.get('motion'))         # said only after the motion wake phrase
        self.bare = bool(grounding.get('bare'))          # the verb alone is a clause ("stop", "go")
        params = grounding.get('parameters') or {}
        self.said = {w.lower() for w in list(grounding.get('verbs', [])) + list(grounding.get('subjects', [])) +
                     [w for spec in params.values() for w in (spec.get('words') or [])]}
        for pname, spec in sorted(params.items()):
            self.param_words += _sayable(spec.get('words') or [], unsayable)
            self.any_words |= bool(spec.get('any'))
            enum = _sayable(_enum_words(spec.get('pattern')), unsayable)
            words = _sayable(spec.get('words') or [], unsayable)
            if enum:
                self.enums[pname] = enum
            elif spec.get('pattern') and not words:
                self.left_out.append('parameter %s (pattern %s: not a list of words)' % (pname, spec['pattern']))
            # an action said with its subject takes its parameters' words in a phrase after it ("follow my hand
            # at a tenth", "... with the right arm", "... with the base"); words that are its own verbs ("open",
            # "drive") are said as the verb
            phrased = [w for w in words if w not in self.verbs]
            if phrased:
                self.phrases[pname] = phrased

        def said_in_words(name: str) -> bool:
            spec = params.get(name) or {}
            return name in self.enums or bool(spec.get('words') or spec.get('any'))
        # a required input no word fills comes from the parent clause: "show it"
        self.takes_parent = any(spec.get('pvf_required', True) and not said_in_words(name)
                                for name, spec in (action.get('input_parameters') or {}).items())

    def objects(self) -> List[str]:
        return self.subjects or sorted(set(self.param_words))


def build(actions: Sequence[dict], wake_words: Sequence[str] = (), unsayable: Iterable[str] = (),
          motion_wake: Sequence[str] = MOTION_WAKE, answers: Sequence[str] = ()) -> Grammar:
    """The grammar of ``actions`` (descriptor JSON, as ``list_actions`` sends it); with ``wake_words`` an
    utterance must open with one of them. ``unsayable``: words the recogniser has no pronunciation for.
    An action that moves the robot (``motion``) is said only after ``motion_wake`` ("robot please go").
    ``answers``: single words said alone, with no wake word, to answer a question ("yes", "no")."""
    unsayable = set(unsayable)
    described = [a for a in (_ActionWords(a, unsayable) for a in actions) if a.verbs]
    det = '[%s]' % _alt(DETERMINERS)
    rules: List[str] = []
    for a in described:
        if a.takes_parent:
            where = ' [%s %s %s]' % (_alt(LOCATIVES), det, _alt(a.subjects)) if a.subjects else ''
            body = ' %s%s' % (_alt(PRONOUNS), where)
        elif a.objects():
            pps = ['with %s %s%s' % (det, _alt(words), ' [%s]' % pname if SAYABLE.match(pname) else '')
                   for pname, words in sorted(a.enums.items())]
            if a.subjects:
                pps += ['(at | with) %s %s%s' % (det, _alt(words), ' [%s]' % pname if SAYABLE.match(pname) else '')
                        for pname, words in sorted(a.phrases.items()) if pname not in a.enums]
            # a place a motion goes to: "go to the shelf"
            body = ' %s%s%s %s%s' % ('[me] ' if a.subjects else '', '[to] ' if a.motion and not a.subjects else '',
                                     '[%s]' % _alt(DETERMINERS + (POSSESSIVE,)) if a.possessive else det,
                                     _alt(a.objects()), ' [%s]' % _alt(pps) if pps else '')
        elif a.any_words:
            others = [_clause_of_other(b) for b in described if b is not a and b.objects() and not b.takes_parent]
            body = ' ' + _alt(list(EVERYTHING) + [o for o in others if o])
        else:
            body = ''
        if a.bare and body:
            body = ' [%s]' % body.strip()
        rules.append('<%s> = %s%s;' % (_rule_name(a.name), _alt(a.verbs), body))
    for a in described:
        a.left_out += ['the word %r (no pronunciation)' % w for w in sorted(unsayable & a.said)]
    left_out = {a.name: a.left_out for a in described if a.left_out}
    if not rules:
        return Grammar('', set(), [], left_out)
    wake = _sayable(wake_words, unsayable)
    still = [a for a in described if not a.motion]
    moving = [a for a in described if a.motion]
    motion_wake = [w for w in (w.lower() for w in motion_wake) if SAYABLE.match(w) and w not in unsayable]
    if not motion_wake:
        moving = []                     # nothing can be said before a motion: none can be said at all
    lead = '%s ' % _alt(wake) if wake else ''
    joined = '%s [%s %s]'
    forms = []
    if still:
        forms.append(joined % ('[%s] <clause>' % POLITE, _alt(JOINERS), '<clause>'))
    if moving:
        # one motion an utterance: a decoder that pads a short motion with a second clause ("go the home" heard
        # as "go then go home") would otherwise start a motion nobody said (bench_speech.py)
        wake_words = ' '.join(motion_wake)
        form = '%s <motion> [%s <clause>]' % (wake_words, _alt(JOINERS)) if still else '%s <motion>' % wake_words
        if still:
            form = '%s (<motion> [%s <clause>] | <clause> [%s (<motion> | <clause>)])' % (
                wake_words, _alt(JOINERS), _alt(JOINERS))
        forms.append(form)
    said_answers = _sayable(answers, unsayable)
    top = '%s%s' % (lead, forms[0] if len(forms) == 1 else _alt(forms))
    if said_answers:
        top = '%s | %s' % (top, _alt(said_answers))       # JSGF: "|" binds loosest
    body = ['public <utterance> = %s;' % top]
    if still:
        body.append('<clause> = %s;' % ' | '.join('<%s>' % _rule_name(a.name) for a in still))
    if moving:
        body.append('<motion> = %s;' % ' | '.join('<%s>' % _rule_name(a.name) for a in moving))
    body += rules
    text = '\n'.join(body)
    words = set(re.findall(r'[a-z]+', re.sub(r'<[^>]*>|^public ', ' ', text, flags=re.M)))
    return Grammar('#JSGF V1.0;\ngrammar temoto;\n' + text + '\n', words, [a.name for a in described], left_out)


def phrases(actions: Sequence[dict], motion_wake: Sequence[str] = MOTION_WAKE) -> List[str]:
    """The plain instructions the grammar of ``actions`` takes: each verb with each object ("track the hand"),
    "<verb> everything" for an action whose parameter takes any words, and the verb alone for one that
    needs no words ("stop"). A motion's opens with the motion wake phrase ("robot please close the
    gripper"). Actions that only take their parent's output ("show it") are said after another clause, so
    they have none of their own."""
    out: List[str] = []
    for a in (_ActionWords(a, set()) for a in actions):
        if a.takes_parent:
            continue
        said: List[str] = []
        if a.subjects:
            said += ['%s the %s' % (v, o) for v in a.verbs for o in a.objects()]
        elif a.objects():
            # a verb that is itself a parameter's word ("finer") is said alone; a place is gone to ("go to the
            # shelf", "go home", "go there")
            words = [o for o in a.objects() if o not in a.verbs]
            said += ['%s %s' % (v, o if o in BARE_PLACES else ('to the %s' % o if a.motion else 'the %s' % o))
                     for v in a.verbs if v not in a.objects() for o in words]
        elif a.any_words:
            said += ['%s everything' % v for v in a.verbs]
        if a.bare:
            said += list(a.verbs)
        wake = ' '.join(motion_wake)
        out += ['%s %s' % (wake, p) for p in said] if a.motion else said
    return out


def _rule_name(action: str) -> str:
    return 'a_' + re.sub(r'[^A-Za-z0-9_]', '_', action)


def _clause_of_other(b: _ActionWords) -> str:
    gerunds = sorted({gerund(v) for v in b.verbs} - b.unsayable)
    return '%s [%s] %s' % (_alt(gerunds), _alt(DETERMINERS), _alt(b.objects())) if gerunds else ''
