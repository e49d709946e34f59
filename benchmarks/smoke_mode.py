"""What the benchmarks share for their smoke mode, `--smoke`: the help text, a short protocol, an interpreter.

Every `benchmarks/bench_*.py` takes `--smoke`: its own measurement code on a few iterations, done in
seconds, exit 0 once every code path ran (the figures mean nothing). tests/test_benchmarks_smoke.py
runs each one that way, so a change under a benchmark fails a test instead of the next measurement.
Not a benchmark itself (no `bench_` prefix): imported by the scripts, whose directory is on the path.
Standard library only at import time.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
JOINT_ESTIMATION = ROOT / "protocols" / "joint_estimation.yaml"
SMOKE_HELP = "a few iterations of the same measurement, to check that it still runs (figures meaningless)"


def short_protocol(
    folder: Path, source: Path = JOINT_ESTIMATION, name: str = "smoke-protocol.yaml", trials: int = 2
) -> Path:
    """A copy of the joint-estimation protocol `source` with `trials` distances (its longest), once each."""
    import yaml  # here, not above: some benchmarks' parents stay stdlib-only for their children's peak RSS

    data = yaml.safe_load(source.read_text(encoding="utf-8"))
    (block,) = data["blocks"]
    block["distances_m"] = sorted(block["distances_m"])[-trials:]
    block["repeats"] = 1
    block.pop("shuffle", None)
    path = folder / name
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def tree_python(tree: Path) -> str:
    """The interpreter for `tree`'s code: its own `.venv`'s, or this one (a worktree on a shared venv)."""
    own = tree / ".venv" / "bin" / "python"
    return str(own) if own.exists() else sys.executable
