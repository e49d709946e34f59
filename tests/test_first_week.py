"""First-week trips of a hardware rig: the shipped template against the shipped protocols, the up axis,
the line stiffness default, a run without a terminal, the calibration's wording for an inline cell."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from rig.hw.loadcell.driver import FIRMWARE_BAUD
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, StaleTimeoutFit, load_rig_config
from tests.helpers import smoke_protocol

REPO = Path(__file__).parent.parent
TEMPLATE = REPO / "protocols" / "rigs" / "hardware.example.yaml"
PROTOCOLS = sorted(
    p
    for p in (REPO / "protocols").glob("*.yaml")
    if str(yaml.safe_load(p.read_text()).get("format", "")).startswith("rig-protocol/")
)


def test_the_shipped_protocols_are_found() -> None:
    names = {p.stem for p in PROTOCOLS}
    assert {"joint_estimation", "joint_estimation_adaptive", "link_validation", "smoke"} <= names
    assert "example_link" not in names  # a link file, not a protocol


TEMPLATE_SEGMENTS = "segment_lengths_m: [0.04, 0.04, 0.04, 0.04, 0.04, 0.04, 0.04, 0.04]"


def _template_for(protocol: Path, tmp_path: Path) -> Path:
    """The template, or for a link-2 protocol (10 joints) a lab's copy of it with link 2's ten segments."""
    if "link2" not in protocol.stem:
        return TEMPLATE
    text = TEMPLATE.read_text()
    assert TEMPLATE_SEGMENTS in text
    copy = tmp_path / "hardware-link2.yaml"
    copy.write_text(text.replace(TEMPLATE_SEGMENTS, "segment_lengths_m: [" + ", ".join(["0.04"] * 10) + "]"))
    return copy


@pytest.mark.parametrize("protocol", PROTOCOLS, ids=lambda p: p.stem)
def test_template_dry_runs_pass(protocol: Path, run_cli: Callable[..., Any], tmp_path: Path) -> None:
    result = run_cli("run", protocol, "--rig", _template_for(protocol, tmp_path), "--dry-run")
    assert result.code == 0, result.err
    assert "nothing was moved" in result.out
    assert "does not exist yet" in result.out  # the calibration is made after the plan, and said so


def test_link2_protocol_on_the_link1_template_says_the_count_is_the_rig_configs(
    run_cli: Callable[..., Any],
) -> None:
    result = run_cli("run", REPO / "protocols" / "link_validation_link2.yaml", "--rig", TEMPLATE, "--dry-run")
    assert result.code == 2 and result.err.count("\n") == 1  # one line, no traceback
    assert "configurations_deg[0].angles: expected 8 numbers" in result.err
    assert f"{TEMPLATE} (article.segment_lengths_m: 8 segments), got 10" in result.err


def test_a_joint_beyond_the_rig_configs_link_says_where_the_count_comes_from(
    run_cli: Callable[..., Any], tmp_path: Path
) -> None:
    protocol = tmp_path / "j9.yaml"
    protocol.write_text(smoke_protocol(block={"joint": 9}))
    result = run_cli("run", protocol, "--rig", TEMPLATE, "--dry-run")
    assert result.code == 2 and result.err.count("\n") == 1
    assert f"blocks[0].joint: 9; allowed: 1..8, the joints of the link in {TEMPLATE} (article" in result.err


def test_template_dry_run_json_carries_the_note(cli_json: Callable[..., Any]) -> None:
    out = cli_json("run", REPO / "protocols" / "smoke.yaml", "--rig", TEMPLATE, "--dry-run", "--json")
    assert all(check["ok"] for check in out["limit_checks"])
    assert any("rig calibrate" in note for note in out["notes"])


def test_a_broken_calibration_file_is_still_refused(tmp_path: Path, run_cli: Callable[..., Any]) -> None:
    rig = tmp_path / "hw.yaml"
    rig.write_text(TEMPLATE.read_text())
    (tmp_path / "loadcell-cal.json").write_text("{not json")
    assert run_cli("run", REPO / "protocols" / "smoke.yaml", "--rig", rig, "--dry-run").code == 2


def test_same_up_axis_in_both_shipped_configs() -> None:
    template = load_rig_config(TEMPLATE).article
    simulated = load_rig_config(DEFAULT_RIG_CONFIG).article
    assert template.direction == simulated.direction == (0.0, -1.0, 0.0)
    assert template.point_m == simulated.point_m


def test_line_stiffness_default_is_thin_nylon(write_file: Callable[[str, str], Path]) -> None:
    data = yaml.safe_load(TEMPLATE.read_text())
    data.pop("line_stiffness_n_per_m")
    data["loadcell"].pop("calibration")
    config = load_rig_config(write_file(yaml.safe_dump(data), "rig.yaml"))
    assert config.line_stiffness_n_per_m == 200.0


def test_ramp_timeout_at_the_default_stiffness_covers_a_short_lever(cli_json: Callable[..., Any]) -> None:
    """The issue's case: 200 N/m of line against a 2000 N/m nominal timed the first trial out.

    With the nominal at 200 N/m the slow ramp to the protocol's maximum force is timed for 200 N/m,
    three times over (rig.runner.ramp): 3 x 70 N / (200 N/m x 0.01 m x 0.08 rad/s) = 1312 s, more
    than the 320 s the first trial needed on that line.
    """
    out = cli_json(
        "run", REPO / "protocols" / "joint_estimation.yaml", "--rig", TEMPLATE, "--dry-run", "--json"
    )
    assert "200 N/m" in out["duration_assumption"]
    slow_ramp_s = 70.0 / (200.0 * 0.010 * 0.08)
    assert 3 * slow_ramp_s > 320.0


def test_hardware_run_without_a_terminal_is_refused_before_anything_moves(
    tmp_path: Path, run_cli: Callable[..., Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    import io
    import sys

    rig = tmp_path / "hw.yaml"
    rig.write_text(TEMPLATE.read_text())
    from rig.hw.loadcell.calibration import Calibration

    Calibration(1 / 80000, 120000, None, 9.80665, "2026-11-27", "x", "rig-lc1").save(
        tmp_path / "loadcell-cal.json"
    )
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    out = tmp_path / "logs"
    result = run_cli("run", REPO / "protocols" / "smoke.yaml", "--rig", rig, "--out", out)
    assert result.code == 2
    assert "ssh -t" in result.err and "prompt" in result.err
    assert not out.exists()  # nothing written, nothing opened


def test_calibration_prompts_fit_an_inline_cell(tmp_path: Path, run_cli: Callable[..., Any]) -> None:
    result = run_cli("calibrate", "--sim", "--yes", "--reference-kg", "1", "--out", tmp_path / "cal.json")
    assert result.code == 0, result.err
    assert "hang the 1 kg mass" in result.out and "reference gauge" in result.out
    assert "over the pulley" in result.out


FIRMWARE_SKETCH = REPO / "firmware" / "rig_hx711" / "rig_hx711.ino"


def test_template_fits_the_projects_firmware() -> None:
    """The issue's case: the template had 921600 baud, no rate, a 0.2 s stale timeout (2 periods at 10/s)."""
    sketch_baud = re.search(r"^#define RIG_BAUD (\d+)", FIRMWARE_SKETCH.read_text(), re.MULTILINE)
    assert sketch_baud is not None
    config = load_rig_config(TEMPLATE)
    assert config.loadcell.baud == int(sketch_baud.group(1)) == FIRMWARE_BAUD
    assert config.loadcell.rate_hz == 10.0  # an HX711 breakout's RATE pin low
    assert StaleTimeoutFit(config.limits.stale_timeout_s, config.loadcell.rate_hz).ok


@pytest.mark.parametrize(("stale_timeout_s", "fits"), [(0.2, False), (0.3, True)])
def test_dry_run_and_rig_check_refuse_the_same_stale_timeout(
    stale_timeout_s: float, fits: bool, tmp_path: Path, run_cli: Callable[..., Any]
) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text(
        "extends: simulated\nsimulation: {loadcell_rate_hz: 10}\n"
        f"limits: {{stale_timeout_s: {stale_timeout_s}}}\n"
    )
    dry = run_cli("run", REPO / "protocols" / "smoke.yaml", "--rig", rig, "--dry-run")
    check = run_cli("check", "--rig", rig, "--only", "loadcell", "--json")
    rows = {row["check"]: row for row in json.loads(check.out)["rows"]}
    verdict = rows["stale timeout holds the sample period"]["verdict"]
    if fits:
        assert dry.code == 0 and verdict == "pass", dry.err
        return
    assert dry.code == 2 and verdict == "fail"
    assert dry.err.count("\n") == 1 and "Traceback" not in dry.err
    assert f"{rig}: limit check failed" in dry.err and "limits.stale_timeout_s 0.2 s (2.0 periods)" in dry.err
