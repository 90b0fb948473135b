"""Run records: the .tlog, the events log, per-tick metrics and the run summary.

The writers never block their caller (the station's control loop) on the disk: a record goes to
a memory buffer that a background thread writes out every ``flush_period_s`` (0.5 s), and at
``close()``. A crash (even SIGKILL) loses at most the last ``flush_period_s`` of records; a
normal interpreter exit flushes what is open. The summary is written atomically (temp file +
rename).

* ``.tlog``: ``[uint64 big-endian microseconds since the Unix epoch][raw MAVLink frame]`` for
  every frame in and out, as MAVProxy's ``mavproxy_link.py`` writes it; readable by
  ``mavutil.mavlink_connection(path)``, ``mavlogdump.py``, Mission Planner and QGC.
* events: JSON lines, one event per line, ``{"type": "VehicleLost", ...fields}``.
* metrics: CSV (columns fixed by the first row) or JSON lines, chosen by the file suffix.
"""

from __future__ import annotations

import atexit
import csv
import dataclasses
import json
import logging
import math
import os
import struct
import threading
import weakref
from collections import deque
from pathlib import Path
from typing import Any
from collections.abc import Mapping, Sequence

__all__ = ["TlogWriter", "EventLog", "MetricsWriter", "write_summary", "DEFAULT_FLUSH_PERIOD_S"]

log = logging.getLogger(__name__)

_TLOG_STAMP = struct.Struct(">Q")

DEFAULT_FLUSH_PERIOD_S = 0.5
"""How often the background thread writes buffered records out (the most a crash loses)."""


class _BackgroundFile:
    """A binary file fed from memory by a daemon thread.

    ``write`` appends bytes to a list (no system call, no waiting for a disk); the thread writes
    the batch every ``flush_period_s``; :meth:`flush` and :meth:`close` write the rest from the
    caller's thread. Batches reach the file in order (one lock around take-and-write).
    """

    def __init__(self, path: Path, mode: str, *, flush_period_s: float, fsync: bool) -> None:
        if not (math.isfinite(flush_period_s) and flush_period_s > 0):
            raise ValueError(f"flush_period_s must be > 0, got {flush_period_s}")
        self.path = path
        self.flush_period_s = float(flush_period_s)
        self._fsync = fsync
        self._f = open(path, mode, buffering=0)
        self._pending: deque[bytes] = deque()
        self._io = threading.Lock()
        self._stop = threading.Event()
        self.closed = False
        self.write_errors = 0
        self.flushes = 0
        self._thread = threading.Thread(target=self._run, name=f"records:{path.name}", daemon=True)
        self._thread.start()
        _OPEN.add(self)

    def write(self, data: bytes) -> None:
        if self.closed:
            raise ValueError(f"{self.path}: write after close")
        self._pending.append(data)  # deque.append/popleft are thread-safe: no lock here

    def _run(self) -> None:
        while not self._stop.wait(self.flush_period_s):
            self.flush()

    def flush(self) -> None:
        """Write everything buffered so far (blocks while the disk takes it)."""
        with self._io:
            if not self._pending or self._f.closed:
                return
            pending = self._pending
            data = memoryview(b"".join([pending.popleft() for _ in range(len(pending))]))
            try:
                while data:
                    data = data[self._f.write(data) :]
                if self._fsync:
                    os.fsync(self._f.fileno())
            except OSError as exc:  # disk full, device gone: the run goes on without its records
                self.write_errors += 1
                if self.write_errors == 1:
                    log.error("%s: cannot write records (%s); dropping them", self.path, exc)
            self.flushes += 1

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join()
        self.flush()
        with self._io:
            self._f.close()
        _OPEN.discard(self)


_OPEN: weakref.WeakSet[_BackgroundFile] = weakref.WeakSet()


@atexit.register
def _flush_open_files() -> None:  # a run that ends without close() still keeps its records
    for f in list(_OPEN):
        f.close()


class TlogWriter:
    """Append MAVLink frames with their timestamps to a .tlog (buffered, see the module doc)."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        fsync: bool = False,
        flush_period_s: float = DEFAULT_FLUSH_PERIOD_S,
    ) -> None:
        self.path = Path(path)
        self._file = _BackgroundFile(self.path, "ab", flush_period_s=flush_period_s, fsync=fsync)
        self.frames = 0

    def write(self, unix_time_s: float, frame: bytes) -> None:
        """One frame, stamped ``unix_time_s`` (seconds since the epoch)."""
        self._file.write(_TLOG_STAMP.pack(int(unix_time_s * 1e6)) + bytes(frame))
        self.frames += 1

    def write_frames(self, frames: Sequence[tuple[float, bool, bytes]]) -> None:
        """Write ``(unix_time_s, outgoing, frame)`` tuples from ``StationLink.take_frames()``."""
        if not frames:
            return
        pack = _TLOG_STAMP.pack
        parts = []
        for t, _out, frame in frames:
            parts.append(pack(int(t * 1e6)))
            parts.append(frame)
        self._file.write(b"".join(parts))
        self.frames += len(frames)

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: Field names of each dataclass written (its ``dataclasses.fields``, looked up once per type).
_FIELD_NAMES: dict[type, tuple[str, ...]] = {}


def _jsonable(value: Any) -> Any:
    """``value`` as JSON takes it: dataclasses as dicts, tuples as lists, NaN / inf as None,
    NumPy as Python; the same result as :func:`_jsonable_reference`, with the scalars that make
    up nearly every event (a flight with batteries writes about 50 BatteryReceived a second)
    answered first and each dataclass's field names looked up once."""
    t = type(value)
    if t is str or t is int or t is bool or value is None:
        return value
    if t is float:
        return value if math.isfinite(value) else None
    names = _FIELD_NAMES.get(t)
    if names is None and dataclasses.is_dataclass(value) and not isinstance(value, type):
        names = _FIELD_NAMES[t] = tuple(f.name for f in dataclasses.fields(value))
    if names is not None:
        return {name: _jsonable(getattr(value, name)) for name in names}
    if t is list or t is tuple:
        return [_jsonable(v) for v in value]
    if t is dict:
        return {str(k): _jsonable(v) for k, v in value.items()}
    return _jsonable_reference(value)


def _jsonable_reference(value: Any) -> Any:
    """The slow, obviously-correct :func:`_jsonable`."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {
            f.name: _jsonable_reference(getattr(value, f.name)) for f in dataclasses.fields(value)
        }
    if isinstance(value, (list, tuple)):
        return [_jsonable_reference(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable_reference(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "tolist"):  # numpy scalars and arrays
        return _jsonable_reference(value.tolist())
    return value


class EventLog:
    """JSON-lines event log, appended (buffered, see the module doc)."""

    def __init__(
        self, path: str | os.PathLike[str], *, flush_period_s: float = DEFAULT_FLUSH_PERIOD_S
    ) -> None:
        self.path = Path(path)
        self._file = _BackgroundFile(self.path, "ab", flush_period_s=flush_period_s, fsync=False)

    def write(self, event: Any, **extra: Any) -> None:
        record = {"type": type(event).__name__, **_jsonable(event), **_jsonable(extra)}
        self._file.write((json.dumps(record, allow_nan=False) + "\n").encode("utf-8"))

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> EventLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _TextSink:
    """What ``csv.writer`` needs (``write(str)``), feeding a :class:`_BackgroundFile`."""

    def __init__(self, file: _BackgroundFile) -> None:
        self._file = file

    def write(self, text: str) -> None:
        self._file.write(text.encode("utf-8"))


class MetricsWriter:
    """Per-tick metrics rows: ``.csv`` (header from the first row) or ``.jsonl`` (buffered, see
    the module doc)."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        flush_period_s: float = DEFAULT_FLUSH_PERIOD_S,
        compact: bool = False,
    ) -> None:
        self.path = Path(path)
        self._csv = self.path.suffix.lower() == ".csv"
        #: ``.jsonl`` without the blanks after ``,`` and ``:`` (a record written every tick).
        self._separators = (",", ":") if compact else None
        self._file = _BackgroundFile(self.path, "wb", flush_period_s=flush_period_s, fsync=False)
        self._f = _TextSink(self._file)
        self._writer: csv.DictWriter[str] | None = None

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
            self._f.write(json.dumps(data, allow_nan=False, separators=self._separators) + "\n")

    def flush(self) -> None:
        self._file.flush()

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> MetricsWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_summary(path: str | os.PathLike[str], summary: Mapping[str, Any]) -> None:
    """Write the run summary JSON atomically."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(_jsonable(dict(summary)), f, indent=2, sort_keys=True, allow_nan=False)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
