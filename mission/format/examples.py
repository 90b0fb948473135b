"""The missions shipped with the package (``mission/format/examples/*.yaml``), usable right after install.

>>> from mission.format.examples import example_path, list_examples
>>> "wildfire" in list_examples()
True
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["list_examples", "example_path", "example_text"]


def _dir():
    return resources.files("mission.format") / "examples"


def list_examples() -> list[str]:
    """Names of the shipped example missions (file names without ``.yaml``), sorted."""
    return sorted(
        entry.name[:-5]
        for entry in _dir().iterdir()
        if entry.name.endswith(".yaml") and entry.is_file()
    )


def _entry(name: str):
    stem = name[:-5] if name.endswith(".yaml") else name
    entry = _dir() / f"{stem}.yaml"
    if not entry.is_file():
        raise KeyError(f"no example mission {name!r}; examples: {', '.join(list_examples())}")
    return entry


def example_path(name: str) -> Path:
    """Filesystem path of the example ``name`` ('wildfire' or 'wildfire.yaml').

    Raises
    ------
    KeyError
        No such example; the message lists the valid names.
    """
    return Path(str(_entry(name)))


def example_text(name: str) -> str:
    """The YAML text of the example ``name`` (works even from a zipped install)."""
    return _entry(name).read_text(encoding="utf-8")
