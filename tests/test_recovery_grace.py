"""`limits.recovery_grace_s`: how long the rig has after a device fault's release to answer healthily again.

On the simulated rig in virtual time: the load cell unplugged mid-ramp never comes back, so the run
waits the whole grace after the release before it stops (exit 1), the servos releasing the line.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.errors import ConfigError
from rig.inputs.rig_config import load_rig_config
from rig.log.reading.reader import read_run
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress

ROOT = Path(__file__).resolve().parents[1]
UNPLUGGED = """\
extends: simulated
name: unplugged
simulation:
  faults:
    - {device: loadcell, kind: disconnect, at_s: 3.0}
"""


@pytest.mark.parametrize(
    ("limits", "grace_s"), [("", 2.0), ("limits: {recovery_grace_s: 0.5}\n", 0.5)], ids=["default", "0.5 s"]
)
def test_a_fault_that_does_not_clear_is_given_the_configured_grace(
    tmp_path: Path, limits: str, grace_s: float
):
    rig = tmp_path / "rig.yaml"
    rig.write_text(UNPLUGGED + limits)
    request = RunRequest(
        protocol_path=ROOT / "protocols" / "smoke.yaml", rig_path=rig, out_dir=tmp_path, seed=0, run_id="r"
    )
    prepared = prepare_run(request)
    report = execute_run(prepared, open_simulated_rig(prepared), SilentProgress())
    assert report.exit_code == 1 and "NotConnectedError" in (report.reason or "")
    assert report.safe_state_verified, report.reason  # the servos released the line
    notes = read_run(tmp_path / "r.mcap").topic("/rig/log")
    times_ns = dict(zip(notes["message"], notes["log_time_ns"], strict=True))
    (released_ns,) = [t for m, t in times_ns.items() if m.startswith("trial 1 stopped:")]
    given_up = f"trial 1: the rig did not recover within {grace_s:g} s"
    assert given_up in times_ns, list(times_ns)
    # The release takes the winch back first (about a second here), then the grace is waited.
    waited_s = (times_ns[given_up] - released_ns) / 1e9
    assert grace_s < waited_s < grace_s + 1.5


@pytest.mark.parametrize("value", ["0", "61", "-1", "soon"])
def test_a_grace_out_of_range_is_refused_naming_the_field(tmp_path: Path, value: str):
    rig = tmp_path / "rig.yaml"
    rig.write_text(f"{UNPLUGGED}limits: {{recovery_grace_s: {value}}}\n")
    with pytest.raises(ConfigError, match=r"rig.yaml: limits.recovery_grace_s: .*allowed.*0.1.*60"):
        load_rig_config(rig)
