"""The planner registry: every method behind one interface, chosen by name.

A planner is built once per run with :func:`make_planner` and then called once per control tick
with a :class:`TickInput`; it returns a :class:`PlanOutput` whose ``disp_m`` is the motion
instruction of every drone for this tick (metres, already within the speed limit). Rows of drones
that are not networked are ignored by the caller (the RTNUA default sends them home).

The same interface serves the in-process simulator, the sweeps and the ground station.

Information models (planner.info). :data:`INFO_OF` says which models each method plans with: the
potential-field planners take both ('async', the paper's message passing and their default, and
'central'); MCCST and 'phireman-central' are central only (MCCST is the centralised controller of
Luo et al. with perfect knowledge: it has no message-passing form). :func:`make_planner` accepts
``info`` for every method and refuses a model the method does not have, and
:func:`params_with_info` is how a run that has decided its model (a mission's ``planner.info``)
asks for it.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from planner.info import INFO_MODELS, check_info
from planner.problem import ProblemConfig

if TYPE_CHECKING:  # for the annotation only: the registry stays light (no tree code imported)
    from planner.hazard import HazardMap

__all__ = [
    "TickInput",
    "PlanOutput",
    "Planner",
    "METHODS",
    "INFO_OF",
    "make_planner",
    "method_names",
    "info_models",
    "params_with_info",
    "UnknownMethod",
]


@dataclass(frozen=True)
class TickInput:
    """What a planner sees at one control tick (arrays are never mutated by planners)."""

    t_step: int
    """Index of this tick since the start of the run (0-based)."""
    pos_m: np.ndarray
    """(N, 2) float64: horizontal positions (north, east) of every drone, metres, mission frame."""
    alive: np.ndarray
    """(N,) bool: drones not (known to be) lost."""
    networked: np.ndarray
    """(N,) bool: D'(t), drones connected to the base through the mesh."""
    task_pos_m: np.ndarray
    """(M, 2) float64: task positions, metres."""
    base_m: np.ndarray = field(default_factory=lambda: np.zeros(2))
    """(2,) float64: base-station position, metres."""
    hazards: HazardMap | None = None
    """The mission's hazard zones (planner.hazard), with their activity windows on the mission
    clock (t = t_step x ProblemConfig.dt_s), or None (the paper's world: no zones). Known to the
    station from the mission file; planners that do not use them ignore them."""
    alt_amsl_m: np.ndarray | None = None
    """(N,) float64: each drone's altitude above mean sea level, metres, over terrain
    (docs/terrain.md §3), or None (the paper's flat world: planners plan in the plane)."""


@dataclass(frozen=True)
class PlanOutput:
    """A planner's answer for one tick."""

    disp_m: np.ndarray
    """(N, 2) float64: motion instruction per drone for this tick, metres (|disp| <= v * dt)."""
    tree: Any = None
    """The task tree used this tick (``planner.steiner.TaskTree``) or None, for plots."""
    info: dict[str, Any] = field(default_factory=dict)
    """Diagnostics (descent iterations, solver status, ...)."""
    alt_agl_m: np.ndarray | None = None
    """(N,) float64: the height above the ground each drone should hold, metres, from a planner
    that chooses altitudes over terrain (planner.terrain_aware); None: the mission's one cruise
    height (every planner of the paper)."""


class Planner(Protocol):
    def plan(self, tick: TickInput) -> PlanOutput: ...


#: name -> "module:factory". A factory is ``factory(problem, params: dict, rng) -> Planner``.
METHODS: dict[str, str] = {
    "phireman": "planner.phireman:make_phireman",
    "phireman-central": "planner.phireman:make_phireman_central",
    "phireman-no-task": "planner.phireman:make_phireman_no_task",
    "phireman-nodes-only": "planner.phireman:make_phireman_nodes_only",
    "dccrs": "planner.dccrs:make_dccrs",
    "mccst": "planner.mccst:make_mccst",
    "phireman-resilient": "planner.resilient:make_resilient",
}


#: name -> the information models (planner.info.INFO_MODELS) the method plans with; a method
#: with one plans with that one whatever it is asked (and refuses another).
INFO_OF: dict[str, tuple[str, ...]] = {
    "phireman": INFO_MODELS,
    "phireman-central": ("central",),
    "phireman-no-task": INFO_MODELS,
    "phireman-nodes-only": INFO_MODELS,
    "dccrs": INFO_MODELS,
    "mccst": ("central",),  # centralised, perfect knowledge (planner.mccst)
    "phireman-resilient": INFO_MODELS,
}


class UnknownMethod(ValueError):
    """A planner name that is not registered."""


def method_names() -> list[str]:
    return list(METHODS)


def _target(name: str) -> str:
    try:
        return METHODS[name]
    except KeyError as exc:
        raise UnknownMethod(
            f"unknown method {name!r}; valid methods: {', '.join(METHODS)}"
        ) from exc


def info_models(name: str) -> tuple[str, ...]:
    """The information models method ``name`` plans with (:data:`INFO_OF`)."""
    _target(name)
    return INFO_OF[name]


def _check_info_of(name: str, info: Any) -> None:
    check_info(info)
    if info not in INFO_OF[name]:
        raise ValueError(
            f"method {name!r} plans with {' or '.join(INFO_OF[name])} information only, "
            f"got info={info!r}"
        )


def params_with_info(name: str, params: Mapping[str, Any] | None, info: str) -> dict[str, Any]:
    """``params`` for method ``name`` planning with information model ``info``: ``info`` set for a
    method with both models, nothing added for a method with one (after checking it is ``info``).

    Raises
    ------
    UnknownMethod
        ``name`` is not registered.
    ValueError
        ``info`` is not a model of the method, or ``params`` already asks for another one.
    """
    _target(name)
    _check_info_of(name, info)
    out = dict(params or {})
    if out.get("info", info) != info:
        raise ValueError(f"params ask for info={out['info']!r} and the run for info={info!r}")
    if len(INFO_OF[name]) > 1:
        out["info"] = info
    return out


def make_planner(
    name: str,
    problem: ProblemConfig,
    params: dict[str, Any] | None = None,
    rng: np.random.Generator | None = None,
) -> Planner:
    """Build the planner registered under ``name``.

    Raises
    ------
    UnknownMethod
        ``name`` is not registered; the message lists the valid names.
    ValueError
        ``params`` contains a key the method does not know, or an ``info`` the method does not
        plan with (:data:`INFO_OF`).
    """
    module_name, factory_name = _target(name).split(":")
    params = dict(params or {})
    if "info" in params:
        _check_info_of(name, params["info"])
        if len(INFO_OF[name]) == 1:  # a one-model method has no such parameter (MCCST)
            del params["info"]
    factory: Callable[..., Planner] = getattr(importlib.import_module(module_name), factory_name)
    return factory(problem, params, rng if rng is not None else np.random.default_rng(0))
