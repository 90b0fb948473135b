"""Mission YAML -> :class:`mission.format.schema.Mission`, validated once, every error reported at once.

Missions may come from strangers, so loading is defensive:

* the document is parsed with a :class:`yaml.SafeLoader` subclass (tags such as
  ``!!python/object`` construct nothing and are refused);
* documents larger than :data:`MAX_BYTES` are refused before parsing;
* alias bombs ("billion laughs") are refused during composition: at most :data:`MAX_ALIASES`
  aliases, at most :data:`MAX_DEPTH` levels of nesting, and the fully expanded document may
  hold at most :data:`MAX_EXPANDED_NODES` nodes (counted with memoisation, so the check is
  linear in the size of the text, not of the expansion);
* duplicate keys in a mapping are errors (PyYAML would silently keep the last one).

Validation walks the schema's dataclasses generically (types and ``metadata`` limits come from
:mod:`mission.format.schema`), then runs each section's ``validate()`` for cross-field rules. Every problem
becomes one line ``path: message`` (``tasks[2].track[0].t_s: expected a number, got 'abc'``), and
all of them are raised together in one :class:`MissionError`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import types
import typing
from pathlib import Path
from typing import Any, Literal, Union

import yaml

from mission.format import schema
from mission.format.schema import Mission

__all__ = [
    "MissionError",
    "load_mission",
    "loads_mission",
    "mission_from_dict",
    "validate_mission",
    "resolve",
    "resolved_dict",
    "dump_mission",
    "MAX_BYTES",
    "MAX_ALIASES",
    "MAX_DEPTH",
    "MAX_EXPANDED_NODES",
]

#: Largest mission document accepted, bytes.
MAX_BYTES = 1024 * 1024
#: Most aliases (``*name``) accepted in one document.
MAX_ALIASES = 100
#: Deepest nesting of collections accepted.
MAX_DEPTH = 40
#: Most nodes accepted once every alias is expanded.
MAX_EXPANDED_NODES = 500_000

_BAD = object()  # marker: this value failed validation (its errors are already recorded)


class MissionError(ValueError):
    """The mission is invalid. ``errors`` holds one ``path: message`` line per problem."""

    def __init__(self, errors: list[str]):
        self.errors = list(errors)
        super().__init__("\n".join(self.errors))


# --------------------------------------------------------------------------------------------
# Safe, bounded YAML


class _Refused(yaml.YAMLError):
    pass


class _Guards:
    """Mixin for a safe loader: refuses alias bombs, deep nesting and duplicate keys.

    Composition is PyYAML's Python ``Composer`` (so these hooks run); scanning and parsing use
    libyaml when available (about 2.5x faster on large documents), else pure Python.
    """

    _aliases = 0
    _depth = 0

    def compose_node(self, parent, index):  # noqa: D401 - PyYAML hook
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise _Refused(f"more than {MAX_ALIASES} YAML aliases; refused")
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                raise _Refused(f"nested deeper than {MAX_DEPTH} levels; refused")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def get_single_data(self):
        node = self.get_single_node()
        if node is None:
            return None
        _check_expanded_size(node)
        return self.construct_document(node)

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _value in node.value:
                if isinstance(key_node, yaml.ScalarNode):
                    key = self.construct_object(key_node)
                    try:
                        if key in seen:
                            mark = key_node.start_mark
                            raise _Refused(
                                f"duplicate key {key!r} (line {mark.line + 1}, first at line "
                                f"{seen[key].line + 1})"
                            )
                        seen[key] = key_node.start_mark
                    except TypeError:  # unhashable key: let PyYAML report it
                        pass
        return super().construct_mapping(node, deep=deep)


class _BoundedSafeLoader(_Guards, yaml.SafeLoader):
    """Pure-Python safe loader with the guards."""


try:
    from yaml._yaml import CParser as _CParser
except ImportError:  # pragma: no cover - PyYAML built without libyaml
    _BoundedLoader: type = _BoundedSafeLoader
else:

    class _BoundedCLoader(
        _Guards,
        yaml.composer.Composer,
        _CParser,
        yaml.constructor.SafeConstructor,
        yaml.resolver.Resolver,
    ):
        """libyaml events, Python composition (with the guards), safe construction."""

        def __init__(self, stream):
            _CParser.__init__(self, stream)
            yaml.composer.Composer.__init__(self)
            yaml.constructor.SafeConstructor.__init__(self)
            yaml.resolver.Resolver.__init__(self)

    _BoundedLoader = _BoundedCLoader


def _check_expanded_size(root: yaml.Node) -> None:
    """Refuse documents whose alias-expanded size exceeds MAX_EXPANDED_NODES (memoised, linear)."""
    sizes: dict[int, int] = {}

    def size(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if isinstance(node, yaml.ScalarNode):
            total = 1
        elif isinstance(node, yaml.SequenceNode):
            total = 1 + sum(size(child) for child in node.value)
        else:
            total = 1 + sum(size(k) + size(v) for k, v in node.value)
        total = min(total, MAX_EXPANDED_NODES + 1)
        sizes[key] = total
        return total

    if size(root) > MAX_EXPANDED_NODES:
        raise _Refused(
            f"more than {MAX_EXPANDED_NODES} nodes once aliases are expanded "
            "(an alias bomb?); refused"
        )


def _parse_yaml(text: str | bytes) -> Any:
    if isinstance(text, bytes):
        if len(text) > MAX_BYTES:
            raise MissionError([f"document is {len(text)} bytes; the limit is {MAX_BYTES} bytes"])
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise MissionError([f"not UTF-8 text ({exc.reason} at byte {exc.start})"]) from None
    elif len(text.encode("utf-8", "surrogatepass")) > MAX_BYTES:
        raise MissionError([f"document is larger than the limit of {MAX_BYTES} bytes"])
    try:
        return yaml.load(text, Loader=_BoundedLoader)  # noqa: S506 - safe constructor only
    except _Refused as exc:
        raise MissionError([f"refused: {exc}"]) from None
    except yaml.constructor.ConstructorError as exc:
        mark = exc.problem_mark
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        problem = exc.problem or str(exc)
        if "constructor for the tag" in problem:
            problem = (
                f"unsupported YAML tag {problem.split('tag', 1)[1].strip()}; tags are not allowed"
            )
        raise MissionError([f"not a plain YAML document: {problem}{where}"]) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        if "maximum nesting depth" in problem:  # libyaml >= 0.2.5's own limit (1000), hit first
            raise MissionError([f"refused: nested deeper than {MAX_DEPTH} levels{where}"]) from None
        raise MissionError([f"not valid YAML: {problem}{where}"]) from None
    except RecursionError:
        raise MissionError(["refused: nested too deeply"]) from None


# --------------------------------------------------------------------------------------------
# Generic schema walk


def _join(path: str, key: str) -> str:
    if not key:
        return path or "<top level>"
    if key.startswith("["):
        return f"{path}{key}"
    return f"{path}.{key}" if path else key


def _describe(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return repr(value) if len(value) <= 40 else repr(value[:37] + "...")
    if isinstance(value, (int, float)):
        return schema._fmt(value)
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return f"a {type(value).__name__}"


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls, vars(schema))
    return _HINTS[cls]


def _ordered_fields(cls: type) -> list[dataclasses.Field]:
    """Fields declared on the class itself first (so dumps read naturally), then inherited ones."""
    own = cls.__dict__.get("__annotations__", {})
    fields = dataclasses.fields(cls)
    return [f for f in fields if f.name in own] + [f for f in fields if f.name not in own]


def _check_number(value: float, path: str, limits: dict, errs: list[str]) -> bool:
    fmt = schema._fmt
    ge, gt, le, lt = (limits.get(k) for k in ("ge", "gt", "le", "lt"))
    if ge is not None and le is not None and ge < 0 and not ge <= value <= le:
        errs.append(f"{path}: must be within [{fmt(ge)}, {fmt(le)}], got {fmt(value)}")
        return False
    checks = [
        (ge, ">=", lambda a, b: a >= b),
        (gt, ">", lambda a, b: a > b),
        (le, "<=", lambda a, b: a <= b),
        (lt, "<", lambda a, b: a < b),
    ]
    for bound, op, ok in checks:
        if bound is not None and not ok(value, bound):
            errs.append(f"{path}: must be {op} {fmt(bound)}, got {fmt(value)}")
            return False
    return True


def _is_scalar(value: Any) -> bool:
    return isinstance(value, (str, bool, int)) or (
        isinstance(value, float) and math.isfinite(value)
    )


def _parse_value(tp: Any, node: Any, path: str, errs: list[str], limits: dict) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (Union, types.UnionType):
        options = [a for a in args if a is not type(None)]
        if node is None:
            if type(None) in args:
                return None
            errs.append(f"{path}: must not be null")
            return _BAD
        if len(options) == 1:
            return _parse_value(options[0], node, path, errs, limits)
        if all(a in (float, int, bool, str) for a in options):  # scalar (planner params)
            if _is_scalar(node):
                return node
            errs.append(f"{path}: expected a number, boolean or string, got {_describe(node)}")
            return _BAD
        raise TypeError(f"unsupported schema type {tp!r}")  # programming error in the schema
    if tp is float:
        if isinstance(node, bool) or not isinstance(node, (int, float)):
            errs.append(f"{path}: expected a number, got {_describe(node)}")
            return _BAD
        if not math.isfinite(node):
            errs.append(f"{path}: must be a finite number, got {node}")
            return _BAD
        return float(node) if _check_number(float(node), path, limits, errs) else _BAD
    if tp is int:
        if isinstance(node, float) and node.is_integer() and math.isfinite(node):
            node = int(node)
        if isinstance(node, bool) or not isinstance(node, int):
            errs.append(f"{path}: expected an integer, got {_describe(node)}")
            return _BAD
        return node if _check_number(node, path, limits, errs) else _BAD
    if tp is bool:
        if not isinstance(node, bool):
            errs.append(f"{path}: expected true or false, got {_describe(node)}")
            return _BAD
        return node
    if tp is str:
        if not isinstance(node, str):
            errs.append(f"{path}: expected a string, got {_describe(node)}")
            return _BAD
        return node
    if origin is Literal:
        if not isinstance(node, str) or node not in args:
            close = difflib.get_close_matches(str(node), [str(a) for a in args], n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            errs.append(f"{path}: must be one of {', '.join(args)}; got {_describe(node)}{hint}")
            return _BAD
        return node
    if origin is tuple:
        if not isinstance(node, list):
            errs.append(f"{path}: expected a list, got {_describe(node)}")
            return _BAD
        n_min, n_max = limits.get("min_len"), limits.get("max_len")
        if n_min is not None and len(node) < n_min:
            errs.append(
                f"{path}: needs at least {n_min} item{'s' if n_min != 1 else ''}, got {len(node)}"
            )
            return _BAD
        if n_max is not None and len(node) > n_max:
            errs.append(f"{path}: at most {n_max} items, got {len(node)}")
            return _BAD
        items = [
            _parse_value(args[0], item, f"{path}[{i}]", errs, {}) for i, item in enumerate(node)
        ]
        return _BAD if any(item is _BAD for item in items) else tuple(items)
    if origin is dict:
        if not isinstance(node, dict):
            errs.append(f"{path}: expected a mapping, got {_describe(node)}")
            return _BAD
        out, ok = {}, True
        for key, value in node.items():
            if not isinstance(key, str):
                errs.append(f"{path}: keys must be strings, got {_describe(key)}")
                ok = False
                continue
            parsed = _parse_value(args[1], value, _join(path, key), errs, {})
            if parsed is _BAD:
                ok = False
            else:
                out[key] = parsed
        return out if ok else _BAD
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return _parse_section(tp, node, path, errs)
    raise TypeError(f"unsupported schema type {tp!r}")  # programming error in the schema


def _parse_section(cls: type, node: Any, path: str, errs: list[str]) -> Any:
    where = path or "<top level>"
    if not isinstance(node, dict):
        errs.append(f"{where}: expected a mapping, got {_describe(node)}")
        return _BAD
    fields = {f.name: f for f in _ordered_fields(cls)}
    hints = _hints(cls)
    ok = True
    for key in node:
        if not isinstance(key, str):
            errs.append(f"{where}: keys must be strings, got {_describe(key)}")
        elif key not in fields:
            close = difflib.get_close_matches(key, list(fields), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            errs.append(f"{_join(path, key)}: unknown key{hint}; valid keys: {', '.join(fields)}")
    kwargs = {}
    for name, f in fields.items():
        sub = _join(path, name)
        if name in node:
            value = _parse_value(hints[name], node[name], sub, errs, dict(f.metadata))
            if value is _BAD:
                ok = False
            else:
                kwargs[name] = value
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            errs.append(f"{sub}: required key missing")
            ok = False
    if not ok:
        return _BAD
    obj = cls(**kwargs)
    problems = obj.validate()
    for rel, message in problems:
        errs.append(f"{_join(path, rel)}: {message}")
    return _BAD if problems else obj


# --------------------------------------------------------------------------------------------
# Public API


def resolve(mission: Mission) -> Mission:
    """Fill values that default to another field (``vehicles.emulated.radio_range_m`` <- radio)."""
    emu = mission.vehicles.emulated
    if emu is not None and emu.radio_range_m is None:
        emu = dataclasses.replace(emu, radio_range_m=mission.radio.range_m)
        mission = dataclasses.replace(
            mission, vehicles=dataclasses.replace(mission.vehicles, emulated=emu)
        )
    return mission


def mission_from_dict(data: Any) -> Mission:
    """Validate a parsed document (plain dicts / lists / scalars) and build the mission.

    Raises
    ------
    MissionError
        With every problem found, one ``path: message`` per entry.
    """
    if data is None:
        raise MissionError(
            ["<top level>: the document is empty (write {} for the default mission)"]
        )
    errs: list[str] = []
    mission = _parse_section(Mission, data, "", errs)
    if errs or mission is _BAD:
        raise MissionError(errs or ["<top level>: invalid mission"])
    return resolve(mission)


def loads_mission(text: str | bytes) -> Mission:
    """Parse and validate a mission from YAML text. Raises :class:`MissionError`."""
    return mission_from_dict(_parse_yaml(text))


def load_mission(path: str | os.PathLike) -> Mission:
    """Read, parse and validate a mission file.

    Raises
    ------
    MissionError
        The file is missing or unreadable, too large, not YAML, or not a valid mission.
    """
    p = Path(path)
    try:
        with p.open("rb") as fh:
            data = fh.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise MissionError([f"{p}: no such file"]) from None
    except IsADirectoryError:
        raise MissionError([f"{p}: is a directory, not a mission file"]) from None
    except OSError as exc:
        raise MissionError([f"{p}: cannot read: {exc.strerror or exc}"]) from None
    if len(data) > MAX_BYTES:
        raise MissionError([f"{p}: larger than the limit of {MAX_BYTES} bytes; refused"])
    return loads_mission(data)


def _plain(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in _ordered_fields(type(obj)):
            value = getattr(obj, f.name)
            if value is not None:
                out[f.name] = _plain(value)
        return out
    if isinstance(obj, (tuple, list)):
        return [_plain(v) for v in obj]
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    return obj


def resolved_dict(mission: Mission) -> dict:
    """The mission as plain data with every default filled (unset optional keys omitted).

    ``mission_from_dict(resolved_dict(m)) == resolve(m)``; record this in a run directory.
    """
    return _plain(resolve(mission))


def validate_mission(mission: Mission) -> Mission:
    """Check a mission built in code against every rule of the loader; return it resolved."""
    return mission_from_dict(resolved_dict(mission))


_FLOW_KEYS = {"t_s", "north_m", "east_m", "lat_deg", "lon_deg", "alt_m", "vehicle"}


class _Dumper(yaml.SafeDumper):
    """Block style, except small coordinate-like mappings, which read best on one line."""


def _represent_dict(dumper: yaml.SafeDumper, data: dict):
    flow = bool(data) and set(data) <= _FLOW_KEYS
    return dumper.represent_mapping("tag:yaml.org,2002:map", data.items(), flow_style=flow)


_Dumper.add_representer(dict, _represent_dict)


def dump_mission(mission: Mission, header: str | None = None) -> str:
    """The mission as YAML (every default written out). ``loads_mission`` round-trips it.

    ``header`` (optional) is written first as ``#`` comment lines.
    """
    text = yaml.dump(
        resolved_dict(mission),
        Dumper=_Dumper,
        sort_keys=False,
        allow_unicode=True,
        default_flow_style=False,
        width=4096,
    )
    if header:
        lines = ["#" + (" " + line if line else "") for line in header.rstrip("\n").split("\n")]
        text = "\n".join(lines) + "\n" + text
    return text
