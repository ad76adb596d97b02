"""Many inputs in one command (scenes, clips, images): each one's failure is its own, reported
in one line, and the command ends with exit status 2 when any failed."""
from __future__ import annotations

import logging
import sys

from mvm.cli.common import err, print_line, progress
from mvm.errors import InputError


def failure_line(item, error: BaseException) -> str:
    """One line for ``error`` raised while handling ``item`` (a scene, a clip, an image): an
    InputError names its file already; any other error is prefixed with the item and its type."""
    if isinstance(error, InputError):
        return str(error)
    text = " ".join(str(error).split()) or "(no message)"
    return f"{item}: {type(error).__name__}: {text}"


def report_failure(item, error: Exception, failed: list, console=None) -> None:
    """``error`` is ``item``'s failure: appended to ``failed`` and printed as one line (the
    traceback of an error other than bad input goes to the debug log, ``mvm -vv``)."""
    if not isinstance(error, InputError):
        logging.getLogger("mvm").debug("%s failed", item, exc_info=error)
    failed.append(item)
    print_line(f"mvm: error: {failure_line(item, error)}", console)


def each_isolated(items, work, failed: list, console=None):
    """Yield ``(item, work(item))`` for every item, each isolated from the others: any exception
    while handling one item is that item's failure (:func:`report_failure`), and the next item
    is done."""
    for item in items:
        try:
            result = work(item)
        except Exception as e:                      # one item's failure is not the run's
            report_failure(item, e, failed, console)
        else:
            yield item, result


def run_outcomes(total: int, outcomes, label: str = "") -> tuple[list, list]:
    """A progress bar over ``outcomes``, ``(item, result or Exception)`` pairs from a library
    driver that isolates its items itself (e.g. :func:`mvm.scenes.reconstruct_dirs`); each
    exception is reported as :func:`report_failure` does. Returns ``([(item, result)], [failed item])``."""
    done, failed = [], []
    with progress() as bar:
        task = bar.add_task(label, total=total)
        for item, outcome in outcomes:
            if isinstance(outcome, Exception):
                report_failure(item, outcome, failed, bar.console)
            else:
                done.append((item, outcome))
            bar.update(task, advance=1, description=f"{label} {getattr(item, 'name', item)}".strip())
    return done, failed


def report_failures(failed: list, total: int, kind: str = "scene") -> None:
    """After a run over several inputs: how many failed, and exit status 2 when any did."""
    if failed:
        err().print(f"{len(failed)} of {total} {kind}(s) failed", style="red")
        sys.exit(2)
