"""Regenerate the spoken-command WAV fixtures (needs Debian's espeak-ng and sox; run by hand).

Each command is synthesised by espeak-ng and stored as 11 025 Hz, 16-bit mono PCM (≈ 30–50 KB): small enough
to commit, and it exercises the resampling path of `llmnav.sensing.voice.read_wav`.
Usage: .venv/bin/python tests/voice/make_fixtures.py
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import wave
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from cases import COMMANDS, REJECTED  # noqa: E402

HERE = Path(__file__).parent / "fixtures"


def synthesise(text: str, out: Path, voice: str = "en") -> None:
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "raw.wav"
        subprocess.run(["espeak-ng", "-v", voice, "-w", str(raw), text], check=True)
        subprocess.run(["sox", str(raw), "-r", "16000", "-b", "16", "-c", "1", str(out)], check=True)


def noise(out: Path) -> None:
    rng = np.random.default_rng(7)
    samples = np.clip(128 + rng.normal(0, 25, 11025 * 2), 0, 255).astype(np.uint8)
    with wave.open(str(out), "wb") as wav:
        wav.setnchannels(1)
        wav.setsampwidth(1)
        wav.setframerate(11025)
        wav.writeframes(samples.tobytes())


def main() -> None:
    HERE.mkdir(exist_ok=True)
    for name, spoken, _scenario, _expected in COMMANDS:
        synthesise(spoken, HERE / f"{name}.wav")
    for name, spoken, voice in REJECTED:
        if spoken:
            synthesise(spoken, HERE / f"{name}.wav", voice)
        else:
            noise(HERE / f"{name}.wav")


if __name__ == "__main__":
    main()
