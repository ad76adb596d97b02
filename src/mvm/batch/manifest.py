"""The manifest of a batch run: every (clip, stage) with its state, in an SQLite database.

``ROOT/.mvm/manifest.sqlite`` (WAL journal, every change one ``BEGIN IMMEDIATE`` transaction):

- ``clips``: id, sequence, scene directory, video (paths relative to the root, so that the
  root can be moved; manifests written with absolute paths are still read).
- ``stages``: one row per (clip, stage): ``state`` (``pending``, ``running``, ``done``,
  ``failed``, ``skipped``), attempts, the owning run and its lease, seconds, the error line,
  the sha256 of the committed files, the clip's statistics (JSON).
- ``runs``: every ``mvm batch`` invocation: host, pid, engine, workers, start, heartbeat, end.
- ``history``: an append-only log of claims, commits, failures, retries and recoveries.

A stage is *claimed* by a run before a worker starts it and *committed* only after the worker
reports its outputs complete. A run renews its leases while it lives; the claims of a run that
died (its process is gone, or its lease expired on another host) go back to ``pending``.
"""
from __future__ import annotations

import json
import math
import os
import socket
import sqlite3
import time
from collections.abc import Iterable
from contextlib import contextmanager
from pathlib import Path

from mvm.batch.clips import Clip
from mvm.batch.stages import STAGES, StageResult
from mvm.errors import InputError

MANIFEST = Path(".mvm") / "manifest.sqlite"
STATES = ("pending", "running", "done", "failed", "skipped")
#: Seconds a claim stays valid without being renewed.
LEASE_S = 120.0
#: Seconds a run waits for the others to let it open the manifest.
OPEN_TIMEOUT_S = 60.0

_SCHEMA = """
CREATE TABLE IF NOT EXISTS clips (
    id TEXT PRIMARY KEY, sequence TEXT NOT NULL, scene TEXT NOT NULL, video TEXT);
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT, host TEXT NOT NULL, pid INTEGER NOT NULL, engine TEXT,
    workers INTEGER, stages TEXT, started REAL NOT NULL, heartbeat REAL NOT NULL, finished REAL,
    outcome TEXT);
CREATE TABLE IF NOT EXISTS stages (
    clip TEXT NOT NULL REFERENCES clips(id), stage TEXT NOT NULL, state TEXT NOT NULL,
    attempts INTEGER NOT NULL DEFAULT 0, run INTEGER, lease_until REAL, started REAL, finished REAL,
    seconds REAL, error TEXT, checksum TEXT, files INTEGER, worker TEXT, stats TEXT, detail TEXT,
    PRIMARY KEY (clip, stage));
CREATE TABLE IF NOT EXISTS history (
    id INTEGER PRIMARY KEY AUTOINCREMENT, time REAL NOT NULL, run INTEGER, clip TEXT NOT NULL,
    stage TEXT NOT NULL, event TEXT NOT NULL, detail TEXT);
CREATE INDEX IF NOT EXISTS history_clip ON history (clip, stage);
"""
#: Statistics of a clip (:func:`mvm.batch.stages.clip_stats`) that are counts.
_COUNTS = ("frames", "poses2d", "matched", "unmatched", "persons", "joints")
#: The columns each table must have (a table of another program with the same name is refused).
_COLUMNS = {
    "clips": ("id", "sequence", "scene", "video"),
    "runs": ("id", "host", "pid", "engine", "workers", "stages", "started", "heartbeat", "finished", "outcome"),
    "stages": ("clip", "stage", "state", "attempts", "run", "lease_until", "started", "finished", "seconds", "error",
               "checksum", "files", "worker", "stats", "detail"),
    "history": ("id", "time", "run", "clip", "stage", "event", "detail"),
}


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class Manifest:
    """The manifest database of ``root`` (created on first use)."""

    def __init__(self, root: str | Path, create: bool = True):
        """Open (with ``create``: create) the manifest of ``root``. Without ``create`` nothing is
        written: a missing manifest, a file that is not an SQLite database or tables of another
        program raise an :class:`InputError` naming the file."""
        self.root = Path(root)
        self.path = self.root / MANIFEST
        if not create and not self.path.is_file():
            raise InputError(self.path, None, "no manifest: run `mvm batch` on this directory first")
        if create:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        deadline = time.monotonic() + OPEN_TIMEOUT_S
        while True:
            db = None
            try:
                db = self.db = sqlite3.connect(self.path, timeout=OPEN_TIMEOUT_S, isolation_level=None)
                self._open(create)
                break
            except (sqlite3.DatabaseError, UnicodeDecodeError) as e:
                if db is not None:
                    db.close()
                # Switching a new database to WAL while another run opens it fails at once with
                # "database is locked", without SQLite's busy timeout: try again until it expires.
                locked = isinstance(e, sqlite3.OperationalError) and "locked" in str(e)
                if not locked or time.monotonic() > deadline:
                    raise self._unreadable(e) from None
                time.sleep(0.05)
        self.db.row_factory = sqlite3.Row

    def _open(self, create: bool) -> None:
        """Set the journal up and create the tables (``create``), then check them."""
        if create:
            self.db.execute("PRAGMA journal_mode=WAL")
            self.db.execute("PRAGMA synchronous=FULL")
            self.db.executescript(f"BEGIN IMMEDIATE;\n{_SCHEMA}\nCOMMIT;")      # readers see all tables or none
        self._check_schema()

    def _unreadable(self, error: Exception) -> InputError:
        """The one-line refusal of a manifest SQLite cannot read (or whose text is not UTF-8)."""
        if isinstance(error, UnicodeDecodeError):
            return InputError(self.path, None, f"not a readable manifest: text that is not UTF-8 (byte {error.start})")
        return InputError(self.path, None, f"not a readable manifest: {' '.join(str(error).split())}")

    def _check_schema(self) -> None:
        """Refuse tables of another program. A database without any table yet (a run is
        creating it) reads as an empty manifest."""
        self.empty = self.db.execute("SELECT count(*) FROM sqlite_master").fetchone()[0] == 0
        if self.empty:
            return
        for table, columns in _COLUMNS.items():
            have = {row[1] for row in self.db.execute(f"PRAGMA table_info({table})")}
            if not have:
                raise InputError(self.path, table, "no such table: not a manifest of `mvm batch`")
            missing = [c for c in columns if c not in have]
            if missing:
                raise InputError(self.path, table, f"not the table of `mvm batch`: no column {', '.join(missing)}")

    def _stored(self, path: str | None) -> str | None:
        """A clip's path as stored: relative to the root when it lies inside it."""
        if path is None:
            return None
        try:
            return Path(path).resolve().relative_to(self.root.resolve()).as_posix()
        except ValueError:
            return str(path)

    def _resolved(self, stored: str | None, fallback: Path | None = None) -> str | None:
        """A stored path made absolute: relative ones are under the root; an absolute one that
        no longer exists (the root was moved) is replaced by ``fallback``."""
        if stored is None:
            return None
        path = Path(stored)
        if not path.is_absolute():
            return str((self.root / path).absolute())
        if fallback is not None and not path.exists():
            return str(fallback.absolute())
        return stored

    def close(self) -> None:
        self.db.close()

    @contextmanager
    def transaction(self):
        """One ``BEGIN IMMEDIATE`` transaction: the write lock is taken at once."""
        self.db.execute("BEGIN IMMEDIATE")
        try:
            yield self.db
        except BaseException:
            self.db.execute("ROLLBACK")
            raise
        self.db.execute("COMMIT")

    def _log(self, db, run: int | None, clip: str, stage: str, event: str, detail: str | None = None) -> None:
        db.execute("INSERT INTO history (time, run, clip, stage, event, detail) VALUES (?, ?, ?, ?, ?, ?)",
                   (time.time(), run, clip, stage, event, detail))

    # ------------------------------------------------------------------------------ runs

    def begin_run(self, engine: str, workers: int, stages: Iterable[str]) -> int:
        now = time.time()
        with self.transaction() as db:
            cur = db.execute("INSERT INTO runs (host, pid, engine, workers, stages, started, heartbeat) "
                             "VALUES (?, ?, ?, ?, ?, ?, ?)",
                             (socket.gethostname(), os.getpid(), engine, workers, ",".join(stages), now, now))
            return int(cur.lastrowid)

    def heartbeat(self, run: int, lease_s: float = LEASE_S) -> None:
        """Renew the run's claims."""
        now = time.time()
        with self.transaction() as db:
            db.execute("UPDATE runs SET heartbeat = ? WHERE id = ?", (now, run))
            db.execute("UPDATE stages SET lease_until = ? WHERE run = ? AND state = 'running'", (now + lease_s, run))

    def end_run(self, run: int, outcome: str) -> None:
        """Close the run; its unfinished claims go back to ``pending``."""
        with self.transaction() as db:
            for row in db.execute("SELECT clip, stage FROM stages WHERE run = ? AND state = 'running'",
                                  (run,)).fetchall():
                self._log(db, run, row["clip"], row["stage"], "release", outcome)
            db.execute("UPDATE stages SET state = 'pending', lease_until = NULL WHERE run = ? AND state = 'running'",
                       (run,))
            db.execute("UPDATE runs SET finished = ?, outcome = ? WHERE id = ?", (time.time(), outcome, run))

    # ----------------------------------------------------------------------------- clips

    def register(self, clips: Iterable[Clip], stages: Iterable[str]) -> None:
        """Add clips and their (clip, stage) rows as ``pending``; known rows keep their state."""
        stages = list(stages)
        with self.transaction() as db:
            for clip in clips:
                db.execute("INSERT INTO clips (id, sequence, scene, video) VALUES (?, ?, ?, ?) ON CONFLICT(id) "
                           "DO UPDATE SET sequence = excluded.sequence, scene = excluded.scene, video = excluded.video",
                           (clip.id, clip.sequence, self._stored(clip.scene), self._stored(clip.video)))
                db.executemany("INSERT OR IGNORE INTO stages (clip, stage, state) VALUES (?, ?, 'pending')",
                               [(clip.id, s) for s in stages])

    def recover_stale(self, run: int) -> list[tuple[str, str]]:
        """Claims of dead runs go back to ``pending``: runs that ended, runs on this host whose
        process is gone, and leases that expired. Returns the recovered (clip, stage) pairs."""
        host, now = socket.gethostname(), time.time()
        recovered = []
        with self.transaction() as db:
            rows = db.execute("SELECT s.clip, s.stage, s.run, s.lease_until, r.host, r.pid, r.finished "
                              "FROM stages s LEFT JOIN runs r ON r.id = s.run "
                              "WHERE s.state = 'running' AND s.run != ?", (run,)).fetchall()
            for row in rows:
                dead = (row["pid"] is None or row["finished"] is not None
                        or (row["host"] == host and not _alive(row["pid"]))
                        or (row["lease_until"] or 0) < now)
                if dead:
                    db.execute("UPDATE stages SET state = 'pending', run = NULL, lease_until = NULL "
                               "WHERE clip = ? AND stage = ?", (row["clip"], row["stage"]))
                    self._log(db, run, row["clip"], row["stage"], "recover", f"claim of run {row['run']} was stale")
                    recovered.append((row["clip"], row["stage"]))
            for row in db.execute("SELECT id, host, pid FROM runs WHERE finished IS NULL AND id != ?",
                                  (run,)).fetchall():
                if row["host"] == host and not _alive(row["pid"]):
                    db.execute("UPDATE runs SET finished = ?, outcome = 'died' WHERE id = ?", (now, row["id"]))
        return recovered

    # ---------------------------------------------------------------------------- stages

    def state(self, clip: str, stage: str) -> str | None:
        if self.empty:
            return None
        row = self.db.execute("SELECT state FROM stages WHERE clip = ? AND stage = ?", (clip, stage)).fetchone()
        return None if row is None else row["state"]

    def claim(self, run: int, clip: str, stage: str, lease_s: float = LEASE_S) -> bool:
        """Take (clip, stage) for ``run`` if it is pending or failed. False when it is done,
        skipped or held by another live run."""
        now = time.time()
        with self.transaction() as db:
            cur = db.execute("UPDATE stages SET state = 'running', run = ?, lease_until = ?, started = ?, "
                             "attempts = attempts + 1, error = NULL WHERE clip = ? AND stage = ? "
                             "AND state IN ('pending', 'failed')", (run, now + lease_s, now, clip, stage))
            if cur.rowcount:
                self._log(db, run, clip, stage, "claim")
            return cur.rowcount == 1

    def _owned(self, db, run: int, clip: str, stage: str) -> bool:
        row = db.execute("SELECT state, run FROM stages WHERE clip = ? AND stage = ?", (clip, stage)).fetchone()
        return row is not None and row["state"] == "running" and row["run"] == run

    def commit(self, run: int, result: StageResult) -> bool:
        """Record a completed stage (its outputs are complete on disk). False, and nothing
        recorded, when the claim is no longer this run's."""
        with self.transaction() as db:
            if not self._owned(db, run, result.clip, result.stage):
                self._log(db, run, result.clip, result.stage, "late", "claim lost; result not recorded")
                return False
            db.execute("UPDATE stages SET state = 'done', finished = ?, seconds = ?, checksum = ?, files = ?, "
                       "worker = ?, stats = ?, lease_until = NULL, error = NULL, detail = NULL "
                       "WHERE clip = ? AND stage = ?",
                       (time.time(), result.seconds, result.checksum, result.files, f"{result.host}:{result.pid}",
                        None if result.stats is None else json.dumps(result.stats), result.clip, result.stage))
            self._log(db, run, result.clip, result.stage, "commit", result.checksum)
            return True

    def fail(self, run: int, result: StageResult, retry: bool) -> None:
        """Record a failure: back to ``pending`` when it will be retried, else ``failed``."""
        with self.transaction() as db:
            if not self._owned(db, run, result.clip, result.stage):
                return
            db.execute("UPDATE stages SET state = ?, finished = ?, seconds = ?, error = ?, worker = ?, "
                       "lease_until = NULL WHERE clip = ? AND stage = ?",
                       ("pending" if retry else "failed", time.time(), result.seconds, result.error,
                        f"{result.host}:{result.pid}", result.clip, result.stage))
            self._log(db, run, result.clip, result.stage, "retry" if retry else "fail", result.error)

    def reopen(self, run: int, clip: str, stage: str, reason: str) -> bool:
        """Put a ``done`` or ``skipped`` stage back to ``pending``: its outputs are out of date
        (``reason``: what changed). False when it is in another state."""
        with self.transaction() as db:
            cur = db.execute("UPDATE stages SET state = 'pending', detail = ?, run = NULL, lease_until = NULL "
                             "WHERE clip = ? AND stage = ? AND state IN ('done', 'skipped')", (reason, clip, stage))
            if cur.rowcount:
                self._log(db, run, clip, stage, "reopen", reason)
            return cur.rowcount == 1

    def skip(self, run: int, clip: str, stage: str, detail: str, stats: dict | None = None,
             checksum: str | None = None, files: int = 0) -> bool:
        """Mark a pending (or failed) stage ``skipped``: nothing to do, or its outputs were already there."""
        with self.transaction() as db:
            cur = db.execute("UPDATE stages SET state = 'skipped', detail = ?, stats = ?, checksum = ?, files = ?, "
                             "finished = ?, error = NULL, run = ? WHERE clip = ? AND stage = ? "
                             "AND state IN ('pending', 'failed')",
                             (detail, None if stats is None else json.dumps(stats), checksum, files, time.time(),
                              run, clip, stage))
            if cur.rowcount:
                self._log(db, run, clip, stage, "skip", detail)
            return cur.rowcount == 1

    # ------------------------------------------------------------------------------ read

    def clips(self) -> list[dict]:
        """Every clip: id, sequence, and its scene and video as absolute paths (under the root
        where it is now). A corrupt cell raises an InputError naming its table, row and column."""
        rows = []
        for r in self._select("SELECT rowid, * FROM clips ORDER BY id"):
            for column in ("id", "sequence", "scene"):
                self._expect(r, "clips", column, isinstance(r[column], str) and r[column] != "", "expected text")
            self._expect(r, "clips", "video", r["video"] is None or isinstance(r["video"], str), "expected text")
            row = {k: r[k] for k in r.keys() if k != "rowid"}
            row["scene"] = self._resolved(r["scene"], self.root / r["id"])
            row["video"] = self._resolved(r["video"])
            rows.append(row)
        return rows

    def stages(self) -> list[dict]:
        """Every (clip, stage) row, ``stats`` decoded. A corrupt cell (an unknown stage or
        state, a non-numeric time, statistics that are not a JSON object of numbers) raises an
        InputError naming its table, row and column."""
        rows = []
        for r in self._select("SELECT rowid, * FROM stages ORDER BY clip, stage"):
            self._expect(r, "stages", "clip", isinstance(r["clip"], str), "expected text")
            self._expect(r, "stages", "stage", r["stage"] in STAGES, f"expected one of {', '.join(STAGES)}")
            self._expect(r, "stages", "state", r["state"] in STATES, f"expected one of {', '.join(STATES)}")
            for column in ("seconds", "started", "finished", "lease_until"):
                value = r[column]
                ok = value is None or (isinstance(value, (int, float)) and math.isfinite(value))
                self._expect(r, "stages", column, ok, "expected a finite number or null")
            for column in ("error", "checksum", "detail", "worker"):
                self._expect(r, "stages", column, r[column] is None or isinstance(r[column], str), "expected text")
            row = {k: r[k] for k in r.keys() if k != "rowid"}
            row["stats"] = self._stats(r)
            rows.append(row)
        return rows

    def _select(self, query: str, parameters: tuple = ()) -> list[sqlite3.Row]:
        if self.empty:
            return []
        try:
            return self.db.execute(query, parameters).fetchall()
        except (sqlite3.DatabaseError, UnicodeDecodeError) as e:
            raise self._unreadable(e) from None

    def _expect(self, row: sqlite3.Row, table: str, column: str, ok: bool, problem: str) -> None:
        if not ok:
            shown = repr(row[column]) if len(repr(row[column])) <= 40 else repr(row[column])[:39] + "…"
            raise InputError(self.path, f"{table}[rowid {row['rowid']}].{column}", f"{problem}, got {shown}")

    def _stats(self, row: sqlite3.Row) -> dict | None:
        if not row["stats"]:
            return None
        try:
            stats = json.loads(row["stats"]) if isinstance(row["stats"], str) else None
        except ValueError:
            stats = None
        ok = isinstance(stats, dict) and all(
            v is None or (isinstance(v, int) and not isinstance(v, bool) and v >= 0) if k in _COUNTS else
            v is None or (isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isinf(v))
            for k, v in stats.items())
        self._expect(row, "stages", "stats", ok, "expected a JSON object of counts and numbers")
        return stats

    def history(self, event: str | None = None) -> list[dict]:
        query = "SELECT * FROM history" + (" WHERE event = ?" if event else "") + " ORDER BY id"
        return [dict(r) for r in self._select(query, (event,) if event else ())]

    def runs(self) -> list[dict]:
        return [dict(r) for r in self._select("SELECT * FROM runs ORDER BY id")]
