"""The speech node: the operator's voice in, the robot's announcements out.

Topics (``<ns>`` is the TeMoto namespace, ``~temoto_namespace``, default ``temoto``):
- in  ``/<ns>/speech/audio``        temoto_speech/AudioData: 16 kHz mono 16-bit PCM in chunks (an
  ``audio_common``-style stream; ``temoto listen --wav`` sends a file). An empty chunk ends the utterance
  at once (the end of a file), else it ends at 0.4 s of silence.
- out ``/<ns>/human_chatter``       std_msgs/String: an accepted utterance, as text (the engine grounds it)
- out ``/<ns>/speech/heard``        std_msgs/String: JSON of every recognition, accepted or rejected, with
  its reason, its margin, and when its speech ended (``speech_end``, wall clock)
- in  ``/<ns>/action_engine/events`` std_msgs/String: said as short sentences (``announcer.py``)
- in  ``/<ns>/speech/say``          std_msgs/String: a sentence to announce
- out ``/<ns>/speech/announcements`` std_msgs/String: every announcement, said aloud or not
- out ``/<ns>/speech/grammar``      std_msgs/String, latched: JSON of the grammar in use (actions, words)

Parameters: ``~source`` (``topic``, or ``microphone``: the ALSA device ``~microphone`` read through sox),
``~wake_words`` (','-separated; an utterance must start with one), ``~min_margin`` (the rejection
threshold, ``recognizer.py``), ``~min_motion_margin`` (the stricter one for an utterance that moves the robot), ``~speak`` (false: announcements only on the topic), ``~voice``,
``~speed``, ``~wav_dir`` (each announcement also written there as a WAV file), ``~grammar_poll_s`` (how
often the engine's action index is read for new plugins), ``~confirm_motion`` (true: a heard motion is said
back and sent only on "yes", ``confirmation.py``) and ``~confirm_window_s``.
"""
from __future__ import annotations

import hashlib
import json
import subprocess
import threading
import time
from typing import Optional

import rospy
from rospy.exceptions import TransportException
from std_msgs.msg import String

from temoto_action_engine.srv import ListActions
from temoto_core.node import init_node, spin
from temoto_core import params
from temoto_speech.announcer import Announcer, Sentences
from temoto_speech.confirmation import ANSWERS, WINDOW_S, YES, MotionConfirmation
from temoto_speech.grammar import MOTION_WAKE
from temoto_speech.audio import FRAME_BYTES, RATE, Utterances
from temoto_speech.msg import AudioData
from temoto_speech.recognizer import MIN_MARGIN, MIN_MOTION_MARGIN, Recognizer
from temoto_speech.voice import DEFAULT_SPEED, DEFAULT_VOICE

NODE_NAME = 'temoto_speech'
STOP_WORDS = ('stop', 'halt')     # never held for a confirmation
NOT_UNDERSTOOD = 'I did not understand'
INDEX_CALL_TIMEOUT_S = 5.0


class SpeechNode:
    def __init__(self) -> None:
        self.ns = params.text('temoto_namespace', 'temoto').strip('/') or 'temoto'
        self.wake_words = params.strings('wake_words', '')
        self.poll_s = params.number('grammar_poll_s', 5.0, above=0)
        source = params.text('source', 'topic', choices=('topic', 'microphone'))
        base = '/%s/speech' % self.ns
        self.chatter = rospy.Publisher('/%s/human_chatter' % self.ns, String, queue_size=10)
        self.heard = rospy.Publisher(base + '/heard', String, queue_size=20)
        self.grammar_pub = rospy.Publisher(base + '/grammar', String, queue_size=1, latch=True)
        announcements = rospy.Publisher(base + '/announcements', String, queue_size=20)
        self.sentences = Sentences()
        self.announcer = Announcer(lambda text: announcements.publish(String(text)),
                                   params.text('voice', DEFAULT_VOICE, empty=False),
                                   params.number('speed', DEFAULT_SPEED, minimum=1, integer=True),
                                   audible=params.flag('speak', True),
                                   wav_dir=params.text('wav_dir', ''),
                                   on_error=lambda text: rospy.logwarn('%s: %s', NODE_NAME, text))
        self.recognizer = Recognizer([], self.wake_words, params.number('min_margin', MIN_MARGIN),
                                     params.number('min_motion_margin', MIN_MOTION_MARGIN))
        self.confirmation = MotionConfirmation(MOTION_WAKE, STOP_WORDS, params.number('confirm_window_s', WINDOW_S,
                                                                                      above=0), self.wake_words) \
            if params.flag('confirm_motion', False) else None
        self._confirm_lock = threading.Lock()
        self._index_digest = ''
        self.utterances = Utterances()
        self._audio_lock = threading.Lock()
        self._stop = threading.Event()
        self._mic: Optional[subprocess.Popen] = None
        self._subs = [rospy.Subscriber(base + '/audio', AudioData, self._on_audio, queue_size=200),
                      rospy.Subscriber(base + '/say', String, lambda m: self.announcer.say(m.data), queue_size=10),
                      rospy.Subscriber('/%s/action_engine/events' % self.ns, String, self._on_event, queue_size=100)]
        self.refresh_grammar()      # after the subscriptions: a grammar on its topic means the node listens
        threading.Thread(target=self._poll_index, name='speech-grammar', daemon=True).start()
        if self.confirmation is not None:
            threading.Thread(target=self._expire_questions, name='speech-confirmation', daemon=True).start()
        if source == 'microphone':
            threading.Thread(target=self._listen_microphone, args=(params.text('microphone', 'default'),),
                             name='speech-microphone', daemon=True).start()

    # ------------------------------------------------------------------ grammar
    def refresh_grammar(self) -> bool:
        """Read the engine's action index; rebuild the grammar if it changed. False if the engine is away."""
        try:
            rospy.wait_for_service('/%s/action_engine/list_actions' % self.ns, timeout=INDEX_CALL_TIMEOUT_S)
            index = json.loads(rospy.ServiceProxy('/%s/action_engine/list_actions' % self.ns,
                                                  ListActions)(reindex=False).json)
        # rospy's TransportException (a connection refused or cut) is no ROSException; an uncaught one ended
        # the poll's thread, and with it every later grammar, without a word
        except (rospy.ROSException, rospy.ServiceException, TransportException, OSError, ValueError) as e:
            rospy.logdebug('%s: the action index is not available: %s', NODE_NAME, e)
            return False
        actions = index.get('actions', [])
        digest = hashlib.sha1(json.dumps(actions, sort_keys=True).encode()).hexdigest()
        if digest == self._index_digest:
            return True
        try:
            built = self.recognizer.update(actions, self.wake_words, ANSWERS if self.confirmation else (),
                                           YES if self.confirmation else ())
        except (ValueError, RuntimeError) as e:      # a grammar pocketsphinx refuses, espeak-ng missing
            rospy.logerr('%s: no new grammar for the %d action(s) now indexed (the last one stays): %s',
                         NODE_NAME, len(actions), e)
            self._index_digest = digest          # tried again when the index changes, not every poll
            return False
        self._index_digest = digest
        self.grammar_pub.publish(String(json.dumps({'actions': built.actions, 'words': sorted(built.words),
                                                    'left_out': built.left_out, 'wake_words': self.wake_words})))
        rospy.loginfo('%s: grammar of %d action(s), %d word(s): %s', NODE_NAME, len(built.actions), len(built.words),
                      ', '.join(built.actions))
        return True

    def _poll_index(self) -> None:
        while not self._stop.wait(self.poll_s) and not rospy.is_shutdown():
            self.refresh_grammar()

    # ------------------------------------------------------------------ speech in
    def _on_audio(self, msg: AudioData) -> None:
        data = bytes(msg.data)
        with self._audio_lock:
            if not data:                       # the end of a file: what was said so far is one utterance
                done = self.utterances.flush()
            else:
                done = self.utterances.feed(data)
        for pcm in done:
            self.handle_utterance(pcm, time.time())

    def handle_utterance(self, pcm: bytes, speech_end: float) -> None:
        result = self.recognizer.recognize(pcm)
        report = dict(result.to_json(), speech_end=speech_end)
        self.heard.publish(String(json.dumps(report)))
        if result.accepted:
            rospy.loginfo('%s: heard "%s" (margin %.1f)', NODE_NAME, result.text, result.margin)
            if self.confirmation is None:
                self.chatter.publish(String(result.text))
                return
            with self._confirm_lock:
                decision = self.confirmation.heard(result.text, time.monotonic())
            if decision.send:
                self.chatter.publish(String(decision.send))
            if decision.say:
                self.announcer.say(decision.say)
        else:
            rospy.loginfo('%s: rejected "%s": %s', NODE_NAME, result.text, result.reason)
            self.announcer.say(NOT_UNDERSTOOD)

    def _expire_questions(self) -> None:
        """A motion left unanswered is dropped, and the operator told, once its window has passed."""
        while not self._stop.wait(0.25) and not rospy.is_shutdown():
            with self._confirm_lock:
                dropped = self.confirmation.expire(time.monotonic())
            if dropped:
                rospy.loginfo('%s: "%s" not confirmed in time: dropped', NODE_NAME, dropped)
                self.announcer.say('not confirmed')

    def _listen_microphone(self, device: str) -> None:
        argv = ['sox', '-q', '-t', 'alsa', device, '-t', 'raw', '-r', str(RATE), '-c', '1', '-b', '16',
                '-e', 'signed-integer', '-L', '-']
        try:
            self._mic = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        except OSError as e:
            rospy.logerr('%s: no microphone: %s', NODE_NAME, e)
            self.announcer.say('no microphone')
            return
        heard_any = False
        while not self._stop.is_set():
            chunk = self._mic.stdout.read(FRAME_BYTES * 5)
            if not chunk:
                err = self._mic.stderr.read().decode(errors='replace').strip()
                rospy.logerr('%s: the microphone %r %s: %s', NODE_NAME, device,
                             'stopped' if heard_any else 'gave no audio', err[:300] or 'no more audio')
                self.announcer.say('the microphone stopped' if heard_any else 'no microphone')
                return
            heard_any = True
            with self._audio_lock:
                done = self.utterances.feed(chunk)
            for pcm in done:
                self.handle_utterance(pcm, time.time())

    # ------------------------------------------------------------------ speech out
    def _on_event(self, msg: String) -> None:
        try:
            ev = json.loads(msg.data)
        except ValueError:
            rospy.logwarn('%s: an event that is not JSON: %r', NODE_NAME, msg.data[:200])
            return
        text = self.sentences.of(ev) if isinstance(ev, dict) else None
        if text:
            self.announcer.say(text)

    def shutdown(self) -> None:
        self._stop.set()
        for sub in self._subs:
            sub.unregister()
        if self._mic is not None and self._mic.poll() is None:
            self._mic.terminate()
            self._mic.wait(5.0)
        self.announcer.stop()


def main() -> None:
    init_node(NODE_NAME)
    node = SpeechNode()
    try:
        spin()
    finally:
        node.shutdown()
