"""Independent chunks of work on the machine's cores, by ``fork``.

:func:`fork_map` runs ``fn(chunk)`` for every chunk: the first in this process, each other in a
forked child that sends its result back pickled through a pipe. A fork shares everything
already loaded (the pose prior, the cameras, the imported modules) for free, and costs about
10 ms where a process pool costs 60–70 ms to import and start: the difference is most of a
small capture's run. Where ``fork`` is missing (Windows) or one worker is asked for, the chunks
run one after the other here. By default only Linux forks (macOS system libraries are not safe
to use in a forked child, which is why Python's own process pools spawn there).

A chunk's exception is raised here as if it had run here (the first in chunk order). A child
that dies without an answer (killed, out of memory) has its chunk run again here, so a lost
worker never loses results. A child never writes to the terminal: its log records (and
warnings) come back with its answer and are handled here, in order, so that nothing waits on a
lock that another thread of the parent (a progress bar) held at the fork. Children never run
the parent's exit handlers or flush its buffers: they leave by ``os._exit``.
"""
from __future__ import annotations

import logging
import os
import pickle
import signal
import sys
from collections.abc import Callable, Sequence
from typing import Any

#: Environment variable capping the worker processes (``1``: everything in this process).
WORKERS_ENV = "MVM_WORKERS"


def available_workers(requested: int | None = None) -> int:
    """Worker processes to use: ``requested`` if given (not 0), else ``$MVM_WORKERS``, else the
    cores this process may run on (Linux; 1 elsewhere); at least 1."""
    if not requested:
        env = os.environ.get(WORKERS_ENV, "").strip()
        requested = int(env) if env.isdigit() else None
    if not requested:
        requested = len(os.sched_getaffinity(0)) if sys.platform.startswith("linux") else 1
    return max(1, int(requested))


def split(n: int, parts: int, min_size: int = 1) -> list[range]:
    """``n`` items as at most ``parts`` contiguous, nearly equal, non-empty ranges of at least
    ``min_size`` items each where ``n`` allows (work too small to be worth a fork stays whole)."""
    if n <= 0:
        return []
    parts = max(1, min(parts, n // max(min_size, 1)))
    bounds = [n * k // parts for k in range(parts + 1)]
    return [range(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def fork_map(fn: Callable[[Any], Any], chunks: Sequence, workers: int | None = None) -> list:
    """``[fn(chunk) for chunk in chunks]``, the chunks after the first in forked children.

    ``workers`` caps the processes (this one included; :func:`available_workers` by default):
    with fewer workers than chunks the extra chunks run here after the first. ``fn`` should not
    write to the terminal or to shared files from a child (its progress is the caller's, from
    the first chunk)."""
    chunks = list(chunks)
    forked = min(len(chunks), available_workers(workers)) - 1
    children = [Forked(fn, chunk) for chunk in chunks[1:1 + max(forked, 0)]]
    try:
        results = [fn(chunks[0])] if chunks else []
        results += [child.result() for child in children]
        return results + [fn(chunk) for chunk in chunks[1 + len(children):]]
    finally:
        for child in children:
            child.stop()


def fork_map_ranges(fn: Callable[[range], Any], n: int, min_size: int = 1, workers: int | None = None) -> list:
    """:func:`fork_map` of ``fn`` over ``n`` items in contiguous ranges (:func:`split`: one per
    worker, at least ``min_size`` items each where ``n`` allows)."""
    workers = available_workers(workers)
    return fork_map(fn, split(n, workers, min_size), workers)


class Forked:
    """``fn(chunk)`` computed in a forked child from the moment this is made (or here, by
    :meth:`result`, where no process can be forked); :meth:`result` waits for it, :meth:`stop`
    ends it. The child writes ``(ok, value, log records)`` pickled to a pipe and leaves."""

    def __init__(self, fn: Callable[[Any], Any], chunk):
        self.fn, self.chunk, self.pid, self.fd = fn, chunk, None, None
        if not hasattr(os, "fork"):                         # not POSIX: done here
            return
        read, write = os.pipe()
        try:
            pid = os.fork()
        except OSError:                                     # no process to be had: done here
            os.close(read)
            os.close(write)
            return
        if pid == 0:
            os.close(read)
            _child(fn, chunk, write)                        # never returns
        os.close(write)
        self.pid, self.fd = pid, read

    def result(self):
        """The child's value (its exception raised here, its log records handled here first);
        the chunk computed here if the child gave no answer (it died) or never ran."""
        if self.fd is None:
            return self.fn(self.chunk)
        with os.fdopen(os.dup(self.fd), "rb") as pipe:
            data = pipe.read()
        try:
            ok, value, records = pickle.loads(data)
        except Exception:                                   # died before answering: redo it here
            return self.fn(self.chunk)
        for record in records:
            logging.getLogger(record.name).handle(record)
        if not ok:
            raise value
        return value

    def stop(self) -> None:
        """Close the pipe and reap the child (killed first if it is still running)."""
        if self.fd is None:
            return
        os.close(self.fd)
        self.fd = None
        try:
            if os.waitpid(self.pid, os.WNOHANG) == (0, 0):
                os.kill(self.pid, signal.SIGKILL)
                os.waitpid(self.pid, 0)
        except ChildProcessError:
            pass


def _child(fn: Callable, chunk, write: int) -> None:
    """In the forked child: compute ``fn(chunk)``, write the answer to ``write`` and exit."""
    status = 0
    try:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        records = _keep_log_records()
        try:
            answer = (True, fn(chunk))
        except BaseException as e:                          # noqa: BLE001 - raised again in the parent
            answer = (False, e)
        try:
            data = pickle.dumps((*answer, records), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as e:                              # an unpicklable result or exception
            data = pickle.dumps((False, RuntimeError(f"worker result could not be sent: {e!r}"), records))
        with os.fdopen(write, "wb") as pipe:
            pipe.write(data)
    except BaseException:                                   # noqa: BLE001 - the parent reruns the chunk
        status = 1
    finally:
        os._exit(status)


class _Kept(logging.Handler):
    """Keeps a child's log records, made picklable (message formatted, no arguments or traceback)."""

    def __init__(self, records: list):
        super().__init__()
        self.records = records

    def emit(self, record: logging.LogRecord) -> None:
        if record.exc_info and not record.exc_text:
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        record.msg, record.args, record.exc_info = record.getMessage(), None, None
        self.records.append(record)


def _keep_log_records() -> list:
    """In a child: every log record (and warning) goes to the returned list instead of the
    parent's handlers."""
    records: list = []
    root = logging.getLogger()
    for logger in [root, *logging.root.manager.loggerDict.values()]:
        if isinstance(logger, logging.Logger):
            logger.handlers = []
    root.addHandler(_Kept(records))
    logging.captureWarnings(True)
    return records
