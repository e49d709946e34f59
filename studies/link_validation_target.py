"""Link validation in simulation, links 1 and 2, seeds 0-4: share of |error| < 15 %, measured vs commanded.

Each run is `rig run` of a link-validation protocol on a rig with a fork on every component
(protocols/rigs/forks-link{1,2}.yaml). "measured": the configuration source is the simulator
(camera-like noise, 0.4 deg per joint) and the forks bend, measure and correct; the prediction uses
the last measurement. "commanded": the same rig with `configuration.source: command`: nothing is
measured, the forks bend once, and the prediction uses the commanded angles, so the forks'
placement error (which depends on the joints' capacities) goes into the prediction.

    python studies/link_validation_target.py --out /tmp/lv-target     # prints a markdown table
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LINKS = {
    "link 1": ("protocols/link_validation.yaml", "protocols/rigs/forks-link1.yaml"),
    "link 2": ("protocols/link_validation_link2.yaml", "protocols/rigs/forks-link2.yaml"),
}
SEEDS = range(5)


def run(protocol: str, rig: Path, seed: int, out: Path) -> list[float]:
    """The absolute percentage errors of one run (its logs in `out`, named by the seed)."""
    done = subprocess.run(
        [sys.executable, "-m", "rig.cli", "run", protocol, "--rig", str(rig), "--seed", str(seed),
         "--devices", "object", "--out", str(out), "--run-id", f"seed{seed}", "--json"],
        cwd=ROOT, capture_output=True, text=True, check=False,
    )  # fmt: skip
    if done.returncode != 0:
        raise RuntimeError(f"{protocol} seed {seed}: exit {done.returncode}: {done.stderr[-500:]}")
    errors: list[float] = json.loads(done.stdout)["percentage_errors"]["percentage_errors"]
    return errors


def commanded_rig(rig: str, where: Path) -> Path:
    """The rig config with `configuration.source: command` (written beside the run's logs)."""
    path = where / f"commanded-{Path(rig).name}"
    path.write_text((ROOT / rig).read_text() + "configuration:\n  source: command\n")
    return path


def main() -> None:
    """Run every link, seed and source; print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(tempfile.mkdtemp(prefix="lv-target-")))
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    jobs = []
    for link, (protocol, rig) in LINKS.items():
        rigs = {"measured": ROOT / rig, "commanded": commanded_rig(rig, args.out)}
        for source, rig_path in rigs.items():
            for seed in SEEDS:
                jobs.append((link, source, protocol, rig_path, seed))
    with ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(lambda j: run(j[2], j[3], j[4], args.out / f"{j[0][-1]}-{j[1]}"), jobs))
    table: dict[tuple[str, str], list[float]] = {}
    for (link, source, *_), errors in zip(jobs, results, strict=True):
        table.setdefault((link, source), []).extend(errors)
    print("| link | prediction from | trials | share \\|error\\| < 15 % | mean \\|error\\| % |")
    print("|---|---|---|---|---|")
    for both in ("link 1", "link 2", "both"):
        for source in ("measured", "commanded"):
            errors = [
                e for (link, s), v in table.items() if s == source and both in (link, "both") for e in v
            ]
            share = sum(e < 15.0 for e in errors) / len(errors)
            mean = sum(errors) / len(errors)
            print(f"| {both} | {source} | {len(errors)} | {100 * share:.1f} % | {mean:.1f} |")


if __name__ == "__main__":
    main()
