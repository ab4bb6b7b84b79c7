"""Offline voice commands: a WAV file becomes a task text, with a speech grammar built from the scenario.

The waypoint source took spoken commands through a cloud speech service; llmnav decodes them offline with
pocketsphinx (optional extra `llmnav[voice]`). Its open language model does poorly on short robot
commands, so by default the decoder is constrained by a JSGF grammar generated from the scenario: command
verbs x every object label and alias, with room numbers spoken the ways people say them ("one oh one",
"one zero one", "a hundred and one"), plus the scenario's own task sentences. The decoded words are mapped
back to the scenario's names ("room 101"), so the task runs exactly as if typed. `--asr-free` uses the
open language model instead, for tasks outside the grammar.
"""

from __future__ import annotations

import hashlib
import math
import re
import time
import wave
from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache
from pathlib import Path
from pathlib import Path as _Path
from typing import TYPE_CHECKING, Any

import numpy as np

from llmnav.errors import BadInputError, ModelUnavailableError

if TYPE_CHECKING:
    from llmnav.world.scenario import Scenario

SAMPLE_RATE = 16_000  # [Hz] what the acoustic model expects
LOG_BASE = 1.0001  # pocketsphinx's log base: scores come back as LOG_BASE ** raw
MIN_FIT = -2.0  # [raw score / frame] grammar path vs free phone loop; below it the speech is not a command
# A microphone-like noise floor (about -42 dBFS): digital silence (exact zeros, as synthesised speech has)
# upsets the decoder's feature normalisation.
DITHER_LSB = 256.0  # [LSB]
VERBS = ("go to", "drive to", "take me to", "navigate to", "head to", "move to", "find", "look for", "go")
ARTICLES = ("the", "a")

_ONES = "zero one two three four five six seven eight nine".split()
_TEENS = "ten eleven twelve thirteen fourteen fifteen sixteen seventeen eighteen nineteen".split()
_TENS = "_ _ twenty thirty forty fifty sixty seventy eighty ninety".split()


@dataclass(frozen=True)
class Transcript:
    """What was heard and what it means."""

    words: str  # the decoded words, e.g. "go to room one oh one"
    task_text: str  # normalised back to the scenario's names, e.g. "Go to room 101"
    confidence: float  # 0..1, 0.5 at the rejection threshold (see `_fit`)
    seconds: float  # [s] decoding time
    grammar: bool  # False with --asr-free


# --- audio ---------------------------------------------------------------------------------------


# A spoken command lasts seconds; an hour of audio took minutes and 1.5 GB before any answer.
MAX_AUDIO_S = 120.0


def read_wav(path: Path) -> np.ndarray:
    """Any PCM WAV the standard library reads, as 16 kHz mono int16 (resampled in process)."""
    try:
        with wave.open(str(path), "rb") as wav:
            rate, channels, width = wav.getframerate(), wav.getnchannels(), wav.getsampwidth()
            seconds = wav.getnframes() / max(rate, 1)
            if seconds > MAX_AUDIO_S:  # checked from the header: a long file is never decoded
                raise BadInputError(
                    f"{path}: {seconds:.0f} s of audio; a spoken command is at most {MAX_AUDIO_S:.0f} s"
                )
            data = wav.readframes(wav.getnframes())
    except FileNotFoundError:
        raise BadInputError(f"{path}: no such audio file") from None
    except (wave.Error, EOFError, OSError) as err:
        raise BadInputError(f"{path}: not a readable PCM WAV file ({err})") from None
    if width == 1:
        samples = (np.frombuffer(data, dtype=np.uint8).astype(np.float64) - 128.0) * 256.0
    elif width == 2:
        samples = np.frombuffer(data, dtype="<i2").astype(np.float64)
    elif width == 4:
        samples = np.frombuffer(data, dtype="<i4").astype(np.float64) / 65536.0
    else:
        raise BadInputError(f"{path}: unsupported sample width of {width} bytes")
    if channels > 1:
        samples = samples[: len(samples) // channels * channels].reshape(-1, channels).mean(axis=1)
    if samples.size < rate // 10:
        raise BadInputError(f"{path}: audio shorter than 0.1 s")
    if rate != SAMPLE_RATE:
        # deferred: scipy.signal (about 0.7 s) loads only for audio not sampled at 16 kHz
        from scipy.signal import resample_poly

        ratio = Fraction(SAMPLE_RATE, rate).limit_denominator(1000)
        samples = resample_poly(samples, ratio.numerator, ratio.denominator)
    samples = samples + np.random.default_rng(0).uniform(-DITHER_LSB, DITHER_LSB, samples.size)
    return np.clip(np.round(samples), -32768, 32767).astype(np.int16)


# --- numbers as people say them -------------------------------------------------------------------

_NUMBER_WORDS = {w: i for i, w in enumerate(_ONES)} | {"oh": 0, "o": 0, "a": 1}
_NUMBER_WORDS |= {w: 10 + i for i, w in enumerate(_TEENS)} | {w: 10 * i for i, w in enumerate(_TENS) if w != "_"}


def _below_hundred(n: int) -> str:
    if n < 10:
        return _ONES[n]
    if n < 20:
        return _TEENS[n - 10]
    tens, ones = divmod(n, 10)
    return _TENS[tens] + ("" if ones == 0 else " " + _ONES[ones])


def spoken_numbers(number: str) -> list[str]:
    """Ways to say a room number: "101" -> one zero one, one oh one, one hundred and one, a hundred one, ..."""
    n = int(number)
    forms = [
        " ".join(_ONES[int(d)] for d in number),
        " ".join("oh" if d == "0" else _ONES[int(d)] for d in number),
    ]
    if 100 <= n <= 999:
        hundreds, rest = divmod(n, 100)
        for head in [_ONES[hundreds] + " hundred"] + (["a hundred"] if hundreds == 1 else []):
            forms += [head] if rest == 0 else [f"{head} and {_below_hundred(rest)}", f"{head} {_below_hundred(rest)}"]
        if rest >= 10:
            forms.append(f"{_ONES[hundreds]} {_below_hundred(rest)}")  # "one fourteen"
    elif n < 100:
        forms.append(_below_hundred(n))
    return list(dict.fromkeys(forms))


def parse_number(words: str) -> int | None:
    """Inverse of `spoken_numbers` for the forms the grammar accepts; None when it is not a number."""
    tokens = [t for t in words.split() if t != "and"]
    if not tokens or any(t not in _NUMBER_WORDS and t != "hundred" for t in tokens):
        return None
    if "hundred" in tokens:
        i = tokens.index("hundred")
        if i != 1 or tokens[0] not in _NUMBER_WORDS or _NUMBER_WORDS[tokens[0]] > 9:
            return None
        rest = sum(_NUMBER_WORDS[t] for t in tokens[2:])
        return _NUMBER_WORDS[tokens[0]] * 100 + rest if rest < 100 else None
    values = [_NUMBER_WORDS[t] for t in tokens]
    if all(v <= 9 for v in values):  # digit by digit
        return int("".join(str(v) for v in values))
    if len(values) >= 2 and values[0] <= 9:  # "one fourteen", "two twenty one"
        rest = sum(values[1:])
        return values[0] * 100 + rest if rest < 100 else None
    return None


# --- the grammar ---------------------------------------------------------------------------------


def _words(text: str) -> str:
    return " ".join(re.sub(r"[^a-z0-9' ]+", " ", text.lower().replace("-", " ")).split())


@dataclass(frozen=True)
class Grammar:
    """A JSGF grammar and the maps from spoken phrases back to the scenario's names."""

    jsgf: str
    targets: dict[str, str]  # spoken object phrase -> canonical name (the object's label)
    numbered: dict[int, str]  # room number -> canonical name ("room 101")
    sentences: dict[str, str]  # spoken whole task sentence -> the scenario's task text


# Room numbers are a small sub-grammar ("one oh one", "a hundred and one", "one fourteen") whose words
# are mapped back to an integer after decoding; listing every number's forms flat made decoding ~50x slower.
_NUMBER_RULES = f"""<digit> = {" | ".join(_ONES)} | oh;
<lead> = {" | ".join(_ONES[1:])};
<teen> = {" | ".join(_TEENS)};
<tens> = {" | ".join(_TENS[2:])};
<ones> = {" | ".join(_ONES[1:])};
<below100> = <digit> | <teen> | <tens> [<ones>];
<number> = <lead> <digit> <digit> | (<lead> | a) hundred [[and] <below100>] | <lead> (<teen> | <tens> [<ones>]);
"""


def build_grammar(scenarios: list[Scenario], in_dictionary: Any) -> Grammar:
    """Grammar over the scenarios' objects and task sentences; `in_dictionary(word)` filters unsayable words."""
    targets: dict[str, str] = {}
    numbered: dict[int, str] = {}
    for scenario in scenarios:
        for obj in scenario.objects:
            for name in (obj.label, *obj.aliases):
                phrase = _words(name)
                room = re.fullmatch(r"room (\d+)", phrase)
                if room:  # room plates: any spoken form of the number, through the number sub-grammar
                    numbered.setdefault(int(room.group(1)), obj.label)
                    continue
                # Other small numbers ("staircase 2") are said as words.
                phrase = re.sub(r"\b\d{1,2}\b", lambda m: _below_hundred(int(m.group())), phrase)
                if phrase and not re.search(r"\d", phrase) and all(in_dictionary(w) for w in phrase.split()):
                    targets.setdefault(phrase, obj.label)
    sentences: dict[str, str] = {}
    for scenario in scenarios:
        for task in scenario.tasks:
            spoken = _words(task.text)
            if spoken and not re.search(r"\d", spoken) and all(in_dictionary(w) for w in spoken.split()):
                sentences.setdefault(spoken, task.text)
    if not targets and not numbered and not sentences:
        raise BadInputError("the scenario names nothing that can be spoken")
    alt = " | ".join
    target_rule = alt([*sorted(targets), *(["room <number>"] if numbered else [])])
    lines = ["#JSGF V1.0;", "grammar llmnav;", "public <command> = <order> | <sentence>;"]
    lines.append(f"<order> = <verb> [{alt(ARTICLES)}] <target>;")
    lines.append(f"<verb> = {alt(VERBS)};")
    lines.append(f"<target> = {target_rule or '<VOID>'};")
    lines.append(f"<sentence> = {alt(sorted(sentences)) if sentences else '<VOID>'};")
    return Grammar("\n".join(lines) + "\n" + _NUMBER_RULES, targets, numbered, sentences)


def interpret(words: str, grammar: Grammar) -> str | None:
    """Decoded words -> task text in the scenario's names, or None when no known target was said."""
    words = " ".join(words.split())
    if words in grammar.sentences:
        return grammar.sentences[words]
    for verb in sorted(VERBS, key=len, reverse=True):
        if not words.startswith(verb + " "):
            continue
        rest = words[len(verb) + 1 :]
        for article in ARTICLES:
            if rest.startswith(article + " ") and rest[len(article) + 1 :] in grammar.targets:
                rest = rest[len(article) + 1 :]
                break
        if rest in grammar.targets:
            name = grammar.targets[rest]
            article = "" if re.search(r"\d", name) else "the "
            return f"{verb.capitalize()} {article}{name}"
        if rest.startswith("room "):
            number = parse_number(rest[5:])
            if number is not None and number in grammar.numbered:
                return f"{verb.capitalize()} {grammar.numbered[number]}"
        return None
    return None


# --- decoding -------------------------------------------------------------------------------------


def _pocketsphinx() -> Any:
    try:
        # deferred: pocketsphinx is the optional 'voice' extra
        import pocketsphinx
    except ImportError:
        raise ModelUnavailableError(
            "voice commands need the optional extra: pip install 'llmnav[voice]' (pocketsphinx)"
        ) from None
    return pocketsphinx


@lru_cache(maxsize=3)
def _decoder(mode: str) -> Any:
    """One decoder per mode ("grammar", "free", "phones"), kept: each load takes about a second."""
    ps = _pocketsphinx()
    if mode == "phones":
        model_dir = _Path(ps.__file__).parent / "model" / "en-us"
        return ps.Decoder(logfn="/dev/null", allphone=str(model_dir / "en-us-phone.lm.bin"))
    return ps.Decoder(logfn="/dev/null")


def _run(decoder: Any, audio: np.ndarray) -> tuple[str, float, int]:
    """Decode one utterance: (words, raw path score, frames)."""
    decoder.start_utt()
    decoder.process_raw(audio.tobytes(), full_utt=True)
    decoder.end_utt()
    hyp = decoder.hyp()
    if hyp is None or not hyp.hypstr.strip() or hyp.score <= 0:
        return "", -math.inf, max(decoder.n_frames(), 1)
    return hyp.hypstr.strip(), math.log(hyp.score) / math.log(LOG_BASE), max(decoder.n_frames(), 1)


def _fit(audio: np.ndarray, grammar_score: float, frames: int) -> float:
    """How well the grammar's best path explains the audio, per frame, against a free phone loop.

    In-grammar commands score well above 0; speech the grammar cannot express (another language, other
    words) is forced onto a path that fits worse than unconstrained phones, and scores below.
    """
    _, phone_score, _ = _run(_decoder("phones"), audio)
    return (grammar_score - phone_score) / frames


def _decode_grammar(audio: np.ndarray, jsgf: str) -> tuple[str, float, int]:
    decoder = _decoder("grammar")
    name = "g" + hashlib.sha256(jsgf.encode()).hexdigest()[:12]
    if decoder.current_search() != name:
        try:
            decoder.activate_search(name)
        except (KeyError, RuntimeError):  # not added yet
            decoder.add_jsgf_string(name, jsgf)
            decoder.activate_search(name)
    return _run(decoder, audio)


def transcribe(path: Path, scenarios: list[Scenario], *, free: bool = False) -> Transcript:
    """Decode a WAV file; raise BadInputError (exit 2) when nothing known was said."""
    audio = read_wav(path)
    started = time.perf_counter()
    if free:
        words, _, _ = _run(_decoder("free"), audio)
        if not words:
            raise BadInputError(f"{path}: no speech recognised")
        return Transcript(words, words[:1].upper() + words[1:], float("nan"), time.perf_counter() - started, False)
    lookup = _decoder("grammar").lookup_word
    grammar = build_grammar(scenarios, lambda w: lookup(w) is not None)
    words, score, frames = _decode_grammar(audio, grammar.jsgf)
    if not words:
        raise BadInputError(f"{path}: no command recognised (silence, noise or another language?)")
    fit = _fit(audio, score, frames)
    confidence = 1.0 / (1.0 + math.exp(-(fit - MIN_FIT) / 4.0))
    seconds = time.perf_counter() - started
    task_text = interpret(words, grammar)
    if task_text is None:
        raise BadInputError(f"{path}: heard '{words}', which names no known target")
    if fit < MIN_FIT:
        raise BadInputError(f"{path}: heard '{words}' with low confidence ({confidence:.2f}); not a known command")
    return Transcript(words, task_text, confidence, seconds, True)


def scenarios_for(scenario: str | None) -> list[Scenario]:
    """The scenario named, or every bundled one (the task then picks the scenario, as typed text does)."""
    # deferred: pydantic and yaml (about 0.15 s, via llmnav.world.scenario), only when a task is transcribed
    from llmnav.world.scenario import list_scenarios, load_scenario

    return [load_scenario(scenario)] if scenario else [load_scenario(n) for n in list_scenarios()]
