"""Nobody waits beside a loaded line: after a slip the line is released before anyone is asked.

A person asked which joint moved leans in to look. The run must have released the line before it
asks, however long the person then takes; the time loaded after a slip is the rig's, bounded by
`limits.max_loaded_after_slip_s` (2 s by default). A protocol cannot put a step between the ramp
and the unload.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from rig.errors import InputError
from rig.hw.seams import ConfigurationReading, ConfigurationSource, MeasurementRequest
from rig.inputs.protocol import load_protocol
from rig.log.reading.reader import read_run
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress
from rig.sim.physics.world import SimWorld
from tests.helpers import shipped_block, smoke_protocol

ROOT = Path(__file__).resolve().parent.parent
SMOKE = ROOT / "protocols" / "smoke.yaml"
SLACK_N = 0.5
PERSON_S = 60.0  # how long the person takes to answer


class SlowPerson:
    """Answers which joint moved after `PERSON_S` of looking (the rig ticking meanwhile).

    Records the true tension of the line at every control period while the question is open.
    """

    def __init__(self, inner: ConfigurationSource, world: SimWorld, clock_ns) -> None:
        self.inner = inner
        self.world = world
        self.clock_ns = clock_ns
        self.request: MeasurementRequest | None = None
        self.asked_at_ns: list[int] = []
        self.tension_while_asked_n: list[float] = []

    def prepare(self, request: MeasurementRequest) -> None:
        self.request = request

    def measure(self) -> ConfigurationReading:
        request = self.request
        if request is not None and request.after_slip:
            self.asked_at_ns.append(self.clock_ns())
            end_ns = self.clock_ns() + round(PERSON_S * 1e9)
            while self.clock_ns() < end_ns:
                self.tension_while_asked_n.append(self.world.tension_n)
                request.keep_alive()
        return self.inner.measure()


def test_the_line_is_slack_before_anyone_is_asked_which_joint_moved(tmp_path):
    prepared = prepare_run(RunRequest(SMOKE, None, tmp_path, seed=0, run_id="slow-person"))
    sim = open_simulated_rig(prepared)
    session = sim.session
    assert session.configuration is not None
    person = SlowPerson(session.configuration, sim.devices.world, session.clock.time_ns)
    asked_rig = dataclasses.replace(sim, session=dataclasses.replace(session, configuration=person))
    report = execute_run(prepared, asked_rig, SilentProgress())
    assert report.exit_code == 0 and [t.outcome for t in report.trials] == ["slip", "slip"]
    # Both slips were asked about, each for a minute, and the line was slack all the while.
    assert len(person.asked_at_ns) == 2
    assert len(person.tension_while_asked_n) > 2 * 1000
    assert max(person.tension_while_asked_n) < SLACK_N
    # The line was loaded for at most 2 s after each slip (the rig's hold and release, not the
    # person's minute): detection to the question, by when the line was slack.
    slips = read_run(tmp_path).topic("/rig/slip")
    detections_ns = [
        int(sec * 1e9) + int(ns)
        for sec, ns in zip(slips["detection.sec"], slips["detection.nsec"], strict=True)
    ]
    loaded_s = [
        (asked - detected) / 1e9 for asked, detected in zip(person.asked_at_ns, detections_ns, strict=True)
    ]
    assert all(0 < s <= 2.0 for s in loaded_s), loaded_s


def test_a_step_between_the_ramp_and_the_unload_is_refused(tmp_path):
    steps = shipped_block("smoke")["steps"]
    steps.insert(steps.index("unload"), "prompt")
    path = tmp_path / "p.yaml"
    path.write_text(smoke_protocol(block={"steps": steps}), encoding="utf-8")
    with pytest.raises(
        InputError, match=r"p\.yaml: blocks\[0\]\.steps: an 'unload' step must come right after"
    ):
        load_protocol(path, seed=0)


def test_the_dry_run_warns_when_a_slip_would_keep_the_line_loaded_beyond_the_bound(cli_json):
    # The template's soft line (200 N/m on a 10 mm drum: 2 N/rad) pays a 35 N slip out in 8.75 s at
    # 2 rad/s; the simulated rig's 5000 N/m line in 0.35 s.
    template = ROOT / "protocols" / "rigs" / "hardware.example.yaml"
    soft = cli_json("run", SMOKE, "--rig", template, "--dry-run", "--json")
    assert any("would keep the line loaded about 8.9 s" in w for w in soft["warnings"]), soft.get("warnings")
    stiff = cli_json("run", SMOKE, "--dry-run", "--json")
    assert not any("line loaded" in w for w in stiff.get("warnings", []))


def test_the_dry_run_warns_when_nobody_is_asked_to_move_the_hook(cli_json, tmp_path):
    """The rig cannot move the hook: a joint-estimation block with several distances and no prompt
    runs every trial wherever the hook hangs (the simulated person, like a real one, moves it only
    when asked). The shipped protocols prompt, so they are not warned about."""
    steps = shipped_block("smoke")["steps"]
    assert steps[0] == "prompt"
    quiet = tmp_path / "no-prompt.yaml"
    quiet.write_text(smoke_protocol(block={"steps": steps[1:]}), encoding="utf-8")
    warned = cli_json("run", quiet, "--dry-run", "--json")
    assert any("nobody is asked to move the hook" in w for w in warned.get("warnings", [])), warned
    for protocol in ("smoke", "joint_estimation", "joint_estimation_adaptive", "link_validation"):
        plan = cli_json("run", ROOT / "protocols" / f"{protocol}.yaml", "--dry-run", "--json")
        assert not any("hook" in w for w in plan.get("warnings", [])), (protocol, plan.get("warnings"))
