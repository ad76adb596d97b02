"""What the ``mvm`` process keeps for itself: its stderr and its signals.

* **Native output into the log** (:func:`native_output_to_log`): COLMAP (glog), FFmpeg and
  OpenCV write to file descriptor 2 directly, past Python. Unless ``-v``, the command runs with
  descriptor 2 pointing to a temporary file, while Python's ``sys.stderr`` (mvm's progress bars,
  warnings and errors) keeps writing to the terminal; what the libraries wrote becomes debug
  records of the log (``mvm -vv`` shows them as they come).
* **A clean exit on SIGINT and SIGTERM** (:func:`install_signal_handlers`): both raise
  :class:`Interrupted` (a ``KeyboardInterrupt``), which ends the command in one line and the
  shell's status (130, 143). pycolmap installs glog's failure handler when imported, which
  turns SIGTERM into a stack dump of the native code; the handlers are put back after that
  import (:class:`_KeepHandlers`).
"""
from __future__ import annotations

import contextlib
import importlib.abc
import logging
import os
import signal
import sys
import tempfile
import threading

#: Modules that install their own signal handlers when imported (glog's failure handler).
HANDLER_STEALERS = frozenset({"pycolmap"})

log = logging.getLogger("mvm.native")


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM received: ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _interrupt(signum, frame):
    raise Interrupted(signum)


def install_signal_handlers() -> None:
    """SIGINT and SIGTERM raise :class:`Interrupted`, now and after a module of
    :data:`HANDLER_STEALERS` is imported. Only from the main thread (elsewhere: nothing)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _interrupt)
    if not any(isinstance(finder, _KeepHandlers) for finder in sys.meta_path):
        sys.meta_path.insert(0, _KeepHandlers())


class _KeepHandlers(importlib.abc.MetaPathFinder):
    """Puts mvm's SIGINT and SIGTERM handlers back once a module of :data:`HANDLER_STEALERS`
    has been imported (it finds nothing itself: the import goes on as usual)."""

    def find_spec(self, name, path=None, target=None):
        if name not in HANDLER_STEALERS or name in sys.modules:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None and spec.loader is not None:
                spec.loader = _ThenRestore(spec.loader)
                return spec
        return None


class _ThenRestore(importlib.abc.Loader):
    def __init__(self, loader):
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module):
        try:
            self.loader.exec_module(module)
        finally:
            if threading.current_thread() is threading.main_thread():
                for signum in (signal.SIGINT, signal.SIGTERM):
                    signal.signal(signum, _interrupt)


def interrupted_line(error: KeyboardInterrupt) -> tuple[str, int]:
    """The one line and the exit status (128 + signal) of an interrupted command."""
    signum = getattr(error, "signum", signal.SIGINT)
    return f"mvm: interrupted ({signal.Signals(signum).name})", 128 + int(signum)


@contextlib.contextmanager
def native_output_to_log():
    """Run the block with file descriptor 2 sent to a temporary file and ``sys.stderr`` (where
    it writes to descriptor 2) on a copy of the original descriptor; afterwards every non-empty
    line the native libraries wrote is a debug record of the ``mvm.native`` logger. Where
    descriptor 2 cannot be duplicated it does nothing."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):
        yield
        return
    original = sys.stderr
    try:
        on_fd2 = original.fileno() == 2
    except (OSError, ValueError, AttributeError):     # a stream of its own (a test's capture): left as it is
        on_fd2 = False
    capture = tempfile.TemporaryFile()
    try:
        os.dup2(capture.fileno(), 2)
        if on_fd2:
            sys.stderr = os.fdopen(os.dup(saved), "w", buffering=1,
                                   encoding=getattr(original, "encoding", None) or "utf-8", errors="backslashreplace")
        try:
            yield
        finally:
            if on_fd2:
                with contextlib.suppress(Exception):
                    sys.stderr.flush()
                    sys.stderr.close()
                sys.stderr = original
            os.dup2(saved, 2)
            capture.seek(0)
            for line in capture.read().decode("utf-8", "replace").splitlines():
                if line.strip():
                    log.debug("%s", line.rstrip())
    finally:
        os.close(saved)
        capture.close()
