"""Run a protocol on the simulated rig through the API `rig run` uses (runner and replay tests share it)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from rig.rigs import open_simulated_rig
from rig.runner.progress import SilentProgress
from rig.runner.run import RunReport, RunRequest, execute_run, prepare_run
from rig.sim.simulated_rig import SimulatedRig


def run_on_simulated_rig(
    protocol: Path,
    out_dir: Path,
    *,
    run_id: str = "r1",
    resume: bool = False,
    seed: int = 3,
    patch: Callable[[SimulatedRig], None] | None = None,
) -> tuple[RunReport, SimulatedRig]:
    """Start run `run_id` (or resume it) and run it to its end; `patch` may alter the rig first."""
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
    return execute_run(prepared, sim.session, SilentProgress()), sim
