"""The one exception type that reaches the user as a single line and exit status 2."""
from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input: names the file, the field (or line) and what is wrong.

    ``str(error)`` is the single line the command line prints, e.g.
    ``scene/poses2d.json: annotations[3].keypoints: expected 51 numbers, got 34``.
    """

    def __init__(self, path: str | Path | None, field: str | None, problem: str):
        self.path = None if path is None else str(path)
        self.field = field
        self.problem = problem
        parts = [p for p in (self.path, field) if p]
        super().__init__(": ".join(parts + [problem]))

    def __reduce__(self):
        """Pickled with its three parts (a worker process raises it in its parent)."""
        return type(self), (self.path, self.field, self.problem)
