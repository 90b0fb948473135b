"""Run records: the .tlog, the events log, per-tick metrics and the run summary.

Every writer flushes after each record, so a crash (even SIGKILL) loses at most the record being
written; the summary is written atomically (temp file + rename).

* ``.tlog``: ``[uint64 big-endian microseconds since the Unix epoch][raw MAVLink frame]`` for
  every frame in and out, as MAVProxy's ``mavproxy_link.py`` writes it; readable by
  ``mavutil.mavlink_connection(path)``, ``mavlogdump.py``, Mission Planner and QGC.
* events: JSON lines, one event per line, ``{"type": "VehicleLost", ...fields}``.
* metrics: CSV (columns fixed by the first row) or JSON lines, chosen by the file suffix.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import struct
from pathlib import Path
from typing import Any, Mapping

__all__ = ["TlogWriter", "EventLog", "MetricsWriter", "write_summary"]

_TLOG_STAMP = struct.Struct(">Q")


class TlogWriter:
    """Append MAVLink frames with their timestamps to a .tlog."""

    def __init__(self, path: str | os.PathLike, *, fsync: bool = False) -> None:
        self.path = Path(path)
        self._f = open(self.path, "ab", buffering=0)  # unbuffered: each write reaches the OS
        self._fsync = fsync
        self.frames = 0

    def write(self, unix_time_s: float, frame: bytes) -> None:
        """One frame, stamped ``unix_time_s`` (seconds since the epoch)."""
        self._f.write(_TLOG_STAMP.pack(int(unix_time_s * 1e6)) + bytes(frame))
        self.frames += 1
        if self._fsync:
            os.fsync(self._f.fileno())

    def write_frames(self, frames) -> None:
        """Write ``(unix_time_s, outgoing, frame)`` tuples from ``StationLink.take_frames()``."""
        for t, _outgoing, frame in frames:
            self.write(t, frame)

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "TlogWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _jsonable(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "tolist"):  # numpy scalars and arrays
        return _jsonable(value.tolist())
    return value


class EventLog:
    """JSON-lines event log; each line is flushed."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._f = open(self.path, "a", encoding="utf-8", buffering=1)  # line buffered

    def write(self, event: Any, **extra: Any) -> None:
        record = {"type": type(event).__name__, **_jsonable(event), **_jsonable(extra)}
        self._f.write(json.dumps(record, allow_nan=False) + "\n")
        self._f.flush()

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "EventLog":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class MetricsWriter:
    """Per-tick metrics rows: ``.csv`` (header from the first row) or ``.jsonl``."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._csv = self.path.suffix.lower() == ".csv"
        self._f = open(self.path, "w", encoding="utf-8", newline="")
        self._writer: csv.DictWriter | None = None

    def write(self, row: Mapping[str, Any]) -> None:
        data = _jsonable(dict(row))
        if self._csv:
            if self._writer is None:
                self._writer = csv.DictWriter(self._f, fieldnames=list(data))
                self._writer.writeheader()
            unknown = set(data) - set(self._writer.fieldnames)
            if unknown:
                raise ValueError(f"metrics row has columns not in the header: {sorted(unknown)}")
            self._writer.writerow(data)
        else:
            self._f.write(json.dumps(data, allow_nan=False) + "\n")
        self._f.flush()

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "MetricsWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def write_summary(path: str | os.PathLike, summary: Mapping[str, Any]) -> None:
    """Write the run summary JSON atomically."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(_jsonable(dict(summary)), f, indent=2, sort_keys=True, allow_nan=False)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
