"""`design: adaptive` joint-estimation blocks: parsing, validation errors (exit 2), and the dry run."""

from __future__ import annotations

from typing import Any

import pytest

from model.design import DEFAULT_STOP_SCALE_CONFIDENCE
from rig.errors import ConfigError
from rig.inputs.files import parse_yaml
from rig.inputs.protocol import AdaptiveBlock, TrialPlan, load_protocol, parse_protocol
from tests.helpers import QUICK_STEPS, adaptive_block, bare_protocol, shipped_block, with_overrides

ADAPTIVE = adaptive_block(max_trials=10)
LINK = shipped_block("link_validation", 1, estimates_from=None, configurations_deg=[[5] * 8])
FIXED = shipped_block("smoke", repeats=2, steps=None)


def adaptive(**fields: Any) -> dict[str, Any]:
    """ADAPTIVE with `fields` (`with_overrides`: None deletes a field)."""
    return with_overrides(ADAPTIVE, fields)


def adaptive_protocol(*blocks: dict[str, Any]) -> str:
    """A protocol named adaptive of `blocks`, with a 70 N ramp and a 75 N ceiling."""
    return bare_protocol("adaptive", blocks, ramp={"max_force_n": 70.0}, limits={"force_ceiling_n": 75.0})


def parse(*blocks: dict[str, Any]):
    text = adaptive_protocol(*blocks)
    return parse_protocol(parse_yaml(text, "p.yaml"), source="p.yaml", text=text, joint_count=8)


def test_an_adaptive_block_keeps_its_budget_of_trial_ids():
    protocol = parse(FIXED, ADAPTIVE, LINK)
    (block,) = protocol.adaptive
    assert isinstance(block, AdaptiveBlock) and block.block == 1
    assert block.first_trial_id == 5 and block.trial_ids == range(5, 15)
    assert [t.trial_id for t in protocol.trials] == [1, 2, 3, 4, 15]  # the link block after the budget
    assert protocol.planned_trial_ids == list(range(1, 16))
    kinds = ["fixed" if isinstance(i, TrialPlan) else "adaptive" for i in protocol.schedule]
    assert kinds == ["fixed"] * 4 + ["adaptive", "fixed"]
    assert protocol.as_metadata()["trials"] == "15"
    design = block.design
    assert (design.distance_min_m, design.distance_max_m, design.max_trials) == (0.03, 0.25, 10)
    assert (design.min_trials, design.startup_trials, design.estimator) == (10, 3, "auto")  # min(10, max)
    assert block.max_force_fraction == 0.8
    assert block.design.stop_scale_confidence == DEFAULT_STOP_SCALE_CONFIDENCE
    trial = block.trial(7, 0.03, 2)
    assert (trial.kind, trial.joint, trial.distance_m, trial.repeat, trial.block) == (
        "joint_estimation",
        1,
        0.03,
        2,
        1,
    )
    with pytest.raises(ValueError, match="outside"):
        block.trial(15, 0.03, 1)


def test_a_link_validation_block_may_take_its_estimates_from_an_adaptive_block():
    protocol = parse(ADAPTIVE, LINK)
    assert protocol.estimates_from == "run" and protocol.kinds == {"joint_estimation", "link_validation"}


def test_fixed_protocols_are_unchanged():
    protocol = load_protocol("protocols/joint_estimation.yaml", seed=3)
    assert protocol.adaptive == () and len(protocol.trials) == 24
    assert protocol.planned_trial_ids == list(range(1, 25))
    assert [item.trial_id for item in protocol.schedule] == list(range(1, 25))  # type: ignore[union-attr]


def test_the_shipped_adaptive_protocol_loads():
    protocol = load_protocol("protocols/joint_estimation_adaptive.yaml")
    (block,) = protocol.adaptive
    assert protocol.trials == () and block.design.max_trials == 24
    assert block.design.candidates_m[0] == 0.03 and block.design.candidates_m[-1] == 0.25


@pytest.mark.parametrize(
    ("blocks", "needles"),
    [
        ([adaptive(distances_m=[0.1])], ["blocks[0].distances_m", "not with design: adaptive"]),
        ([adaptive(repeats=3)], ["blocks[0].repeats", "allowed: distance_range_m"]),
        ([adaptive(distance_range_m=[0.25, 0.03])], ["blocks[0].distance_range_m", "shortest < longest"]),
        ([adaptive(distance_range_m=[0.0, 0.25])], ["blocks[0].distance_range_m[0]", "allowed"]),
        ([adaptive(distance_range_m=[0.03])], ["blocks[0].distance_range_m", "expected 2 numbers"]),
        ([adaptive(distance_range_m=None)], ["blocks[0].distance_range_m"]),
        ([adaptive(target_half_width_rel=0.9)], ["blocks[0].target_half_width_rel", "0.001", "0.5"]),
        ([adaptive(min_trials=12)], ["blocks[0].min_trials", "out of range", "2", "10"]),
        ([adaptive(startup_trials=1)], ["blocks[0].startup_trials", "out of range"]),
        ([adaptive(max_trials=1)], ["blocks[0].max_trials", "out of range"]),
        ([adaptive(estimator="best")], ["blocks[0].estimator", "allowed: paper, weighted, auto"]),
        ([adaptive(max_force_fraction=1.5)], ["blocks[0].max_force_fraction", "0.95"]),
        ([adaptive(min_spread_fraction=0.7)], ["blocks[0].min_spread_fraction", "0.5"]),
        ([adaptive(stop_scale_confidence=1)], ["blocks[0].stop_scale_confidence", "0.99"]),
        ([adaptive(distance_count=1)], ["blocks[0].distance_count", "out of range"]),
        ([adaptive(design="smart")], ["blocks[0].design", "allowed: fixed, adaptive"]),
        ([with_overrides(FIXED, {"max_trials": 5})], ["blocks[0].max_trials", "only with design: adaptive"]),
        ([with_overrides(LINK, {"design": "adaptive"})], ["blocks[0]", "design"]),
        ([adaptive(max_trials=1000)] * 11, ["max_trials", "at most 10000"]),
    ],
)
def test_bad_adaptive_blocks_are_refused_naming_the_field(blocks, needles):
    with pytest.raises(ConfigError) as info:
        parse(*blocks)
    message = str(info.value)
    assert message.startswith("p.yaml: "), message
    for needle in needles:
        assert needle in message, message


def test_bad_adaptive_block_exits_2_with_one_line(run_cli, protocol_file):
    path = protocol_file(adaptive_protocol(adaptive(target_half_width_rel=0)))
    result = run_cli("run", path, "--dry-run")
    assert result.code == 2 and result.out == ""
    lines = result.err.strip().splitlines()
    assert len(lines) == 1 and "p.yaml" in lines[0] and "blocks[0].target_half_width_rel" in lines[0]
    assert "allowed" in lines[0] and "Traceback" not in result.err


def test_dry_run_shows_the_startup_trials_then_the_adaptive_rest(run_cli, cli_json):
    result = run_cli("run", "protocols/joint_estimation_adaptive.yaml", "--dry-run")
    assert result.code == 0, result.err
    out = result.out
    assert "2 trials planned ahead" in out  # the shipped protocol's startup_trials
    assert "0.250 m" in out and "0.030 m" in out
    assert "trials 1, 2 are its start-up" in out and "then adaptive up to 24 trials" in out
    assert "below 56.0 N" in out  # 0.8 x max_force_n 70 N
    plan = cli_json("run", "protocols/joint_estimation_adaptive.yaml", "--dry-run", "--json")
    assert [t["distance_m"] for t in plan["trials"]] == [0.25, 0.03]
    (block,) = plan["adaptive"]
    assert block["max_trials"] == 24 and block["target_half_width_rel"] == 0.06
    assert block["max_slip_force_n"] == pytest.approx(56.0) and len(block["candidate_distances_m"]) == 8


def test_dry_run_of_a_fixed_protocol_has_no_adaptive_key(cli_json):
    plan = cli_json("run", "protocols/joint_estimation.yaml", "--dry-run", "--json")
    assert "adaptive" not in plan and len(plan["trials"]) == 24


@pytest.mark.slow  # a few trials on the byte-level simulated rig
def test_rig_run_on_the_simulated_rig_says_why_the_adaptive_block_stopped(run_cli, protocol_file, tmp_path):
    path = protocol_file(
        adaptive_protocol(adaptive(max_trials=4, min_trials=3, target_half_width_rel=0.5, steps=QUICK_STEPS))
    )
    result = run_cli("run", path, "--out", tmp_path / "out", "--run-id", "sim1")
    assert result.code == 0, result.err
    summary = result.out.splitlines()
    assert summary[0].startswith("run sim1: ") and "/4 trials done" in summary[0]
    stop = next(line for line in summary if line.startswith("adaptive design, block 0 (joint 1): stopped"))
    assert "target reached" in stop or "trial budget of 4 used" in stop
    assert "lack of fit" in stop
