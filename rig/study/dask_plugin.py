"""The Dask worker plugin of `rig study --scheduler`: the rig imported once per worker, up front.

Imported only where Dask is (`rig.study.executor.run_dask`): this module needs `distributed`.
Registering the plugin makes every worker unpickle it, which imports this module and, through
`setup`, the study's worker module with everything a run needs (the runner, the simulated rig,
the estimators): once per worker, on all workers at once, before the first chunk of seeds
arrives, and on any worker that joins later.
"""

from __future__ import annotations

from distributed.diagnostics.plugin import WorkerPlugin

PRELOAD_PLUGIN = "rig-study-preload"


class PreloadRig(WorkerPlugin):  # type: ignore[misc]  # distributed is untyped here
    """Imports the rig on a worker when registered or when the worker joins."""

    idempotent = True  # registered by every study: a worker that has it keeps it

    def setup(self, worker: object) -> None:
        """Import what a run needs."""
        import rig.study.worker  # noqa: F401
