#!/usr/bin/env python3
"""Speech in: recognition over every instruction phrase of the bundled actions, rejection of sentences that
are not instructions, the latency from the end of speech to the graph starting, and the idle CPU of the
speech node.

Goals (issue: the operator speaks; motion: issue 41): spoken by espeak-ng in 3 voices and speeds, with and without noise,
>= 95 % of the phrases grounded to the right graph and 0 wrong actions started (a rejection is a miss, not
a wrong action); latency <= 0.5 s median; idle CPU <= 10 % of a core.

- **Phrases:** each action's verbs with each of its objects ("<verb> the <object>"), "<stop verb>
  everything", and the compound instructions of the docs ("track the hand and show it on the screen",
  "stop tracking the hand", "show the environment with a hot standby").
- **Right graph:** the recognised text grounds (the engine's own grounder, with the engine's rule that a
  motion needs "robot please") to the same actions with the same parameters as the phrase itself. Accepted
  and grounded otherwise: a wrong action. A **motion not said**: a wrong action that moves the robot.
- **Noise:** white noise added at SNR_DB below the speech's power (numpy, seeded).
- **Latency:** across processes: a roscore, the engine and the speech node; an utterance sent on the audio
  topic with its end marker, to the engine's event of the graph running; utterances PACE_S apart.

With ``--confirm``, only the motion instructions, as the speech node takes them with ``~confirm_motion``:
each heard as a motion is said back, the operator answers "yes" or "no" (synthesized in the same voice and
noise), and the motion starts only on a "yes" heard as one.

Prints markdown tables; writes bench/results/speech.json (speech_confirm.json).
Usage: python bench/bench_speech.py [--quick] [--confirm]
"""
import argparse
import json
import os
import sys
import tempfile
import threading
import time

import numpy as np
import psutil
import rospy
from std_msgs.msg import String

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from common import loopback_master, pct  # noqa: E402
from temoto_action_engine.grounding import Grounder  # noqa: E402
from temoto_action_engine.indexer import ActionIndex  # noqa: E402
from temoto_testing.action_engine import write_plugin  # noqa: E402
from temoto_core.wait import wait_for  # noqa: E402
from temoto_speech import grammar as grammar_mod  # noqa: E402
from temoto_speech.confirmation import ANSWERS, YES  # noqa: E402
from temoto_speech.msg import AudioData  # noqa: E402
from temoto_speech.recognizer import Recognizer  # noqa: E402
from temoto_speech.voice import synthesize_pcm  # noqa: E402

VOICES = [('en-us', 175), ('en+m3', 140), ('en-gb+f2', 200)]     # espeak-ng voice, words per minute
SNR_DB = 20.0
COMPOUND = ['track the hand and show it on the screen', 'stop tracking the hand', 'stop showing the environment',
            'show the environment with a hot standby']
NOT_INSTRUCTIONS = ['what is the weather like today', 'open the door and go outside', 'show me the money',
                    'please make me a sandwich', 'the quick brown fox jumps over the lazy dog',
                    'how are you doing', 'turn left at the next corner', 'can you hear me',
                    'I would like a cup of coffee', 'where did I put my keys', 'it is raining again',
                    'play some music', 'call my mother', 'the meeting starts at nine', 'hello there',
                    'good morning everyone', 'what time is it', 'we need more power', 'send the report',
                    'close the window']
GOALS = {'right': 95.0, 'wrong': 0, 'latency': 0.5, 'idle_cpu': 10.0}
LATENCY_RUNS = 20
PACE_S = 3.0       # between utterances, as an operator's instructions come: the engine's spare worker is ready
IDLE_S = 20.0


def with_noise(pcm: bytes, snr_db: float, rng) -> bytes:
    x = np.frombuffer(pcm, dtype='<i2').astype(np.float64)
    noise = rng.normal(0.0, np.sqrt(np.mean(x ** 2) / 10 ** (snr_db / 10.0)), x.size)
    return np.clip(x + noise, -32768, 32767).astype('<i2').tobytes()


def meaning(grounder, text: str):
    """What a sentence would start, as the engine takes what speech heard: its actions and their parameters, or
    None if it grounds to nothing, or if it asks for a motion without the motion wake phrase."""
    words = text.split()
    woke = [w.lower() for w in words[:len(grammar_mod.MOTION_WAKE)]] == list(grammar_mod.MOTION_WAKE)
    result = grounder.ground(' '.join(words[len(grammar_mod.MOTION_WAKE):]) if woke else text)
    if not result.ok or (not woke and any(grounder.descriptors[c.action].motion for c in result.clauses)):
        return None
    return sorted(json.dumps([a['name'], {k: v.get('pvf_value') for k, v in a.get('input_parameters', {}).items()}],
                             sort_keys=True) for a in result.graph['actions'])


def motions(grounder, meant) -> set:
    """The actions of a meaning that move the robot."""
    return {json.loads(m)[0] for m in meant or []} & {n for n, d in grounder.descriptors.items() if d.motion}


def recognition(quick: bool) -> dict:
    index = ActionIndex([], include_bundled=True)
    index.reindex()
    actions = index.to_json()['actions']
    grounder = Grounder(index.descriptors())
    recognizer = Recognizer(actions)
    said = grammar_mod.phrases(actions) + COMPOUND
    if quick:
        said = said[::6]
    rng = np.random.default_rng(20261124)
    rows = []
    for voice, speed in VOICES:
        for text in said + NOT_INSTRUCTIONS:
            clean = synthesize_pcm(text, voice, speed)
            for noisy in (False, True):
                pcm = with_noise(clean, SNR_DB, rng) if noisy else clean
                rec = recognizer.recognize(pcm)
                expected = meaning(grounder, text) if text not in NOT_INSTRUCTIONS else None
                got = meaning(grounder, rec.text) if rec.accepted else None
                if expected is not None:
                    outcome = 'right' if got == expected else ('rejected' if got is None else 'wrong')
                else:
                    outcome = 'rejected' if got is None else 'wrong'
                # a motion started that was not said: another motion, or one from words that asked for none
                wrong_motion = bool(motions(grounder, got)) and got != expected
                rows.append({'text': text, 'voice': voice, 'speed': speed, 'noise': noisy, 'heard': rec.text,
                             'accepted': rec.accepted, 'margin': rec.margin, 'decode_s': rec.decode_s,
                             'instruction': expected is not None, 'outcome': outcome,
                             'motion': bool(motions(grounder, expected)), 'wrong_motion': wrong_motion})
        print('  %s done' % voice, file=sys.stderr, flush=True)
    return {'rows': rows, 'phrases': len(said)}


def latency() -> dict:
    """End of speech (the end marker sent) to the engine's event of the graph running, across processes."""
    master, launcher = loopback_master('bench_speech_')
    plugins = tempfile.mkdtemp(prefix='bench_speech_plugins_')
    write_plugin(plugins, 'wave', 'from temoto_action_engine.action_base import ActionBase\n\n'
                 'class Wave(ActionBase):\n    def execute(self):\n        pass\n',
                 grounding={'verbs': ['wave'], 'subjects': ['flag']})
    try:
        launcher.node('temoto_action_engine', 'temoto_action_engine', params={'action_paths': plugins})
        speech = launcher.node('temoto_speech', 'temoto_speech', params={'speak': False})
        rospy.init_node('bench_speech', disable_signals=True)
        running = []
        heard = []
        rospy.Subscriber('/temoto/action_engine/events', String, lambda m: (lambda e: running.append(time.monotonic())
                         if e.get('event') == 'state' and e.get('state') == 'RUNNING' else None)(json.loads(m.data)))
        rospy.Subscriber('/temoto/speech/heard', String, lambda m: heard.append(json.loads(m.data)))
        grammar_seen = threading.Event()
        rospy.Subscriber('/temoto/speech/grammar', String,
                         lambda m: 'wave' in json.loads(m.data)['actions'] and grammar_seen.set())
        pub = rospy.Publisher('/temoto/speech/audio', AudioData, queue_size=1000)
        wait_for(lambda: grammar_seen.is_set() and pub.get_num_connections() > 0, 60, 'the speech node ready')
        pcm = synthesize_pcm('wave the flag', 'en-us', 175)
        idle = psutil.Process(speech.pid)
        idle.cpu_percent(None)
        time.sleep(IDLE_S)          # the measuring window itself: the node idle, nothing sent
        idle_cpu = idle.cpu_percent(None)
        took, decode = [], []
        for i in range(LATENCY_RUNS):
            time.sleep(PACE_S)      # pacing, not a wait for something
            before = len(running)
            for k in range(0, len(pcm), 3200):
                pub.publish(AudioData(data=pcm[k:k + 3200]))
            end = time.monotonic()
            pub.publish(AudioData(data=b''))
            wait_for(lambda: len(running) > before, 30, 'the graph of utterance %d' % i)
            took.append(running[before] - end)
            wait_for(lambda: len(heard) > i, 10, 'the report of utterance %d' % i)
            decode.append(heard[i]['decode_s'])
        return {'latency_s': took, 'decode_s': decode, 'idle_cpu_percent': idle_cpu,
                'accepted': sum(h['accepted'] for h in heard)}
    finally:
        rospy.signal_shutdown('bench done')
        launcher.stop_all()
        master.stop()


def confirmation(quick: bool) -> dict:
    """``~confirm_motion``: every motion instruction heard as a motion is said back, and the operator answers
    "yes" if it is what was said, else "no", in the same voice and noise; the motion starts only on a "yes"
    heard as one. The sentences that are no instruction are also tried as answers: a "yes" made up of talk
    while a question waits would start a motion too."""
    index = ActionIndex([], include_bundled=True)
    index.reindex()
    actions = index.to_json()['actions']
    grounder = Grounder(index.descriptors())
    recognizer = Recognizer([])
    recognizer.update(actions, answers=ANSWERS, moving_answers=YES)
    said = [t for t in grammar_mod.phrases(actions) if motions(grounder, meaning(grounder, t))]
    if quick:
        said = said[::6]
    rng = np.random.default_rng(20261126)
    out = {'motions': 0, 'started_right': 0, 'started_wrong': 0, 'refused_wrong': 0, 'yes_lost': 0,
           'not_heard': 0, 'talk_as_yes': 0, 'talk': 0, 'wrong_heard': []}

    def answer_is_yes(word, voice, speed, noisy):
        pcm = synthesize_pcm(word, voice, speed)
        rec = recognizer.recognize(with_noise(pcm, SNR_DB, rng) if noisy else pcm)
        return rec.accepted and rec.text.lower() in YES
    for voice, speed in VOICES:
        for text in said:
            expected = meaning(grounder, text)
            clean = synthesize_pcm(text, voice, speed)
            for noisy in (False, True):
                out['motions'] += 1
                rec = recognizer.recognize(with_noise(clean, SNR_DB, rng) if noisy else clean)
                got = meaning(grounder, rec.text) if rec.accepted else None
                if not motions(grounder, got):
                    out['not_heard'] += 1             # rejected, or heard as no motion: nothing to confirm
                    continue
                right = got == expected
                yes = answer_is_yes('yes' if right else 'no', voice, speed, noisy)
                if right and yes:
                    out['started_right'] += 1
                elif right:
                    out['yes_lost'] += 1
                elif yes:
                    out['started_wrong'] += 1
                    out['wrong_heard'].append('"%s" heard as "%s", and "no" as "yes"' % (text, rec.text))
                else:
                    out['refused_wrong'] += 1
                    out['wrong_heard'].append('"%s" heard as "%s"; "no" said' % (text, rec.text))
        for text in NOT_INSTRUCTIONS:
            for noisy in (False, True):
                out['talk'] += 1
                pcm = synthesize_pcm(text, voice, speed)
                rec = recognizer.recognize(with_noise(pcm, SNR_DB, rng) if noisy else pcm)
                out['talk_as_yes'] += rec.accepted and rec.text.lower() in YES
        print('  %s done (confirmation)' % voice, file=sys.stderr, flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--quick', action='store_true', help='every sixth phrase only')
    ap.add_argument('--confirm', action='store_true', help='only the motion instructions with ~confirm_motion')
    opts = ap.parse_args(argv)
    if opts.confirm:
        c = confirmation(opts.quick)
        print('| figure (~confirm_motion) | value | goal |')
        print('| --- | --- | --- |')
        print('| motion instructions x voices x (clean, %g dB SNR) | %d | - |' % (SNR_DB, c['motions']))
        print('| started as said (heard right, its "yes" heard) | %.1f %% (%d) | >= 95 %% |'
              % (100.0 * c['started_right'] / c['motions'], c['started_right']))
        print('| a motion started that was not said (heard wrong, and "no" heard as "yes") | %d | 0 |'
              % c['started_wrong'])
        print('| heard wrong, refused by the operator\'s "no" | %d | reported |' % c['refused_wrong'])
        print('| heard right, its "yes" not heard (said again) | %d | reported |' % c['yes_lost'])
        print('| not heard as a motion (rejected: said again) | %d | reported |' % c['not_heard'])
        print('| sentences that are no instruction heard as "yes" | %d of %d | 0 |' % (c['talk_as_yes'], c['talk']))
        if c['wrong_heard']:
            print('\n' + '; '.join(c['wrong_heard'][:12]))
        os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
        with open(os.path.join(ROOT, 'bench', 'results', 'speech_confirm.json'), 'w') as f:
            json.dump(c, f, indent=1)
        return 0
    rec = recognition(opts.quick)
    rows = rec['rows']
    lat = latency()
    print('| figure | value | goal |')
    print('| --- | --- | --- |')
    said = [r for r in rows if r['instruction']]
    others = [r for r in rows if not r['instruction']]
    count = lambda rs, o: sum(r['outcome'] == o for r in rs)      # noqa: E731
    print('| instruction phrases x voices x (clean, %g dB SNR) | %d x %d x 2 = %d utterances | every phrase |'
          % (SNR_DB, rec['phrases'], len(VOICES), len(said)))
    print('| grounded to the right graph | %.1f %% (%d) | >= %.0f %% |' % (100.0 * count(said, 'right') / len(said),
                                                                         count(said, 'right'), GOALS['right']))
    print('| rejected (a miss) | %.1f %% (%d) | - |' % (100.0 * count(said, 'rejected') / len(said),
                                                     count(said, 'rejected')))
    print('| wrong action started | %d | %d |' % (count(said, 'wrong') + count(others, 'wrong'), GOALS['wrong']))
    print('| of them, from %d sentences that are no instruction (%d utterances) | %d | 0 |'
          % (len(NOT_INSTRUCTIONS), len(others), count(others, 'wrong')))
    moving = [r for r in said if r['motion']]
    print('| motion instructions ("robot please ...") grounded to the right motion | %.1f %% (%d of %d) | >= 95 %% |'
          % (100.0 * count(moving, 'right') / max(1, len(moving)), count(moving, 'right'), len(moving)))
    print('| motions started that were not said: from %d non-instructions / from %d other utterances | %d / %d | 0 |'
          % (len(others), len(said) - len(moving), sum(r['wrong_motion'] for r in others),
             sum(r['wrong_motion'] for r in said)))
    for noisy in (False, True):
        part = [r for r in said if r['noise'] == noisy]
        print('| right, %s | %.1f %% | - |' % ('%g dB SNR' % SNR_DB if noisy else 'clean',
                                              100.0 * count(part, 'right') / len(part)))
    for voice, speed in VOICES:
        part = [r for r in said if r['voice'] == voice]
        print('| right, %s at %d wpm | %.1f %% | - |' % (voice, speed, 100.0 * count(part, 'right') / len(part)))
    decode = [r['decode_s'] for r in rows]
    print('| decoding an utterance (both searches), median / p95 | %.2f / %.2f s | - |' % (pct(decode, 50),
                                                                                         pct(decode, 95)))
    print('| end of speech to the graph running, median / p95 (n = %d) | %.2f / %.2f s | <= %.1f s median |'
          % (len(lat['latency_s']), pct(lat['latency_s'], 50), pct(lat['latency_s'], 95), GOALS['latency']))
    print('| CPU of the idle speech node (%.0f s) | %.1f %% of a core | <= %.0f %% |'
          % (IDLE_S, lat['idle_cpu_percent'], GOALS['idle_cpu']))
    wrong = [r for r in rows if r['outcome'] == 'wrong']
    if wrong:
        print('\nwrong actions: ' + '; '.join('"%s" heard as "%s" (%s%s)' % (r['text'], r['heard'], r['voice'],
                                                                            ', noise' if r['noise'] else '')
                                              for r in wrong[:12]))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'speech.json'), 'w') as f:
        json.dump({'rows': rows, 'latency': lat}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
