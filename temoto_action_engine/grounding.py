"""Natural-language grounding: an instruction becomes a UMRF graph, with no model at all.

The original used the MeTA toolkit (tokenizer, POS tagger, parser) and then matched verb
phrases to indexed tasks by action/alias and by scored subject words. Operator instructions
are short imperative sentences, so a deterministic word grounder does the same job here:

1. an optional wake word must open the sentence;
2. the sentence is split into clauses on "and", "then", commas and semicolons;
3. in each clause the first word that is (an inflection of) an action's verb or alias picks the
   candidate actions;
4. a verb that is also one of a parameter's words fills that parameter ("open the gripper");
   each candidate is scored as the original did: +2 for each of its subject words or parameter
   words said, +2 for a token matching a parameter's pattern (a topic name, say), +1 when its
   wildcard parameter takes the leftover words; a candidate that declares subject words needs
   at least one of them, and every required input must be filled, by words or by the parent;
5. "it", "them" or "there" make the clause a child of the previous clause, receiving its
   outputs; any other clause starts a new, parallel branch.

Everything here is pure: ``Grounder(descriptors).ground(text)`` returns a GroundingResult.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

from .umrf import ActionDescriptor

SEPARATORS = {'and', 'then', ',', ';'}
DEPENDENT_WORDS = {'it', 'them', 'there'}
STOPWORDS = {
    'a', 'an', 'the', 'please', 'kindly', 'can', 'could', 'would', 'will', 'you', 'me', 'i',
    'us', 'we', 'our', 'your', 'to', 'on', 'in', 'at', 'of', 'for', 'with', 'from', 'into', 'onto',
    'up', 'now', 'also', 'just', 'some', 'this', 'that', 'these', 'those', 'is', 'are', 'be', 'let',
    'lets', "let's", 'go', 'ahead', 'all', 'again', 'over', 'here', 'away', 'do', 'start',
    'starting',
}
# "my" is not a stopword: "follow my hand" is the operator's own hand (follow_hand lists it as a subject word),
# where "follow the hand" may be a tracked one (a tie goes to the action that does not move)
TOKEN_RE = re.compile(r"[A-Za-z0-9_/~][A-Za-z0-9_/~\-\.']*|[,;]")


def inflections(verb: str) -> set[str]:
    """The forms an operator may use for ``verb``: show/shows/showing/showed, track/tracking, ..."""
    forms = {verb, verb + 's', verb + 'es', verb + 'ing', verb + 'ed', verb + 'd'}
    if verb.endswith('e'):
        forms |= {verb[:-1] + 'ing', verb + 'd'}
    if verb.endswith('y'):
        forms |= {verb[:-1] + 'ies', verb[:-1] + 'ied'}
    if len(verb) >= 3 and verb[-1] not in 'aeiouwxy' and verb[-2] in 'aeiou' and verb[-3] not in 'aeiou':
        forms |= {verb + verb[-1] + 'ing', verb + verb[-1] + 'ed'}     # stop -> stopping
    return forms


def word_forms(word: str) -> set[str]:
    """Singular and plural of a subject word (hand/hands, box/boxes)."""
    return {word, word + 's', word + 'es'}


@dataclass
class Token:
    text: str       # as said (topic names are case-sensitive)
    low: str


@dataclass
class GroundedClause:
    text: str
    action: str
    inputs: dict
    parent: int | None               # index of the parent clause, or None for a branch root
    from_parent: list = field(default_factory=list)   # inputs that the parent's outputs fill
    score: int = 0
    ignored: list = field(default_factory=list)        # words said but not used


@dataclass
class GroundingResult:
    ok: bool
    message: str
    addressed: bool = True           # False when a wake word is required and was not said
    clauses: list = field(default_factory=list)
    unmatched: list = field(default_factory=list)
    graph: dict | None = None        # UMRF graph JSON when ok


@dataclass
class _Candidate:
    action: ActionDescriptor
    inputs: dict
    from_parent: list
    score: int
    unmatched: list
    missing: list
    evidence: bool      # something said (or the parent) points at this action


class Grounder:
    """Grounds instructions against a fixed set of action descriptors (name -> ActionDescriptor)."""

    def __init__(self, descriptors: dict, wake_words: list[str] | tuple = ()):
        self.descriptors = dict(descriptors)
        self.wake_words = {w.lower() for w in wake_words if w}
        self._verbs: dict[str, list[str]] = {}       # inflected form -> action names
        for name, d in sorted(self.descriptors.items()):
            for v in d.grounding.verbs:
                for form in inflections(v):
                    self._verbs.setdefault(form, [])
                    if name not in self._verbs[form]:
                        self._verbs[form].append(name)

    # ------------------------------------------------------------------ public
    def ground(self, text: str) -> GroundingResult:
        tokens = [Token(t, t.lower().strip(".'")) for t in TOKEN_RE.findall(text or '')]
        tokens = [t for t in tokens if t.low]
        if self.wake_words:
            if not tokens or tokens[0].low not in self.wake_words:
                return GroundingResult(False, 'ignored: the instruction does not start with a wake word (%s)'
                                       % ', '.join(sorted(self.wake_words)), addressed=False)
            tokens = tokens[1:]
            if tokens and tokens[0].low == ',':
                tokens = tokens[1:]
        if not any(t.low not in SEPARATORS for t in tokens):
            return GroundingResult(False, 'nothing to do: the instruction is empty. ' + self.known_actions())
        clauses = self._split(tokens)
        grounded: list[GroundedClause] = []
        problems: list[str] = []
        unmatched: list[str] = []
        for i, clause in enumerate(clauses):
            g, problem, words = self._ground_clause(clause, grounded, i)
            unmatched.extend(words)
            if problem:
                problems.append(problem)
            else:
                grounded.append(g)
        if problems:
            msg = 'could not ground "%s": %s. %s' % (text.strip(), '; '.join(problems), self.known_actions())
            return GroundingResult(False, msg, clauses=grounded, unmatched=unmatched)
        graph = self.to_graph(grounded, text.strip())
        return GroundingResult(True, 'grounded "%s" as %s' % (text.strip(), self.describe(grounded)),
                               clauses=grounded, unmatched=unmatched, graph=graph)

    def known_actions(self) -> str:
        if not self.descriptors:
            return 'No actions are indexed.'
        parts = ['%s (%s)' % (n, '/'.join(d.grounding.verbs)) for n, d in sorted(self.descriptors.items())]
        return 'Known actions: ' + ', '.join(parts) + '.'

    @staticmethod
    def describe(clauses: list[GroundedClause]) -> str:
        parts = []
        for c in clauses:
            args = ['%s=%s' % (k, v) for k, v in sorted(c.inputs.items())]
            args += ['%s from %s' % (k, clauses[c.parent].action) for k in c.from_parent]
            s = '%s(%s)' % (c.action, ', '.join(args))
            if c.parent is not None:
                s = '%s -> %s' % (clauses[c.parent].action, s)
            parts.append(s)
        return '; '.join(parts)

    @staticmethod
    def to_graph(clauses: list[GroundedClause], description: str) -> dict:
        actions = []
        for i, c in enumerate(clauses):
            node = {'name': c.action, 'instance_id': i,
                    'input_parameters': {k: {'pvf_type': 'string', 'pvf_value': v} for k, v in c.inputs.items()},
                    'parents': [], 'children': []}
            if c.parent is not None:
                node['parents'].append({'name': clauses[c.parent].action, 'instance_id': c.parent,
                                        'required': True})
            for j, other in enumerate(clauses):
                if other.parent == i:
                    node['children'].append({'name': other.action, 'instance_id': j})
            actions.append(node)
        name = '_'.join(dict.fromkeys(c.action for c in clauses))[:60] or 'graph'
        return {'graph_name': name, 'graph_description': description, 'actions': actions}

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _split(tokens: list[Token]) -> list[list[Token]]:
        clauses, cur = [], []
        for t in tokens:
            if t.low in SEPARATORS:
                if cur:
                    clauses.append(cur)
                cur = []
            else:
                cur.append(t)
        if cur:
            clauses.append(cur)
        return clauses

    def _ground_clause(self, clause: list[Token], previous: list[GroundedClause], index: int):
        text = ' '.join(t.text for t in clause)
        verb_at = next((i for i, t in enumerate(clause) if t.low in self._verbs), None)
        content = [t for t in clause if t.low not in STOPWORDS and t.low not in DEPENDENT_WORDS]
        if verb_at is None:
            words = [t.low for t in content] or [t.low for t in clause]
            return None, 'in "%s" no word names an action (words not matched: %s)' % (
                text, ', '.join(repr(w) for w in words)), words
        verb = clause[verb_at]
        said = {t.low for t in clause if t.low in DEPENDENT_WORDS}
        if said and not previous:
            # "go there" with nothing before it: "there" is the place pointed at, when an action of this verb
            # takes it as a word of its own; "it" still refers to nothing
            own = {w for n in self._verbs[verb.low] for gp in self.descriptors[n].grounding.parameters.values()
                   for w in gp.words}
            if not said <= own:
                return None, 'in "%s", "it"/"there" refers to nothing said before' % text, []
            content += [t for t in clause if t.low in said]
            said = set()
        dependent = bool(said)
        parent = len(previous) - 1 if dependent else None
        parent_outputs = self.descriptors[previous[parent].action].outputs if parent is not None else {}
        words = [t for t in content if t is not verb]
        cands = [self._score(self.descriptors[n], words, parent_outputs, verb) for n in self._verbs[verb.low]]
        viable = [c for c in cands if not c.missing and c.evidence]
        if not viable:
            reasons = []
            for c in cands:
                if c.missing:
                    reasons.append('%s needs %s%s' % (c.action.name, ', '.join(c.missing),
                                                      ' (from words or from a previous action via "it")'))
                else:
                    reasons.append('%s needs one of the words %s' % (
                        c.action.name, ', '.join(c.action.grounding.subjects + tuple(
                            w for gp in c.action.grounding.parameters.values() for w in gp.words))))
            bad = [w for c in cands for w in c.unmatched]
            bad = list(dict.fromkeys(bad))
            return None, 'in "%s" the verb "%s" matched, but %s%s' % (
                text, verb.low, '; '.join(reasons),
                (' (words not matched: %s)' % ', '.join(repr(w) for w in bad)) if bad else ''), bad
        # a tie goes to the action that does not move the robot: "follow the hand" may mean the view's
        best = max(viable, key=lambda c: (c.score, -len(c.unmatched), not c.action.motion, -len(c.from_parent)))
        return GroundedClause(text, best.action.name, best.inputs, parent, best.from_parent, best.score,
                              best.unmatched), None, []

    @staticmethod
    def _score(desc: ActionDescriptor, words: list[Token], parent_outputs: dict, verb: Token | None = None
               ) -> _Candidate:
        g = desc.grounding
        inputs: dict = {}
        score = 0
        subject_hit = False
        by_verb = set()             # filled by the verb, which points at no action by itself ("close the door")
        if verb is not None:        # a verb that is also a parameter's word fills it: "open the gripper"
            for pname, gp in g.parameters.items():
                hit = next((w for w in gp.words if verb.low in inflections(w)), None)
                if hit is not None:
                    inputs[pname] = hit
                    by_verb.add(pname)
                    break
        left: list[Token] = []
        subjects = {f: s for s in g.subjects for f in word_forms(s)}
        for t in words:
            if t.low in subjects:
                score += 2
                subject_hit = True
                continue
            used = False
            for pname, gp in g.parameters.items():
                if pname in inputs:
                    continue
                hit = next((w for w in gp.words if t.low in word_forms(w)), None)
                if hit is not None:
                    inputs[pname], used = hit, True
                elif gp.pattern and re.fullmatch(gp.pattern, t.text):
                    inputs[pname], used = t.text, True
                if used:
                    score += 2
                    subject_hit = True
                    break
            if not used:
                left.append(t)
        for pname, gp in g.parameters.items():
            if gp.any_word and pname not in inputs and left:
                inputs[pname] = ' '.join(t.text for t in left)
                left = []
                score += 1
                break
        from_parent = [k for k, p in desc.inputs.items()
                       if k not in inputs and k in parent_outputs and parent_outputs[k].pvf_type == p.pvf_type]
        missing = [k for k, p in desc.inputs.items()
                   if p.required and p.default is None and k not in inputs and k not in from_parent]
        # An action nothing points at is not chosen by its verb alone, unless it takes no words at all.
        evidence = subject_hit or bool(set(inputs) - by_verb) or bool(from_parent) or \
            not (g.subjects or g.parameters) or g.bare
        return _Candidate(desc, inputs, from_parent, score, [t.low for t in left], missing, evidence)
