"""How tangled replay's path is: the modules `rig replay --report` runs and the calls between packages.

Runs `rig replay LOG --json --report DIR` in this process under `sys.setprofile` and records every
Python call from a function of one `rig`/`model` module into a function of another. Prints:

* modules: the `rig` and `model` modules whose functions ran;
* crossings: the distinct (caller function, callee function) pairs whose modules lie one in
  `rig.analysis` and the other in `rig.log` (either way), i.e. the places where the path goes
  between the two packages;
* frames entries: the distinct (caller function, callee function) pairs that enter
  `rig.log.reading.frames` from another module.

Counts are of distinct call sites seen at run time, so they do not grow with the log. Run it with
the tree to measure first on the path, e.g.
`PYTHONPATH=TREE python tools/replay_crossings.py LOG`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from contextlib import redirect_stdout
from pathlib import Path
from types import FrameType
from typing import Any


def _module(frame: FrameType) -> str | None:
    name = frame.f_globals.get("__name__")
    if isinstance(name, str) and (name.startswith("rig.") or name.startswith("model.")):
        return name
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    from rig.cli import main as rig_main

    modules: set[str] = set()
    edges: set[tuple[str, str, str, str]] = set()  # caller module, function, callee module, function

    def profile(frame: FrameType, event: str, _arg: Any) -> None:
        if event != "call":
            return
        callee = _module(frame)
        if callee is None:
            return
        modules.add(callee)
        caller_frame = frame.f_back
        caller = _module(caller_frame) if caller_frame is not None else None
        if caller is not None and caller_frame is not None and caller != callee:
            edges.add((caller, caller_frame.f_code.co_name, callee, frame.f_code.co_name))

    with tempfile.TemporaryDirectory() as tmp, open(os.devnull, "w") as sink, redirect_stdout(sink):
        sys.setprofile(profile)
        try:
            code = rig_main(["replay", str(args.log), "--json", "--report", str(Path(tmp) / "r")])
        finally:
            sys.setprofile(None)
    if code != 0:
        raise SystemExit(f"rig replay exited {code}")

    def package(module: str) -> str:
        return ".".join(module.split(".")[:2])

    crossings = sorted(e for e in edges if {package(e[0]), package(e[2])} == {"rig.analysis", "rig.log"})
    frames_entries = sorted(e for e in edges if e[2] == "rig.log.reading.frames")
    result = {
        "modules": len(modules),
        "crossings": len(crossings),
        "frames_entries": len(frames_entries),
        "module_list": sorted(modules),
        "crossing_list": [f"{a}.{f} -> {b}.{g}" for a, f, b, g in crossings],
        "frames_entry_list": [f"{a}.{f} -> {b}.{g}" for a, f, b, g in frames_entries],
    }
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print(
            f"modules {result['modules']}, analysis<->log crossings {result['crossings']}, "
            f"frames.py entries {result['frames_entries']}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
