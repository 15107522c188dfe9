"""Speech to instruction text, offline: pocketsphinx with the actions' grammar, and a rejection test.

A grammar decoder always answers with *some* sentence of its grammar when the audio fits one at all, so a
sentence nobody meant ("show me the money") could start an action. Two tests stand between the audio and
the action:

1. **The grammar must match the whole utterance.** The search is run without its best-path pass
   (``bestpath=False``: with it, a grammar turned "show the environment" into "show the"), and an
   utterance no path of the grammar explains gives no hypothesis: rejected, "not understood".
2. **The grammar's words must explain the audio about as well as free phones do.** The same audio is
   decoded by the phone loop (any phone after any other), the best any English speech could score. Per
   frame of audio, the acoustic score of the grammar's words minus the phone loop's score is the
   *margin*: words that were said score above the phone loop (its phone-to-phone penalties cost more
   than the words fit worse), a sentence forced onto words that were not said scores below. Below
   ``min_margin``: rejected, "not sure". The grammar's own path probabilities are left out of the
   margin: they shrink as a plugin adds words, which would reject more the more actions there are.

Before either search, a faint noise floor (``NOISE_FLOOR_RMS``, about -61 dBFS) is added to the audio. A
microphone always has one; synthesized speech and gated recordings have stretches of digital silence,
which the front end's noise estimate and cepstral normalisation handle badly: over 15 phrases in 3
espeak-ng voices, 38 of 45 were grounded right without it, 45 with it, and no more sentences outside the
grammar were accepted (bench/bench_speech.py).

Scores are in pocketsphinx's log base (1.0001); the Python API returns them as probabilities, which are
taken back to the log scale here. They are relative to each search's best path per frame, so the margin
is an empirical test, not a likelihood ratio: its threshold is measured (bench/bench_speech.py).
"""
from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
from typing import Dict, Optional, Sequence

import numpy as np
from pocketsphinx import Decoder, get_model_path

from . import grammar as grammar_mod
from .phonemes import espeak_pronunciations

GRAMMAR_SEARCH = 'actions'
PHONE_SEARCH = 'phones'
LOG_BASE = math.log(1.0001)
# per frame (10 ms): over 15 of the bundled actions' phrases in 3 espeak-ng voices, 32 of the 37 heard
# right scored above 0 (up to 23), and 10 of 11 sentences outside the grammar below (bench_speech.py)
MIN_MARGIN = 0.0
# a motion is held to more: at 4 the speech benchmark kept 90 % of instructions and dropped half the wrong ones
# (BENCHMARKS.md, bench_speech.py); the wake phrase does the rest
MIN_MOTION_MARGIN = 4.0
NOISE_FLOOR_RMS = 30.0      # in 16-bit sample units; seeded, so a recognition is the same every time


@dataclasses.dataclass
class Recognition:
    text: str                 # the grammar's sentence ('' when none matched)
    accepted: bool
    reason: str               # why it was rejected ('' when accepted)
    margin: Optional[float]   # the grammar's score over the phone loop's, per frame
    decode_s: float
    seconds: float            # length of the audio

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


class Recognizer:
    """One decoder, rebuilt when the actions change; ``recognize`` is safe to call from any thread."""

    def __init__(self, actions: Sequence[dict], wake_words: Sequence[str] = (), min_margin: float = MIN_MARGIN,
                 min_motion_margin: float = MIN_MOTION_MARGIN) -> None:
        self.min_margin = float(min_margin)
        self.min_motion_margin = max(float(min_motion_margin), self.min_margin)
        self.wake_words: Sequence[str] = ()
        self.moving_answers: Sequence[str] = ()
        self._lock = threading.Lock()
        self.grammar: Optional[grammar_mod.Grammar] = None
        self._decoder: Optional[Decoder] = None
        self.update(actions, wake_words)

    def update(self, actions: Sequence[dict], wake_words: Sequence[str] = (), answers: Sequence[str] = (),
               moving_answers: Sequence[str] = ()) -> grammar_mod.Grammar:
        """A grammar for ``actions`` (descriptor JSON), and ``answers`` said alone ("yes", "no"); a new decoder
        replaces the old one at once. ``moving_answers`` ("yes") are held to the motion margin, since they
        start a motion; the others ("no") only drop one, and a short "no" often scores low."""
        self.moving_answers = tuple(a.lower() for a in moving_answers)
        built = grammar_mod.build(actions, wake_words, answers=answers)
        self.wake_words = tuple(w.lower() for w in wake_words)
        decoder = Decoder(samprate=16000, lm=None, bestpath=False, loglevel='FATAL')
        if built.jsgf:
            for word, phones in espeak_pronunciations(sorted(built.words)).items():
                if phones:
                    _add_pronunciation(decoder, word, phones)
            unsayable = [w for w in built.words if decoder.lookup_word(w) is None]
            if unsayable:
                built = grammar_mod.build(actions, wake_words, unsayable, answers=answers)
        if built.jsgf:
            decoder.add_jsgf_string(GRAMMAR_SEARCH, built.jsgf)
            decoder.add_allphone_file(PHONE_SEARCH, os.path.join(get_model_path(), 'en-us', 'en-us-phone.lm.bin'))
        with self._lock:
            self.grammar, self._decoder = built, decoder
        return built

    def recognize(self, pcm: bytes) -> Recognition:
        """``pcm``: one utterance, 16 kHz mono 16-bit."""
        length = len(pcm) / 32000.0
        t0 = time.monotonic()
        pcm = with_noise_floor(pcm)
        with self._lock:
            if not self.grammar or not self.grammar.jsgf:
                return Recognition('', False, 'no action can be said (none is indexed)', None, 0.0, length)
            text, words_score, frames = self._decode(GRAMMAR_SEARCH, pcm)
            if not text:
                return Recognition('', False, 'not understood', None, time.monotonic() - t0, length)
            _, phones_score, _ = self._decode(PHONE_SEARCH, pcm)
        margin = (words_score - phones_score) / max(frames, 1)
        took = time.monotonic() - t0
        moving = self.moves(text) or text.lower() in self.moving_answers
        needed = self.min_motion_margin if moving else self.min_margin
        if margin < needed:
            return Recognition(text, False, 'not sure (margin %.1f, below %.1f%s)'
                               % (margin, needed, ' for a motion' if needed != self.min_margin else ''),
                               margin, took, length)
        return Recognition(text, True, '', margin, took, length)

    def moves(self, text: str) -> bool:
        """Whether ``text`` (as the grammar gives it) asks for a motion: it opens, after any wake word, with
        the motion wake phrase, which the grammar demands of every motion action and of nothing else."""
        words = text.lower().split()
        if words and words[0] in self.wake_words:
            words = words[1:]
        return words[:len(grammar_mod.MOTION_WAKE)] == list(grammar_mod.MOTION_WAKE)

    def _decode(self, search: str, pcm: bytes):
        decoder = self._decoder
        decoder.activate_search(search)
        decoder.start_utt()
        decoder.process_raw(pcm, False, True)
        decoder.end_utt()
        hyp = decoder.hyp()
        if hyp is None or not hyp.hypstr or hyp.score <= 0.0:
            return '', 0.0, decoder.n_frames()
        if search == GRAMMAR_SEARCH:       # the words' acoustic scores, without the grammar's path probabilities
            score = sum(math.log(max(seg.ascore, 1e-300)) for seg in decoder.seg()) / LOG_BASE
        else:
            score = math.log(hyp.score) / LOG_BASE
        return hyp.hypstr, score, decoder.n_frames()


def with_noise_floor(pcm: bytes, rms: float = NOISE_FLOOR_RMS) -> bytes:
    """``pcm`` with white noise of ``rms`` added (always the same noise for the same length)."""
    samples = np.frombuffer(pcm[:len(pcm) // 2 * 2], dtype='<i2').astype(np.float64)
    samples += np.random.default_rng(0).normal(0.0, rms, samples.size)
    return np.clip(samples, -32768, 32767).astype('<i2').tobytes()


def _add_pronunciation(decoder: Decoder, word: str, phones: str) -> None:
    """``phones`` as ``word``'s pronunciation, or as another variant ("hand(2)") if it has one already."""
    variants: Dict[str, str] = {}
    name = word
    n = 1
    while True:
        known = decoder.lookup_word(name)
        if known is None:
            break
        variants[name] = known
        n += 1
        name = '%s(%d)' % (word, n)
    if phones not in variants.values():
        decoder.add_word(name, phones, False)     # the grammar, added after, is built with it
