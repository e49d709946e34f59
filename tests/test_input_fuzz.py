"""Fuzzing every input parser: arbitrary bytes, text edits and structured mutations of valid files.

Each case must load or raise `InputError` naming the file (never another exception), within a
deadline; through the CLI it must exit 0 or 2, and 2 with one line on stderr. Each test runs a
quick profile in the normal suite and a long one marked `slow`.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import json
import math
from collections.abc import Callable
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, reject, settings
from hypothesis import strategies as st

from rig.cli import main
from rig.cli.sim_loadcell import build_emulator
from rig.cli.sim_servos import build_bus, parse_ids
from rig.errors import InputError
from rig.hw.loadcell.calibration import Calibration
from rig.inputs.files import parse_json, parse_yaml
from rig.inputs.linkfile import load_link_file
from rig.inputs.protocol import load_protocol
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, load_rig_config
from rig.runner.journal import RunJournal
from rig.runner.run_estimates import RunEstimator, load_estimates_file
from rig.sim.dxl.faults import parse_fault as parse_dxl_fault
from rig.sim.loadcell.emulator import FaultPlan
from rig.sim.loadcell.emulator import parse_fault as parse_loadcell_fault
from rig.sim.loadcell.profiles import parse_profile
from tests.helpers import QUICK_PROTOCOL
from tests.test_input_limits import ESTIMATES, journal_setup

REPO = Path(__file__).resolve().parents[1]
PROTOCOLS = REPO / "protocols"

PROFILES = {
    "quick": settings(
        max_examples=100,
        deadline=timedelta(seconds=2),
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    ),
    "slow": settings(
        max_examples=600,
        deadline=timedelta(seconds=2),
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    ),
}
PROFILE = pytest.mark.parametrize(
    "profile", [pytest.param("quick"), pytest.param("slow", marks=pytest.mark.slow)]
)

# ------------------------------------------------------------------------------------------ strategies

NASTY_VALUES = st.one_of(
    st.sampled_from(
        [
            None,
            True,
            False,
            0,
            -1,
            1,
            2,
            0.5,
            -0.0,
            1e300,
            -1e300,
            1e-320,
            5e-324,
            10**400,
            -(10**30),
            "",
            "x",
            "nan",
            ".inf",
            "1e999",
            "run",
            "{joint:>99999}",
            "\x07",
            "\ud800",
            "a" * 300,
            [],
            {},
            [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]],
        ]
    ),
    st.floats(),
    st.integers(),
    st.text(max_size=12),
    st.lists(st.one_of(st.floats(), st.integers(-5, 300)), max_size=10),
    st.dictionaries(st.text(max_size=6), st.integers(), max_size=3),
)


def _paths(tree: Any) -> list[tuple[Any, Any]]:
    """(container, key) of every node below the top, breadth first."""
    out: list[tuple[Any, Any]] = []
    queue = [tree]
    while queue:
        node = queue.pop(0)
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for key, value in items:
            out.append((node, key))
            queue.append(value)
    return out


@st.composite
def mutated_tree(draw: st.DrawFn, seed: Any) -> Any:
    """`seed` with 1-4 random edits: a node replaced, removed, duplicated, or a key added."""
    tree = copy.deepcopy(seed)
    for _ in range(draw(st.integers(1, 4))):
        paths = _paths(tree)
        if not paths:
            return tree
        container, key = draw(st.sampled_from(paths))
        op = draw(st.sampled_from(["replace", "replace", "remove", "duplicate", "add_key"]))
        if op == "replace":
            container[key] = copy.deepcopy(draw(NASTY_VALUES))
        elif op == "remove":
            del container[key]
        elif op == "duplicate" and isinstance(container, list):
            container.extend(copy.deepcopy([container[key]] * draw(st.integers(1, 50))))
        elif op == "add_key" and isinstance(container, dict):
            container[draw(st.sampled_from(["extra", "name", "g", "steps", "n", "1"]))] = copy.deepcopy(
                draw(NASTY_VALUES)
            )
    return tree


SNIPPETS = st.sampled_from(
    ["&a ", "*a", "{", "[", "\n  ", ": ", "- ", '"', "\t", "#", "0x1", "1e-320", "nan", "\x00"]
)


@st.composite
def edited_text(draw: st.DrawFn, seed: str) -> str:
    """`seed` with 1-5 character-level edits (insert, delete, replace)."""
    text = seed
    for _ in range(draw(st.integers(1, 5))):
        at = draw(st.integers(0, len(text)))
        op = draw(st.sampled_from(["insert", "delete", "replace"]))
        piece = draw(st.one_of(st.text(max_size=8), SNIPPETS))
        if op == "insert":
            text = text[:at] + piece + text[at:]
        elif op == "delete":
            text = text[:at] + text[at + draw(st.integers(1, 20)) :]
        else:
            text = text[:at] + piece + text[at + len(piece) :]
    return text


def _dump(tree: Any, kind: str) -> bytes:
    try:
        text = yaml.safe_dump(tree, sort_keys=False) if kind == "yaml" else json.dumps(tree)
        return text.encode("utf-8")
    except (ValueError, TypeError, yaml.YAMLError, UnicodeEncodeError, RecursionError):
        reject()


def file_inputs(seed_text: str, kind: str) -> st.SearchStrategy[bytes]:
    """Bytes for a file: arbitrary, edited text of the seed, or a dump of a mutated parse of it."""
    seed_tree = (
        parse_yaml(seed_text, "seed") if kind == "yaml" else parse_json(seed_text, "seed", allow_nan=True)
    )
    return st.one_of(
        st.binary(max_size=300),
        st.text(max_size=300).map(lambda t: t.encode("utf-8")),
        edited_text(seed_text).map(lambda t: t.encode("utf-8", "surrogatepass")),
        mutated_tree(seed_tree).map(lambda tree: _dump(tree, kind)),
    )


# ------------------------------------------------------------------------------------------ harness


def loads_or_input_error(load: Callable[[Path], Any], path: Path, data: bytes) -> Any:
    """Write `data` to `path` and load it: the result, or None after an InputError naming the file."""
    path.write_bytes(data)
    try:
        return load(path)
    except InputError as exc:
        assert str(path) in str(exc), exc
        return None


def cli(*argv: object) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def exits_0_or_2_with_one_line(*argv: object) -> int:
    code, out, err = cli(*argv)
    assert code in (0, 2), (code, err)
    if code == 2:
        assert out == "" and err.startswith("rig: error: ") and err.count("\n") == 1, err
    else:
        assert "Traceback" not in err
    return code


def fuzz(profile: str, strategy: st.SearchStrategy[Any], check: Callable[[Any], None]) -> None:
    @PROFILES[profile]
    @given(strategy)
    def run(value: Any) -> None:
        check(value)

    run()


# ------------------------------------------------------------------------------------------ files


@PROFILE
def test_protocol(profile, tmp_path):
    path = tmp_path / "p.yaml"
    seeds = [
        QUICK_PROTOCOL,
        *(p.read_text() for p in sorted(PROTOCOLS.glob("*.yaml")) if "link" not in p.stem),
    ]
    seeds.append((PROTOCOLS / "link_validation.yaml").read_text())

    def check(data: bytes) -> None:
        if loads_or_input_error(lambda p: load_protocol(p, joint_count=8), path, data) is not None:
            exits_0_or_2_with_one_line("run", path, "--dry-run", "--json", "--out", tmp_path / "out")

    fuzz(profile, st.one_of(*(file_inputs(s, "yaml") for s in seeds)), check)


@PROFILE
def test_rig_config(profile, tmp_path):
    path = tmp_path / "rig.yaml"
    seeds = [DEFAULT_RIG_CONFIG.read_text(), (PROTOCOLS / "rigs" / "hardware.example.yaml").read_text()]

    def check(data: bytes) -> None:
        if loads_or_input_error(load_rig_config, path, data) is not None:
            exits_0_or_2_with_one_line("run", PROTOCOLS / "smoke.yaml", "--rig", path, "--dry-run", "--json")

    fuzz(profile, st.one_of(*(file_inputs(s, "yaml") for s in seeds)), check)


@PROFILE
def test_link_file(profile, tmp_path):
    path = tmp_path / "link.yaml"

    def check(data: bytes) -> None:
        if loads_or_input_error(load_link_file, path, data) is not None:
            exits_0_or_2_with_one_line("predict", path, "--json")
            exits_0_or_2_with_one_line("predict", path)

    fuzz(profile, file_inputs((PROTOCOLS / "example_link.yaml").read_text(), "yaml"), check)


def _csv_inputs() -> st.SearchStrategy[bytes]:
    seed = (PROTOCOLS / "example_fit.csv").read_text()
    cell = st.one_of(
        st.sampled_from(["0", "1e-320", "1e300", "nan", "-1", "", "1_0", " 2 ", '"3"']), st.text(max_size=6)
    )
    rows = st.lists(st.lists(cell, min_size=1, max_size=4).map(",".join), max_size=8)
    headers = st.sampled_from(
        ["distance_m,mass_kg", "distance_m,force_n", "mass_kg,distance_m,x", "distance_m"]
    )
    built = st.tuples(headers, rows).map(lambda hr: "\n".join([hr[0], *hr[1]]) + "\n")
    return st.one_of(
        st.binary(max_size=300),
        edited_text(seed).map(lambda t: t.encode("utf-8", "surrogatepass")),
        built.map(str.encode),
    )


@PROFILE
def test_fit_csv(profile, tmp_path):
    path = tmp_path / "data.csv"

    def check(data: bytes) -> None:
        path.write_bytes(data)
        for options in (
            ["--json"],
            ["--constant", "derived", "--level", "0.5"],
            ["--g", "0.1", "--radius-m", "1"],
        ):
            exits_0_or_2_with_one_line("fit", path, "--radius-m", "0.01", *options)

    fuzz(profile, _csv_inputs(), check)


@PROFILE
def test_estimates_file(profile, tmp_path):
    path = tmp_path / "est.json"
    run_file = json.dumps({"run_id": "r", "estimate": {**ESTIMATES, "r2": math.nan}, "joints": []})
    _, fitted, _ = cli("fit", PROTOCOLS / "example_fit.csv", "--radius-m", "0.01", "--json")
    article = load_rig_config().article

    def check(data: bytes) -> None:
        summary = loads_or_input_error(load_estimates_file, path, data)
        if summary is not None:  # what the run does with it
            estimator = RunEstimator(article, prior_summary=summary)
            assert estimator.predict_joint_estimation_force_n(0.1) is not None
            assert estimator.predict_link([0.0] * article.joint_count) is not None
            assert estimator.estimate(1).to_payload()["capacity_nm"] == summary.capacity_nm

    seeds = [json.dumps(ESTIMATES), run_file, fitted]
    fuzz(profile, st.one_of(*(file_inputs(s, "json") for s in seeds)), check)


@PROFILE
def test_calibration_file(profile, tmp_path):
    path = tmp_path / "cal.json"
    seed = Calibration(1.25e-5, 120000.0, 1.0, 9.80665, "2026-11-21T10:15:00+00:00", "", "rig-lc1", 400.0)

    def check(data: bytes) -> None:
        calibration = loads_or_input_error(Calibration.load, path, data)
        if calibration is not None:
            assert math.isfinite(calibration.force_n(2**31)) and math.isfinite(
                calibration.raw_for_force(500.0)
            )

    fuzz(profile, file_inputs(json.dumps(seed.to_dict()), "json"), check)


@PROFILE
def test_run_journal(profile, tmp_path):
    _, journal = journal_setup(tmp_path)
    path = tmp_path / "r1.journal.json"
    article = load_rig_config().article
    lv = copy.deepcopy(journal)
    lv["completed"].append({**journal["completed"][0], "trial_id": 2, "kind": "link_validation",
                            "distance_m": None, "lever_arms_m": [0.03 * i for i in range(8, 0, -1)],
                            "slipped_joint": 2, "peak_force_n": 7.0})  # fmt: skip

    def check(data: bytes) -> None:
        loaded = loads_or_input_error(RunJournal.load, path, data)
        if loaded is not None:  # what --resume does with it
            with contextlib.suppress(InputError):
                RunEstimator(article).replay(loaded.completed, str(path))

    fuzz(
        profile,
        st.one_of(file_inputs(json.dumps(journal), "json"), file_inputs(json.dumps(lv), "json")),
        check,
    )


# ------------------------------------------------------------------------------------------ options

SPEC_TEXT = st.one_of(
    st.text(max_size=30),
    st.lists(
        st.one_of(
            st.sampled_from(
                [
                    "drop",
                    "corrupt",
                    "delay",
                    "silent",
                    "hwerror",
                    "baud",
                    "garbage",
                    "truncate",
                    "checksum",
                    "gap",
                    "silence",
                    "constant",
                    "sawtooth",
                    "",
                    "nan",
                    "inf",
                    "-1",
                    "0x20",
                    "1e-320",
                    "1e999",
                    "57600",
                    "99999999999999999999",
                ]
            ),
            st.integers(-5, 300).map(str),
            st.floats().map(str),
        ),
        min_size=1,
        max_size=5,
    ).map(":".join),
)


@PROFILE
def test_fault_and_profile_specs(profile):
    def check(spec: str) -> None:
        for parse in (
            parse_dxl_fault,
            lambda s: parse_loadcell_fault(s, FaultPlan()),
            parse_profile,
            parse_ids,
        ):
            with contextlib.suppress(InputError):
                parse(spec)

    fuzz(profile, SPEC_TEXT, check)


@PROFILE
def test_rig_sim_loadcell_options(profile):
    options = st.fixed_dictionaries(
        {
            "rate": st.one_of(st.none(), st.floats(), st.sampled_from([10.0, 12.0, 80.0, 1000.0, 2000.0])),
            "format": st.sampled_from([None, "rig-lc1", "indicator-st", "value-unit"]),
            "cell": st.sampled_from([None, "hx711-10", "hx711-80", "hx717-320", "gauge-12"]),
            "clock_error_ppm": st.one_of(st.floats(), st.sampled_from([0.0, -5000.0, 50_000.0])),
            "baud": st.sampled_from([921600, 115200, 0, -1, 10**30]),
            "profile": SPEC_TEXT,
            "fault": st.lists(SPEC_TEXT, max_size=3),
            "seed": st.integers(-(2**70), 2**70),
            "gain_counts_per_n": st.one_of(st.floats(), st.just(80000.0)),
            "offset_counts": st.one_of(st.floats(), st.just(0.0)),
            "noise_counts": st.one_of(st.floats(), st.just(400.0)),
            "drift_counts_per_s": st.one_of(st.floats(), st.just(5.0)),
            "banner": st.booleans(),
            "dtr_reset_s": st.one_of(st.floats(), st.sampled_from([0.0, 1.5, 10.0])),
        }
    )

    def check(values: dict[str, Any]) -> None:
        try:
            emulator = build_emulator(argparse.Namespace(**values), 0)
        except InputError:
            return
        emulator.receive(b"?\r?\r", 1_000_000)  # a polled format answers; a streaming one ignores it
        emulator.lines_until(50_000_000)  # 50 ms of lines: the values reach every computation

    fuzz(profile, options, check)


@PROFILE
def test_rig_sim_servos_options(profile):
    options = st.fixed_dictionaries(
        {
            "ids": st.one_of(
                st.text(max_size=12),
                st.lists(st.integers(-3, 260), max_size=4).map(lambda v: ",".join(map(str, v))),
            ),
            "model": st.sampled_from(["XM430-W350", "XL430-W250", "", "x"]),
            "baud": st.sampled_from([57600, 1_000_000, 0, -1, 10**30]),
            "firmware": st.one_of(st.none(), st.integers(-5, 300)),
            "fault": st.lists(SPEC_TEXT, max_size=3),
            "usb_latency_ms": st.floats(-5, 300) | st.sampled_from([float("nan"), float("inf")]),
            "voltage_v": st.none() | st.floats(allow_nan=True, allow_infinity=True),
            "temperature_c": st.none() | st.integers(-5, 300),
        }
    )

    def check(values: dict[str, Any]) -> None:
        with contextlib.suppress(InputError):
            build_bus(argparse.Namespace(**values))

    fuzz(profile, options, check)
