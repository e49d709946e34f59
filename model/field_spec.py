"""Declared settings fields: each field's type, bounds, unit and doc, stated once on the dataclass field.

A settings dataclass declares a field as `name: float = field(default=1.0, metadata=number(0, 10,
unit="s", doc="..."))`; the dataclass default is the field's default. These are declarations only
(pure, no I/O): `rig.inputs.validate.read_fields` parses a file's section from them and refuses keys that no
field declares, `tools.config_docs` writes the docs tables from them, and `model.slip_detector`
checks `DetectorParams` against them. A declaration is a `FieldSpec` under `SPEC_KEY` in the field's
metadata; fields without one (a config's source path, say) are not read from the file.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

SPEC_KEY = "field_spec"


class FieldType(StrEnum):
    """What a declared field holds, and so how it is read."""

    NUMBER = "number"  # a finite real within the bounds
    INTEGER = "integer"  # an integer within the bounds
    TEXT = "text"  # a string
    CHOICE = "choice"  # one of `choices`
    FLAG = "flag"  # true or false
    NUMBERS = "numbers"  # a list of numbers, each within the bounds
    SECTION = "section"  # a nested mapping read as the field's own dataclass
    CUSTOM = "custom"  # read by the owner's code (documented here all the same)


@dataclass(frozen=True)
class Bounds:
    """An interval of allowed values; `None` leaves that side open to infinity."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False  # lo itself is not allowed
    hi_open: bool = False  # hi itself is not allowed

    def accepts(self, value: float) -> bool:
        """Whether `value` is finite and inside the interval."""
        if not math.isfinite(value):
            return False
        if self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo):
            return False
        return self.hi is None or (value < self.hi if self.hi_open else value <= self.hi)

    def interval(self, *, integer: bool = False, short: bool = False) -> str:
        """The interval as text: `[0.001, 0.2]`, `(0, 1)`, `0..10` for integers, `>= 0`.

        Numbers as `{:g}` writes them (`1e+06`), or with `short` as the docs do (`1e6`).
        """
        lo, hi = _number_text(self.lo, short, integer), _number_text(self.hi, short, integer)
        if self.lo is None and self.hi is None:
            return "any finite number"
        if integer and not (self.lo_open or self.hi_open) and self.lo is not None and self.hi is not None:
            return f"{lo}..{hi}"
        if self.hi is None:
            return f"{'>' if self.lo_open else '>='} {lo}"
        if self.lo is None:
            return f"{'<' if self.hi_open else '<='} {hi}"
        return f"{'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open else ']'}"


def _number_text(value: float | None, short: bool, integer: bool) -> str:
    if integer and value is not None:
        return str(int(value))
    text = f"{value:g}"
    return text.replace("e+0", "e").replace("e+", "e").replace("e-0", "e-") if short else text


@dataclass(frozen=True)
class FieldSpec:
    """One declared field (see the module docstring); built by `number`, `integer`, ... below."""

    type: FieldType
    bounds: Bounds = Bounds()
    unit: str = ""  # of the value, e.g. "N/m" (the name carries it too: `_n_per_m`)
    doc: str = ""  # what it means, for the docs table
    key: str = ""  # its key in the file when that is not the attribute's name
    within: str = ""  # the key of the sub-mapping that holds it (e.g. `load` for `load.point_m`)
    choices: tuple[str, ...] = ()
    choice_type: Callable[[str], Any] | None = None  # an enum class to read a choice as (None: the string)
    optional: bool = False  # None is allowed: the feature is off, or the value absent
    length: int | None = None  # a list's exact length
    min_length: int = 1
    max_length: int | None = None
    default_doc: str = ""  # the docs' default when it is not the plain default value
    allowed_doc: str = ""  # the docs' allowed text when the generated one does not say it
    expand_doc: bool = True  # a section: list its fields in the docs (else one row)


def _metadata(spec: FieldSpec) -> Mapping[str, Any]:
    return {SPEC_KEY: spec}


def number(
    lo: float | None,
    hi: float | None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    unit: str = "",
    doc: str = "",
    optional: bool = False,
    key: str = "",
    within: str = "",
    default_doc: str = "",
    allowed_doc: str = "",
) -> Mapping[str, Any]:
    """A real number in [lo, hi] (or with an open side); `optional`: None turns it off."""
    bounds = Bounds(lo, hi, lo_open, hi_open)
    spec = FieldSpec(
        FieldType.NUMBER,
        bounds,
        unit,
        doc,
        key,
        within,
        optional=optional,
        default_doc=default_doc,
        allowed_doc=allowed_doc,
    )
    return _metadata(spec)


def integer(
    lo: int | None, hi: int | None, *, unit: str = "", doc: str = "", key: str = "", default_doc: str = ""
) -> Mapping[str, Any]:
    """An integer in [lo, hi]."""
    return _metadata(FieldSpec(FieldType.INTEGER, Bounds(lo, hi), unit, doc, key, default_doc=default_doc))


def text(*, doc: str = "", key: str = "", default_doc: str = "", allowed_doc: str = "") -> Mapping[str, Any]:
    """A string (its checks, if any, are the owner's and its docs in `allowed_doc`)."""
    return _metadata(
        FieldSpec(FieldType.TEXT, doc=doc, key=key, default_doc=default_doc, allowed_doc=allowed_doc)
    )


def choice(
    choices: Iterable[str], *, doc: str = "", key: str = "", default_doc: str = ""
) -> Mapping[str, Any]:
    """One of `choices` (a tuple of names, or an enum class: its values, read as its members)."""
    names = tuple(str(getattr(c, "value", c)) for c in choices)
    enum_type = choices if isinstance(choices, type) else None
    return _metadata(
        FieldSpec(
            FieldType.CHOICE,
            doc=doc,
            key=key,
            choices=names,
            choice_type=enum_type,
            default_doc=default_doc,
        )
    )


def flag(*, doc: str = "", key: str = "") -> Mapping[str, Any]:
    """True or false."""
    return _metadata(FieldSpec(FieldType.FLAG, doc=doc, key=key))


def numbers(
    lo: float | None,
    hi: float | None,
    *,
    length: int | None = None,
    min_length: int = 1,
    max_length: int | None = None,
    unit: str = "",
    doc: str = "",
    key: str = "",
    within: str = "",
    allowed_doc: str = "",
) -> Mapping[str, Any]:
    """A list of numbers, each in [lo, hi]: `length` of them, or `min_length`..`max_length`."""
    spec = FieldSpec(
        FieldType.NUMBERS,
        Bounds(lo, hi),
        unit,
        doc,
        key,
        within,
        length=length,
        min_length=min_length,
        max_length=max_length,
        allowed_doc=allowed_doc,
    )
    return _metadata(spec)


def section(
    *, doc: str = "", key: str = "", default_doc: str = "", expand_doc: bool = True
) -> Mapping[str, Any]:
    """A nested mapping, read as the field's own (declared) dataclass."""
    spec = FieldSpec(FieldType.SECTION, doc=doc, key=key, default_doc=default_doc, expand_doc=expand_doc)
    return _metadata(spec)


def custom(
    *, doc: str = "", key: str = "", default_doc: str = "", allowed_doc: str = "", optional: bool = False
) -> Mapping[str, Any]:
    """A field its owner reads with its own code; declared here for the unknown-key check and the docs."""
    spec = FieldSpec(
        FieldType.CUSTOM,
        doc=doc,
        key=key,
        optional=optional,
        default_doc=default_doc,
        allowed_doc=allowed_doc,
    )
    return _metadata(spec)


@dataclass(frozen=True)
class Declared:
    """A declared field of a dataclass: its attribute name, its key in the file, its spec and default."""

    name: str
    key: str
    spec: FieldSpec
    default: Any  # `dataclasses.MISSING` when the field is required

    @property
    def required(self) -> bool:
        """Whether a file must give it."""
        return self.default is dataclasses.MISSING


@functools.cache
def declared_fields(cls: type) -> tuple[Declared, ...]:
    """The declared fields of dataclass `cls`, in declaration order."""
    found: list[Declared] = []
    for f in dataclasses.fields(cls):
        spec = f.metadata.get(SPEC_KEY)
        if not isinstance(spec, FieldSpec):
            continue
        default: Any = f.default
        if f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        found.append(Declared(f.name, spec.key or f.name, spec, default))
    return tuple(found)


@functools.cache
def section_type(cls: type, name: str) -> type:
    """The dataclass type of section field `name` of `cls` (from its annotation; `X | None` gives X)."""
    hint = typing.get_type_hints(cls)[name]
    for candidate in (hint, *typing.get_args(hint)):
        if isinstance(candidate, type) and dataclasses.is_dataclass(candidate):
            return candidate
    raise TypeError(f"{cls.__name__}.{name}: a section field must be annotated with a dataclass")


def top_keys(cls: type) -> tuple[str, ...]:
    """The keys a mapping read as `cls` may hold: each field's key, or the sub-mapping holding it."""
    return tuple(dict.fromkeys(d.spec.within or d.key for d in declared_fields(cls)))


def keys_within(cls: type, within: str) -> tuple[str, ...]:
    """The keys of sub-mapping `within` of a mapping read as `cls`."""
    return tuple(d.key for d in declared_fields(cls) if d.spec.within == within)


# Text for the docs tables (tools.config_docs renders them; a declaration may use them for its own docs).


def default_text(declared: Declared) -> str:
    """A field's default as the docs write it: `required`, `none`, a number, `` `a name` ``."""
    if declared.spec.default_doc:
        return declared.spec.default_doc
    return "required" if declared.required else value_text(declared.default)


def value_text(value: Any) -> str:
    """A value as the docs write it."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f"`{value}`" if value else "empty"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple | list):
        return "[" + ", ".join(value_text(v) for v in value) + "]"
    return str(value)


def allowed_text(declared: Declared) -> str:
    """What a field allows, as the docs write it: range and unit, or the choices; then its doc."""
    spec = declared.spec
    if spec.allowed_doc:
        return spec.allowed_doc
    unit = f" {spec.unit}" if spec.unit else ""
    match spec.type:
        case FieldType.NUMBER:
            allowed = (
                spec.bounds.interval(short=True) + unit + ("; none turns it off" if spec.optional else "")
            )
        case FieldType.INTEGER:
            allowed = spec.bounds.interval(integer=True, short=True) + unit
        case FieldType.CHOICE:
            allowed = ", ".join(f"`{c}`" for c in spec.choices)
        case FieldType.FLAG:
            allowed = "true or false"
        case FieldType.TEXT:
            allowed = "text"
        case FieldType.NUMBERS:
            each = spec.bounds.interval(short=True) + unit
            if spec.length is not None:
                allowed = f"{spec.length} numbers, each in {each}"
            else:
                most = "" if spec.max_length is None else f"-{spec.max_length}"
                allowed = f"a list of {spec.min_length}{most} numbers, each in {each}"
        case FieldType.SECTION | FieldType.CUSTOM:
            return spec.doc
    return f"{allowed}; {spec.doc}" if spec.doc else allowed


def inline_text(cls: type) -> str:
    """The declared fields of `cls` on one line for a table cell: `{id: 0..252, role: a|b}` (| escaped)."""
    parts = []
    for d in declared_fields(cls):
        if d.spec.type == FieldType.CHOICE:
            names = [f"{c} (default)" if c == d.default else c for c in d.spec.choices]
            parts.append(f"{d.key}: " + "\\|".join(names))
        else:
            parts.append(f"{d.key}: {allowed_text(d)}")
    return "{" + ", ".join(parts) + "}"
