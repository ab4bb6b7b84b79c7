"""The YAML text of a generated scenario: comment lines, then its sections, every shape on one line.

Written by hand around PyYAML's flow style so the file reads like the bundled ones and the same mapping
always gives the same bytes (keys in insertion order, no anchors, no line folding).
"""

from __future__ import annotations

from typing import Any

import yaml

_FLOW_LISTS = ("walls", "objects")


class _NoAliases(yaml.SafeDumper):
    """A dumper that writes repeated values out in full (no &anchors, *aliases)."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def _flow(value: Any) -> str:
    """One value in flow style on one line."""
    text = yaml.dump(value, Dumper=_NoAliases, default_flow_style=True, width=1 << 20, sort_keys=False)
    return text.strip().removesuffix("...").strip()


def to_yaml(data: dict[str, Any], header: list[str]) -> str:
    """`data` (a scenario mapping) as YAML text under `header` comment lines."""
    lines = [f"# {line}".rstrip() for line in header]
    for key, value in data.items():
        if key in _FLOW_LISTS:
            lines.append(f"{key}:")
            lines.extend(f"  - {_flow(item)}" for item in value)
        elif key == "tasks":
            lines.append("tasks:")
            for task in value:
                first = True
                for field, item in task.items():
                    lead = "  - " if first else "    "
                    first = False
                    if field == "start_poses" or field == "paraphrases":
                        lines.append(f"{lead}{field}:")
                        lines.extend(f"      - {_flow(entry)}" for entry in item)
                    else:
                        lines.append(f"{lead}{field}: {_flow(item)}")
        else:
            lines.append(f"{key}: {_flow(value)}")
    return "\n".join(lines) + "\n"
