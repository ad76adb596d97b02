"""Where the stages run: a local process pool, or Ray (a local instance or a cluster).

An engine takes ``(clip, stage)`` tasks and gives back :class:`StageResult` s. A worker that
dies (killed, out of memory, a lost node) gives a transient failure for the tasks it held;
the runner decides whether to retry them.
"""
from __future__ import annotations

import logging
import os
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from mvm.batch.clips import Clip
from mvm.batch.stages import GPU_STAGES, BatchOptions, StageResult, run_stage
from mvm.errors import InputError
from mvm.parallel import WORKERS_ENV

log = logging.getLogger(__name__)

ENGINES = ("local", "ray")
#: Set to 1 in every worker: one BLAS thread, and no worker processes of its own (mvm.parallel):
#: the engine already keeps every core busy.
_SINGLE_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS", WORKERS_ENV)


def _lost(clip: Clip, stage: str, why: str) -> StageResult:
    return StageResult(clip.id, stage, ok=False, error=f"worker lost: {why}", transient=True)


def _watch_parent(parent: int) -> None:
    """End this worker when the driver is gone, so that no orphan keeps working."""
    while True:
        if os.getppid() != parent:
            os._exit(1)
        time.sleep(0.5)


def _init_worker(parent: int) -> None:
    for name in _SINGLE_THREAD_ENV:
        os.environ[name] = "1"
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()


class LocalEngine:
    """``workers`` processes of this machine (spawned, single-threaded BLAS each)."""

    name = "local"

    def __init__(self, workers: int, options: BatchOptions):
        import multiprocessing

        self.capacity = max(1, int(workers))
        self.options = options
        self._context = multiprocessing.get_context("spawn")
        self._pool = self._new_pool()
        self._running: dict[Future, tuple[Clip, str]] = {}
        self._lost_results: list[StageResult] = []

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.capacity, mp_context=self._context, initializer=_init_worker,
                                   initargs=(os.getpid(),))

    def worker_pids(self) -> list[int]:
        return [p.pid for p in (self._pool._processes or {}).values()]

    def submit(self, clip: Clip, stage: str, force: bool = False) -> None:
        try:
            future = self._pool.submit(run_stage, clip, stage, self.options, force)
        except BrokenProcessPool:                       # a worker ended since the last poll
            self._restart()
            future = self._pool.submit(run_stage, clip, stage, self.options, force)
        self._running[future] = (clip, stage)

    def poll(self, timeout: float) -> list[StageResult]:
        results, self._lost_results = self._lost_results, []
        if not self._running:
            return results
        done, _ = wait(list(self._running), timeout=timeout, return_when=FIRST_COMPLETED)
        broken = False
        for future in done:
            clip, stage = self._running.pop(future)
            try:
                results.append(future.result())
            except BrokenProcessPool:
                broken = True
                results.append(_lost(clip, stage, "a worker process ended abruptly"))
        if broken:
            self._restart()
            results, self._lost_results = results + self._lost_results, []
        return results

    def _restart(self) -> None:
        """A worker ended abruptly: every stage still running is lost (reported by the next
        :meth:`poll`, and retried by the runner) and the pool is started afresh."""
        log.warning("a worker process ended abruptly; restarting the pool")
        self._lost_results += [_lost(clip, stage, "a worker process ended abruptly")
                               for clip, stage in self._running.values()]
        self._running.clear()
        self._pool.shutdown(wait=False, cancel_futures=True)
        self._pool = self._new_pool()

    def close(self, wait: bool = True) -> None:
        """Stop the pool; without ``wait`` (an interrupted run) its workers are ended at once."""
        processes = list((self._pool._processes or {}).values())
        self._pool.shutdown(wait=wait, cancel_futures=True)
        if not wait:
            for process in processes:
                process.kill()


class RayEngine:
    """One Ray task per (clip, stage) on a local Ray instance (``address`` None, ``workers``
    CPUs) or an existing cluster (``address``, e.g. ``ray://head:10001`` or ``auto``). ``detect``
    asks for a GPU when the cluster has one and the network runs; the other stages one CPU.
    The clips' directories must be on a file system every node sees."""

    name = "ray"

    def __init__(self, workers: int | None, options: BatchOptions, address: str | None = None):
        try:
            import ray
        except ImportError:
            raise InputError(None, "--engine", "ray is not installed (pip install 'mvm[ray]')") from None
        self.ray = ray
        self.options = options
        self._started = not ray.is_initialized()
        if self._started:
            kwargs = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
            try:
                if address:
                    ray.init(address=address, **kwargs)
                else:
                    ray.init(num_cpus=workers, **kwargs)
            except Exception as e:  # noqa: BLE001 - Ray raises many types; the user needs one line
                raise InputError(None, "--engine ray", f"cannot start or reach Ray: {str(e).splitlines()[0]}") from None
        resources = ray.cluster_resources()
        cpus = int(resources.get("CPU", 1))
        self.gpus = float(resources.get("GPU", 0))
        self.capacity = max(1, int(workers) if workers else cpus)
        self._task = ray.remote(run_stage)
        self._running: dict = {}

    def submit(self, clip: Clip, stage: str, force: bool = False) -> None:
        gpu = 1 if (stage in GPU_STAGES and self.gpus >= 1 and self.options.checkpoint) else 0
        options = self.options if not gpu else _with_device(self.options, "cuda")
        ref = self._task.options(num_cpus=1, num_gpus=gpu, max_retries=0).remote(clip, stage, options, force)
        self._running[ref] = (clip, stage)

    def poll(self, timeout: float) -> list[StageResult]:
        if not self._running:
            return []
        ready, rest = self.ray.wait(list(self._running), num_returns=1, timeout=timeout)
        if ready and rest:
            ready += self.ray.wait(rest, num_returns=len(rest), timeout=0)[0]
        results = []
        for ref in ready:
            clip, stage = self._running.pop(ref)
            try:
                results.append(self.ray.get(ref))
            except self.ray.exceptions.RayError as e:
                results.append(_lost(clip, stage, type(e).__name__))
        return results

    def close(self, wait: bool = True) -> None:
        for ref in list(self._running):
            self.ray.cancel(ref, force=True)
        self._running.clear()
        if self._started:
            self.ray.shutdown()


def _with_device(options: BatchOptions, device: str) -> BatchOptions:
    from dataclasses import replace

    return replace(options, detect=replace(options.detect, device=device))


def make_engine(name: str, workers: int | None, options: BatchOptions, address: str | None = None):
    """The engine ``name`` (one of :data:`ENGINES`)."""
    if name == "local":
        if address:
            raise InputError(None, "--address", "only with --engine ray")
        return LocalEngine(workers or os.cpu_count() or 1, options)
    if name == "ray":
        return RayEngine(workers, options, address)
    raise InputError(None, "--engine", f"unknown engine {name!r}: expected one of {', '.join(ENGINES)}")
