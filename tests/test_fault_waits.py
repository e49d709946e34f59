"""The waits after a device fault that a rig config sets.

`limits.recovery_grace_s`, `servos.release_margin_s`, `loadcell.slack_settle_s`. On the simulated
rig in virtual time, with a fault 3 s into the smoke protocol (mid-ramp) that never clears: the run
releases the line, waits the grace for the rig to answer healthily again and stops (exit 1). The
release waits for the winch twice its travel time and the margin; with the winch back, the safe
state waits the settle time for the cell to read the line slack.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.errors import ConfigError
from rig.inputs.rig_config import load_rig_config
from rig.log.reading.reader import read_run
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunReport, RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress

ROOT = Path(__file__).resolve().parents[1]


def _fault_config(device: str, kind: str) -> str:
    """The built-in simulated rig with one fault of `device` 3 s into the run, for good."""
    fault = f"{{device: {device}, kind: {kind}, at_s: 3.0}}"
    return f"extends: simulated\nname: f\nsimulation:\n  faults:\n    - {fault}\n"


def _run(tmp_path: Path, config: str) -> tuple[RunReport, dict[str, int]]:
    """The smoke protocol on `config`; the report and each note's log time [ns]."""
    rig = tmp_path / "rig.yaml"
    rig.write_text(config)
    request = RunRequest(
        protocol_path=ROOT / "protocols" / "smoke.yaml", rig_path=rig, out_dir=tmp_path, seed=0, run_id="r"
    )
    prepared = prepare_run(request)
    report = execute_run(prepared, open_simulated_rig(prepared), SilentProgress())
    notes = read_run(tmp_path / "r.mcap").topic("/rig/log")
    return report, dict(zip(notes["message"], notes["log_time_ns"], strict=True))


def _stopped_ns(notes: dict[str, int]) -> int:
    (stopped_ns,) = [t for m, t in notes.items() if m.startswith("trial 1 stopped:")]
    return stopped_ns


def test_a_cell_gone_for_good_is_given_the_configured_grace_then_the_configured_settle_time(tmp_path: Path):
    # The cell unplugged mid-ramp: the release has the winch back after about a second, then the
    # run waits the grace for the rig to answer healthily, stops, and its safe state waits the
    # settle time for a sample that never comes. Only the two settings differ between the runs.
    waited_s = {}
    for grace_s, settle_s in ((None, None), (0.5, 0.2)):
        config = _fault_config("loadcell", "disconnect")
        if grace_s is not None:
            config += f"limits: {{recovery_grace_s: {grace_s}}}\nloadcell: {{slack_settle_s: {settle_s}}}\n"
        (tmp_path / str(grace_s)).mkdir()
        report, notes = _run(tmp_path / str(grace_s), config)
        assert report.exit_code == 1 and "NotConnectedError" in (report.reason or "")
        assert report.safe_state_verified, report.reason  # the servos released the line
        assert "the load cell gave no reading once the winch was back" in (report.reason or "")
        given_up = f"trial 1: the rig did not recover within {grace_s or 2.0:g} s"
        (stopped_ns,) = [t for m, t in notes.items() if m.startswith("run stopped:")]
        (safe_ns,) = [t for m, t in notes.items() if m.startswith("safe state:")]
        waited_s[grace_s] = ((notes[given_up] - _stopped_ns(notes)) / 1e9, (safe_ns - stopped_ns) / 1e9)
    (grace_default_s, settle_default_s), (grace_short_s, settle_short_s) = waited_s[None], waited_s[0.5]
    assert 2.0 < grace_default_s < 2.0 + 1.5  # the release (about a second), then the grace
    assert grace_default_s - grace_short_s == pytest.approx(2.0 - 0.5, abs=0.05), waited_s
    assert settle_default_s - settle_short_s == pytest.approx(1.0 - 0.2, abs=0.05), waited_s


def test_the_release_waits_for_a_silent_winch_its_travel_time_and_the_configured_margin(tmp_path: Path):
    # The winch's replies lost: the release is never read back; without patience it waits its
    # deadline, then the grace. Only the margin differs between the runs.
    waited_s = {}
    for margin_s in (None, 0.5):
        margin = "" if margin_s is None else f", release_margin_s: {margin_s}"
        config = _fault_config("winch", "silent") + f"servos: {{release_patience_s: 0{margin}}}\n"
        (tmp_path / str(margin_s)).mkdir()
        report, notes = _run(tmp_path / str(margin_s), config)
        assert report.exit_code == 1 and not report.safe_state_verified
        assert "servos.release_patience_s 0 s" in (report.reason or "")
        waited_s[margin_s] = (notes["trial 1: the rig did not recover within 2 s"] - _stopped_ns(notes)) / 1e9
    assert waited_s[None] - waited_s[0.5] == pytest.approx(2.0 - 0.5, abs=0.05)


@pytest.mark.parametrize(
    ("field", "value"),
    [("limits.recovery_grace_s", v) for v in ("0", "61", "-1", "soon")]
    + [("servos.release_margin_s", v) for v in ("0.05", "61", "nan")]
    + [("loadcell.slack_settle_s", v) for v in ("0", "100")],
)
def test_a_wait_out_of_range_is_refused_naming_the_field(tmp_path: Path, field: str, value: str):
    section, key = field.split(".")
    rig = tmp_path / "rig.yaml"
    rig.write_text(f"{_fault_config('loadcell', 'disconnect')}{section}: {{{key}: {value}}}\n")
    with pytest.raises(ConfigError, match=rf"rig.yaml: {field}: .*allowed.*0.1.*60"):
        load_rig_config(rig)
