"""Every benchmark in benchmarks/ still runs: each `bench_*.py --smoke` as a script, exit 0.

A benchmark's smoke mode is its own measurement code on a few iterations (benchmarks/smoke_mode.py);
the figures are not checked, only that the code under the benchmark has not moved away from it. The
list is the directory's, so a new benchmark without `--smoke` fails here (argparse: exit 2; the
source is also checked for the option, as a script without argparse would run in full).
Each script runs as `__main__` in a process forked from a fork server (`ForkServer`, one per test
process, started afresh: not the test process, whose other tests may have left threads behind, e.g.
Dask's event loop, that a fork would not have): its own process, as `python SCRIPT --smoke` would
give it, but without an interpreter start and with the rig, numpy and pandas imported already
(0.2-1.5 s a benchmark; the processes the benchmarks start themselves still start afresh).
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

import importlib
import importlib.util
import json
import multiprocessing
import os
import runpy
import select
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = sorted((ROOT / "benchmarks").glob("bench_*.py"))
TIMEOUT_S = 100  # under pytest's own 120 s, so that a hung benchmark shows its output
STRICT_LOG_ENV = "RIG_LOG_STRICT"
STRICT_LOG = {"bench_log_writer.py", "bench_log_reader.py"}  # they log payloads they build themselves
PRELOAD = ("numpy", "yaml", "rig.cli", "rig.rigs", "rig.runner.execute", "rig.analysis")  # most benchmarks'


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
    import rig  # preloaded by the server: the tree's, as PYTHONPATH=ROOT gives a script

    assert Path(rig.__file__).resolve().is_relative_to(ROOT), f"rig imported from {rig.__file__}, not {ROOT}"
    sys.argv = [str(script), *argv]
    sys.path.insert(0, str(script.parent))  # as for a script: its directory first
    runpy.run_path(str(script), run_name="__main__")


def serve_forks() -> None:
    """The fork server's loop, in a fresh interpreter: imports PRELOAD, then runs each request in a fork.

    A request is a JSON line on stdin, [script, argv, output, unset] (`_run_as_main`'s arguments); the
    replies are two lines on stdout, the child's pid once it is started and its exit code once it ended.
    multiprocessing's fork start gives the exit code a script would have (an uncaught exception: its
    traceback and 1; `SystemExit`: its code, or its message and 1) and waits for the script's threads
    as an interpreter exit does.
    """
    for module in PRELOAD:
        importlib.import_module(module)
    context = multiprocessing.get_context("fork")
    for line in sys.stdin:
        script, argv, output, unset = json.loads(line)
        child = context.Process(target=_run_as_main, args=(Path(script), argv, Path(output), tuple(unset)))
        child.start()
        print(child.pid, flush=True)
        child.join()
        print(child.exitcode, flush=True)


class ForkServer:
    """`serve_forks` in a process of its own; `run` a script in a fork of it."""

    def __init__(self) -> None:
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH")))),
        }
        self._process = subprocess.Popen(
            [sys.executable, "-c", "from tests.test_benchmarks_smoke import serve_forks; serve_forks()"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            cwd=ROOT,
            env=env,
        )
        self._pending = b""

    def run(
        self, script: Path, argv: list[str], output: Path, timeout_s: float, unset: tuple[str, ...] = ()
    ) -> int | None:
        """The exit code of `python script argv` (its output in `output`), None if it timed out.

        `unset`: environment variables the script and its processes do not get.
        """
        assert self._process.stdin is not None
        output.touch()
        request = [str(script), argv, str(output), list(unset)]
        self._process.stdin.write(json.dumps(request).encode() + b"\n")
        self._process.stdin.flush()
        pid = int(self._reply(30.0))
        code = None
        try:
            code = int(self._reply(timeout_s))
        except TimeoutError:
            pass
        finally:
            if code is None:  # timed out, or the test was interrupted: stop it and what it started
                try:
                    os.killpg(pid, signal.SIGKILL)
                except ProcessLookupError:
                    os.kill(pid, signal.SIGKILL)
                self._reply(30.0)
        return code

    def _reply(self, timeout_s: float) -> str:
        """The server's next line; raw reads, so that no line waits in a buffer while select waits."""
        assert self._process.stdout is not None
        fd = self._process.stdout.fileno()
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._pending:
            ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
            if not ready:
                raise TimeoutError
            chunk = os.read(fd, 4096)
            if not chunk:
                raise RuntimeError(f"the fork server stopped (exit {self._process.wait()})")
            self._pending += chunk
        line, self._pending = self._pending.split(b"\n", 1)
        return line.decode()

    def close(self) -> None:
        assert self._process.stdin is not None
        self._process.stdin.close()
        try:
            self._process.wait(10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()


@pytest.fixture(scope="module")
def fork_server() -> Iterator[ForkServer]:
    server = ForkServer()
    yield server
    server.close()


@pytest.mark.slow
@pytest.mark.parametrize("script", BENCHMARKS, ids=[path.name for path in BENCHMARKS])
def test_benchmark_runs_in_smoke_mode(script: Path, tmp_path: Path, fork_server: ForkServer) -> None:
    requirement = REQUIREMENTS.get(script.name)
    missing = requirement() if requirement is not None else None
    if missing is not None:
        pytest.skip(missing)
    output = tmp_path / "output.txt"
    start = time.perf_counter()
    unset = () if script.name in STRICT_LOG else (STRICT_LOG_ENV,)
    code = fork_server.run(script, ["--smoke"], output, TIMEOUT_S, unset)
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
def test_the_fork_gives_a_scripts_exit_code_and_output(
    name: str, tmp_path: Path, fork_server: ForkServer
) -> None:
    source, expected = SCRIPTS[name]
    script = tmp_path / name
    script.write_text(source, encoding="utf-8")
    output = tmp_path / "output.txt"
    assert fork_server.run(script, ["--smoke"], output, TIMEOUT_S) == expected
    text = output.read_text(encoding="utf-8")
    wanted = {"raises.py": "RuntimeError: broken", "says_why.py": "smoke: nothing measured"}
    wanted |= {"bad_option.py": "unrecognized arguments: --smoke", "fine.py": "child"}
    assert wanted[name] in text


def test_the_fork_leaves_out_the_unset_variables_for_the_script_and_its_processes(
    tmp_path: Path, fork_server: ForkServer
) -> None:
    script = tmp_path / "environ.py"
    script.write_text(
        "import os, subprocess, sys\n"
        "print('script', os.environ.get('RIG_LOG_STRICT'), flush=True)\n"
        "code = \"import os; print('child', os.environ.get('RIG_LOG_STRICT'))\"\n"
        "subprocess.run([sys.executable, '-c', code])\n",
        encoding="utf-8",
    )
    output = tmp_path / "output.txt"
    assert fork_server.run(script, [], output, TIMEOUT_S, unset=(STRICT_LOG_ENV,)) == 0
    assert output.read_text(encoding="utf-8").splitlines() == ["script None", "child None"]
    kept = tmp_path / "kept.txt"
    assert fork_server.run(script, [], kept, TIMEOUT_S) == 0  # the server has this process's (conftest's)
    strict = os.environ[STRICT_LOG_ENV]
    assert kept.read_text(encoding="utf-8").splitlines() == [f"script {strict}", f"child {strict}"]


HELD = threading.Lock()  # held by a thread of the test process in the test below


def test_what_the_test_process_holds_is_not_held_in_the_fork(tmp_path: Path, fork_server: ForkServer) -> None:
    # As Dask's event loop thread, left running by another test, held its locks in a fork of this process.
    script = tmp_path / "lock.py"
    script.write_text("from tests.test_benchmarks_smoke import HELD\nassert HELD.acquire(timeout=1)\n")
    release = threading.Event()

    def hold() -> None:
        with HELD:
            release.wait(30)

    holder = threading.Thread(target=hold)
    holder.start()
    try:
        assert fork_server.run(script, [], tmp_path / "output.txt", TIMEOUT_S) == 0
    finally:
        release.set()
        holder.join()


def _running(pid: int) -> bool:
    """Whether process `pid` exists and is not a zombie (killed, waiting to be reaped)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat[stat.rindex(")") + 2] != "Z"


def test_a_hung_benchmark_is_stopped_with_what_it_started(tmp_path: Path, fork_server: ForkServer) -> None:
    pid_file = tmp_path / "child.pid"
    script = tmp_path / "hangs.py"
    script.write_text(
        "import pathlib, subprocess, sys, time\n"
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
        f"pathlib.Path({str(pid_file)!r}).write_text(str(child.pid))\n"
        "time.sleep(60)\n",
        encoding="utf-8",
    )
    assert fork_server.run(script, [], tmp_path / "output.txt", 1.0) is None
    grandchild = int(pid_file.read_text())
    deadline = time.monotonic() + 5
    while _running(grandchild) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _running(grandchild), "the benchmark's own child outlived the timeout"
