"""Scenario rig configs: their simulation sections are validated (exit 2), and every scenario runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rig.analysis.runlog import read_parts, run_settings
from rig.inputs.rig_config import load_rig_config
from rig.sim.kinds import SlipKind
from rig.sim.settings import require_simulated
from tests.helpers import QUICK_PROTOCOL

SCENARIOS = Path(__file__).resolve().parent.parent / "protocols" / "rigs" / "scenarios"
# Cells as labs have them (issue 21): tests/test_loadcell_cells.py runs them.
CELL_NAMES = ("cell-hx711-10", "cell-hx711-80", "cell-hx717-320", "cell-gauge-12")
# A low-rate cell on a compliant line (issue 21): tests/test_ramp_counts.py, bench_rates.py --scenario.
LINE_NAMES = ("compliant-10",)
NAMES = ("small-drops", "creep", "stick-slip", "noisy-cell", "additive-scatter", "mixed-scatter", "mixed")


def test_every_scenario_is_shipped_and_loads() -> None:
    assert sorted(p.stem for p in SCENARIOS.glob("*.yaml")) == sorted(NAMES + CELL_NAMES + LINE_NAMES)
    compliant = load_rig_config(SCENARIOS / "compliant-10.yaml")
    spring_n_per_m = require_simulated(compliant).spring_stiffness_n_per_m
    assert spring_n_per_m == 1000
    series_n_per_m = 1 / (1 / 5000 + 1 / spring_n_per_m)
    assert compliant.line_stiffness_n_per_m == pytest.approx(series_n_per_m, rel=1e-3)
    mixed = require_simulated(load_rig_config(SCENARIOS / "mixed.yaml"))
    assert mixed is not None and all(mixed.slips.probability(kind) > 0 for kind in tuple(SlipKind))
    noisy = require_simulated(load_rig_config(SCENARIOS / "noisy-cell.yaml"))
    assert noisy is not None and noisy.loadcell.noise_scale == 10 and noisy.loadcell.active
    additive = require_simulated(load_rig_config(SCENARIOS / "additive-scatter.yaml"))
    assert additive is not None and (additive.scatter.shape, additive.scatter.a_kg) == ("additive", 0.1)
    mixed_scatter = require_simulated(load_rig_config(SCENARIOS / "mixed-scatter.yaml"))
    assert mixed_scatter is not None
    assert (mixed_scatter.scatter.shape, mixed_scatter.scatter.a_kg, mixed_scatter.scatter.b) == (
        "mixed",
        0.07,
        0.06,
    )


@pytest.mark.parametrize(
    ("simulation", "field", "allowed"),
    [
        ("slips: {mix: {sudden: 0.5, creep: 0.3}}", "simulation.slips.mix", "they sum to 1"),
        (
            "slips: {mix: {sudden: 1.0, skid: 0.0}}",
            "simulation.slips.mix.skid",
            "allowed: sudden, small_drop",
        ),
        ("slips: {mix: {creep: 1.5}}", "simulation.slips.mix.creep", "allowed: 0.0 <= x <= 1.0"),
        (
            "slips: {small_drop_fraction: [0.2, 0.1]}",
            "simulation.slips.small_drop_fraction",
            "lowest, highest",
        ),
        ("slips: {creep_duration_s: [0.05, 20]}", "simulation.slips.creep_duration_s[1]", "<= 10"),
        ("slips: {stick_slip_drops: [2.5, 4]}", "simulation.slips.stick_slip_drops", "whole numbers"),
        ("slips: {no_slip_capacity_factor: 1}", "simulation.slips.no_slip_capacity_factor", "1.0 < x"),
        ("scatter: {shape: cubic}", "simulation.scatter.shape", "multiplicative, additive, mixed"),
        ("scatter: {shape: additive}", "simulation.scatter.a_kg", "required"),
        ("scatter: {shape: additive, a_kg: 0.1, b: 0.1}", "simulation.scatter.b", "change the shape"),
        ("scatter: {a_kg: 0.1}", "simulation.scatter.a_kg", "additive or mixed"),
        ("scatter: {shape: mixed, a_kg: 0.1, b: 0.9}", "simulation.scatter.b", "<= 0.5"),
        ("loadcell: {hum_hz: 0}", "simulation.loadcell.hum_hz", "1.0 <= x <= 500.0"),
        ("loadcell: {noise_scal: 2}", "simulation.loadcell.noise_scal", "did you mean 'noise_scale'"),
    ],
)
def test_bad_simulation_fields_exit_2_naming_file_field_and_range(
    tmp_path: Path, run_cli, simulation: str, field: str, allowed: str
) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text(f"extends: simulated\nsimulation:\n  {simulation}\n")
    protocol = tmp_path / "quick.yaml"
    protocol.write_text(QUICK_PROTOCOL)
    result = run_cli("run", protocol, "--rig", rig, "--out", tmp_path)
    assert result.code == 2, result.err
    assert str(rig) in result.err and field in result.err and allowed in result.err
    assert "Traceback" not in result.err
    assert not list(tmp_path.glob("*.mcap"))


@pytest.mark.parametrize("name", NAMES)
def test_scenario_runs_a_short_protocol_to_the_end(tmp_path: Path, run_cli, name: str) -> None:
    protocol = tmp_path / "quick.yaml"
    protocol.write_text(QUICK_PROTOCOL)
    result = run_cli(
        "run", protocol, "--rig", SCENARIOS / f"{name}.yaml", "--seed", 2, "--json", "--out", tmp_path
    )
    report = json.loads(result.out)
    assert report["completed"] == report["planned"] == 3
    assert all(trial["outcome"] for trial in report["trials"])
    # A run whose trials all end without a usable slip (here: mixed at seed 2, other joints and
    # no slip) fails saying so (exit 1); any slip of the joint under test makes it a success.
    slipped = any(trial["outcome"] in ("slip", "creep", "stick_slip") for trial in report["trials"])
    assert result.code == (0 if slipped else 1), result.err
    # The log's sim_truth has every trial's kind and slip events, on the run clock.
    settings = run_settings(read_parts(report["log"]), [])
    assert settings.truth is not None
    world = settings.truth["world"]
    config = require_simulated(load_rig_config(SCENARIOS / f"{name}.yaml"))
    assert config is not None
    assert world["scatter"]["shape"] == config.scatter.shape
    for trial in world["trials"]:
        assert config.slips.probability(trial["slip_kind"]) > 0
        for event in trial["slip_events"]:
            assert event["onset_time_ns"] >= trial["start_ns"] + world["run_clock_offset_ns"]
            assert event["load_n"] > 0
    slipped = [t for t in report["trials"] if t["outcome"] in ("slip", "creep", "stick_slip", "other_joint")]
    events = {t["index"]: t["slip_events"] for t in world["trials"]}
    assert all(
        events[i] for i in range(1, len(events) + 1) if world["trials"][i - 1]["slip_kind"] != "no_slip"
    )
    assert len(slipped) >= 1


@pytest.mark.slow  # a 24-trial run and its replay
def test_replay_re_detects_every_creep_of_a_run(tmp_path: Path, run_cli) -> None:
    """Creep detection hangs on every sample from the ramp's start: the runner must feed the detector
    the very samples replay reads (it once missed the one stamped at the phase change's instant)."""
    protocol = Path(__file__).resolve().parent.parent / "protocols" / "joint_estimation.yaml"
    result = run_cli(
        "run", protocol, "--rig", SCENARIOS / "creep.yaml", "--seed", 0, "--json", "--out", tmp_path
    )
    assert result.code == 0, result.err
    report = json.loads(result.out)
    assert "creep" in {t["outcome"] for t in report["trials"]}
    replay = run_cli("replay", report["log"], "--json")
    assert replay.code == 0, replay.err
    redetection = json.loads(replay.out)["redetection"]
    assert redetection["by_status"] == {"match": report["completed"]}, redetection["mismatches"]
