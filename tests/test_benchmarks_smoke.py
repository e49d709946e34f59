"""Every benchmark in benchmarks/ still runs: each `bench_*.py --smoke` in its own process, exit 0.

A benchmark's smoke mode is its own measurement code on a few iterations (benchmarks/smoke_mode.py);
the figures are not checked, only that the code under the benchmark has not moved away from it. The
list is the directory's, so a new benchmark without `--smoke` fails here (argparse: exit 2; the
source is also checked for the option, as a script without argparse would run in full).
Skipped, with the reason, only where what a benchmark needs is not installed, as its tests skip:
the AVR toolchain and simavr (bench_firmware.py), OpenCV with cv2.aruco (bench_camera.py), valgrind
(bench_runner_instructions.py), Dask (bench_study.py).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = sorted((ROOT / "benchmarks").glob("bench_*.py"))
TIMEOUT_S = 100  # under pytest's own 120 s, so that a hung benchmark shows its output


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


@pytest.mark.slow
@pytest.mark.parametrize("script", BENCHMARKS, ids=[path.name for path in BENCHMARKS])
def test_benchmark_runs_in_smoke_mode(script: Path) -> None:
    requirement = REQUIREMENTS.get(script.name)
    missing = requirement() if requirement is not None else None
    if missing is not None:
        pytest.skip(missing)
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH")))),
    }
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, str(script), "--smoke"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
    )
    seconds = time.perf_counter() - start
    assert done.returncode == 0, (
        f"{script.name} --smoke: exit {done.returncode} after {seconds:.1f} s\n"
        f"stdout (end):\n{done.stdout[-3000:]}\nstderr (end):\n{done.stderr[-3000:]}"
    )
