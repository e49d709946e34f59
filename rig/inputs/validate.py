"""Validation of YAML-sourced mappings with errors that name the file, the field path and what is allowed.

Rig configs and protocol files are validated through `Section` before anything moves, so every
message has the same shape: `<file>: <field.path>: <problem>; allowed: <what>`. A settings dataclass
whose fields are declared (`model.field_spec`) is read by `read_fields`: the declarations give each
field's type, bounds and default, and the keys a section may hold.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, cast

from model.field_spec import (
    Declared,
    FieldType,
    declared_fields,
    keys_within,
    section_type,
    top_keys,
)
from rig.errors import ConfigError

_MISSING: Any = object()

# The longest file or directory name common file systems accept (NAME_MAX on Linux, ext4, NTFS).
MAX_FILE_NAME_BYTES = 255


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

    def file_path(self, key: str, base_dir: Path) -> Path | None:
        """A file named relative to `base_dir`, or None when absent or empty.

        Checked for what the operating system can open at all (no NUL byte, each name at most
        `MAX_FILE_NAME_BYTES`), so that later existence checks never fail on the name itself.
        """
        name = self.string(key, default="")
        if not name:
            return None
        if "\0" in name:
            raise self.error(key, "contains a NUL character; allowed: a file path")
        longest = max(len(os.fsencode(part)) for part in Path(name).parts)
        if longest > MAX_FILE_NAME_BYTES:
            raise self.error(
                key, f"a path component of {longest} bytes; allowed: at most {MAX_FILE_NAME_BYTES} bytes each"
            )
        return base_dir / name

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


def reject_undeclared(sec: Section, cls: type, extra_keys: Iterable[str] = ()) -> None:
    """Fail on keys of `sec` that no declared field of `cls` (nor `extra_keys`) names."""
    sec.reject_unknown([*top_keys(cls), *extra_keys])


def read_fields(
    sec: Section, cls: type, *, given: Mapping[str, Any] | None = None, extra_keys: Iterable[str] = ()
) -> dict[str, Any]:
    """Every declared field of `cls` read from `sec` by attribute name, after refusing undeclared keys.

    Fields in `given` (attribute names) are the caller's: read with its own code, or not from the
    file. A custom field must be given. A field declared `within` a sub-mapping is read from it, and
    that sub-mapping's undeclared keys are refused too; it may be absent if all its fields have defaults.
    """
    reject_undeclared(sec, cls, extra_keys)
    values: dict[str, Any] = dict(given or {})
    subsections: dict[str, Section] = {}
    for declared in declared_fields(cls):
        if declared.name in values:
            continue
        where = sec
        within = declared.spec.within
        if within:
            if within not in subsections:
                inner = [d for d in declared_fields(cls) if d.spec.within == within]
                optional = all(not d.required for d in inner)
                subsections[within] = sec.section(within, default={} if optional else _MISSING)
                subsections[within].reject_unknown(keys_within(cls, within))
            where = subsections[within]
        values[declared.name] = read_value(where, cls, declared)
    return values


def read_field(sec: Section, cls: type, name: str, *, default: Any = _MISSING, required: bool = False) -> Any:
    """One declared field of `cls` (attribute `name`) from `sec`, with another `default`, or `required`."""
    for declared in declared_fields(cls):
        if declared.name == name:
            if required:
                default = dataclasses.MISSING
            elif default is _MISSING:
                default = declared.default
            return read_value(sec, cls, dataclasses.replace(declared, default=default))
    raise KeyError(f"{cls.__name__} declares no field {name!r}")


def read_value(sec: Section, cls: type, declared: Declared) -> Any:
    """One declared field's value from `sec` (its key there), checked as declared."""
    spec, key = declared.spec, declared.key
    default = _MISSING if declared.required else declared.default
    lo, hi = spec.bounds.lo, spec.bounds.hi
    if spec.bounds.hi_open:
        raise TypeError(f"{cls.__name__}.{declared.name}: a file's field cannot have an open upper bound")
    match spec.type:
        case FieldType.NUMBER:
            return sec.number(
                key, default=default, min_value=lo, max_value=hi, min_exclusive=spec.bounds.lo_open
            )
        case FieldType.INTEGER:
            return sec.integer(
                key,
                default=default,
                min_value=None if lo is None else int(lo),
                max_value=None if hi is None else int(hi),
            )
        case FieldType.TEXT:
            return sec.string(key, default=default)
        case FieldType.CHOICE:
            name = sec.string(key, default=default, choices=spec.choices)
            return name if spec.choice_type is None or name is None else spec.choice_type(name)
        case FieldType.FLAG:
            return sec.boolean(key, default=default)
        case FieldType.NUMBERS:
            values = sec.numbers(
                key,
                length=spec.length,
                min_length=spec.min_length,
                max_length=spec.max_length,
                min_value=lo,
                max_value=hi,
                default=default if default is _MISSING else list(default),
            )
            return tuple(values)
        case FieldType.SECTION:
            inner = section_type(cls, declared.name)
            nested = sec.section(key, default=_MISSING if declared.required else {})
            return inner(**read_fields(nested, inner))
        case FieldType.CUSTOM:
            raise TypeError(f"{cls.__name__}.{declared.name}: a custom field is read by its owner's code")


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
