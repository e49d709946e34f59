"""Every benchmark in benchmarks/ still runs: each `bench_*.py --smoke` as a script, exit 0.

A benchmark's smoke mode is its own measurement code on a few iterations (benchmarks/smoke_mode.py);
the figures are not checked, only that the code under the benchmark has not moved away from it. The
list is the directory's, so a new benchmark without `--smoke` fails here (argparse: exit 2; the
source is also checked for the option, as a script without argparse would run in full).
Each script runs as `__main__` in a process forked from the test's (`run_script_in_a_fork`): its own
process, as `python SCRIPT --smoke` would give it, but without an interpreter start and with the
rig, numpy and the test's other imports already done (about 0.2-1 s a benchmark; the processes the
benchmarks start themselves still start afresh).
The suite's check of every logged payload against its schema (RIG_LOG_STRICT, tests/conftest.py)
stays on only for the benchmarks that build payloads themselves (`STRICT_LOG`); the others log
through the rig's runs, whose payloads the run tests check that way, and for them it only made
logging slower than a user's benchmark run (about 10 s of the file's 47 s of CPU; the traced run of
bench_runner_bytecodes.py 2.8x).
Skipped, with the reason, only where what a benchmark needs is not installed, as its tests skip:
the AVR toolchain and simavr (bench_firmware.py), OpenCV with cv2.aruco (bench_camera.py), valgrind
(bench_runner_instructions.py), Dask (bench_study.py).
"""

from __future__ import annotations

import importlib.util
import multiprocessing
import os
import runpy
import shutil
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = sorted((ROOT / "benchmarks").glob("bench_*.py"))
TIMEOUT_S = 100  # under pytest's own 120 s, so that a hung benchmark shows its output
STRICT_LOG_ENV = "RIG_LOG_STRICT"
STRICT_LOG = {"bench_log_writer.py", "bench_log_reader.py"}  # they log payloads they build themselves


def _firmware_missing() -> str | None:
    from tests.test_firmware_simavr import _missing_tools

    missing = _missing_tools()
    return None if missing is None else f"firmware toolchain or simavr missing: {missing}"


def _opencv_missing() -> str | None:
    if importlib.util.find_spec("cv2") is None:
        return "OpenCV is not installed: pip install -e '.[camera]'"
    import cv2

    if not hasattr(cv2, "aruco") or not hasattr(cv2.aruco, "ArucoDetector"):
        return f"OpenCV {cv2.__version__} has no cv2.aruco.ArucoDetector (needs >= 4.7)"
    return None


def _valgrind_missing() -> str | None:
    return None if shutil.which("valgrind") else "valgrind not found (apt-get install valgrind)"


def _dask_missing() -> str | None:
    found = importlib.util.find_spec("distributed") is not None
    return None if found else "dask[distributed] is not installed: pip install -e '.[study]'"


# What a benchmark needs beyond the project's and the test extra's packages: None when it is there.
REQUIREMENTS: dict[str, Callable[[], str | None]] = {
    "bench_firmware.py": _firmware_missing,
    "bench_camera.py": _opencv_missing,
    "bench_runner_instructions.py": _valgrind_missing,
    "bench_study.py": _dask_missing,
}


def test_the_requirements_name_benchmarks_that_exist() -> None:
    assert set(REQUIREMENTS) <= {path.name for path in BENCHMARKS}


@pytest.mark.parametrize("script", BENCHMARKS, ids=[path.name for path in BENCHMARKS])
def test_benchmark_declares_a_smoke_mode(script: Path) -> None:
    # A script without argparse would ignore `--smoke` and run its whole measurement.
    assert '"--smoke"' in script.read_text(encoding="utf-8"), f"{script.name}: no --smoke option"


def _run_as_main(script: Path, argv: list[str], output: Path, unset: tuple[str, ...]) -> None:
    """In the forked child: `script` as `__main__`, its output (and its children's) into `output`."""
    os.setpgrp()  # its own process group: a timeout stops whatever it started too
    fd = os.open(output, os.O_WRONLY | os.O_APPEND)
    for target in (1, 2):
        os.dup2(fd, target)
    os.close(fd)
    sys.stdout = open(1, "w", encoding="utf-8", closefd=False)  # noqa: SIM115 (flushed by multiprocessing)
    sys.stderr = open(2, "w", encoding="utf-8", closefd=False)  # noqa: SIM115
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH"))))
    for name in unset:
        os.environ.pop(name, None)
    os.chdir(ROOT)
    sys.argv = [str(script), *argv]
    sys.path.insert(0, str(script.parent))  # as for a script: its directory first
    runpy.run_path(str(script), run_name="__main__")


def run_script_in_a_fork(
    script: Path, argv: list[str], output: Path, timeout_s: float, unset: tuple[str, ...] = ()
) -> int | None:
    """The exit code of `python script argv` run in a fork of this process; None if it timed out.

    `unset`: environment variables the script and its processes do not get.

    multiprocessing's fork start gives the exit code a script would have (an uncaught exception:
    its traceback and 1; `SystemExit`: its code, or its message and 1) and waits for the child's
    threads as an interpreter exit does.
    """
    output.touch()
    context = multiprocessing.get_context("fork")
    child = context.Process(target=_run_as_main, args=(script, argv, output, unset))
    child.start()
    try:
        child.join(timeout_s)
        code = child.exitcode
    finally:
        if child.exitcode is None:  # timed out, or the test was interrupted
            assert child.pid is not None
            try:
                os.killpg(child.pid, signal.SIGKILL)
            except ProcessLookupError:
                child.kill()
            child.join()
    return code


@pytest.mark.slow
@pytest.mark.parametrize("script", BENCHMARKS, ids=[path.name for path in BENCHMARKS])
def test_benchmark_runs_in_smoke_mode(script: Path, tmp_path: Path) -> None:
    requirement = REQUIREMENTS.get(script.name)
    missing = requirement() if requirement is not None else None
    if missing is not None:
        pytest.skip(missing)
    import rig  # the fork runs the rig this process imported: the tree's, as with PYTHONPATH=ROOT

    assert Path(rig.__file__).resolve().is_relative_to(ROOT), f"rig imported from {rig.__file__}, not {ROOT}"
    output = tmp_path / "output.txt"
    start = time.perf_counter()
    unset = () if script.name in STRICT_LOG else (STRICT_LOG_ENV,)
    code = run_script_in_a_fork(script, ["--smoke"], output, TIMEOUT_S, unset)
    seconds = time.perf_counter() - start
    text = output.read_text(encoding="utf-8", errors="replace")
    outcome = f"timed out after {TIMEOUT_S} s" if code is None else f"exit {code} after {seconds:.1f} s"
    assert code == 0, f"{script.name} --smoke: {outcome}\noutput (end):\n{text[-6000:]}"


SCRIPTS = {  # what a broken benchmark does, and the exit code `python SCRIPT` gives it
    "raises.py": ("print('measuring')\nraise RuntimeError('broken')\n", 1),
    "says_why.py": ("raise SystemExit('smoke: nothing measured')\n", 1),
    "bad_option.py": ("import argparse\nargparse.ArgumentParser().parse_args()\n", 2),
    "fine.py": ("import subprocess, sys\nsubprocess.run([sys.executable, '-c', 'print(\"child\")'])\n", 0),
}


@pytest.mark.parametrize("name", SCRIPTS)
def test_the_fork_gives_a_scripts_exit_code_and_output(name: str, tmp_path: Path) -> None:
    source, expected = SCRIPTS[name]
    script = tmp_path / name
    script.write_text(source, encoding="utf-8")
    output = tmp_path / "output.txt"
    assert run_script_in_a_fork(script, ["--smoke"], output, TIMEOUT_S) == expected
    text = output.read_text(encoding="utf-8")
    wanted = {"raises.py": "RuntimeError: broken", "says_why.py": "smoke: nothing measured"}
    wanted |= {"bad_option.py": "unrecognized arguments: --smoke", "fine.py": "child"}
    assert wanted[name] in text


def test_the_fork_leaves_out_the_unset_variables_for_the_script_and_its_processes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SMOKE_UNSET", "1")
    monkeypatch.setenv("SMOKE_KEPT", "1")
    script = tmp_path / "environ.py"
    script.write_text(
        "import os, subprocess, sys\n"
        "print('script', os.environ.get('SMOKE_UNSET'), os.environ.get('SMOKE_KEPT'), flush=True)\n"
        "code = \"import os; print('child', os.environ.get('SMOKE_UNSET'), os.environ.get('SMOKE_KEPT'))\"\n"
        "subprocess.run([sys.executable, '-c', code])\n",
        encoding="utf-8",
    )
    output = tmp_path / "output.txt"
    assert run_script_in_a_fork(script, [], output, TIMEOUT_S, unset=("SMOKE_UNSET",)) == 0
    assert output.read_text(encoding="utf-8").splitlines() == ["script None 1", "child None 1"]
    assert os.environ["SMOKE_UNSET"] == "1"  # this process keeps it


def _running(pid: int) -> bool:
    """Whether process `pid` exists and is not a zombie (killed, waiting to be reaped)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


def test_a_hung_benchmark_is_stopped_with_what_it_started(tmp_path: Path) -> None:
    pid_file = tmp_path / "child.pid"
    script = tmp_path / "hangs.py"
    script.write_text(
        "import pathlib, subprocess, sys, time\n"
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
        f"pathlib.Path({str(pid_file)!r}).write_text(str(child.pid))\n"
        "time.sleep(60)\n",
        encoding="utf-8",
    )
    assert run_script_in_a_fork(script, [], tmp_path / "output.txt", 1.0) is None
    grandchild = int(pid_file.read_text())
    deadline = time.monotonic() + 5
    while _running(grandchild) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _running(grandchild), "the benchmark's own child outlived the timeout"
