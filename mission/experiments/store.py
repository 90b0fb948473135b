"""The results store: one SQLite row per simulation run, safe to kill and resume.

A *run* is one configuration (problem, method, resolved planner parameters) and one seed. Its
``run_key`` is a hash of the canonical JSON of the full resolved configuration plus the seed, with a
UNIQUE constraint, so a run is stored at most once whichever grid asked for it (the default
ΦIREMAN S / 1 % runs of ``paper-table`` are also the ablations' default and are run once).

Durability: the database is in WAL mode and only the parent process writes, committing each batch
of completed runs as it arrives; killing the sweep at any moment loses at most the runs in flight.
Readers (``phireman report``, a test polling progress) may read while a sweep writes.

The code version is recorded per row, by the process that ran it, but is not part of the key:
rerunning a grid after a code change skips the runs already present (the sweep warns when the
present rows come from other code); use a new store, or ``--rerun-other-code``, to redo them.

Schema (table ``runs``)::

    id            INTEGER PRIMARY KEY
    run_key       TEXT UNIQUE  sha256(config_json + seed)[:32]
    config_key    TEXT         sha256(config_json)[:32]: the configuration without the seed
    spec_key      TEXT         sha256(spec_json)[:32]: what was asked (grid-independent)
    grid          TEXT         the grid that first produced the row (paper-table, custom, tune, ...)
    label         TEXT         variant label within the grid ('v = 0.1', 'step_size=0.3', ...)
    size, attrition, reading, method   denormalised from the spec, for queries
    spec_json     TEXT         {size, attrition, reading, method, params, problem_overrides}
    config_json   TEXT         {problem: asdict(ProblemConfig), method, params: resolved, params_resolved}
    seed          INTEGER
    status        TEXT         'ok' | 'error'
    error         TEXT         'ExceptionType: message' when status = 'error'
    tu1, tu2      REAL         fractions in [0, 1] (NULL on error)
    wall_s        REAL         wall time of the run in its worker, seconds
    final_alive, final_active  INTEGER  drones alive / alive-and-networked at the last measured step
    code_version  TEXT         'phireman <version> git <commit>[+dirty] src <hash of planner/ + vehicle_emu/world.py>'
    host          TEXT         host name of the worker
    created_utc   TEXT         ISO 8601 completion time

Table ``sweeps`` logs each invocation (command line, executor, counts, wall time, interrupted).
"""

from __future__ import annotations

import datetime as _dt
import json
import pathlib
import sqlite3
from collections.abc import Iterable, Iterator

__all__ = ["ResultStore", "StoreError", "SCHEMA_VERSION", "ROW_FIELDS", "utc_now"]

SCHEMA_VERSION = 1

#: Columns a run row carries (besides the autoincrement id).
ROW_FIELDS: tuple[str, ...] = (
    "run_key",
    "config_key",
    "spec_key",
    "grid",
    "label",
    "size",
    "attrition",
    "reading",
    "method",
    "spec_json",
    "config_json",
    "seed",
    "status",
    "error",
    "tu1",
    "tu2",
    "wall_s",
    "final_alive",
    "final_active",
    "code_version",
    "host",
    "created_utc",
)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS runs (
    id           INTEGER PRIMARY KEY,
    run_key      TEXT NOT NULL UNIQUE,
    config_key   TEXT NOT NULL,
    spec_key     TEXT NOT NULL,
    grid         TEXT NOT NULL,
    label        TEXT NOT NULL DEFAULT '',
    size         TEXT NOT NULL,
    attrition    REAL NOT NULL,
    reading      TEXT NOT NULL,
    method       TEXT NOT NULL,
    spec_json    TEXT NOT NULL,
    config_json  TEXT NOT NULL,
    seed         INTEGER NOT NULL,
    status       TEXT NOT NULL CHECK (status IN ('ok', 'error')),
    error        TEXT,
    tu1          REAL,
    tu2          REAL,
    wall_s       REAL,
    final_alive  INTEGER,
    final_active INTEGER,
    code_version TEXT NOT NULL,
    host         TEXT,
    created_utc  TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS runs_spec ON runs (spec_key);
CREATE INDEX IF NOT EXISTS runs_config ON runs (config_key);
CREATE TABLE IF NOT EXISTS sweeps (
    id            INTEGER PRIMARY KEY,
    started_utc   TEXT NOT NULL,
    finished_utc  TEXT,
    grid          TEXT NOT NULL,
    argv          TEXT NOT NULL,
    executor      TEXT NOT NULL,
    workers       INTEGER,
    code_version  TEXT NOT NULL,
    planned       INTEGER NOT NULL,
    present       INTEGER NOT NULL,
    completed     INTEGER NOT NULL DEFAULT 0,
    errors        INTEGER NOT NULL DEFAULT 0,
    interrupted   INTEGER NOT NULL DEFAULT 0,
    wall_s        REAL
);
"""


class StoreError(RuntimeError):
    """The file is not a results store of this version."""


def utc_now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


class ResultStore:
    """A results database (one file). Use as a context manager; only one process should write.

    Parameters
    ----------
    path : the SQLite file; created with the schema if missing.
    readonly : open an existing store without creating or migrating anything.
    """

    def __init__(self, path: str | pathlib.Path, readonly: bool = False) -> None:
        self.path = pathlib.Path(path)
        if self.path.is_dir():
            raise StoreError(
                f"{self.path} is a directory; a results store is one SQLite file, "
                f"e.g. {self.path / 'results.sqlite'}"
            )
        if readonly and not self.path.exists():
            raise FileNotFoundError(f"no results store at {self.path}")
        try:
            if readonly:
                self.db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, timeout=30)
            else:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.db = sqlite3.connect(self.path, timeout=30)
                # WAL: readers never block the writer; a killed writer loses only uncommitted rows.
                self.db.execute("PRAGMA journal_mode=WAL")
                self.db.execute("PRAGMA synchronous=NORMAL")
            self.db.row_factory = sqlite3.Row
            self._check_schema(readonly)
        except sqlite3.DatabaseError as exc:
            msg = str(exc)
            if "not a database" in msg:
                raise StoreError(
                    f"{self.path} is not a phireman results store (not an SQLite file); "
                    f"give the .sqlite file written by 'phireman sweep --store'"
                ) from None
            raise StoreError(f"{self.path}: cannot open the results store: {msg}") from None
        except OSError as exc:
            raise StoreError(
                f"{self.path}: cannot create the results store: {exc.strerror or exc}"
            ) from None

    def _check_schema(self, readonly: bool) -> None:
        tables = {
            r[0] for r in self.db.execute("SELECT name FROM sqlite_master WHERE type='table'")
        }
        if "meta" in tables:
            row = self.db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
            if row is None or int(row[0]) != SCHEMA_VERSION:
                raise StoreError(
                    f"{self.path}: results store schema {row[0] if row else '?'}, "
                    f"this code reads schema {SCHEMA_VERSION}"
                )
            return
        if tables:
            raise StoreError(f"{self.path} is an SQLite database but not a phireman results store")
        if readonly:
            raise StoreError(f"{self.path} is empty, not a phireman results store")
        with self.db:
            self.db.executescript(_SCHEMA)
            self.db.execute(
                "INSERT INTO meta (key, value) VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),)
            )

    # -- context manager -------------------------------------------------------------------------
    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- runs -----------------------------------------------------------------------------------
    def keys(self, status: str | None = None) -> set[str]:
        """Run keys present (optionally only those with ``status``)."""
        if status is None:
            cur = self.db.execute("SELECT run_key FROM runs")
        else:
            cur = self.db.execute("SELECT run_key FROM runs WHERE status = ?", (status,))
        return {r[0] for r in cur}

    def insert_runs(self, rows: Iterable[dict]) -> int:
        """Insert completed runs in one transaction; keys already present are left as they are.

        Returns the number of rows actually inserted.
        """
        cols = ", ".join(ROW_FIELDS)
        marks = ", ".join("?" for _ in ROW_FIELDS)
        values = [tuple(row.get(f) for f in ROW_FIELDS) for row in rows]
        with self.db:
            before = self.db.total_changes
            self.db.executemany(f"INSERT OR IGNORE INTO runs ({cols}) VALUES ({marks})", values)
            return self.db.total_changes - before

    def delete_runs(self, keys: Iterable[str]) -> int:
        """Delete runs by key (to redo failed runs); returns the number deleted."""
        keys = list(keys)
        with self.db:
            before = self.db.total_changes
            for i in range(0, len(keys), 500):
                part = keys[i : i + 500]
                self.db.execute(
                    f"DELETE FROM runs WHERE run_key IN ({','.join('?' * len(part))})", part
                )
            return self.db.total_changes - before

    def runs(self, where: str = "", params: tuple = ()) -> list[dict]:
        """All run rows (as dicts, ``id`` order), optionally filtered by an SQL ``where`` clause."""
        sql = "SELECT * FROM runs" + (f" WHERE {where}" if where else "") + " ORDER BY id"
        return [dict(r) for r in self.db.execute(sql, params)]

    def iter_runs(self) -> Iterator[dict]:
        for r in self.db.execute("SELECT * FROM runs ORDER BY id"):
            yield dict(r)

    def count(self, status: str | None = None) -> int:
        if status is None:
            return self.db.execute("SELECT COUNT(*) FROM runs").fetchone()[0]
        return self.db.execute("SELECT COUNT(*) FROM runs WHERE status = ?", (status,)).fetchone()[
            0
        ]

    def code_versions(self) -> dict[str, int]:
        """code_version -> number of rows."""
        return {
            r[0]: r[1]
            for r in self.db.execute(
                "SELECT code_version, COUNT(*) FROM runs GROUP BY code_version ORDER BY MIN(id)"
            )
        }

    def code_versions_of(self, keys: Iterable[str]) -> dict[str, int]:
        """code_version -> number of rows, over the given run keys."""
        keys = set(keys)
        out: dict[str, int] = {}
        for key, version in self.db.execute("SELECT run_key, code_version FROM runs"):
            if key in keys:
                out[version] = out.get(version, 0) + 1
        return out

    # -- sweep log ------------------------------------------------------------------------------
    def start_sweep(
        self,
        grid: str,
        argv: list[str],
        executor: str,
        workers: int | None,
        code_version: str,
        planned: int,
        present: int,
    ) -> int:
        with self.db:
            cur = self.db.execute(
                "INSERT INTO sweeps (started_utc, grid, argv, executor, workers, code_version, planned, "
                "present) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    utc_now(),
                    grid,
                    json.dumps(argv),
                    executor,
                    workers,
                    code_version,
                    planned,
                    present,
                ),
            )
            assert cur.lastrowid is not None  # set by the INSERT
            return int(cur.lastrowid)

    def finish_sweep(
        self, sweep_id: int, completed: int, errors: int, interrupted: bool, wall_s: float
    ) -> None:
        with self.db:
            self.db.execute(
                "UPDATE sweeps SET finished_utc = ?, completed = ?, errors = ?, interrupted = ?, wall_s = ? "
                "WHERE id = ?",
                (utc_now(), completed, errors, int(interrupted), wall_s, sweep_id),
            )

    def sweeps(self) -> list[dict]:
        return [dict(r) for r in self.db.execute("SELECT * FROM sweeps ORDER BY id")]
