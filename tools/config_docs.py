"""The docs' tables of settings fields, written from the fields' declarations (`model.field_spec`).

Each table sits in a docs page between `<!-- fields: NAME -->` and `<!-- /fields -->`.
`python -m tools.config_docs` rewrites them in place; `python -m tools.config_docs --check` (and
tests/test_config_docs.py) fails when a page and the declarations differ. So a field's range,
default and unit are written once, on the dataclass, and the docs cannot drift from the parser.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path

from model.field_spec import (
    Declared,
    FieldType,
    allowed_text,
    declared_fields,
    default_text,
    section_type,
    value_text,
)
from model.slip_detector import DetectorParams
from rig.inputs.protocol import AdaptiveBlockFields, FixedBlockFields, LinkValidationBlockFields, Protocol
from rig.inputs.rig_config import RigConfig, SimulationSection
from rig.sim.settings import SimulationConfig

ROOT = Path(__file__).resolve().parent.parent

# Sections a config keeps as written for another layer to parse: the dataclass that declares their fields.
PARSED_ELSEWHERE: dict[type, type] = {SimulationSection: SimulationConfig}


def _declaring(section_cls: type) -> type:
    return PARSED_ELSEWHERE.get(section_cls, section_cls)


def field_rows(cls: type, prefix: str = "") -> list[tuple[str, str, str]]:
    """(`field.path`, default, allowed) of every declared field of `cls`, sections expanded."""
    rows: list[tuple[str, str, str]] = []
    for declared in declared_fields(cls):
        within = f"{declared.spec.within}." if declared.spec.within else ""
        path = f"{prefix}{within}{declared.key}"
        if declared.spec.type == FieldType.SECTION and declared.spec.expand_doc:
            rows += field_rows(_declaring(section_type(cls, declared.name)), f"{path}.")
        else:
            rows.append((f"`{path}`", default_text(declared), allowed_text(declared)))
    return rows


def field_table(cls: type) -> str:
    """A markdown table of the fields of `cls` (a config file's)."""
    lines = ["| field | default | allowed |", "|---|---|---|"]
    lines += [f"| {path} | {default} | {allowed} |" for path, default, allowed in field_rows(cls)]
    return "\n".join(lines)


# The block declarations and the kind column's name for each.
_BLOCKS = (
    ("fixed", FixedBlockFields),
    ("adaptive", AdaptiveBlockFields),
    ("link_validation", LinkValidationBlockFields),
)


def blocks_table() -> str:
    """The fields of a protocol's blocks, with the kinds (and designs) each belongs to."""
    found: dict[str, tuple[Declared, list[str]]] = {}
    for label, cls in _BLOCKS:
        for declared in declared_fields(cls):
            found.setdefault(declared.key, (declared, []))[1].append(label)
    lines = ["| field | kind | default | allowed |", "|---|---|---|---|"]
    for key, (declared, labels) in found.items():
        if len(labels) == len(_BLOCKS):
            kind = "all"
        elif labels == ["fixed", "adaptive"]:
            kind = "joint_estimation"
        else:
            kind = ", ".join(labels)
        lines.append(f"| `{key}` | {kind} | {default_text(declared)} | {allowed_text(declared)} |")
    return "\n".join(lines)


def detector_table() -> str:
    """The slip detector's parameters: default with its unit, and the range (`none` turns a trigger off)."""
    lines = ["| parameter | default | allowed |", "|---|---|---|"]
    for declared in declared_fields(DetectorParams):
        spec = declared.spec
        default = spec.default_doc or value_text(declared.default)
        if declared.default is not None and spec.unit:
            default += f" {spec.unit}"
        allowed = spec.allowed_doc or spec.bounds.interval(short=True) + (" or none" if spec.optional else "")
        lines.append(f"| `{declared.name}` | {default} | {allowed} |")
    return "\n".join(lines)


# Table name -> (page, writer).
TABLES: dict[str, tuple[str, Callable[[], str]]] = {
    "protocol": ("docs/formats.md", lambda: field_table(Protocol)),
    "protocol-blocks": ("docs/formats.md", blocks_table),
    "rig-config": ("docs/formats.md", lambda: field_table(RigConfig)),
    "detector": ("docs/model.md", detector_table),
}


def _pattern(name: str) -> re.Pattern[str]:
    return re.compile(rf"(<!-- fields: {re.escape(name)} -->\n)(.*?)(\n<!-- /fields -->)", re.DOTALL)


def rendered(page: str, text: str) -> str:
    """`text` (the contents of docs page `page`) with each of its tables written afresh."""
    for name, (where, table) in TABLES.items():
        if where != page:
            continue
        found = _pattern(name).search(text)
        if found is None:
            raise ValueError(f"{page}: no <!-- fields: {name} --> ... <!-- /fields --> markers")
        text = text[: found.start(2)] + table() + text[found.end(2) :]
    return text


def stale_pages(root: Path = ROOT) -> list[str]:
    """The docs pages whose tables differ from the declarations."""
    pages = sorted({where for where, _ in TABLES.values()})
    return [page for page in pages if rendered(page, (root / page).read_text()) != (root / page).read_text()]


def main(argv: list[str] | None = None) -> int:
    """Rewrite the tables (or, with --check, exit 1 naming the pages that differ)."""
    parser = argparse.ArgumentParser(prog="python -m tools.config_docs", description=__doc__)
    parser.add_argument("--check", action="store_true", help="only check; exit 1 if a page differs")
    args = parser.parse_args(argv)
    stale = stale_pages()
    if args.check:
        for page in stale:
            print(
                f"{page}: its settings tables differ from the declarations; run python -m tools.config_docs"
            )
        return 1 if stale else 0
    for page in stale:
        path = ROOT / page
        path.write_text(rendered(page, path.read_text()))
        print(f"rewrote the tables of {page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
