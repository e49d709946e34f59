"""The JSON Schema subset that Foxglove's and Lichtblick's schema reader turns into panel fields.

The viewers do not validate messages against a channel's schema: they convert the schema into
message definitions (field names and types) that their panels, message paths and plots use. The
converter (`parseJsonSchema` in the viewers' `mcap-support` package) understands a small subset,
and one field outside it makes the *whole channel* unreadable ("Unsupported type ... for FIELD"
in the Problems tab, every panel on that topic empty). Its rules, per property of an object:

* `oneOf` is accepted only as a list of alternatives that each carry a numeric `const` (and a
  `title`, the constant's name): an enum of numbers;
* otherwise `type` must be one string: `boolean`, `string` (no `contentEncoding`, or `base64`),
  `number`, `integer`, `object` (read recursively) or `array`;
* an array's `items` must be one schema whose `type` is `boolean`, `string` (no
  `contentEncoding`), `number`, `integer` or `object`: no arrays of arrays, no tuple `items` lists;
* a type list such as `["integer", "null"]`, the type `"null"`, or no `type` at all is refused.

The root must be an object. Keywords the converter does not read (`$ref`, `anyOf`, `allOf`,
`not`, `if`, `const` outside `oneOf`, `patternProperties`) are reported too: the viewer would
silently show something other than what the schema says. A missing value is an absent field, not
null. `problems` is a pure function of the schema JSON; tests run it over every advertised schema.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

_SCALAR_TYPES = frozenset({"boolean", "string", "number", "integer"})
_ITEM_TYPES = _SCALAR_TYPES | {"object"}
_FIELD_TYPES = _ITEM_TYPES | {"array"}
_UNREAD_KEYWORDS = ("$ref", "anyOf", "allOf", "not", "if", "patternProperties")


def problems(schema: Mapping[str, Any]) -> list[str]:
    """Every construct of `schema` (a channel's top-level JSON Schema) that the viewers' reader refuses.

    Each entry names the field by its dotted path. An empty list means every field of the channel
    becomes a panel field.
    """
    found: list[str] = []
    if schema.get("type") != "object":
        found.append(f'(root): type must be "object", not {schema.get("type")!r}')
        return found
    _check_object(schema, "", found)
    return found


def _check_object(schema: Mapping[str, Any], path: str, found: list[str]) -> None:
    _check_unread(schema, path or "(root)", found)
    properties = schema.get("properties", {})
    if not isinstance(properties, Mapping):
        found.append(f"{path or '(root)'}: properties must be an object")
        return
    for name, field in properties.items():
        where = f"{path}.{name}" if path else str(name)
        if not isinstance(field, Mapping):
            found.append(f"{where}: the field's schema must be an object")
            continue
        _check_field(field, where, found)


def _check_field(field: Mapping[str, Any], where: str, found: list[str]) -> None:
    if "oneOf" in field:
        _check_numeric_enum(field["oneOf"], where, found)
        return
    _check_unread(field, where, found)
    kind = field.get("type")
    if not isinstance(kind, str) or kind not in _FIELD_TYPES:
        found.append(f"{where}: type {kind!r} is not one of {sorted(_FIELD_TYPES)} (one string; no null)")
        return
    if "const" in field:
        found.append(f"{where}: const outside oneOf is not read")
    if kind == "string":
        encoding = field.get("contentEncoding")
        if encoding not in (None, "base64"):
            found.append(f"{where}: contentEncoding {encoding!r} (only base64 is read)")
    elif kind == "object":
        _check_object(field, where, found)
    elif kind == "array":
        _check_items(field.get("items"), where, found)


def _check_items(items: Any, where: str, found: list[str]) -> None:
    if not isinstance(items, Mapping):
        found.append(f"{where}: items must be one schema (not {type(items).__name__})")
        return
    _check_unread(items, f"{where}[]", found)
    kind = items.get("type")
    if not isinstance(kind, str) or kind not in _ITEM_TYPES:
        found.append(f"{where}[]: item type {kind!r} is not one of {sorted(_ITEM_TYPES)}")
        return
    if kind == "string" and items.get("contentEncoding") is not None:
        found.append(f"{where}[]: contentEncoding on array items is not read")
    if kind == "object":
        _check_object(items, f"{where}[]", found)


def _check_numeric_enum(alternatives: Any, where: str, found: list[str]) -> None:
    if not isinstance(alternatives, list) or not alternatives:
        found.append(f"{where}: oneOf must be a non-empty list")
        return
    for i, alternative in enumerate(alternatives):
        ok = (
            isinstance(alternative, Mapping)
            and type(alternative.get("const")) in (int, float)
            and isinstance(alternative.get("title"), str)
        )
        if not ok:
            found.append(f"{where}: oneOf[{i}] must be {{title: NAME, const: NUMBER}} (a numeric enum)")


def _check_unread(schema: Mapping[str, Any], where: str, found: list[str]) -> None:
    for keyword in _UNREAD_KEYWORDS:
        if keyword in schema:
            found.append(f"{where}: {keyword} is not read by the viewer")
