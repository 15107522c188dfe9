"""Pronunciations from espeak-ng, in the recogniser's phone set (CMU ARPAbet).

The recogniser's dictionary (cmudict) lacks words a plugin may use ("rviz", "vaultbot"), and the synthetic
voices the benchmarks use say some words unlike cmudict does (espeak's en-us "hand" is nearer HH AA N D
than HH AE N D). espeak-ng's own letter-to-sound rules give a pronunciation for any word; this maps its
phoneme mnemonics (``espeak-ng -x``) to ARPAbet, and the grammar adds the result as a variant.
"""
from __future__ import annotations

import shutil
import subprocess
from typing import Dict, Iterable, List, Optional

ESPEAK = 'espeak-ng'
ESPEAK_TIMEOUT_S = 10.0
# espeak-ng's English phoneme mnemonics -> ARPAbet; matched longest first
ESPEAK_TO_ARPABET: Dict[str, str] = {
    'aI@': 'AY ER', 'aI3': 'AY ER', 'aU@': 'AW ER', 'i@3': 'IH R', 'A@r': 'AA R', 'O@r': 'AO R', 'e@r': 'EH R',
    'aI': 'AY', 'aU': 'AW', 'eI': 'EY', 'oU': 'OW', 'OI': 'OY', 'O:': 'AO', 'A:': 'AA', 'i:': 'IY', 'u:': 'UW',
    '3:': 'ER', 'A@': 'AA R', 'O@': 'AO R', 'e@': 'EH R', 'i@': 'IH R', 'U@': 'UH R', 'o@': 'OW R', '@L': 'AH L',
    'I2': 'IH', 'I#': 'IH', '@2': 'AH', '@5': 'AH', 'a#': 'AH', 'aa': 'AA', 'tS': 'CH', 'dZ': 'JH', 'n-': 'N',
    'l-': 'L', 'r-': 'R', '@': 'AH', '3': 'ER', 'a': 'AA', 'A': 'AA', 'E': 'EH', 'e': 'EH', 'I': 'IH', 'i': 'IY',
    '0': 'AA', 'O': 'AO', 'o': 'OW', 'U': 'UH', 'u': 'UW', 'V': 'AH', 'p': 'P', 'b': 'B', 't': 'T', 'd': 'D',
    'k': 'K', 'g': 'G', 'f': 'F', 'v': 'V', 'T': 'TH', 'D': 'DH', 's': 'S', 'z': 'Z', 'S': 'SH', 'Z': 'ZH',
    'h': 'HH', 'm': 'M', 'n': 'N', 'N': 'NG', 'l': 'L', 'r': 'R', 'j': 'Y', 'w': 'W', 'x': 'K', '?': '',
}
_TOKENS = sorted(ESPEAK_TO_ARPABET, key=len, reverse=True)


class PhonemeError(RuntimeError):
    """espeak-ng is missing or failed."""


def to_arpabet(mnemonics: str) -> str:
    """espeak-ng phoneme mnemonics of one word ("h'and") as ARPAbet ("HH AA N D"); unknown marks skipped."""
    out: List[str] = []
    i = 0
    while i < len(mnemonics):
        for token in _TOKENS:
            if mnemonics.startswith(token, i):
                if ESPEAK_TO_ARPABET[token]:
                    out.extend(ESPEAK_TO_ARPABET[token].split())
                i += len(token)
                break
        else:
            i += 1              # stress, length and pause marks, and mnemonics with no ARPAbet counterpart

    return ' '.join(out)


def espeak_pronunciations(words: Iterable[str], voice: str = 'en-us') -> Dict[str, Optional[str]]:
    """Each word's pronunciation by espeak-ng's rules (None for a word it gave nothing for), in one call:
    one word per line in, one line of mnemonics per word out."""
    words = list(words)
    if not words:
        return {}
    if shutil.which(ESPEAK) is None:
        raise PhonemeError('%s is not installed (Debian package espeak-ng)' % ESPEAK)
    try:
        proc = subprocess.run([ESPEAK, '-q', '-x', '-v', voice], input='\n'.join(w + '.' for w in words),
                              capture_output=True, text=True, timeout=ESPEAK_TIMEOUT_S, check=False)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise PhonemeError('%s failed: %s' % (ESPEAK, e)) from e
    lines = [line.strip() for line in proc.stdout.splitlines() if line.strip()]
    if proc.returncode != 0 or len(lines) != len(words):
        raise PhonemeError('%s gave %d pronunciations for %d words (rc %d): %s'
                           % (ESPEAK, len(lines), len(words), proc.returncode, proc.stderr.strip()[:200]))
    return {w: (to_arpabet(line) or None) for w, line in zip(words, lines)}
