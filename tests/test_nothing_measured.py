"""A run that measured nothing fails: every trial done without one usable slip is exit 1, saying why."""

from __future__ import annotations

from tests.helpers import smoke_protocol


def test_a_run_whose_trials_all_end_without_a_slip_exits_1_naming_the_cause(tmp_path, run_cli):
    # The joints hold about 15 N at these distances; a ramp capped at 5 N never sees them slip.
    protocol = tmp_path / "low.yaml"
    protocol.write_text(smoke_protocol(ramp={"max_force_n": 5.0}))
    result = run_cli("run", protocol, "--out", tmp_path / "out", "--run-id", "low")
    assert result.code == 1
    assert (
        "FAILED: no trial gave a usable slip (2 no_slip of 2): no joint slipped below ramp.max_force_n"
        in (result.err)
    )
    assert "--resume" not in result.err  # every trial is done: nothing to resume
    assert '"status": "completed"' in (tmp_path / "out" / "low.journal.json").read_text(encoding="utf-8")
