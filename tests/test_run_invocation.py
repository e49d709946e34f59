"""One `rig run` invocation against a hostile world: signals at bad moments, a second process on the
same run, moved protocols, run ids that try to leave --out, and an --out that cannot be written."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import pytest

import rig.rigs as composition
from rig.cli import build_parser
from rig.cli import main as cli_main
from rig.errors import InputError
from rig.runner.execute import RunReport, RunRequest, prepare_run
from rig.runner.journal import RunJournal
from rig.runner.progress import SilentProgress
from rig.runner.runlock import RunInProgressError
from tests.helpers import QUICK_PROTOCOL, quick_protocol
from tests.runner_rig import RunnerRig, assert_released_then_torque_off, execute_on, runner_rig

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def quick(protocol_file) -> Path:
    return protocol_file(QUICK_PROTOCOL)


def request(protocol: Path, out: Path, *, run_id: str | None = "f1", resume: str | None = None) -> RunRequest:
    return RunRequest(
        protocol_path=protocol,
        rig_path=None,
        out_dir=out,
        seed=1,
        run_id=None if resume else run_id,
        resume=resume,
    )


def run_sim(
    protocol: Path,
    out: Path,
    *,
    interrupt_at_trial: int | None = None,
    setup: Callable[[RunnerRig], None] | None = None,
    **kwargs,
) -> tuple[RunReport, RunnerRig]:
    """Prepare the run and execute it on its object-level simulated rig (tests/runner_rig.py)."""
    prepared = prepare_run(request(protocol, out, **kwargs))
    rig = runner_rig(prepared, interrupt_at_trial=interrupt_at_trial)
    if setup is not None:
        setup(rig)
    return execute_on(prepared, rig), rig


def interrupted_run(protocol: Path, out: Path) -> None:
    """Run f1 on the simulated rig and Ctrl-C it at trial 2: a journal with one trial, status interrupted."""
    report, _ = run_sim(protocol, out, interrupt_at_trial=2)
    assert report.exit_code == 130 and report.completed == 1


def signal_during_shutdown(rig: RunnerRig, *signums: int) -> None:
    """Send `signums` to this process while the servo bus runs its safe-state shutdown."""
    bus = rig.sim.devices.bus
    shutdown = bus.shutdown

    def signalled(release=None):
        for signum in signums:
            os.kill(os.getpid(), signum)
        shutdown(release)

    bus.shutdown = signalled  # type: ignore[method-assign]


def status(out: Path, run_id: str = "f1") -> str:
    return RunJournal.load(out / f"{run_id}.journal.json").status


# ------------------------------------------------------------------ 1. a second Ctrl-C in the safe state


def test_a_second_ctrl_c_in_the_safe_state_still_saves_the_journal_and_report(
    tmp_path, quick, signal_handlers
):
    report, rig = run_sim(
        quick,
        tmp_path / "out",
        interrupt_at_trial=2,
        setup=lambda rig: signal_during_shutdown(rig, signal.SIGINT, signal.SIGTERM),
    )
    assert report.exit_code == 130 and report.aborted and report.completed == 1
    assert report.reason == "interrupted by the operator"
    assert status(tmp_path / "out") == "interrupted"
    assert_released_then_torque_off(rig)  # the safe state itself ran to its end


def test_a_second_ctrl_c_prints_the_json_report_and_exits_130(
    tmp_path, quick, signal_handlers, monkeypatch, run_cli
):
    rigs: list[RunnerRig] = []

    def open_rig(prepared, **kwargs):
        rigs.append(runner_rig(prepared, interrupt_at_trial=2))
        signal_during_shutdown(rigs[-1], signal.SIGINT)
        return dataclasses.replace(rigs[-1].sim, session=rigs[-1].session)

    monkeypatch.setattr(composition, "open_rig", open_rig)
    result = run_cli("run", quick, "--out", tmp_path / "out", "--run-id", "f1", "--json")
    (rig,) = rigs
    assert result.code == 130, result.err
    report = json.loads(result.out)  # exactly one JSON object
    assert report["run_id"] == "f1" and report["aborted"] and report["completed"] == 1
    assert status(tmp_path / "out") == "interrupted"
    assert "Traceback" not in result.err
    assert_released_then_torque_off(rig)


def test_ctrl_c_after_the_last_trial_does_not_undo_a_completed_run(tmp_path, quick, signal_handlers):
    report, rig = run_sim(
        quick, tmp_path / "out", setup=lambda rig: signal_during_shutdown(rig, signal.SIGINT)
    )
    assert report.exit_code == 0 and report.completed == 3 and not report.aborted
    assert status(tmp_path / "out") == "completed"
    assert_released_then_torque_off(rig)


def test_ctrl_c_while_the_log_is_set_up_ends_interrupted_before_anything_moved(
    tmp_path, quick, signal_handlers
):
    class Progress(SilentProgress):
        def start(self, run_id: str, planned: int, done: int) -> None:
            os.kill(os.getpid(), signal.SIGINT)

    prepared = prepare_run(request(quick, tmp_path / "out"))
    rig = runner_rig(prepared)
    report = execute_on(prepared, rig, Progress())
    assert report.exit_code == 130 and report.completed == 0
    assert status(tmp_path / "out") == "interrupted"
    assert "connect" not in rig.servos.call_names()
    assert not any(servo.torque_enabled for servo in rig.sim.devices.bus.servos)


# ------------------------------------------------------------------ 2. signals from the first instruction

# `rig.cli.main` with a byte written to fd SYNC as it begins building the parser (its first step
# after installing the SIGTERM handler), so the delays count from there, not from process start.
CHILD = """\
import os, sys
import rig.cli
build = rig.cli.build_parser
def announced(argv):
    os.write(int(sys.argv[1]), b"!")
    return build(argv)
rig.cli.build_parser = announced
sys.exit(rig.cli.main(sys.argv[2:]))
"""


@pytest.mark.subprocess
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("delay_s", [0.0, 0.05, 0.1, 0.3, 1.5])
def test_a_signal_early_in_rig_run_exits_130_without_a_traceback(tmp_path, signum, delay_s):
    read_fd, write_fd = os.pipe()
    argv = ["run", str(ROOT / "protocols" / "joint_estimation.yaml"), "--out", str(tmp_path)]
    argv += ["--run-id", "e1", "--realtime", "--json"]  # real time: 1.5 s is well inside the run
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(write_fd), *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        pass_fds=(write_fd,),
        cwd=ROOT,
    )
    os.close(write_fd)
    try:
        assert os.read(read_fd, 1) == b"!"
        time.sleep(delay_s)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=60)
    finally:
        os.close(read_fd)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    journal = tmp_path / "e1.journal.json"
    if out.strip():  # the run had begun: its report, and a journal that says how it ended
        assert json.loads(out)["aborted"]
        assert RunJournal.load(journal).status == "interrupted"
    else:
        assert not journal.exists() or RunJournal.load(journal).status == "interrupted"


# ------------------------------------------------------------------ 3. one process per run


def test_a_run_in_progress_cannot_be_started_or_resumed_twice(tmp_path, quick, run_cli):
    out = tmp_path / "out"
    interrupted_run(quick, out)
    held = prepare_run(request(quick, out, resume="f1"))
    try:
        with pytest.raises(RunInProgressError, match=f"run f1 is in progress in process {os.getpid()}"):
            prepare_run(request(quick, out, resume="f1"))
        result = run_cli("run", quick, "--out", out, "--resume", "f1", "--json")
        assert result.code == 2 and result.out == ""
        assert result.err.count("\n") == 1 and f"in progress in process {os.getpid()}" in result.err
    finally:
        held.release()
    assert not (out / "f1.lock").exists()
    report, _ = run_sim(quick, out, resume="f1")
    assert report.exit_code == 0 and report.completed == 3


def test_the_lock_is_given_back_when_preparing_fails(tmp_path, quick, protocol_file):
    out = tmp_path / "out"
    interrupted_run(quick, out)
    quick.write_text(quick_protocol(block={"repeats": 2}))
    with pytest.raises(InputError, match="changed since run f1 started"):
        prepare_run(request(quick, out, resume="f1"))
    assert not (out / "f1.lock").exists()
    with pytest.raises(InputError, match="no journal"):
        prepare_run(request(quick, out, resume="f9"))
    assert sorted(p.suffix for p in out.iterdir()) == [".json", ".json", ".mcap"]


@pytest.mark.subprocess
def test_a_lock_held_by_a_killed_process_does_not_block_resume(tmp_path, quick):
    out = tmp_path / "out"
    interrupted_run(quick, out)
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import fcntl, os, sys, time\n"
            "fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT)\n"
            "fcntl.flock(fd, fcntl.LOCK_EX)\n"
            "os.write(fd, f'{os.getpid()}\\n'.encode())\n"
            "print('locked', flush=True)\n"
            "time.sleep(60)\n",
            str(out / "f1.lock"),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(RunInProgressError, match=f"in progress in process {holder.pid}"):
            prepare_run(request(quick, out, resume="f1"))
    finally:
        holder.kill()  # SIGKILL: no chance to clean up; the kernel drops the flock
        holder.wait()
    assert (out / "f1.lock").exists()  # stale file left behind ...
    report, _ = run_sim(quick, out, resume="f1")  # ... blocks nothing
    assert report.exit_code == 0 and report.completed == 3
    assert not (out / "f1.lock").exists()


@pytest.mark.slow
@pytest.mark.subprocess
def test_resume_of_a_run_alive_in_another_process_is_refused(tmp_path):
    protocol = ROOT / "protocols" / "smoke.yaml"
    base = [sys.executable, "-m", "rig.cli", "run", str(protocol), "--out", str(tmp_path)]
    first = subprocess.Popen(
        [*base, "--run-id", "live", "--realtime"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT
    )
    try:
        journal = tmp_path / "live.journal.json"
        deadline = time.monotonic() + 60
        while not journal.exists() and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert first.poll() is None and RunJournal.load(journal).status == "running"
        second = subprocess.run(
            [*base, "--resume", "live"], capture_output=True, text=True, cwd=ROOT, timeout=60
        )
        assert second.returncode == 2
        assert f"run live is in progress in process {first.pid}" in second.stderr
        assert "Traceback" not in second.stderr
    finally:
        first.kill()
        first.wait()
    assert RunJournal.load(journal).status == "running"  # killed: no chance to say otherwise
    resumed = subprocess.run(
        [*base, "--resume", "live", "--json"], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads(resumed.stdout)["completed"] == 2


# ------------------------------------------------------------------ 4. resume by content, not path


def test_a_moved_but_identical_protocol_resumes(tmp_path, quick):
    out = tmp_path / "out"
    interrupted_run(quick, out)
    moved = tmp_path / "elsewhere" / "renamed.yaml"
    moved.parent.mkdir()
    quick.rename(moved)
    report, _ = run_sim(moved, out, resume="f1")
    assert report.exit_code == 0 and [t.trial_id for t in report.trials] == [1, 2, 3]


def test_a_changed_protocol_at_another_path_is_refused(tmp_path, quick, protocol_file):
    out = tmp_path / "out"
    interrupted_run(quick, out)
    other = protocol_file(quick_protocol(block={"distances_m": [0.12, 0.2, 0.3]}), "other.yaml")
    with pytest.raises(InputError, match="changed since run f1 started"):
        prepare_run(request(other, out, resume="f1"))


def _rig_file(tmp_path: Path, zero_tolerance_n: float = 2.0) -> Path:
    rig = tmp_path / "lab" / "rig.yaml"
    rig.parent.mkdir(exist_ok=True)
    rig.write_text(f"extends: simulated\nname: lab\nlimits: {{zero_tolerance_n: {zero_tolerance_n:g}}}\n")
    return rig


def _started_on(rig: Path | None, protocol: Path, out: Path) -> None:
    """Run f1 on the simulated rig of `rig`'s config and Ctrl-C it at trial 2 (as `interrupted_run`)."""
    req = RunRequest(protocol_path=protocol, rig_path=rig, out_dir=out, seed=1, run_id="f1")
    prepared = prepare_run(req)
    assert execute_on(prepared, runner_rig(prepared, interrupt_at_trial=2)).exit_code == 130


def _resume_by_id(out: Path, rig: Path | None = None) -> RunRequest:
    return RunRequest(protocol_path=None, rig_path=rig, out_dir=out, seed=0, resume="f1")


@pytest.mark.parametrize("own_rig", [False, True], ids=["built-in rig", "rig file"])
def test_resume_by_id_alone_takes_protocol_and_rig_from_the_journal(tmp_path, quick, monkeypatch, own_rig):
    """The lab's case: `rig run --resume ID` said PROTOCOL required; without --rig, "rig config changed"."""
    out = tmp_path / "out"
    rig = _rig_file(tmp_path) if own_rig else None
    _started_on(rig, quick, out)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the journal's paths do not depend on the directory
    prepared = prepare_run(_resume_by_id(out))
    assert prepared.config.name == ("lab" if own_rig else "simulated")
    report = execute_on(prepared, runner_rig(prepared))
    assert report.exit_code == 0 and [t.trial_id for t in report.trials] == [1, 2, 3]


def test_resume_by_id_on_the_command_line(tmp_path, quick, run_cli):
    out = tmp_path / "out"
    interrupted_run(quick, out)
    result = run_cli("run", "--resume", "f1", "--out", out, "--dry-run", "--json")
    assert result.code == 0, result.err
    assert [t["trial_id"] for t in json.loads(result.out)["trials"]] == [1, 2, 3]  # the plan of the run


def test_a_run_without_protocol_or_resume_is_refused_in_one_line(tmp_path, run_cli):
    result = run_cli("run", "--out", tmp_path / "out")
    assert result.code == 2 and result.err.count("\n") == 1
    assert "PROTOCOL: required" in result.err and "--resume RUN_ID" in result.err


def test_a_changed_rig_config_is_named_with_what_changed(tmp_path, quick):
    out = tmp_path / "out"
    rig = _rig_file(tmp_path, zero_tolerance_n=2)
    _started_on(rig, quick, out)
    _rig_file(tmp_path, zero_tolerance_n=3)  # edited in place
    with pytest.raises(
        InputError,
        match=r"rig\.yaml: rig config changed since run f1 started \(limits\.zero_tolerance_n: 2 -> 3\)",
    ):
        prepare_run(_resume_by_id(out))


def test_a_changed_protocol_is_named_with_what_changed(tmp_path, quick):
    out = tmp_path / "out"
    interrupted_run(quick, out)
    quick.write_text(quick_protocol(block={"distances_m": [0.12, 0.2, 0.3]}))
    with pytest.raises(
        InputError,
        match=r"changed since run f1 started \(it used .*: blocks\[0\]\.distances_m\[\d\]: 0\.25 -> 0\.3\)",
    ):
        prepare_run(_resume_by_id(out))


def test_a_journal_written_before_the_texts_were_kept_still_resumes(tmp_path, quick):
    out = tmp_path / "out"
    interrupted_run(quick, out)
    path = RunJournal.path_for(out, "f1")
    data = json.loads(path.read_text())
    for key in ("rig_builtin", "protocol_text", "rig_text"):
        del data[key]
    path.write_text(json.dumps(data))
    report, _ = run_sim(quick, out, resume="f1")
    assert report.exit_code == 0 and report.completed == 3


@pytest.mark.parametrize("out_given", [False, True], ids=["default --out", "--out DIR"])
def test_the_stop_line_prints_a_resume_command_that_works(tmp_path, run_cli, monkeypatch, out_given):
    """A run stopped by a fault with the hardware safe says how to continue; that command runs as printed."""
    monkeypatch.chdir(tmp_path)
    # A log file capped at 220 kB (a smoke run writes about 336 kB): trial 2 stops on the full disk,
    # with the hardware verified safe; the resumed part, trial 2 alone, fits.
    rig = tmp_path / "log-cap.yaml"
    rig.write_text(
        "extends: simulated\nname: log-cap\nsimulation:\n  faults:\n"
        "    - {device: logger, kind: write_error, after_bytes: 220000}\n",
        encoding="utf-8",
    )
    out = ["--out", str(tmp_path / "o")] if out_given else []
    first = run_cli("run", ROOT / "protocols" / "smoke.yaml", "--rig", rig, "--run-id", "dz", *out)
    assert first.code == 1, first.err
    printed = re.search(r"hardware left safe; `([^`]*)` continues", first.err)
    assert printed is not None, first.err
    command = shlex.split(printed.group(1))
    assert command[:4] == ["rig", "run", "--resume", "dz"] and command[4:] == out
    again = run_cli(*command[1:])
    assert again.code == 0, again.err
    journal = json.loads(RunJournal.path_for(Path(out[1]) if out else tmp_path / "logs", "dz").read_text())
    assert journal["invocations"] == 2 and journal["status"] == "completed"


# ------------------------------------------------------------------ 5. run ids stay inside --out


@pytest.mark.parametrize("name", ["../../../escaped", "/etc/passwd", "a b/c", "....", "n" * 300])
def test_an_unsafe_protocol_name_is_refused_before_anything_is_written(tmp_path, quick, run_cli, name):
    quick.write_text(quick_protocol(name=name))
    result = run_cli("run", quick, "--out", tmp_path / "out")
    assert result.code == 2 and "name:" in result.err and result.err.count("\n") == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("file_name", "expected"),
    [
        ("a b (copy).yaml", "a_b_copy"),
        ("..yaml", "run"),
        ("x.part2.yaml", "x_part2"),
        ("ü-тест.yaml", "run"),
    ],
)
def test_a_protocol_file_name_gives_a_safe_run_id(tmp_path, file_name, expected):
    # Without `name:`, the protocol is named after its file, which may hold any character: the run
    # id keeps only letters, digits, '_' and '-' of it.
    protocol = tmp_path / file_name
    protocol.write_text(quick_protocol(name=None))
    out = tmp_path / "deep" / "out"
    prepared = prepare_run(request(protocol, out, run_id=None))
    prepared.release()
    stamp, _, rest = prepared.run_id.partition("-")
    assert (len(stamp) == 15 and rest.strip("_") == expected.strip("_")) or rest == expected
    assert prepared.journal.path.parent == out and prepared.log_path.parent == out


def test_a_long_protocol_file_name_is_cut_to_the_run_id_limit(tmp_path):
    protocol = tmp_path / ("n" * 200 + ".yaml")
    protocol.write_text(quick_protocol(name=None))
    report, _ = run_sim(protocol, tmp_path / "out", run_id=None)
    assert report.exit_code == 0 and len(report.run_id) == 100
    assert Path(report.log).parent == tmp_path / "out"


@pytest.mark.parametrize(
    "run_id", ["../x", "a/b", ".hidden", "-x", "x" * 101, "r1.part2", "abc\n", "", "ü", "a b"]
)
def test_an_unsafe_run_id_is_refused_with_exit_2(tmp_path, quick, run_cli, run_id):
    result = run_cli("run", quick, "--out", tmp_path / "out", f"--run-id={run_id}")
    assert result.code == 2 and "--run-id" in result.err and result.err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_a_symbolic_link_out_of_out_is_refused(tmp_path, quick):
    out = tmp_path / "out"
    out.mkdir()
    (out / "f1.mcap").symlink_to(tmp_path / "outside.mcap")
    with pytest.raises(InputError, match="outside --out"):
        prepare_run(request(quick, out))
    assert not (tmp_path / "outside.mcap").exists() and not (out / "f1.lock").exists()


# ------------------------------------------------------------------ 6. --out that cannot be written


@pytest.mark.parametrize("where", ["a file", "below a file"])
def test_out_through_a_file_exits_2_in_one_line(tmp_path, quick, run_cli, where):
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    out = blocker if where == "a file" else blocker / "sub" / "out"
    result = run_cli("run", quick, "--out", out, "--run-id", "f1", "--json")
    assert result.code == 2 and result.out == ""
    assert result.err.startswith(f"rig: error: --out {out}") and result.err.count("\n") == 1


NOBODY_ID = 65534  # the unprivileged `nobody` user and `nogroup` group of Debian and most Linux


def run_cli_as_nobody(argv: list[str]) -> tuple[int, str]:
    """`rig.cli.main(argv)` in a forked child that has dropped root for `nobody`: (exit code, stderr).

    Forked rather than spawned so the child needs no read access to the interpreter or the sources
    (a pyenv Python under /root is private): building the parser here imports every command first.
    """
    build_parser()
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        try:
            os.close(read_fd)
            os.setgroups([])
            os.setgid(NOBODY_ID)
            os.setuid(NOBODY_ID)
            err = io.StringIO()
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                code = cli_main(argv)
            report = [code, err.getvalue()]
        except BaseException:  # any failure goes to the parent, which shows it
            report = [-1, traceback.format_exc()]
        with os.fdopen(write_fd, "w") as pipe:
            json.dump(report, pipe)
        os._exit(0)
    os.close(write_fd)
    with os.fdopen(read_fd) as pipe:
        code, err = json.load(pipe)
    os.waitpid(pid, 0)
    return code, err


def test_a_read_only_out_exits_2_in_one_line(run_cli):
    """Root writes into read-only directories, so as root (CI) the CLI runs as `nobody` in a forked
    child (run_cli_as_nobody); as anyone else, here. The refusal checked is the same."""
    with tempfile.TemporaryDirectory() as tmp:  # not tmp_path: pytest's base directory is private
        base = Path(tmp)
        base.chmod(0o755)
        protocol = base / "quick.yaml"
        protocol.write_text(QUICK_PROTOCOL)
        out = base / "ro"
        out.mkdir()
        out.chmod(0o555)
        argv = ["run", str(protocol), "--out", str(out), "--run-id", "f1"]
        try:
            if os.geteuid() == 0:
                code, err = run_cli_as_nobody(argv)
            else:
                result = run_cli(*argv)
                code, err = result.code, result.err
        finally:
            out.chmod(0o755)
    assert code == 2 and err == f"rig: error: --out {out}: not writable\n", err


def test_a_read_only_file_system_exits_2_in_one_line(tmp_path, quick, run_cli, monkeypatch):
    real_open = os.open

    def read_only(path, flags, *args, **kwargs):
        if str(path).endswith(".lock"):
            raise OSError(30, "Read-only file system")
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", read_only)
    result = run_cli("run", quick, "--out", tmp_path / "out", "--run-id", "f1")
    assert result.code == 2
    assert result.err == f"rig: error: --out {tmp_path / 'out'}: cannot write there (Read-only file system)\n"
    assert list((tmp_path / "out").iterdir()) == []
