"""Audio in the recogniser's format (16 kHz, mono, signed 16-bit little-endian PCM), and utterances cut
from a stream of it.

A WAV file in any other format is converted by sox, never through a shell. A stream (a microphone, an
audio topic) arrives in chunks; ``Utterances`` cuts it at silences with an energy detector whose threshold
follows the background level, so an utterance is handed on as soon as the speaker stops (``END_SILENCE_S``
after the last loud frame): that is where the latency to the graph starting is counted from.
"""
from __future__ import annotations

import shutil
import subprocess
import wave
from typing import List, Optional

import numpy as np

RATE = 16000
SAMPLE_BYTES = 2
FRAME_S = 0.02
FRAME_BYTES = int(RATE * FRAME_S) * SAMPLE_BYTES
SOX = 'sox'
SOX_TIMEOUT_S = 30.0
MAX_WAV_BYTES = 50 * 1024 * 1024


class AudioError(RuntimeError):
    """A file that is not audio, or a tool that is missing or failed."""


def read_wav(path: str) -> bytes:
    """The file's audio in the recogniser's format."""
    try:
        with wave.open(path, 'rb') as w:
            if (w.getframerate(), w.getnchannels(), w.getsampwidth()) == (RATE, 1, SAMPLE_BYTES):
                return w.readframes(w.getnframes())
    except FileNotFoundError:
        raise AudioError('%s: no such file' % path) from None
    except (wave.Error, EOFError):
        pass                      # not a plain PCM WAV (float, compressed): sox reads more formats
    return convert(path)


def convert(path: str) -> bytes:
    """Any audio file sox reads, as 16 kHz mono 16-bit PCM."""
    if shutil.which(SOX) is None:
        raise AudioError('%s is not installed (Debian package sox); cannot convert %s' % (SOX, path))
    try:
        proc = subprocess.run([SOX, path, '-t', 'raw', '-r', str(RATE), '-c', '1', '-b', '16', '-e', 'signed-integer',
                               '-L', '-'], capture_output=True, timeout=SOX_TIMEOUT_S, check=False)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise AudioError('%s failed on %s: %s' % (SOX, path, e)) from e
    if proc.returncode != 0:
        raise AudioError('%s cannot read %s: %s' % (SOX, path, proc.stderr.decode(errors='replace').strip()[:200]))
    if len(proc.stdout) > MAX_WAV_BYTES:
        raise AudioError('%s: longer than %d s of audio' % (path, MAX_WAV_BYTES // (RATE * SAMPLE_BYTES)))
    return proc.stdout


def write_wav(path: str, pcm: bytes) -> None:
    with wave.open(path, 'wb') as w:
        w.setnchannels(1)
        w.setsampwidth(SAMPLE_BYTES)
        w.setframerate(RATE)
        w.writeframes(pcm)


def seconds(pcm: bytes) -> float:
    return len(pcm) / float(RATE * SAMPLE_BYTES)


class Utterances:
    """Cuts a stream into utterances: feed chunks, get back each utterance once its speaker stopped.

    A frame is speech when its energy is ``SPEECH_RATIO`` above the background (the quietest recent level,
    never below ``FLOOR``). An utterance starts at ``START_FRAMES`` speech frames in a row (with
    ``LEAD_S`` of audio before them, so its first phoneme is whole) and ends after ``END_SILENCE_S`` of
    non-speech. One longer than ``MAX_S`` is cut there: nobody gives a 15 s instruction.
    """
    SPEECH_RATIO = 4.0
    FLOOR = 100.0               # RMS of 16-bit samples: below this, nothing is speech
    START_FRAMES = 3
    END_SILENCE_S = 0.4
    LEAD_S = 0.2
    MAX_S = 15.0
    BACKGROUND_WINDOW = 100     # frames whose quietest level is the background (2 s)

    def __init__(self) -> None:
        self._pending = b''
        self._recent: List[float] = []
        self._lead: List[bytes] = []
        self._speech: Optional[List[bytes]] = None
        self._loud_run = 0
        self._quiet_run = 0

    def feed(self, chunk: bytes) -> List[bytes]:
        """The utterances this chunk completed (usually none)."""
        self._pending += chunk
        out = []
        while len(self._pending) >= FRAME_BYTES:
            frame, self._pending = self._pending[:FRAME_BYTES], self._pending[FRAME_BYTES:]
            done = self._frame(frame)
            if done is not None:
                out.append(done)
        return out

    def flush(self) -> List[bytes]:
        """The end of the stream (a file): the utterance under way, if one started, ends here."""
        if self._speech is None:
            self._pending, self._lead, self._loud_run = b'', [], 0
            return []
        done = b''.join(self._speech) + self._pending
        self._speech, self._pending, self._lead, self._loud_run = None, b'', [], 0
        return [done]

    def _frame(self, frame: bytes) -> Optional[bytes]:
        level = float(np.sqrt(np.mean(np.frombuffer(frame, dtype='<i2').astype(np.float64) ** 2)))
        background = max(min(self._recent) if self._recent else self.FLOOR, self.FLOOR)
        self._recent = (self._recent + [level])[-self.BACKGROUND_WINDOW:]
        loud = level > background * self.SPEECH_RATIO
        if self._speech is None:
            self._lead = (self._lead + [frame])[-int(self.LEAD_S / FRAME_S) - self.START_FRAMES:]
            self._loud_run = self._loud_run + 1 if loud else 0
            if self._loud_run >= self.START_FRAMES:
                self._speech, self._quiet_run = list(self._lead), 0
            return None
        self._speech.append(frame)
        self._quiet_run = 0 if loud else self._quiet_run + 1
        if self._quiet_run * FRAME_S >= self.END_SILENCE_S or len(self._speech) * FRAME_S >= self.MAX_S:
            done, self._speech, self._loud_run, self._lead = b''.join(self._speech), None, 0, []
            return done
        return None
