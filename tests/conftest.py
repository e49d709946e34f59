"""Test-wide settings and the shared fixtures.

Files and the CLI:
  `write_file(text, name)`, `protocol_file(body, name="p.yaml")`: files in tmp_path.
  `run_cli(*argv)`: `rig.cli.main` in-process, with its exit code, stdout, stderr and JSON.
  `cli_json(*argv, quiet=False)`: the same, asserting exit 0 (and an empty stderr if `quiet`).
Dynamixel:
  `emulated_dxl(ids=..., **driver_kwargs)`: an emulated bus with the real `DynamixelServoBus` on it,
  in-process and in virtual time (shut down after the test).
  `sdk_on_emulated_bus(ids=..., coupled=True)`: the raw dynamixel-sdk on an emulated bus.
  `dxl_server(ids=..., baud=...)`: `rig sim servos` in a subprocess on a pty (always terminated).
Hardware rig over ptys:
  `loadcell_server(profile)`: `rig sim loadcell` in a subprocess on a pty (stopped after the test).
  `hardware_rig(servo_link, cell_link, ...)`: a hardware rig config on them, with a calibration.
  `hardware_twin(protocol, ...)`: `rig sim rig` serving a hardware config's coupled world on ptys,
  with its console (`say`) and its truth when stopped.
Runs:
  `run_on_simulated_rig` (session scope): runs a protocol on the simulated rig into any directory.
  `sim_run(protocol, ...)`: the same into tmp_path/out; returns (report, SimulatedRig).
  `default_run_log` (session scope): the MCAP log of `rig run protocols/joint_estimation.yaml --seed 0`.
  `assert_safe(sim)`: the line released and every servo torque-off after a run.
Signals:
  `signal_handlers`: SIGINT/SIGTERM handlers restored after the test, whatever it installed.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import select
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import yaml
from dynamixel_sdk import PacketHandler
from hypothesis import settings as hypothesis_settings

from rig.cli import main as cli_main
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.loadcell.calibration import Calibration
from rig.inputs.rig_config import ServoSpec
from rig.rigs import open_simulated_rig
from rig.runner.execute import RunReport, RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress
from rig.sim.dxl.emulated_bus import EmulatedBus
from rig.sim.dxl.inprocess_port import SimPortHandler
from rig.sim.simulated_rig import SimulatedRig
from rig.sim.virtual_clock import VirtualClock
from tests.helpers import s32, u32

# Every payload a test logs is checked against its topic schema (rig/log/format/schemas.py).
os.environ.setdefault("RIG_LOG_STRICT", "1")

# The suite is a gate, so it must not fail at random: every run tries the same examples (a seed
# fixed per test). HYPOTHESIS_EXPLORE=1 draws new ones each run, to look for new failing cases;
# a case found that way becomes a plain test.
hypothesis_settings.register_profile("gate", derandomize=True)
hypothesis_settings.register_profile("explore", derandomize=False)
hypothesis_settings.load_profile("explore" if os.environ.get("HYPOTHESIS_EXPLORE") == "1" else "gate")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """A test that starts `rig sim servos` (`dxl_server`) must be marked `pty` and `subprocess`."""
    unmarked = [
        item.nodeid
        for item in items
        if "dxl_server" in getattr(item, "fixturenames", ())
        and not {"pty", "subprocess"} <= {mark.name for mark in item.iter_markers()}
    ]
    if unmarked:
        raise pytest.UsageError("mark these pty and subprocess (they use dxl_server): " + ", ".join(unmarked))
    # Under pytest-xdist (two workers, `--dist loadgroup`): the real-time tests over ptys run one at a
    # time, on one worker, so two of them never compete for the cores; the rest spread over both.
    for item in items:
        if item.get_closest_marker("pty") is not None:
            item.add_marker(pytest.mark.xdist_group("realtime"))


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C as in a shell, and bytecode caches for the rig's processes.

    An xdist worker ignores SIGINT, and children would inherit that.
    A process started with SIGINT ignored keeps ignoring it (Python installs its handler only where
    the signal is not ignored), so the tests that send SIGINT to `rig run` would wait in vain.
    """
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    # The suite starts a few hundred Python processes (`rig` commands, emulators, the log writer):
    # each would compile the rig from source where the environment forbids bytecode caches
    # (PYTHONDONTWRITEBYTECODE), about 0.2 s of CPU per `rig run`. Let them, and this process, keep it.
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    sys.dont_write_bytecode = False


# ------------------------------------------------------------------------------------------ files, CLI


@pytest.fixture
def write_file(tmp_path: Path) -> Callable[[str, str], Path]:
    """`write_file(text, name)` -> tmp_path/name holding `text` (UTF-8)."""

    def write(text: str, name: str) -> Path:
        path = tmp_path / name
        path.write_text(text, encoding="utf-8")
        return path

    return write


@pytest.fixture
def protocol_file(write_file: Callable[[str, str], Path]) -> Callable[..., Path]:
    """`protocol_file(body, name="p.yaml")` -> a protocol YAML in tmp_path (`body` is dedented)."""

    def write(body: str, name: str = "p.yaml") -> Path:
        return write_file(textwrap.dedent(body), name)

    return write


@dataclass
class CliRun:
    """One in-process `rig` invocation."""

    code: int
    out: str
    err: str

    @property
    def data(self) -> Any:
        """stdout parsed as JSON ({} when it is empty)."""
        return json.loads(self.out) if self.out.strip() else {}


@pytest.fixture
def run_cli(capsys: pytest.CaptureFixture[str]) -> Callable[..., CliRun]:
    """`run_cli(*argv)` -> CliRun: `rig.cli.main` with the arguments as strings, output captured."""

    def run(*argv: object) -> CliRun:
        capsys.readouterr()  # only this invocation's output
        code = cli_main([str(a) for a in argv])
        captured = capsys.readouterr()
        return CliRun(code, captured.out, captured.err)

    return run


@pytest.fixture
def cli_json(run_cli: Callable[..., CliRun]) -> Callable[..., Any]:
    """`cli_json(*argv, quiet=False)` -> parsed stdout; asserts exit 0, and nothing on stderr if `quiet`."""

    def run(*argv: object, quiet: bool = False) -> Any:
        result = run_cli(*argv)
        assert result.code == 0, result.err
        if quiet:
            assert result.err == ""
        return json.loads(result.out)

    return run


# ------------------------------------------------------------------------------------------ Dynamixel

DXL_ROLES = {1: "winch", 2: "bender", 3: "bender"}


@dataclass
class EmulatedDxl:
    """An emulated bus (virtual time) and the real driver on it through the in-process port."""

    clock: VirtualClock
    bus: EmulatedBus
    specs: list[ServoSpec]
    driver: DynamixelServoBus = field(init=False)
    ports: list[SimPortHandler] = field(default_factory=list)

    def make_port(self, name: str) -> SimPortHandler:
        """A new in-process port on the bus (the driver's port factory)."""
        port = SimPortHandler(self.bus, self.clock, name)
        self.ports.append(port)
        return port

    def reg(self, servo_id: int, name: str) -> int:
        """A register of an emulated servo, read behind the driver's back."""
        return self.bus[servo_id].register(name)


@pytest.fixture
def emulated_dxl() -> Iterator[Callable[..., EmulatedDxl]]:
    """Factory: `emulated_dxl(ids=(1, 2, 3), model=..., specs=None, firmware=None, **driver_kwargs)`.

    The driver is not connected yet; every driver made is shut down after the test (idempotent).
    Roles: 1 is the winch, the others benders.
    """
    made: list[EmulatedDxl] = []

    def make(
        ids: Sequence[int] = (1, 2, 3),
        *,
        model: str = "XM430-W350",
        specs: list[ServoSpec] | None = None,
        firmware: int | None = None,
        **driver_kwargs: Any,
    ) -> EmulatedDxl:
        clock = VirtualClock()
        servo_kwargs = {} if firmware is None else {"firmware": firmware}
        bus = EmulatedBus.with_servos(clock, ids=list(ids), model=model, **servo_kwargs)
        specs = specs or [ServoSpec(i, DXL_ROLES.get(i, "bender"), model) for i in ids]
        rig = EmulatedDxl(clock, bus, specs)
        rig.driver = DynamixelServoBus(
            "sim://dxl", 1_000_000, specs, clock, port_factory=rig.make_port, **driver_kwargs
        )
        made.append(rig)
        return rig

    yield make
    for rig in made:
        with contextlib.suppress(Exception):
            rig.driver.shutdown()


class SdkOnEmulatedBus:
    """The raw dynamixel-sdk (Protocol 2.0) on an emulated bus through an open in-process port."""

    def __init__(
        self,
        ids: Sequence[int] = (1, 2, 3),
        model: str = "XM430-W350",
        baud: int = 1_000_000,
        *,
        coupled: bool = True,
        **servo_kwargs: Any,
    ) -> None:
        self.clock = VirtualClock()
        self.bus = EmulatedBus.with_servos(self.clock, ids=list(ids), model=model, baud=baud, **servo_kwargs)
        if coupled:
            self.clock.on_advance(self.bus.advance_to)  # as the simulated world does
        self.port = SimPortHandler(self.bus, self.clock)
        assert self.port.openPort() and self.port.setBaudRate(baud)
        self.ph = PacketHandler(2.0)

    def w1(self, i: int, addr: int, v: int) -> tuple[int, int]:
        return self.ph.write1ByteTxRx(self.port, i, addr, v)

    def w2(self, i: int, addr: int, v: int) -> tuple[int, int]:
        return self.ph.write2ByteTxRx(self.port, i, addr, v & 0xFFFF)

    def w4(self, i: int, addr: int, v: int) -> tuple[int, int]:
        return self.ph.write4ByteTxRx(self.port, i, addr, u32(v))

    def r1(self, i: int, addr: int) -> tuple[int, int, int]:
        return self.ph.read1ByteTxRx(self.port, i, addr)

    def r2(self, i: int, addr: int) -> tuple[int, int, int]:
        return self.ph.read2ByteTxRx(self.port, i, addr)

    def r4(self, i: int, addr: int) -> tuple[int, int, int]:
        return self.ph.read4ByteTxRx(self.port, i, addr)

    def position(self, i: int) -> int:
        """Present Position (132) in pulses, signed."""
        value, result, _ = self.r4(i, 132)
        assert result == 0
        return s32(value)

    def sleep(self, s: float) -> None:
        self.clock.sleep(s)


@pytest.fixture
def sdk_on_emulated_bus() -> Callable[..., SdkOnEmulatedBus]:
    """Factory: `sdk_on_emulated_bus(ids=(1, 2, 3), model=..., baud=..., coupled=True, **servo_kwargs)`.

    `coupled` moves the servos on every clock advance, as the simulated world does.
    """
    return SdkOnEmulatedBus


STARTUP_TIMEOUT_S = 10.0
STOP_TIMEOUT_S = 5.0


@dataclass
class ServoServer:
    """A running `rig sim servos` process."""

    link: str
    pty: str
    process: subprocess.Popen[str]

    def stop(self, sig: int = signal.SIGTERM) -> tuple[int, str]:
        """Signal the server, wait (bounded) and return (exit code, stderr)."""
        if self.process.poll() is None:
            self.process.send_signal(sig)
        try:
            _, err = self.process.communicate(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
            _, err = self.process.communicate(timeout=STOP_TIMEOUT_S)
        return self.process.returncode, err


@contextlib.contextmanager
def _servo_server(
    link: str | os.PathLike[str],
    ids: Sequence[int] = (1,),
    *,
    baud: int = 1_000_000,
    model: str = "XM430-W350",
    faults: Sequence[str] = (),
    extra_args: Sequence[str] = (),
) -> Iterator[ServoServer]:
    """Start `python -m rig.cli.sim_servos`, wait for its `PTY ... LINK ...` line, always terminate it."""
    cmd = [
        sys.executable,
        "-m",
        "rig.cli.sim_servos",
        "--ids",
        ",".join(str(i) for i in ids),
        "--baud",
        str(baud),
        "--model",
        model,
        "--link",
        str(link),
        *(f"--fault={f}" for f in faults),
        *extra_args,
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        line = ""
        while not line:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or proc.poll() is not None:
                break
            ready, _, _ = select.select([proc.stdout], [], [], remaining)
            if ready:
                line = proc.stdout.readline()  # type: ignore[union-attr]
                if not line:
                    break
        words = line.split()
        if len(words) != 4 or words[0] != "PTY" or words[2] != "LINK":
            proc.kill()
            _, err = proc.communicate(timeout=STOP_TIMEOUT_S)
            raise RuntimeError(
                f"servo server did not start (line {line!r}, exit {proc.returncode}): {err.strip()}"
            )
        yield ServoServer(link=words[3], pty=words[1], process=proc)
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=STOP_TIMEOUT_S)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


@pytest.fixture
def dxl_server(tmp_path: Path) -> Iterator[Callable[..., ServoServer]]:
    """Factory: `dxl_server(ids=[1, 2], baud=57600, model=..., faults=[...], extra_args=[...])`.

    Each is a ServoServer: `rig sim servos` (the same code) in a subprocess on a pty; every server
    is terminated after the test.
    """
    with contextlib.ExitStack() as stack:
        count = 0

        def start(**kwargs: Any) -> ServoServer:
            nonlocal count
            count += 1
            return stack.enter_context(_servo_server(tmp_path / f"dxl{count}", **kwargs))

        yield start


@dataclass
class LoadCellServer:
    """A running `rig sim loadcell` process at a constant tension, and its link."""

    link: Path
    process: subprocess.Popen[str]


@pytest.fixture
def loadcell_server(tmp_path: Path) -> Iterator[Callable[..., LoadCellServer]]:
    """Factory: `loadcell_server("constant:0.5", link=None)`: `rig sim loadcell` on a pty at 200 lines/s.

    rig-lc1 lines at the emulated cell's nominal gain and offset (`hardware_rig`'s calibration);
    the link is tmp_path/cellN unless given. Every server still running is stopped after the test.
    """
    servers: list[LoadCellServer] = []

    def start(profile: str, link: Path | None = None) -> LoadCellServer:
        link = tmp_path / f"cell{len(servers)}" if link is None else link
        cmd = [sys.executable, "-m", "rig.cli", "sim", "loadcell", "--link", str(link), "--rate", "200",
               "--profile", profile]  # fmt: skip
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        servers.append(LoadCellServer(link, proc))
        ready, _, _ = select.select([proc.stdout], [], [], 20)
        assert ready and proc.stdout is not None and proc.stdout.readline().startswith("PTY"), "no load cell"
        return servers[-1]

    yield start
    for server in servers:
        if server.process.poll() is None:
            server.process.terminate()
        server.process.communicate(timeout=STOP_TIMEOUT_S)


@pytest.fixture
def hardware_rig(tmp_path: Path) -> Callable[..., Path]:
    """Factory: `hardware_rig(servo_link, cell_link, ...)` -> tmp_path/hw.yaml, a hardware rig config.

    Two XM430-W350 (1 winch, 2 bender) at 1 Mbps with a 500 ms Bus Watchdog on `servo_link`; a
    rig-lc1 cell at 921600 baud on `cell_link` with the emulated cell's nominal calibration
    (tmp_path/cal.json; `calibration=False`: none); a link of two 3 cm segments. The keyword
    mappings `servos`, `loadcell`, `limits`, `article` add keys to (or replace keys of) those
    sections, `top` to the top level.
    """

    def write(
        servo_link: str | os.PathLike[str],
        cell_link: str | os.PathLike[str],
        *,
        calibration: bool = True,
        servos: dict[str, Any] | None = None,
        loadcell: dict[str, Any] | None = None,
        limits: dict[str, Any] | None = None,
        article: dict[str, Any] | None = None,
        top: dict[str, Any] | None = None,
    ) -> Path:
        cell: dict[str, Any] = {"port": str(cell_link), "baud": 921600, "format": "rig-lc1"}
        if calibration:  # the emulated cell's nominal gain and offset
            Calibration(1 / 80000, 120000, None, 9.80665, "2026-11-23", "pty", "rig-lc1").save(
                tmp_path / "cal.json"
            )
            cell["calibration"] = "cal.json"
        config = {
            "kind": "hardware",
            "spool_radius_m": 0.01,
            **(top or {}),
            "servos": {
                "port": str(servo_link),
                "baud": 1_000_000,
                "watchdog_ms": 500,
                **(servos or {}),
                "ids": [
                    {"id": 1, "role": "winch", "model": "XM430-W350"},
                    {"id": 2, "role": "bender", "model": "XM430-W350"},
                ],
            },
            "loadcell": {**cell, **(loadcell or {})},
            "article": {
                "joint_radius_m": 0.01,
                "segment_lengths_m": [0.03, 0.03],
                "load": {"point_m": [0, 0, 0.03], "direction": [0, -1, 0]},
                **(article or {}),
            },
            "limits": {
                "force_ceiling_n": 50,
                "winch_current_limit_a": 0.35,
                "stale_timeout_s": 0.2,
                "max_winch_travel_rev": 20,
                **(limits or {}),
            },
        }
        path = tmp_path / "hw.yaml"
        path.write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
        return path

    return write


# `hardware_twin`'s line, and its config's nominal: the `link1` world's line alone. These tests run
# in real time: at 2000 N/m (that line in series with a spring) a trial's ramp from its tare to the
# slip took 3.65 s and the release after the slip 0.83 s; at 5000 N/m 3.3 s and 0.6 s (200/s cell).
TWIN_LINE_STIFFNESS_N_PER_M = 5000.0
# `hardware_twin`'s cell (lines/s). The ramp's tension rate is bound by the cell's rate
# (rig/runner/ramp_speed.py): from 2.5 N to the twin's 13.5 N slip took 1.9 s at 200/s, 0.8 s at
# 500/s, 0.6 s at 1000/s. The fault tests upset the rig in that stretch, after polling the twin's
# console for 2.5 N, so it must stay long enough for that: 400/s, about 1 s.
TWIN_CELL_RATE_HZ = 400
# `hardware_twin`'s `limits.recovery_grace_s`, `servos.release_margin_s` (2 s each by default) and
# `loadcell.slack_settle_s` (1 s): a fault that clears lets the twin's rig answer within a tick of
# the release, its winch is back well within twice its travel time and its cell reads the slack line
# at its next sample (2.5 ms at 400/s); the tests of a fault that does not clear wait all of them.
TWIN_RECOVERY_GRACE_S = 0.5
TWIN_RELEASE_MARGIN_S = 0.5
TWIN_SLACK_SETTLE_S = 0.3
# The twin and the run share two cores with the rest of the suite: a bus reply may miss the SDK's
# 34 ms packet timeout while the twin waits for a core (a real adapter has no such contention). A
# run stopped at connect on three of them at a load of 4-5; five retries ride out about 0.2 s. The
# faults the tests inject (a second's silence and more, a pulled port) outlast them by far.
TWIN_BUS_RETRIES = 5


@dataclass
class TwinServer:
    """A running `rig sim rig`: its config, its ports, and its console (stdin in, stderr lines out)."""

    config: Path
    servo_link: Path
    cell_link: Path
    truth_path: Path
    process: subprocess.Popen[str]
    said: queue.Queue[str] = field(default_factory=queue.Queue)  # the twin's stderr, line by line

    def say(self, command: str, reply_starts: str, timeout_s: float = 10.0) -> str:
        """Type `command` at the twin's console; the first line it prints that starts with `reply_starts`."""
        assert self.process.stdin is not None
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        return self.hear(reply_starts, timeout_s)

    def hear(self, starts: str, timeout_s: float = 10.0) -> str:
        """The next line the twin prints on stderr that starts with `starts` (others are skipped)."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                line = self.said.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"the twin said no {starts!r} line in {timeout_s:g} s") from None
            if line.startswith(starts):
                return line

    def tension_n(self) -> float:
        """The line's tension now, from the console's `status`."""
        return float(self.say("status", "line ").split()[1])

    def wait_for_tension(
        self, at_least_n: float, run: subprocess.Popen[str], timeout_s: float = 60.0
    ) -> None:
        """Poll `status` until the line carries `at_least_n` (the run must still be going)."""
        deadline = time.monotonic() + timeout_s
        while self.tension_n() < at_least_n:
            assert run.poll() is None, run.communicate()
            assert time.monotonic() < deadline, f"the line never reached {at_least_n:g} N"
            time.sleep(0.05)

    def stop(self) -> dict[str, Any]:
        """Stop the twin (SIGTERM, exit 0 expected) and return its truth (`--truth-out`)."""
        if self.process.poll() is None:
            self.process.terminate()
        self.process.wait(timeout=STOP_TIMEOUT_S)
        assert self.process.returncode == 0, list(self.said.queue)
        truth: dict[str, Any] = json.loads(self.truth_path.read_text())
        return truth


@pytest.fixture
def hardware_twin(tmp_path: Path, hardware_rig: Callable[..., Path]) -> Iterator[Callable[..., TwinServer]]:
    """Factory: `hardware_twin(protocol, **hardware_rig_kwargs)`: `rig sim rig` serving `hardware_rig`'s twin.

    The config is `hardware_rig`'s at tmp_path/dxl and tmp_path/cell, with a link of eight 4 cm
    segments (the `link1` world's), the cell at `TWIN_CELL_RATE_HZ`, a line of
    `TWIN_LINE_STIFFNESS_N_PER_M` (the world's line; the config's nominal stiffness is the same),
    `TWIN_RECOVERY_GRACE_S`, `TWIN_RELEASE_MARGIN_S`, `TWIN_SLACK_SETTLE_S`, `TWIN_BUS_RETRIES` and
    the calibration the twin writes for its cell. The hand follows `protocol` (a path). Killed after
    the test if still running.
    """
    servers: list[TwinServer] = []

    def start(protocol: Path, **kwargs: Any) -> TwinServer:
        top = {
            "line_stiffness_n_per_m": TWIN_LINE_STIFFNESS_N_PER_M,
            "simulation": {},
            **kwargs.pop("top", {}),
        }
        config = hardware_rig(
            tmp_path / "dxl",
            tmp_path / "cell",
            calibration=False,
            loadcell={
                "rate_hz": TWIN_CELL_RATE_HZ,
                "calibration": "cal.json",
                "slack_settle_s": TWIN_SLACK_SETTLE_S,
                **kwargs.pop("loadcell", {}),
            },
            article={"segment_lengths_m": [0.04] * 8, **kwargs.pop("article", {})},
            limits={"recovery_grace_s": TWIN_RECOVERY_GRACE_S, **kwargs.pop("limits", {})},
            servos={
                "retries": TWIN_BUS_RETRIES,
                "release_margin_s": TWIN_RELEASE_MARGIN_S,
                **kwargs.pop("servos", {}),
            },
            top=top,
            **kwargs,
        )
        truth = tmp_path / "truth.json"
        cmd = [sys.executable, "-m", "rig.cli", "sim", "rig", "--rig", str(config),
               "--protocol", str(protocol), "--calibration-out", str(tmp_path / "cal.json"),
               "--truth-out", str(truth)]  # fmt: skip
        proc = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        server = TwinServer(config, tmp_path / "dxl", tmp_path / "cell", truth, proc)
        servers.append(server)
        stderr = proc.stderr
        assert stderr is not None

        def listen() -> None:
            for line in stderr:
                server.said.put(line.rstrip("\n"))

        threading.Thread(target=listen, daemon=True).start()
        ready, _, _ = select.select([proc.stdout], [], [], 30)
        assert ready and proc.stdout is not None, "the twin did not start"
        assert proc.stdout.readline().startswith("SERVOS"), list(server.said.queue)
        assert proc.stdout.readline().startswith("LOADCELL"), list(server.said.queue)
        return server

    yield start
    for server in servers:
        if server.process.poll() is None:
            server.process.kill()
        server.process.wait(timeout=STOP_TIMEOUT_S)


# ------------------------------------------------------------------------------------------ runs

SimRun = Callable[..., tuple[RunReport, SimulatedRig]]


def _run_on_simulated_rig(
    protocol: Path,
    out_dir: Path,
    *,
    run_id: str = "r1",
    resume: bool = False,
    seed: int = 3,
    patch: Callable[[SimulatedRig], None] | None = None,
) -> tuple[RunReport, SimulatedRig]:
    """Start run `run_id` (or resume it) and run it to its end as `rig run` does.

    `patch(sim)` may alter the rig first.
    """
    request = RunRequest(
        protocol_path=protocol,
        rig_path=None,
        out_dir=out_dir,
        seed=seed,
        run_id=None if resume else run_id,
        resume=run_id if resume else None,
    )
    prepared = prepare_run(request)
    sim = open_simulated_rig(prepared)
    if patch is not None:
        patch(sim)
    return execute_run(prepared, sim, SilentProgress()), sim


@pytest.fixture(scope="session")
def run_on_simulated_rig() -> SimRun:
    """`run_on_simulated_rig(protocol, out_dir, run_id="r1", resume=False, seed=3, patch=None)`.

    Runs a protocol on the built-in simulated rig through `prepare_run`, `open_simulated_rig` and
    `execute_run` (what `rig run` does); returns (report, SimulatedRig). Session-scoped, for
    fixtures that build logs once.
    """
    return _run_on_simulated_rig


@pytest.fixture(scope="session")
def default_run_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The log of the default run (`rig run protocols/joint_estimation.yaml --seed 0`), made once."""
    protocol = Path(__file__).parent.parent / "protocols" / "joint_estimation.yaml"
    out = tmp_path_factory.mktemp("default-run")
    report, _sim = _run_on_simulated_rig(protocol, out, run_id="default", seed=0)
    assert report.exit_code == 0, report.reason
    return out / "default.mcap"


@pytest.fixture
def sim_run(tmp_path: Path) -> SimRun:
    """`sim_run(protocol, run_id="r1", resume=None, seed=3, patch=None)` into tmp_path/out.

    `resume` is the id of the run to resume; `patch(sim)` may alter the rig before the run.
    Returns (report, SimulatedRig).
    """

    def run(
        protocol: Path,
        *,
        run_id: str = "r1",
        resume: str | None = None,
        seed: int = 3,
        patch: Callable[[SimulatedRig], None] | None = None,
    ) -> tuple[RunReport, SimulatedRig]:
        return _run_on_simulated_rig(
            protocol,
            tmp_path / "out",
            run_id=resume or run_id,
            resume=resume is not None,
            seed=seed,
            patch=patch,
        )

    return run


@pytest.fixture
def assert_safe() -> Callable[[SimulatedRig], None]:
    """`assert_safe(sim)`: the line is released (no tension left) and every servo is torque-off."""

    def check(sim: SimulatedRig) -> None:
        for servo in sim.devices.bus.servos:
            assert not servo.torque_enabled, f"servo {servo.servo_id} left with torque on"
        assert sim.devices.world.tension_n < 1.0

    return check


# ------------------------------------------------------------------------------------------ signals


@pytest.fixture
def signal_handlers() -> Iterator[None]:
    """Whatever a test installs for SIGINT and SIGTERM, the handlers before it are back after it."""
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in saved.items():
        signal.signal(sig, handler)
