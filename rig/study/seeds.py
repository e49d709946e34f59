"""The `--seeds` syntax: ranges and lists, e.g. `0-199`, `0,3,7`, `0-9,20,30-39`."""

from __future__ import annotations

import re

from rig.errors import InputError
from rig.runner.journal import MAX_SEED

MAX_STUDY_SEEDS = 100_000
_ITEM = re.compile(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?")
_ALLOWED = "comma-separated seeds and ranges, e.g. 0-199 or 0,3,7 or 0-9,20 (each 0-{max}, at most {n})"


def parse_seeds(text: str) -> tuple[int, ...]:
    """The seeds `text` names, in the order given, each once; `InputError` (exit 2) otherwise."""
    allowed = _ALLOWED.format(max=MAX_SEED, n=MAX_STUDY_SEEDS)
    seeds: dict[int, None] = {}  # ordered, without repeats
    for item in text.split(","):
        match = _ITEM.fullmatch(item)
        if match is None:
            raise InputError(
                f"--seeds {text!r}: {item.strip()!r} is not a seed or a range; allowed: {allowed}"
            )
        first = int(match.group(1))
        last = int(match.group(2)) if match.group(2) is not None else first
        if last < first:
            raise InputError(f"--seeds {text!r}: range {first}-{last} runs backwards; allowed: {allowed}")
        if last > MAX_SEED:
            raise InputError(f"--seeds {text!r}: {last} is beyond the largest seed; allowed: {allowed}")
        if last - first + 1 + len(seeds) > MAX_STUDY_SEEDS:
            raise InputError(f"--seeds {text!r}: more than {MAX_STUDY_SEEDS} seeds; allowed: {allowed}")
        for seed in range(first, last + 1):
            seeds[seed] = None
    return tuple(seeds)
