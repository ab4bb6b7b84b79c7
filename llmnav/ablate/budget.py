"""`ablate --max-cost USD`: a sweep that would cost more is refused; one that reaches the limit stops.

Before any episode runs, the episodes left are priced one by one: an episode whose planner asks no model,
or whose backend is free (`llmnav.backends.prices`), costs 0; a paid one costs `--episode-tokens
PROMPT,COMPLETION` at its model's price, or else the mean `cost_usd` of the episodes of the same backend
this ablation already finished. Above the limit, or with a paid episode no basis prices, the sweep is
refused (exit 2) before anything runs. While it runs, the `cost_usd` of each finished episode is added up;
once the sum reaches the limit no further episode starts (`CostLimitError`, exit 5). Episodes already
running finish (with several workers the spend may pass the limit by what they cost). Everything finished
is in the manifest and the folders: the same command with a higher limit resumes the sweep.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from llmnav.backends.base import get_backend, parse_spec
from llmnav.backends.prices import FREE_BACKENDS, estimate, free
from llmnav.errors import BadInputError, LlmnavError
from llmnav.planners.base import planner_class

if TYPE_CHECKING:
    from llmnav.ablate.grid import Episode
    from llmnav.ablate.manifest import Ablation
    from llmnav.backends.prices import PriceTable


class CostLimitError(LlmnavError):
    """A sweep reached its `--max-cost`; what ran is kept and the sweep resumes when run again."""

    exit_code = 5


def parse_episode_tokens(text: str) -> tuple[int, int]:
    """`--episode-tokens PROMPT,COMPLETION` (tokens per episode, whole numbers ≥ 0)."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise BadInputError(
            f"--episode-tokens {text!r}: expected PROMPT,COMPLETION tokens per episode, e.g. 20000,2000"
        )
    return int(parts[0]), int(parts[1])


def check_limit(max_usd: float) -> float:
    """`--max-cost`: a finite amount of dollars ≥ 0."""
    if not math.isfinite(max_usd) or max_usd < 0:
        raise BadInputError(f"--max-cost {max_usd}: expected an amount of US dollars, 0 or more")
    return max_usd


@dataclass
class Budget:
    """A sweep's spending limit and how to price episodes before they run."""

    max_usd: float  # [USD]
    prices: PriceTable
    episode_tokens: tuple[int, int] | None = None  # (prompt, completion) tokens assumed per episode
    spent_usd: float = 0.0  # [USD] by the episodes this sweep ran
    _billing: dict[str, dict[str, Any]] = field(default_factory=dict, repr=False)

    def billing(self, spec: str) -> dict[str, Any]:
        """Who bills a backend spec (built once per spec: HTTP backends build without any request)."""
        if spec not in self._billing:
            name = parse_spec(spec)[0]
            if name in FREE_BACKENDS:  # never load a local model only to learn that it is free
                self._billing[spec] = {"free": f"{name} backend"}
            else:
                backend = get_backend(spec)
                try:
                    self._billing[spec] = backend.billing()
                finally:
                    backend.close()
        return self._billing[spec]

    def episode_cost(self, ep: Episode, ablation: Ablation) -> tuple[float | None, str]:
        """[USD] one pending episode is expected to cost, or None with the reason it cannot be priced."""
        if not planner_class(ep.options.planner).needs_backend:
            return 0.0, "no model"
        billing = self.billing(ep.backend)
        if free(billing, self.prices):
            return 0.0, "free"
        if self.episode_tokens is not None:
            return estimate(billing, *self.episode_tokens, self.prices)
        done = [
            e.cost_usd
            for other, e in ((o, ablation.entries[o.key]) for o in ablation.episodes)
            if e.status == "done" and other.backend == ep.backend
        ]
        if done and all(c is not None for c in done):
            known = [c for c in done if c is not None]
            return sum(known) / len(known), f"mean of {len(known)} finished episode(s)"
        why = "finished episodes of unknown cost" if done else "no finished episode to go by"
        return None, f"{ep.backend}: {why}; give --episode-tokens PROMPT,COMPLETION"

    def check_start(self, pending: list[Episode], ablation: Ablation) -> float:
        """The estimate [USD] of the episodes left; BadInputError when it passes the limit or cannot be made."""
        total = 0.0
        for ep in pending:
            cost, why = self.episode_cost(ep, ablation)
            if cost is None:
                raise BadInputError(f"--max-cost {self.max_usd:g}: cannot estimate episode {ep.key} ({why})")
            total += cost
        if self.spent_usd + total > self.max_usd:
            spent = f" after {self.spent_usd:.4f} USD spent" if self.spent_usd else ""
            raise BadInputError(
                f"--max-cost {self.max_usd:g}: the {len(pending)} episode(s) left are estimated at {total:.4f} USD"
                f"{spent}; raise the limit or run fewer episodes (nothing was run)"
            )
        return total

    def add(self, summary: dict[str, Any] | None) -> str | None:
        """Count a finished episode; why the sweep must stop now (the limit reached, a cost unknown), or None."""
        if summary is None:
            return None
        cost = summary.get("cost_usd", 0.0)
        if cost is None:
            return f"an episode's cost is unknown ({summary.get('cost_note')})"
        self.spent_usd += float(cost)
        if self.spent_usd > self.max_usd or (self.max_usd > 0 and self.spent_usd >= self.max_usd):
            return f"{self.spent_usd:.4f} USD spent, the limit is reached"
        return None

    def stop(self, why: str, left: int) -> CostLimitError:
        """The error that ends a sweep with `left` episodes not started."""
        return CostLimitError(
            f"--max-cost {self.max_usd:g}: {why}; stopped with {left} episode(s) not run "
            "(the same command, with a higher limit, resumes the sweep)"
        )
