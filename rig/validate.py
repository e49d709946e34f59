"""Validation of YAML-sourced mappings with errors that name the file, the field path and what is allowed.

Rig configs and protocol files are validated through `Section` before anything moves, so every
message has the same shape: `<file>: <field.path>: <problem>; allowed: <what>`.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, cast

from rig.errors import ConfigError

_MISSING: Any = object()


class Section:
    """A mapping read from a file, addressed by a dotted field path for error messages."""

    def __init__(self, data: Any, source: str, path: str = "") -> None:
        self.source = source
        self.path = path
        if not isinstance(data, Mapping):
            where = path or "top level"
            raise ConfigError(f"{source}: {where}: expected a mapping of keys to values, got {_kind(data)}")
        self.data: Mapping[str, Any] = data

    def field(self, key: str | int) -> str:
        """The dotted path of `key` inside this section."""
        if isinstance(key, int):
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str | int, problem: str) -> ConfigError:
        """An error naming the file and the field."""
        return ConfigError(f"{self.source}: {self.field(key)}: {problem}")

    def reject_unknown(self, allowed: Iterable[str]) -> None:
        """Fail on keys that are not in `allowed`, suggesting the closest allowed name."""
        allowed = list(allowed)
        for key in self.data:
            if key not in allowed:
                close = difflib.get_close_matches(str(key), allowed, n=1)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                raise self.error(str(key), f"unknown field{hint}; allowed: {', '.join(allowed)}")

    def has(self, key: str) -> bool:
        """Whether `key` is present (and not null)."""
        return self.data.get(key) is not None

    def raw(self, key: str, default: Any = _MISSING) -> Any:
        """The value as parsed, or `default`; missing without a default is an error."""
        value = self.data.get(key)
        if value is None:
            if default is _MISSING:
                raise self.error(key, "required field is missing")
            return default
        return value

    def number(
        self,
        key: str,
        *,
        default: Any = _MISSING,
        min_value: float | None = None,
        max_value: float | None = None,
        min_exclusive: bool = False,
    ) -> float:
        """A finite real number within [min, max] (or (min, max] with `min_exclusive`)."""
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return cast(float, value)  # the caller's default, as given
        return check_number(self, key, value, min_value, max_value, min_exclusive)

    def integer(
        self, key: str, *, default: Any = _MISSING, min_value: int | None = None, max_value: int | None = None
    ) -> int:
        """An integer within [min, max]."""
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return cast(int, value)  # the caller's default, as given
        if isinstance(value, bool) or not isinstance(value, int):
            allowed = _range(min_value, max_value)
            raise self.error(key, f"expected an integer, got {_short(value)}; allowed: {allowed}")
        if (min_value is not None and value < min_value) or (max_value is not None and value > max_value):
            raise self.error(key, f"{_short(value)} is out of range; allowed: {_range(min_value, max_value)}")
        return value

    def string(self, key: str, *, default: Any = _MISSING, choices: Sequence[str] | None = None) -> str:
        """A string, optionally one of `choices`."""
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return cast(str, value)  # the caller's default, as given
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {_short(value)}")
        if choices is not None and value not in choices:
            close = difflib.get_close_matches(value, list(choices), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise self.error(key, f"{_short(value)} is not allowed{hint}; allowed: {', '.join(choices)}")
        return value

    def boolean(self, key: str, *, default: Any = _MISSING) -> bool:
        """A boolean: true or false."""
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"expected true or false, got {_short(value)}")
        return value

    def section(self, key: str, *, default: Any = _MISSING) -> Section:
        """A nested mapping (an empty one when absent and `default` is `{}`)."""
        return Section(self.raw(key, default), self.source, self.field(key))

    def sequence(
        self, key: str, *, default: Any = _MISSING, min_length: int = 0, max_length: int | None = None
    ) -> list[Any]:
        """A list with at least `min_length` and at most `max_length` items."""
        value = self.raw(key, default)
        if not isinstance(value, list):
            raise self.error(key, f"expected a list, got {_kind(value)}")
        if len(value) < min_length:
            raise self.error(key, f"expected at least {min_length} item(s), got {len(value)}")
        if max_length is not None and len(value) > max_length:
            raise self.error(key, f"{len(value)} items; allowed: at most {max_length}")
        return value

    def numbers(
        self,
        key: str,
        *,
        length: int | None = None,
        min_length: int = 1,
        max_length: int | None = None,
        min_value: float | None = None,
        max_value: float | None = None,
        min_exclusive: bool = False,
        default: Any = _MISSING,
    ) -> list[float]:
        """A list of finite numbers, each within range, of a fixed `length` if given."""
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return cast(list[float], value)  # the caller's default, as given
        if not isinstance(value, list):
            raise self.error(key, f"expected a list of numbers, got {_kind(value)}")
        if length is not None and len(value) != length:
            raise self.error(key, f"expected {length} numbers, got {len(value)}")
        if len(value) < min_length:
            raise self.error(key, f"expected at least {min_length} number(s), got {len(value)}")
        if max_length is not None and len(value) > max_length:
            raise self.error(key, f"{len(value)} numbers; allowed: at most {max_length}")
        item = Section({}, self.source, self.field(key))
        return [check_number(item, i, v, min_value, max_value, min_exclusive) for i, v in enumerate(value)]


def check_number(
    section: Section,
    key: str | int,
    value: Any,
    min_value: float | None,
    max_value: float | None,
    min_exclusive: bool = False,
) -> float:
    """Check one value is a finite number in range; errors name `section.field(key)`."""
    allowed = _range(min_value, max_value, min_exclusive)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise section.error(key, f"expected a number, got {_short(value)}; allowed: {allowed}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond the float range
        number = math.inf if value > 0 else -math.inf
    too_low = min_value is not None and (number <= min_value if min_exclusive else number < min_value)
    too_high = max_value is not None and number > max_value
    if not math.isfinite(number) or too_low or too_high:
        raise section.error(key, f"{_short(value)} is out of range; allowed: {allowed}")
    return number


def _range(lo: float | None, hi: float | None, lo_exclusive: bool = False) -> str:
    if lo is None and hi is None:
        return "any finite number"
    if hi is None:
        return f"{'>' if lo_exclusive else '>='} {lo}"
    if lo is None:
        return f"<= {hi}"
    return f"{lo} {'<' if lo_exclusive else '<='} x <= {hi}"


def _short(value: Any) -> str:
    """`repr(value)`, shortened for a one-line message (a file may hold long values)."""
    if isinstance(value, int) and value.bit_length() > 100:
        return f"an integer of about {int(value.bit_length() * math.log10(2)) + 1} digits"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return f"{type(value).__name__} {_short(value)}"
