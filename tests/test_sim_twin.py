"""The twin over the ports (`rig sim rig`, rig/sim/twin.py) and its simulated hand (rig/sim/twin_hand.py).

The fast tests build the twin without serving it and move its clock by hand; the rehearsal serves it
on ptys in real time and runs a lab's bring-up against it with the unchanged hardware template.
"""

from __future__ import annotations

import io
import json
import os
import pty
import select
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import serial
import yaml
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from rig.errors import ConfigError, InputError
from rig.inputs.protocol import load_protocol
from rig.inputs.rig_config import load_rig_config
from rig.log.reading.reader import read_run
from rig.sim.dxl.bus_pty_server import IDLE_POLL_MS
from rig.sim.kinds import ArticleSetup, SlipKind
from rig.sim.pty_port import Stop
from rig.sim.twin import TICK_S, build_twin, serve_twin
from rig.sim.twin_console import ReferenceLoad, run_console
from rig.sim.twin_hand import SLACK_DWELL_S
from rig.sim.twin_ports import PortAction, PortCondition, TwinDevice
from rig.vocabulary import TrialKind
from tests.helpers import build_firmware

ROOT = Path(__file__).resolve().parent.parent
TEMPLATE = ROOT / "protocols" / "rigs" / "hardware.example.yaml"
SMOKE = ROOT / "protocols" / "smoke.yaml"
RATE_HZ = 80  # the rehearsal's load cell (docstring of the rehearsal test)
LED = 65  # the servos' LED register (X-series control table)
# The rehearsal waits in real time for each of these, three opens of the cell and a jog each way:
# a board reset shorter than an Uno's optiboot wait (about 1.5 s, docs/hardware.md) shows the same
# reset and banner; the jog only needs to pass the twin's 0.5 rad of slack and the 5 N rise the
# right way (0.097 rev, reeled in on the twin in virtual time), and goes the whole travel (there and
# back) the wrong way.
DTR_RESET_S = 0.5
JOG_TRAVEL_REV = 0.15


def _hardware_config(tmp_path: Path, simulation: str = "simulation:\n  winch_reversed: true\n") -> Path:
    """The lab's template with its ports and calibration file in tmp_path, and a `simulation:` section."""
    text = TEMPLATE.read_text(encoding="utf-8")
    for old, new in (
        ("port: /dev/ttyUSB0", f"port: {tmp_path / 'dxl'}"),
        ("port: /dev/ttyACM0", f"port: {tmp_path / 'cell'}"),
        ("calibration: loadcell-cal.json", "calibration: cal.json"),
    ):
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "lab-rig.yaml"
    path.write_text(text + simulation, encoding="utf-8")
    return path


def config_joints(twin) -> int:
    return twin.world.preset.joint_count


def _slack_for(twin, seconds: float) -> None:
    twin.clock.advance_ns(round(seconds * 1e9))
    assert twin.world.tension_n == 0.0


def test_the_hand_moves_the_hook_only_after_a_slip_and_a_slack_line(tmp_path):
    config = load_rig_config(_hardware_config(tmp_path))
    protocol = load_protocol(SMOKE, joint_count=config.article.joint_count)
    twin = build_twin(config, protocol=protocol)
    world = twin.world
    assert world.setup == ArticleSetup.SPECIMEN and world.hook_distance_m == 0.1
    first = world.draw_trial()  # what the first trial's loading draws
    assert (first.kind, first.distance_m, first.specimen_joint) == (TrialKind.JOINT_ESTIMATION, 0.1, 1)
    _slack_for(twin, 3.0)  # a slack line alone (a check, a tare) is no reason to touch the hook
    assert world.hook_distance_m == 0.1
    world.open_slip(1, 16.0, 16.0, SlipKind.SUDDEN, world.now_ns)  # the first trial's slip
    _slack_for(twin, SLACK_DWELL_S / 2)
    assert world.hook_distance_m == 0.1  # not yet: a careful person waits
    _slack_for(twin, SLACK_DWELL_S)
    assert world.hook_distance_m == 0.2
    assert world.draw_trial().capacity_factors != first.capacity_factors  # a fresh draw


def test_the_twins_line_is_as_stiff_as_the_config_says(tmp_path):
    """`rig check --move --write` on the twin must find the lab's own stiffness, not the preset's."""
    config = load_rig_config(_hardware_config(tmp_path))
    assert config.line_stiffness_n_per_m == 200.0  # the template's
    assert build_twin(config).world.line.stiffness_n_per_m == 200.0


def test_without_a_protocol_the_hand_sets_up_link_validation_on_the_straight_link(tmp_path):
    twin = build_twin(load_rig_config(_hardware_config(tmp_path)))
    assert twin.world.setup == ArticleSetup.LINK and twin.world.hook_distance_m is None
    assert twin.world.link.planar_joint_angles() == (0.0,) * config_joints(twin)
    assert twin.world.draw_trial().kind == TrialKind.LINK_VALIDATION


def test_a_fault_of_the_host_or_the_logger_is_refused_naming_it(tmp_path):
    faults = "simulation:\n  faults:\n    - {device: host, kind: pause, at_s: 1, duration_s: 1}\n"
    config = load_rig_config(_hardware_config(tmp_path, faults))
    with pytest.raises(ConfigError, match=r"lab-rig.yaml: simulation.faults\[0\].device: host; allowed"):
        build_twin(config)


@pytest.mark.subprocess
def test_a_port_that_is_not_a_symlink_is_refused_and_left_alone(tmp_path):
    path = _hardware_config(tmp_path)
    (tmp_path / "cell").write_text("a lab's file\n")
    done = subprocess.run(
        [sys.executable, "-m", "rig.cli", "sim", "rig", "--rig", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "lab-rig.yaml: loadcell.port:" in done.stderr
    assert "not a symlink" in done.stderr
    assert (tmp_path / "cell").read_text() == "a lab's file\n"
    assert not (tmp_path / "dxl").exists()  # the servo link made first was removed again


def _firmware_harness() -> Path | None:
    """The built firmware harness where the AVR toolchain and simavr are installed, else None."""
    from tests.test_firmware_simavr import HARNESS, _missing_tools

    if _missing_tools() is not None:
        return None
    build = build_firmware()
    assert build.returncode == 0, build.stdout[-2000:] + build.stderr[-2000:]
    return HARNESS


def _rig(*args: str, stdin: int | None = None) -> subprocess.CompletedProcess[str]:
    """`rig ARGS` to its end; one that hangs is killed after 90 s and fails with its stderr."""
    command = [sys.executable, "-m", "rig.cli", *args]
    with subprocess.Popen(
        command, stdin=stdin, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    ) as proc:
        try:
            out, err = proc.communicate(timeout=90)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
            pytest.fail(f"rig {' '.join(args)} hung: {err[-2000:]}")
    return subprocess.CompletedProcess(command, proc.returncode, out, err)


@pytest.mark.pty
@pytest.mark.subprocess
@pytest.mark.slow
def test_rehearsal_check_move_write_then_smoke_run_on_the_twin_of_a_reversed_winch(tmp_path):
    """A lab's bring-up on the twin (docs/hardware.md, "Rehearse before the rig exists"), 25-50 s.

    Where the AVR toolchain and simavr are installed (CI installs them) the load cell is the built
    firmware image under simavr, reset on every open (`DTR_RESET_S`); else the emulator.
    The cell runs at 80/s (the HX711's RATE pin high): at the template's 10/s the smoke protocol's
    detector (drop_fraction 0.15) missed a 20 % slip whose peak fell between samples in 1 of 4
    rehearsals (the sampled drop was 14 %), and caught the third slip of the trial 0.7 s later.
    """
    firmware = _firmware_harness()
    simulation = "simulation:\n  winch_reversed: true\n"
    if firmware is not None:
        simulation += f"  loadcell_dtr_reset_s: {DTR_RESET_S}\n"
    path = _hardware_config(tmp_path, simulation)
    text = path.read_text()
    assert "  rate_hz: 10 " in text
    text = text.replace("  rate_hz: 10 ", f"  rate_hz: {RATE_HZ} ")
    # A lab with a stiff line (a short steel one): the twin's line is the config's, and the smoke
    # protocol's speeds suit 5000 N/m (the template's 200 N/m would take minutes of real time).
    assert "line_stiffness_n_per_m: 200 " in text
    text = text.replace("line_stiffness_n_per_m: 200 ", "line_stiffness_n_per_m: 5000 ")
    # The twin, simavr and the CLI share two cores with the rest of the suite: a bus reply may miss
    # the SDK's 34 ms packet timeout while the twin's thread waits for a core (a real adapter has
    # no such contention). Five retries ride out about 0.2 s of that.
    assert "  retries: 2 " in text
    path.write_text(text.replace("  retries: 2 ", "  retries: 5 "))
    truth_path = tmp_path / "truth.json"
    twin = subprocess.Popen(
        [sys.executable, "-m", "rig.cli", "sim", "rig", "--rig", str(path), "--protocol", str(SMOKE),
         "--calibration-out", str(tmp_path / "cal.json"), "--truth-out", str(truth_path),
         *([] if firmware is None else ["--firmware", str(firmware)])],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert twin.stdout is not None
        assert twin.stdout.readline().startswith(f"SERVOS {tmp_path / 'dxl'} /dev/")
        cell = twin.stdout.readline()
        assert cell.startswith(f"LOADCELL {tmp_path / 'cell'} /dev/")
        assert cell.endswith(" firmware\n") == (firmware is not None)
        jog = ("--move", "--jog-travel-rev", str(JOG_TRAVEL_REV), "--window-s", "1", "--json")
        first = _rig("check", "--rig", str(path), "--write", *jog)
        assert first.returncode == 1, first.stderr  # the reversed winch, found by the jog
        assert yaml.safe_load(path.read_text())["reel_direction"] == -1, first.stdout
        second = _rig("check", "--rig", str(path), *jog)
        assert second.returncode == 0 and json.loads(second.stdout)["counts"]["fail"] == 0, second.stdout
        operator, terminal = pty.openpty()  # the person at the terminal confirms the hook placements
        os.write(operator, b"\n" * 4)  # both, and any prompt a recovery would add
        run = _rig("run", str(SMOKE), "--rig", str(path), "--json", "--out", str(tmp_path / "out"),
                   "--run-id", "smoke", stdin=terminal)  # fmt: skip
        os.close(operator)
        os.close(terminal)
    finally:
        twin.terminate()
        _, err = twin.communicate(timeout=10)
    assert twin.returncode == 0, err
    assert not (tmp_path / "dxl").exists() and not (tmp_path / "cell").exists()
    report = json.loads(run.stdout)
    assert run.returncode == 0, run.stderr
    assert report["safe_state_verified"] is True and report["completed"] == 2
    truth = json.loads(truth_path.read_text())["world"]
    assert [t["distance_m"] for t in truth["trials"][:2]] == [0.1, 0.2]  # the hand moved the hook
    period_ns = 1e9 / RATE_HZ
    slips = read_run(tmp_path / "out" / "smoke.mcap").topic("/rig/slip")
    # The detector's onset (the peak sample) and the sample that fired (by design two samples on).
    onsets_ns = [s * 10**9 + n for s, n in zip(slips["onset.sec"], slips["onset.nsec"], strict=True)]
    fired_ns = [s * 10**9 + n for s, n in zip(slips["detection.sec"], slips["detection.nsec"], strict=True)]
    for trial in report["trials"]:
        # The world's slips in the trial's (last) attempt: a bus timeout under load makes the run
        # repeat a trial, by when the hand has set up the next one; the first slip is the trial's
        # (a joint that re-sticks while the winch still reels slips again).
        start_ns, end_ns = trial["start_time_ns"], trial["end_time_ns"]
        (true_trial, true_ns), *_ = [
            (t, e["onset_time_ns"])
            for t in truth["trials"]
            for e in t["slip_events"]
            if start_ns <= e["onset_time_ns"] <= end_ns
        ]
        assert trial["outcome"] == "slip"
        assert trial["peak_force_n"] == pytest.approx(true_trial["slip_force_n"], rel=0.03)
        ((onset_ns, fired_at_ns),) = [
            (o, f) for o, f in zip(onsets_ns, fired_ns, strict=True) if start_ns <= f <= end_ns
        ]
        assert abs(onset_ns - true_ns) <= 2 * period_ns, (onset_ns - true_ns) / 1e6
        assert fired_at_ns > true_ns


def test_the_console_hangs_and_unhangs_a_reference_mass():
    load = ReferenceLoad()
    out = io.StringIO()
    run_console(["hang 1.5\n", "\n", "hang lots\n", "hang -1\n", "jump\n"], load, out)
    assert load.read_n() == pytest.approx(1.5 * 9.80665)
    run_console(["unhang\n"], load, out)
    assert load.read_n() == 0.0
    lines = out.getvalue().splitlines()
    assert lines[0] == "hanging 1.5 kg: 14.710 N in the line"
    assert lines[1:3] == [f"hang {m}: allowed: a mass in kg from 0 to 1000" for m in ("lots", "-1")]
    assert lines[3].startswith("jump: commands: `hang KG`")


@pytest.mark.pty
@pytest.mark.subprocess
@pytest.mark.slow
def test_rig_calibrate_on_the_twin_with_a_mass_hung_at_its_console(tmp_path):
    """`rig calibrate --rig` against the twin finds the twin's own calibration (about 5 s)."""
    path = _hardware_config(tmp_path)
    twin = subprocess.Popen(
        [sys.executable, "-m", "rig.cli", "sim", "rig", "--rig", str(path),
         "--calibration-out", str(tmp_path / "ideal.json")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    calibrate = None
    try:
        assert twin.stdout is not None and twin.stdin is not None
        assert twin.stdout.readline().startswith("SERVOS") and twin.stdout.readline().startswith("LOADCELL")
        # The twin's hung mass pulls at once (a person's takes a while to stop swinging: the 2 s
        # default); half a second before the confirmation and half after it are plenty here.
        calibrate = subprocess.Popen(
            [sys.executable, "-m", "rig.cli", "calibrate", "--rig", str(path), "--reference-kg", "1.0",
             "--settle-s", "0.5"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        )  # fmt: skip
        assert calibrate.stdin is not None and calibrate.stdout is not None
        seen = _until(calibrate.stdout, b"Press Enter", b"")  # step 1: the line slack
        calibrate.stdin.write(b"\n")
        calibrate.stdin.flush()
        seen = _until(calibrate.stdout, b"Press Enter", seen.split(b"Press Enter", 1)[1])  # step 2
        twin.stdin.write("hang 1.0\n")
        twin.stdin.flush()
        time.sleep(0.5)  # the mass comes to rest
        calibrate.stdin.write(b"\n")
        calibrate.stdin.flush()
        calibrate.communicate(timeout=60)
        assert calibrate.returncode == 0
    finally:
        if calibrate is not None and calibrate.poll() is None:
            calibrate.kill()
        twin.terminate()
        twin.communicate(timeout=10)
    found = json.loads((tmp_path / "cal.json").read_text())
    ideal = json.loads((tmp_path / "ideal.json").read_text())
    assert found["factor_n_per_count"] == pytest.approx(ideal["factor_n_per_count"], rel=0.002)
    # The offset is a mean of the cell's samples at rest, with 400 counts RMS of noise each: within
    # 4 standard errors of a mean of 10 or more (a loaded machine lets fewer samples through; 259
    # counts off was seen at load 10, 2 standard errors of 10 samples).
    assert found["offset_counts"] == pytest.approx(ideal["offset_counts"], abs=500)


def _until(stream, word: bytes, seen: bytes, timeout_s: float = 30.0) -> bytes:
    """Read `stream` until `word` is in what was read after `seen`; returns all of it."""
    deadline = time.monotonic() + timeout_s
    while word not in seen:
        ready, _, _ = select.select([stream], [], [], max(0.0, deadline - time.monotonic()))
        chunk = os.read(stream.fileno(), 4096) if ready else b""
        assert chunk, f"no {word!r} in {seen!r}"
        seen += chunk
    return seen


def test_a_sample_older_than_the_worlds_history_reads_the_tension_now(tmp_path):
    # The twin stopped for a while (SIGSTOP, a suspended laptop): the main thread may bring the
    # world up to the wall clock before the cell's thread takes the samples it owes since.
    twin = build_twin(load_rig_config(_hardware_config(tmp_path)))
    start_ns = twin.world.now_ns
    twin.clock.advance_ns(5_000_000_000)
    assert twin.loadcell.tension_n(start_ns) == twin.world.tension_n


def test_the_firmware_in_the_loop_needs_the_harness_and_a_cell_it_can_be(tmp_path):
    from rig.sim.twin_firmware import harness_command

    config = load_rig_config(_hardware_config(tmp_path, "simulation:\n  loadcell_dtr_reset_s: 1.5\n"))
    harness = tmp_path / "hx711-sim"
    with pytest.raises(InputError, match=r"--firmware .*hx711-sim: not built; allowed"):
        harness_command(harness, config, 10.0, 1.5)
    harness.write_text("")
    assert harness_command(harness, config, 10.0, 1.5)[1:] == [
        "--link", str(tmp_path / "cell"), "--rate", "10", "--signal", "stdin", "--reset-on-open", "1500",
    ]  # fmt: skip
    with pytest.raises(ConfigError, match=r"loadcell.rate_hz: 12; allowed with --firmware: 10, 80"):
        harness_command(harness, config, 12.0, 0.0)


def test_trial_n_at_the_console_puts_the_hand_on_the_trial_the_run_repeats(tmp_path):
    config = load_rig_config(_hardware_config(tmp_path))
    twin = build_twin(config, protocol=load_protocol(SMOKE, joint_count=config.article.joint_count))
    out = io.StringIO()
    run_console(["trial 2\n", "trial 1\n", "trial 3\n", "trial x\n"], twin.reference, out, twin.set_up_trial)
    assert twin.world.hook_distance_m == 0.1  # where trial 1, the last one set up, hangs it
    assert out.getvalue().splitlines() == [
        "trial 2 set up (joint_estimation, the hook at 0.2 m)",
        "trial 1 set up (joint_estimation, the hook at 0.1 m)",
        "trial 3: allowed: 1-2",
        "trial x: allowed: a trial number",
    ]
    assert twin.hand.index == 0  # the next slip and slack line move it on to trial 2


def test_a_port_without_a_path_is_refused_naming_it(tmp_path):
    # The built-in simulated rig's ports are in-process (sim://dxl): the twin would have made a
    # directory `sim:` in the working directory and a link in it.
    from rig.inputs.rig_config import DEFAULT_RIG_CONFIG

    with pytest.raises(
        ConfigError, match=r"simulated.yaml: servos.port: sim://dxl; allowed in `rig sim rig`"
    ):
        build_twin(load_rig_config(DEFAULT_RIG_CONFIG))
    path = _hardware_config(tmp_path)
    path.write_text(path.read_text().replace(f"port: {tmp_path / 'cell'}", f"port: {tmp_path / 'dxl'}"))
    with pytest.raises(ConfigError, match=r"loadcell.port: .*dxl; allowed: another path than servos.port"):
        build_twin(load_rig_config(path))


def test_the_console_unplugs_freezes_and_reports_the_ports(tmp_path):
    twin = build_twin(load_rig_config(_hardware_config(tmp_path)))
    out = io.StringIO()
    typed = ["status", "unplug servos 2.5", "freeze loadcell", "thaw servos", "replug servos 1",
             "freeze servos", "unplug printer", "freeze loadcell -1", "unplug loadcell",
             "status"]  # fmt: skip
    run_console([f"{line}\n" for line in typed], twin.reference, out, twin.set_up_trial, twin)
    assert out.getvalue().splitlines() == [
        "line 0.000 N; torque on: none; servos: served; loadcell: served",
        "unplug servos for 2.5 s: ok",
        "freeze loadcell: ok",
        "thaw servos: the port is unplugged; allowed: replug",
        "replug servos 1: allowed: `replug servos`",
        "freeze servos: the port is unplugged; allowed: replug",
        "unplug printer: allowed devices: servos, loadcell",
        "freeze loadcell -1: allowed: a duration in seconds above 0, at most 3600",
        "unplug loadcell: ok",
        "line 0.000 N; torque on: none; servos: unplugged; loadcell: unplugged",
    ]
    start_ns = time.monotonic_ns()
    assert twin.port_wanted(TwinDevice.SERVOS, start_ns + 3_000_000_000) is PortCondition.SERVED  # 2.5 s on


def _ping(link: Path) -> int:
    """One ping of servo 1 through the SDK on `link`: its COMM result."""
    port = PortHandler(str(link))
    assert port.openPort() and port.setBaudRate(1_000_000)
    try:
        _, result, _ = PacketHandler(2.0).ping(port, 1)
        return int(result)
    finally:
        port.closePort()


# A port asked to change is brought to it on the twin's next tick, once its serving thread has seen
# its stop (the bus server looks every 50 ms, rig.sim.dxl.bus_pty_server.IDLE_POLL_MS).
SETTLED_S = TICK_S + IDLE_POLL_MS / 1000 + 0.05


@pytest.mark.pty
def test_the_ports_are_unplugged_frozen_and_served_again_as_asked_and_as_configured(tmp_path):
    # The cell's configured disconnect, 0.6 s after the twin is built, for 0.6 s.
    faults = "simulation:\n  faults:\n  - {device: loadcell, kind: disconnect, at_s: 0.6, duration_s: 0.6}\n"
    config = load_rig_config(_hardware_config(tmp_path, faults))
    built_ns = time.monotonic_ns()
    twin = build_twin(config)
    servos, cell = tmp_path / "dxl", tmp_path / "cell"
    stop, ready = Stop(), threading.Event()
    server = threading.Thread(target=serve_twin, args=(twin, stop), kwargs={"ready": lambda *_: ready.set()})
    server.start()
    try:
        assert ready.wait(10)
        reader = serial.Serial(str(cell), 115200, timeout=0.5)
        assert reader.readline().endswith(b"\n")  # the cell's lines
        assert _ping(servos) == COMM_SUCCESS
        twin.act(PortAction.FREEZE, TwinDevice.SERVOS)
        time.sleep(SETTLED_S)
        port = PortHandler(str(servos))
        assert port.openPort() and port.setBaudRate(1_000_000)
        handler = PacketHandler(2.0)
        assert handler.write1ByteTxRx(port, 1, LED, 1)[0] != COMM_SUCCESS  # nothing answers
        assert handler.ping(port, 1)[1] != COMM_SUCCESS
        twin.act(PortAction.THAW, TwinDevice.SERVOS)
        time.sleep(SETTLED_S)
        assert handler.read1ByteTxRx(port, 1, LED) == (0, COMM_SUCCESS, 0)  # the write never reached it
        twin.act(PortAction.UNPLUG, TwinDevice.SERVOS)
        time.sleep(SETTLED_S)
        assert not servos.exists()
        with pytest.raises(serial.SerialException):  # the host's open port fails, as a pulled adapter's
            port.ser.write(b"\xff\xff\xfd\x00")
            port.ser.read(1)
        port.closePort()
        twin.act(PortAction.REPLUG, TwinDevice.SERVOS)
        time.sleep(SETTLED_S)
        assert _ping(servos) == COMM_SUCCESS  # back at the same path
        while cell.exists():  # the configured disconnect: the cell's path goes
            assert time.monotonic_ns() - built_ns < 1_000_000_000, "the cell was not unplugged"
            time.sleep(0.01)
        with pytest.raises(serial.SerialException):
            reader.read(10_000)
        reader.close()
        while not cell.exists():  # and comes back, 0.6 s later
            assert time.monotonic_ns() - built_ns < 2_000_000_000, "the cell was not plugged back"
            time.sleep(0.01)
        with serial.Serial(str(cell), 115200, timeout=0.5) as again:
            assert again.readline().endswith(b"\n")
        assert twin.status().endswith("servos: served; loadcell: served")
    finally:
        stop.stopped = True
        server.join(10)
    assert not servos.exists() and not cell.exists()


def test_a_load_cell_fault_with_the_firmware_in_the_loop_is_refused_naming_it(tmp_path):
    # The board under simavr is the cell then: the emulator the fault would act on is not served.
    faults = "simulation:\n  faults:\n    - {device: loadcell, kind: disconnect, at_s: 1}\n"
    twin = build_twin(load_rig_config(_hardware_config(tmp_path, faults)))
    refused = r"simulation.faults\[0\].device: loadcell; allowed with --firmware"
    with pytest.raises(ConfigError, match=refused):
        serve_twin(twin, Stop(), ready=lambda *_: None, firmware=tmp_path / "hx711-sim")
    assert not (tmp_path / "dxl").exists()
