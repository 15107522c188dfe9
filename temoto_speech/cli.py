"""``temoto listen [--wav FILE]`` and ``temoto say --voice "..."``: the speech node from a shell.

``listen`` without a file prints what the speech node hears, as it hears it. With ``--wav`` it sends the
file to the node as speech and prints what the node understood. ``say --voice`` speaks the instruction
with espeak-ng first, then does the same: the whole path from a voice to a graph. ``say`` without
``--voice`` is the action engine's (text, no speech).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from typing import List, Optional

import rospy
from std_msgs.msg import String

from temoto_action_engine import cli as engine_cli
from temoto_core.wait import wait_for
from temoto_speech.audio import AudioError, read_wav, write_wav
from temoto_speech.msg import AudioData
from temoto_speech.voice import DEFAULT_VOICE, VoiceError, synthesize_pcm

CHUNK_BYTES = 3200              # 0.1 s of audio a message
SUBSCRIBER_WAIT_S = 5.0
ANSWER_WAIT_S = 20.0


def _start(ns: str) -> str:
    """This process as a node; the speech node's topic prefix."""
    rospy.init_node('temoto_listen', anonymous=True, disable_signals=True)
    return '/%s/speech' % ns.strip('/')


def send(ns: str, pcm: bytes, timeout: float = ANSWER_WAIT_S) -> dict:
    """``pcm`` to the speech node as one utterance; the node's report of what it heard."""
    base = _start(ns)
    answers: List[dict] = []
    got = threading.Event()

    def on_heard(msg) -> None:
        answers.append(json.loads(msg.data))
        got.set()
    sub = rospy.Subscriber(base + '/heard', String, on_heard, queue_size=5)
    pub = rospy.Publisher(base + '/audio', AudioData, queue_size=1000)
    try:
        wait_for(lambda: pub.get_num_connections() and sub.get_num_connections(), SUBSCRIBER_WAIT_S,
                 'the speech node')
    except TimeoutError:
        raise SystemExit('error: no speech node listens on %s/audio (is temoto_speech running in namespace %r?)'
                         % (base, ns)) from None
    for i in range(0, len(pcm), CHUNK_BYTES):
        pub.publish(AudioData(data=pcm[i:i + CHUNK_BYTES]))
    pub.publish(AudioData(data=b''))          # the end of the utterance
    if not got.wait(timeout):
        raise SystemExit('error: the speech node did not answer within %.0f s' % timeout)
    return answers[0]


def _report(heard: dict) -> int:
    if heard['accepted']:
        print('heard: %s' % heard['text'])
        return 0
    print('not understood%s: %s' % (' ("%s")' % heard['text'] if heard['text'] else '', heard['reason']))
    return 1


def listen_main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog='temoto listen', description='What the speech node hears; or send it a WAV file.')
    p.add_argument('--ns', '--namespace', dest='ns', default=engine_cli.DEFAULT_NS)
    p.add_argument('--wav', help='a WAV file (any rate and channels sox reads) to send as speech')
    args = p.parse_args(argv)
    if args.wav:
        try:
            pcm = read_wav(args.wav)
        except AudioError as e:
            print('error: %s' % e, file=sys.stderr)
            return 2
        return _report(send(args.ns, pcm))
    base = _start(args.ns)
    rospy.Subscriber(base + '/heard', String, lambda m: print(_line(json.loads(m.data)), flush=True))
    rospy.Subscriber(base + '/announcements', String, lambda m: print('said: %s' % m.data, flush=True))
    print('listening to %s (Ctrl-C to stop)' % base, flush=True)
    try:
        while not rospy.is_shutdown():
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    return 0


def _line(heard: dict) -> str:
    if heard['accepted']:
        return 'heard: %s (margin %.1f, %.2f s to decode)' % (heard['text'], heard['margin'], heard['decode_s'])
    return 'not understood: %s%s' % (heard['reason'], ' ("%s")' % heard['text'] if heard['text'] else '')


def say_main(argv: Optional[List[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if '--voice' not in argv:
        return engine_cli.say(argv)
    p = argparse.ArgumentParser(prog='temoto say --voice',
                                description='Speak an instruction (espeak-ng) to the speech node, which grounds it.')
    p.add_argument('--ns', '--namespace', dest='ns', default=engine_cli.DEFAULT_NS)
    p.add_argument('--voice', action='store_true', help='say it aloud to the speech node instead of typing it')
    p.add_argument('--speaker', default=DEFAULT_VOICE, help="espeak-ng's voice (default %(default)s)")
    p.add_argument('--speed', type=int, default=160, help='words per minute (default %(default)s)')
    p.add_argument('--keep-wav', default='', help='also write the spoken instruction to this WAV file')
    p.add_argument('text', nargs='+')
    args = p.parse_args(argv)
    text = ' '.join(args.text)
    try:
        pcm = synthesize_pcm(text, args.speaker, args.speed)
    except VoiceError as e:
        print('error: %s' % e, file=sys.stderr)
        return 2
    if args.keep_wav:
        write_wav(os.path.abspath(args.keep_wav), pcm)
    return _report(send(args.ns, pcm))
