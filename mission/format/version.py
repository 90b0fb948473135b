"""The code version: one string for store rows, run directories and ``phireman --version``.

A sweep's store row (:mod:`mission.experiments.store`), an in-process run directory's ``summary.json``
(:func:`mission.experiments.playback.write_run_dir`), a flight's ``run.json`` (:mod:`mission.flight.run_dir`) and
``phireman --version`` all record :func:`code_version`, so a row and a run directory made by the
same code carry the same string (docs/design/architecture.md §8: a run records its seed, its
resolved configuration and its code version).
"""

from __future__ import annotations

import functools
import hashlib
import pathlib
import subprocess

__all__ = ["code_version"]

_ROOT = pathlib.Path(__file__).resolve().parents[2]

#: Hashed sources outside planner/ (paths from the repository root).
_LOOSE_SOURCES = (
    "vehicle_emu/world.py",
    "mission/experiments/sim.py",
    "mission/experiments/world_loop.py",
)


def _source_files() -> list[pathlib.Path]:
    """Sources whose change can change a run's numbers: the planners, the world, the episode and
    the world loop (:data:`_LOOSE_SOURCES`)."""
    files = sorted((_ROOT / "planner").rglob("*.py"))
    files += [_ROOT / p for p in _LOOSE_SOURCES]
    return [f for f in files if f.is_file()]


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """'phireman <version> git <commit>[+dirty] src <hash>' of the code in this process.

    ``src`` hashes planner/**.py, vehicle_emu/world.py, mission/experiments/sim.py and mission/experiments/world_loop.py
    (:func:`_source_files`) as they were when first
    asked (cached per process), so rows from changed code are distinguishable even without git;
    ``+dirty`` says that git sees uncommitted changes to those same sources.
    """
    try:
        from importlib.metadata import version

        pkg = version("phireman")
    except Exception:  # not installed as a distribution
        pkg = "unknown"
    h = hashlib.sha256()
    for f in _source_files():
        h.update(f.relative_to(_ROOT).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    commit = "none"
    try:
        out = subprocess.run(
            ["git", "-C", str(_ROOT), "rev-parse", "--short=12", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        if out.returncode == 0:
            commit = out.stdout.strip()
            dirty = subprocess.run(
                [
                    "git",
                    "-C",
                    str(_ROOT),
                    "status",
                    "--porcelain",
                    "--",
                    "planner",
                    *_LOOSE_SOURCES,
                ],
                capture_output=True,
                text=True,
                timeout=10,
            )
            if dirty.returncode == 0 and dirty.stdout.strip():
                commit += "+dirty"
    except (OSError, subprocess.SubprocessError):
        pass
    return f"phireman {pkg} git {commit} src {h.hexdigest()[:12]}"
