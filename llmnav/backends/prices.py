"""What a run's model calls cost: tokens × a dated price table (`prices.toml`, or the user's own).

The table gives US dollars per million prompt and completion tokens per model, in one TOML table per
backend (`[openai]`, `[gemini]`, ...), with the date the prices were read (`as_of`). `LLMNAV_PRICES` (or
`--prices FILE`) names another file. A price that is negative, not a number, or a table of the wrong shape
is bad input: one line naming the entry, exit 2.

Who pays: the runner records the backend's `billing()` in the run's configuration line: free (the local
engine, policies, a replay) or a provider and model, marked `local` when the server is on this machine or a
private network. A listed model is charged wherever it is served (a proxy on this machine may forward to a
paid API); an unlisted one costs 0 on a local server and `None` elsewhere ("unknown", never 0), with the
reason in `cost_note`. Calls served from the reply cache (`--cache`) reached no server: they cost nothing.
"""

from __future__ import annotations

import datetime
import ipaddress
import math
import os
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from llmnav.core.safefiles import UnsafeFileError, read_text
from llmnav.errors import BadInputError, one_line

PRICES_VARIABLE = "LLMNAV_PRICES"
BUNDLED = Path(__file__).with_name("prices.toml")
PER_TOKENS = 1_000_000  # prices are per million tokens
PRICE_FILE_LIMIT = 1 << 20  # [bytes] a price table is a few kB
# Backends that never send a request anyone bills (a backend absent from a run's billing record and not
# listed here is priced as unknown).
FREE_BACKENDS = frozenset({"local", "policy", "replay", "hf", "gemma"})


@dataclass(frozen=True)
class Price:
    """USD per million tokens."""

    prompt: float
    completion: float

    def cost(self, prompt_tokens: int, completion_tokens: int) -> float:
        """[USD] for these token counts."""
        return (prompt_tokens * self.prompt + completion_tokens * self.completion) / PER_TOKENS


@dataclass(frozen=True)
class PriceTable:
    """A loaded price file."""

    as_of: str  # ISO date the prices were read
    source: str  # the file it came from
    prices: Mapping[str, Mapping[str, Price]]  # backend -> model -> price

    def lookup(self, provider: str, model: str) -> tuple[str, Price] | None:
        """The listed name and price for `model`, or None.

        An exact entry, else the longest listed name `model` extends with "-" or ":" (a dated snapshot).
        """
        listed = self.prices.get(provider, {})
        if model in listed:
            return model, listed[model]
        stems = [name for name in listed if model.startswith((f"{name}-", f"{name}:"))]
        if not stems:
            return None
        name = max(stems, key=len)
        return name, listed[name]

    @property
    def label(self) -> str:
        """How notes name the table: `prices.toml of 2025-06-01`."""
        return f"{Path(self.source).name} of {self.as_of}"


def price_file(path: Path | str | None = None) -> Path:
    """The file to read: `path`, else `$LLMNAV_PRICES`, else the bundled table."""
    chosen = path or os.environ.get(PRICES_VARIABLE, "").strip() or None
    return Path(chosen) if chosen else BUNDLED


def load_prices(path: Path | str | None = None) -> PriceTable:
    """Read and check a price table (see the module docstring); BadInputError with one line when it is bad."""
    file = price_file(path)
    where = f"price file {file}"
    try:
        data = tomllib.loads(read_text(file, limit=PRICE_FILE_LIMIT, what=where))
    except FileNotFoundError:
        raise BadInputError(f"{where}: no such file") from None
    except UnsafeFileError:
        raise
    except OSError as err:
        raise BadInputError(f"{where}: cannot read ({err.strerror or err})") from None
    except tomllib.TOMLDecodeError as err:
        raise BadInputError(f"{where}: not valid TOML ({one_line(err, 100)})") from None
    return parse_prices(data, str(file))


def parse_prices(data: dict[str, Any], source: str) -> PriceTable:
    """The checked table of a parsed price file."""
    where = f"price file {source}"
    as_of = data.get("as_of")
    if not isinstance(as_of, datetime.date) or isinstance(as_of, datetime.datetime):
        raise BadInputError(f"{where}: 'as_of' must be the date the prices were read (as_of = 2025-06-01)")
    prices: dict[str, dict[str, Price]] = {}
    for provider, models in data.items():
        if provider == "as_of":
            continue
        if not isinstance(models, dict):
            raise BadInputError(f"{where}: '{provider}' must be a table of models ([{provider}])")
        prices[provider] = {}
        for model, entry in models.items():
            name = f"{provider}.{model}"
            if not isinstance(entry, dict) or set(entry) != {"prompt", "completion"}:
                raise BadInputError(f"{where}: {name} must be {{ prompt = USD, completion = USD }} per million tokens")
            prices[provider][model] = Price(_price(entry["prompt"], f"{where}: {name}.prompt"),
                                            _price(entry["completion"], f"{where}: {name}.completion"))  # fmt: skip
    return PriceTable(as_of.isoformat(), source, prices)


def _price(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise BadInputError(f"{where}: {value!r} is not a price (a number of USD per million tokens, 0 or more)")
    return float(value)


def local_server(url: str) -> bool:
    """Whether `url`'s host is this machine or a private network (nobody bills per token there)."""
    host = (urlsplit(url).hostname or "").strip("[]").lower()
    if host == "localhost" or host.endswith(".localhost"):
        return True
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        return False
    return address.is_loopback or address.is_private or address.is_link_local


def billing_of(config: Mapping[str, Any]) -> dict[str, Any]:
    """Who bills a run, from its configuration line: {"free": why} or {"provider", "model"}.

    Runs logged before the line recorded it: free for the backends in FREE_BACKENDS, else unknown.
    """
    recorded = config.get("billing")
    if isinstance(recorded, dict) and ("free" in recorded or {"provider", "model"} <= set(recorded)):
        return dict(recorded)
    spec = config.get("backend")
    if not spec:
        return {"free": "no model"}
    name = str(spec).partition(":")[0].lower()
    if name in FREE_BACKENDS:
        return {"free": f"{name} backend"}
    return {"unknown": f"{spec}: the run does not record who bills it"}


def run_cost(config: Mapping[str, Any], calls: Iterable[Mapping[str, Any]], table: PriceTable) -> dict[str, Any]:
    """A run's cache hits, tokens and `cost_usd` (None: unknown, with `cost_note` saying why).

    `calls` are the run's `llm_call` events. Tokens are counted over every reply; only calls that reached
    the server (not `"cache": "hit"`) are paid.
    """
    prompt = completion = paid_prompt = paid_completion = hits = 0
    uncounted = 0  # paid replies whose server reported no token counts
    for call in calls:
        reply = call.get("reply")
        hit = call.get("cache") == "hit"
        hits += hit
        if not isinstance(reply, dict):
            continue
        given = reply.get("prompt_tokens"), reply.get("completion_tokens")
        counted = all(isinstance(n, int) and not isinstance(n, bool) for n in given)
        p, c = (int(given[0]), int(given[1])) if counted else (0, 0)  # type: ignore[arg-type]
        prompt, completion = prompt + p, completion + c
        if not hit:
            paid_prompt, paid_completion = paid_prompt + p, paid_completion + c
            uncounted += not counted and "scores" not in reply  # scoring replies report no tokens
    tokens = {
        "prompt": prompt,
        "completion": completion,
        "paid_prompt": paid_prompt,
        "paid_completion": paid_completion,
    }
    cost, note = _priced(billing_of(config), paid_prompt, paid_completion, uncounted, table)
    return {"cache_hits": hits, "tokens": tokens, "cost_usd": cost, "cost_note": note}


def _priced(
    billing: dict[str, Any], prompt: int, completion: int, uncounted: int, table: PriceTable
) -> tuple[float | None, str]:
    if "free" in billing:
        return 0.0, f"free: {billing['free']}"
    if "unknown" in billing:
        return None, f"unknown: {billing['unknown']}"
    provider, model = str(billing["provider"]), str(billing["model"])
    found = table.lookup(provider, model)
    if found is None and billing.get("local"):
        return 0.0, f"free: {provider}:{model} on a server on this machine or a private network, not in {table.label}"
    if found is None:
        return None, f"unknown: no price for {provider}:{model} in {table.label}"
    if uncounted:
        return None, f"unknown: {uncounted} paid call(s) without token counts ({provider}:{model})"
    name, price = found
    cost = round(price.cost(prompt, completion), 6)
    return cost, f"{provider}:{name} at {price.prompt:g}/{price.completion:g} USD per 1M tokens ({table.label})"


def free(billing: Mapping[str, Any], table: PriceTable) -> bool:
    """Whether calls billed so cost nothing under `table` (a free backend, or an unlisted model on a local server)."""
    cost, note = _priced(dict(billing), 0, 0, 0, table)
    return cost is not None and note.startswith("free")


def estimate(billing: Mapping[str, Any], prompt: int, completion: int, table: PriceTable) -> tuple[float | None, str]:
    """[USD] of one episode assumed to use `prompt` and `completion` tokens; None (with why) when unknown."""
    return _priced(dict(billing), prompt, completion, 0, table)
