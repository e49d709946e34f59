"""Running a study's seeds: in local worker processes, or on a Dask cluster.

Local: `jobs` worker processes, forked from this process while it has a single thread (they
start with the rig imported), else started by a forkserver that imports this module once (so none
inherits another thread's state), fed one seed at a time from a queue. Each run is independent
and seeded, so the order they finish in does not matter. A worker that dies mid-run (a crash the
run could not catch) costs that seed only: it is recorded as aborted with the exit code, and a new
worker takes over. Workers ignore SIGINT: Ctrl-C reaches the parent, which stops every worker
(SIGTERM, then SIGKILL for any that does not stop within a second) and raises `KeyboardInterrupt`
with nothing written.

Dask: the seeds go to the scheduler at ADDRESS (`dask[distributed]`, the `study` extra; the
workers need this package installed) in chunks sized to the cluster's worker threads, largest
first and shrinking to single seeds (guided self-scheduling: few tasks, so little per-task
overhead, and small ones at the end, so no worker idles while another finishes a long chunk).
A worker plugin imports the rig on every worker once, before the first chunk arrives (and on
workers that join later). Each chunk's records come back as soon as the chunk is done, in the
order the chunks finish. A chunk whose worker failed (lost, killed) costs its seeds: each is
recorded as aborted with the reason.
"""

from __future__ import annotations

import math
import multiprocessing
import queue
import signal
import threading
from collections.abc import Callable, Sequence
from multiprocessing.context import BaseContext
from multiprocessing.process import BaseProcess
from typing import Any

from rig.errors import InputError
from rig.study.worker import RunRecord, StudySpec, run_seed

OnRecord = Callable[[RunRecord], None]
_STOP_GRACE_S = 1.0
_POLL_S = 0.2


def _worker_main(spec: StudySpec, tasks: Any, results: Any) -> None:
    """A worker process: take seeds until the None sentinel; report (start, seed) then each record."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    name = multiprocessing.current_process().name
    while True:
        seed = tasks.get()
        if seed is None:
            return
        results.put(("start", name, seed))
        results.put(("done", name, run_seed(spec, seed)))


class _LocalPool:
    """`jobs` worker processes on one task queue; see the module docstring."""

    def __init__(self, spec: StudySpec, jobs: int, ctx: BaseContext) -> None:
        self.spec = spec
        self.ctx = ctx
        self.tasks: Any = ctx.Queue()
        self.results: Any = ctx.Queue()
        self.workers: dict[str, BaseProcess] = {}
        self.current: dict[str, int] = {}  # worker name -> seed it is running
        for _ in range(jobs):
            self.start_worker()

    def start_worker(self) -> None:
        process = self.ctx.Process(  # type: ignore[attr-defined]
            target=_worker_main, args=(self.spec, self.tasks, self.results), daemon=True
        )
        process.start()
        self.workers[process.name] = process

    def reap_dead(self, on_record: OnRecord) -> int:
        """Record the seed of every worker that died mid-run as aborted and replace it; returns how many."""
        lost = 0
        for name, process in list(self.workers.items()):
            if process.is_alive():
                continue
            del self.workers[name]
            seed = self.current.pop(name, None)
            if seed is not None:
                reason = f"worker process died (exit code {process.exitcode}) during the run"
                on_record(RunRecord(seed, "aborted", reason, 0, 0, 0.0, ()))
                lost += 1
                self.start_worker()
        return lost

    def stop(self) -> None:
        """Stop every worker: SIGTERM, then SIGKILL after a grace period."""
        for process in self.workers.values():
            if process.is_alive():
                process.terminate()
        for process in self.workers.values():
            process.join(_STOP_GRACE_S)
            if process.is_alive():
                process.kill()
                process.join()
        self.tasks.cancel_join_thread()
        self.results.cancel_join_thread()

    def close(self) -> None:
        """Let the workers take their sentinels and end."""
        for process in self.workers.values():
            process.join(_STOP_GRACE_S)
        self.stop()


def _start_context() -> BaseContext:
    """How the workers start: fork while this process has one thread, else forkserver (or spawn).

    A forked worker has every module of the rig imported already (this process imported them to
    parse the command line and the protocol); a forkserver has to import them all once more,
    about as long as a run of a seed, before the first worker starts. Forking a process with other
    threads can leave a lock held in the child, so with any thread besides the main one the
    workers come from a forkserver that preloads this module.
    """
    methods = multiprocessing.get_all_start_methods()
    if "fork" in methods and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    if "forkserver" in methods:
        forkserver = multiprocessing.get_context("forkserver")
        forkserver.set_forkserver_preload([__name__])  # the server imports the rig once; workers fork
        return forkserver
    return multiprocessing.get_context("spawn")


def run_local(spec: StudySpec, seeds: Sequence[int], jobs: int, on_record: OnRecord) -> list[RunRecord]:
    """Every seed's record, run in `jobs` processes (in this process if jobs is 1)."""
    records: list[RunRecord] = []

    def collect(record: RunRecord) -> None:
        records.append(record)
        on_record(record)

    if jobs == 1:
        for seed in seeds:
            collect(run_seed(spec, seed))
        return records
    pool = _LocalPool(spec, min(jobs, len(seeds)), _start_context())
    try:
        for seed in seeds:
            pool.tasks.put(seed)
        for _ in range(len(pool.workers) + len(seeds)):  # a sentinel for every worker, replacements too
            pool.tasks.put(None)
        while len(records) < len(seeds):
            try:
                kind, name, payload = pool.results.get(timeout=_POLL_S)
            except queue.Empty:
                pool.reap_dead(collect)
                continue
            if kind == "start":
                pool.current[name] = payload
            else:
                pool.current.pop(name, None)
                collect(payload)
        pool.close()
    except BaseException:
        pool.stop()
        raise
    return records


# Chunks per worker thread in the first round of `seed_chunks`: each chunk is this share of what is left.
_CHUNKS_PER_THREAD = 4


def seed_chunks(seeds: Sequence[int], threads: int) -> list[list[int]]:
    """`seeds` in order, in chunks of ceil(remaining / (4 x threads)): largest first, then single seeds."""
    chunks: list[list[int]] = []
    start = 0
    while start < len(seeds):
        size = math.ceil((len(seeds) - start) / (_CHUNKS_PER_THREAD * max(1, threads)))
        chunks.append(list(seeds[start : start + size]))
        start += size
    return chunks


def run_chunk(spec: StudySpec, seeds: Sequence[int]) -> list[RunRecord]:
    """A Dask task: the records of `seeds`, run one after the other in this worker."""
    return [run_seed(spec, seed) for seed in seeds]


def require_dask() -> None:
    """`InputError` naming the extra to install when Dask's distributed scheduler is not importable."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise InputError(
            "--scheduler needs Dask, which is not installed; allowed: install the `study` extra "
            "(pip install 'slip-trial-rig[study]', i.e. dask[distributed])"
        ) from None


def run_dask(spec: StudySpec, seeds: Sequence[int], address: str, on_record: OnRecord) -> list[RunRecord]:
    """Every seed's record, run on the Dask scheduler at `address`."""
    require_dask()
    from distributed import Client, as_completed

    from rig.study.dask_plugin import PRELOAD_PLUGIN, PreloadRig

    try:
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(
            f"--scheduler {address}: cannot connect ({exc}); allowed: a running Dask scheduler"
        ) from None
    records: list[RunRecord] = []
    futures = []
    try:
        client.register_plugin(PreloadRig(), name=PRELOAD_PLUGIN)
        threads = sum(client.nthreads().values())
        chunks = seed_chunks(seeds, threads)
        futures = client.map(run_chunk, [spec] * len(chunks), chunks, pure=False)
        chunk_of = {future.key: chunk for future, chunk in zip(futures, chunks, strict=True)}
        for future in as_completed(futures):
            try:
                done: list[RunRecord] = future.result()
            except Exception as exc:  # the worker itself failed (lost, killed): the chunk's seeds are aborted
                reason = f"dask: {type(exc).__name__}: {exc}"
                done = [RunRecord(seed, "aborted", reason, 0, 0, 0.0, ()) for seed in chunk_of[future.key]]
            for record in done:
                records.append(record)
                on_record(record)
    finally:
        client.cancel(futures)
        client.close()
    return records
