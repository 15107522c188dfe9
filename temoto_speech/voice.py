"""Speech out, with espeak-ng: a sentence to a WAV file, or to the loudspeaker.

espeak-ng is run with an argument list, never through a shell, and the text goes in on its standard input
(so a sentence that begins with '-' is not taken for an option). Voices and speeds are espeak-ng's
(``espeak-ng --voices``); the recognition benchmark speaks every phrase in several of them.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from typing import Optional

from .audio import AudioError, read_wav

ESPEAK = 'espeak-ng'
DEFAULT_VOICE = 'en-us'
DEFAULT_SPEED = 160            # words per minute (espeak-ng's default is 175; announcements are slower)
SPEAK_TIMEOUT_S = 30.0
MAX_TEXT = 500                 # characters: an announcement is a sentence, not a report


class VoiceError(RuntimeError):
    """espeak-ng is missing, refused the voice, or failed."""


def _espeak(text: str, voice: str, speed: int, wav: Optional[str]) -> None:
    if shutil.which(ESPEAK) is None:
        raise VoiceError('%s is not installed (Debian package espeak-ng)' % ESPEAK)
    if not text.strip():
        raise VoiceError('nothing to say')
    argv = [ESPEAK, '-v', voice, '-s', str(int(speed))] + (['-w', wav] if wav else [])
    try:
        proc = subprocess.run(argv, input=text[:MAX_TEXT], capture_output=True, text=True, timeout=SPEAK_TIMEOUT_S,
                              check=False)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise VoiceError('%s failed: %s' % (ESPEAK, e)) from e
    if proc.returncode != 0 or (wav and not os.path.exists(wav)):
        raise VoiceError('%s -v %s failed (rc %d): %s' % (ESPEAK, voice, proc.returncode, proc.stderr.strip()[:200]))
    # with no audio device espeak-ng still exits 0, and says so only on stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith('error:')]
    if not wav and errors:
        raise VoiceError('no audio output: %s (%s)' % (errors[-1][len('error:'):].strip(),
                                                       proc.stderr.strip().splitlines()[0][:120]))


def synthesize(text: str, wav: str, voice: str = DEFAULT_VOICE, speed: int = DEFAULT_SPEED) -> str:
    """``text`` spoken into the WAV file ``wav`` (espeak-ng's own format: 22 kHz mono); returns ``wav``."""
    _espeak(text, voice, speed, wav)
    return wav


def synthesize_pcm(text: str, voice: str = DEFAULT_VOICE, speed: int = DEFAULT_SPEED) -> bytes:
    """``text`` spoken, as the recogniser's audio (16 kHz mono 16-bit)."""
    with tempfile.TemporaryDirectory(prefix='temoto_voice_') as tmp:
        path = synthesize(text, os.path.join(tmp, 'say.wav'), voice, speed)
        try:
            return read_wav(path)
        except AudioError as e:
            raise VoiceError(str(e)) from e


def speak(text: str, voice: str = DEFAULT_VOICE, speed: int = DEFAULT_SPEED) -> None:
    """``text`` on the loudspeaker (espeak-ng's audio output); returns once it is said."""
    _espeak(text, voice, speed, None)
