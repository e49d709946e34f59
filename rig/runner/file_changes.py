"""What changed in a protocol or rig config since a run started: its values, as dotted keys.

A resume refuses a file whose content differs from the one the run started with (the journal holds
its hash and, since the lab-safety issue's finding 6, its text). Saying which values changed, e.g.
`limits.force_ceiling_n: 75 -> 70`, tells the operator what to restore.
"""

from __future__ import annotations

import json
from typing import Any

from rig.errors import InputError
from rig.inputs.files import parse_yaml

MAX_CHANGES_SHOWN = 5
_MAX_VALUE_CHARS = 40


def changed_values(old_text: str, new_text: str, source: str) -> list[str]:
    """Each value that differs between two texts of a YAML file, as "dotted.key: old -> new"."""
    old = parse_yaml(old_text, f"{source} (as the run started)")
    new = parse_yaml(new_text, source)
    changes: list[str] = []
    _compare(old, new, "", changes)
    return changes


def describe_changes(old_text: str | None, new_text: str, source: str) -> str:
    """The changes in a few words, for a refusal; "" when the old text is not known (an older journal)."""
    if old_text is None:
        return ""
    try:
        changes = changed_values(old_text, new_text, source)
    except InputError:
        return ""
    if not changes:
        return "no value changed, only comments or layout"
    shown = "; ".join(changes[:MAX_CHANGES_SHOWN])
    more = len(changes) - MAX_CHANGES_SHOWN
    return shown + (f"; and {more} more" if more > 0 else "")


def _compare(old: Any, new: Any, path: str, changes: list[str]) -> None:
    if isinstance(old, dict) and isinstance(new, dict):
        for key in [*old, *(k for k in new if k not in old)]:
            where = f"{path}.{key}" if path else str(key)
            if key not in new:
                changes.append(f"{where}: {_shown(old[key])} -> (removed)")
            elif key not in old:
                changes.append(f"{where}: (not set) -> {_shown(new[key])}")
            else:
                _compare(old[key], new[key], where, changes)
        return
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for i, (a, b) in enumerate(zip(old, new, strict=True)):
            _compare(a, b, f"{path}[{i}]", changes)
        return
    if old != new:
        changes.append(f"{path or 'the whole file'}: {_shown(old)} -> {_shown(new)}")


def _shown(value: Any) -> str:
    text = json.dumps(value, ensure_ascii=False, default=str)
    return text if len(text) <= _MAX_VALUE_CHARS else text[: _MAX_VALUE_CHARS - 3] + "..."
