"""Config fields declared once: the declarations drive parsing, unknown-key refusal and the docs tables."""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import pytest
import yaml

from model.field_spec import FieldType, declared_fields, section_type
from rig.errors import ConfigError
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, RigConfig, parse_rig_config

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # tools/ is not part of the installed package
from tools.config_docs import TABLES, field_rows, rendered, stale_pages  # noqa: E402


def test_docs_tables_match_the_declarations():
    assert stale_pages() == [], "run `python -m tools.config_docs` to rewrite the tables"


def test_a_changed_declaration_makes_the_docs_stale():
    page = TABLES["rig-config"][0]
    text = (ROOT / page).read_text()
    edited = text.replace("| `servos.retries` | 2 | 0..10;", "| `servos.retries` | 3 | 0..10;")
    assert edited != text
    assert rendered(page, edited) == text


def _number_fields(cls: type, path: tuple[str, ...] = ()):
    """(key path, declared) of the numeric fields the generic reader parses, sections walked."""
    for d in declared_fields(cls):
        where = (*path, *([d.spec.within] if d.spec.within else []), d.key)
        if d.spec.type == FieldType.SECTION:
            yield from _number_fields(section_type(cls, d.name), where)
        elif d.spec.type in (FieldType.NUMBER, FieldType.INTEGER):
            yield where, d


def _with(data: dict, where: tuple[str, ...], value: object) -> dict:
    out = copy.deepcopy(data)
    target = out
    for key in where[:-1]:
        target = target.setdefault(key, {})
    target[where[-1]] = value
    return out


NUMBER_FIELDS = list(_number_fields(RigConfig))


@pytest.mark.parametrize(("where", "declared"), NUMBER_FIELDS, ids=[".".join(w) for w, _ in NUMBER_FIELDS])
def test_each_declared_bound_is_what_the_parser_enforces(where, declared):
    base = yaml.safe_load(DEFAULT_RIG_CONFIG.read_text())
    if where[:2] == ("simulation", "scatter"):  # the shape that takes both a_kg and b
        base = _with(_with(base, (*where[:2], "shape"), "mixed"), (*where[:2], "a_kg"), 0.1)
    bounds = declared.spec.bounds
    assert bounds.hi is not None and bounds.lo is not None and not bounds.hi_open
    parse_rig_config(_with(base, where, bounds.hi), source="r.yaml")  # the bound itself is allowed
    above = bounds.hi + 1 if declared.spec.type == FieldType.INTEGER else bounds.hi * 1.5 + 1
    with pytest.raises(ConfigError, match=rf"^r\.yaml: {'.'.join(where)}: .*allowed"):
        parse_rig_config(_with(base, where, above), source="r.yaml")


def test_every_documented_field_is_accepted_and_an_undeclared_one_is_refused():
    documented = {row[0].strip("`") for row in field_rows(RigConfig)}
    assert {"servos.watchdog_ms", "article.load.direction", "simulation.noise_scale"} <= documented
    base = yaml.safe_load(DEFAULT_RIG_CONFIG.read_text())
    with pytest.raises(ConfigError, match=r"limits\.bogus: unknown field; allowed: force_ceiling_n, "):
        parse_rig_config(_with(base, ("limits", "bogus"), 1), source="r.yaml")
    with pytest.raises(
        ConfigError, match=r"article\.load\.bogus: unknown field; allowed: point_m, direction"
    ):
        parse_rig_config(_with(base, ("article", "load", "bogus"), 1), source="r.yaml")
