"""The planner registry: every method behind one interface, chosen by name.

A planner is built once per run with :func:`make_planner` and then called once per control tick
with a :class:`TickInput`; it returns a :class:`PlanOutput` whose ``disp_m`` is the motion
instruction of every drone for this tick (metres, already within the speed limit). Rows of drones
that are not networked are ignored by the caller (the RTNUA default sends them home).

The same interface serves the in-process simulator, the sweeps and the ground station (which uses
``info='central'``: one planner that sees every networked drone).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Protocol
from collections.abc import Callable

import numpy as np

from planner.problem import ProblemConfig

__all__ = ["TickInput", "PlanOutput", "Planner", "METHODS", "make_planner", "method_names",
           "UnknownMethod"]


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


@dataclass(frozen=True)
class PlanOutput:
    """A planner's answer for one tick."""

    disp_m: np.ndarray
    """(N, 2) float64: motion instruction per drone for this tick, metres (|disp| <= v * dt)."""
    tree: Any = None
    """The task tree used this tick (``planner.steiner.TaskTree``) or None, for plots."""
    info: dict[str, Any] = field(default_factory=dict)
    """Diagnostics (descent iterations, solver status, ...)."""


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


class UnknownMethod(ValueError):
    """A planner name that is not registered."""


def method_names() -> list[str]:
    return list(METHODS)


def make_planner(name: str, problem: ProblemConfig, params: dict[str, Any] | None = None,
                 rng: np.random.Generator | None = None) -> Planner:
    """Build the planner registered under ``name``.

    Raises
    ------
    UnknownMethod
        ``name`` is not registered; the message lists the valid names.
    ValueError
        ``params`` contains a key the method does not know.
    """
    try:
        target = METHODS[name]
    except KeyError as exc:
        raise UnknownMethod(f"unknown method {name!r}; valid methods: {', '.join(METHODS)}") from exc
    module_name, factory_name = target.split(":")
    factory: Callable[..., Planner] = getattr(importlib.import_module(module_name), factory_name)
    return factory(problem, dict(params or {}), rng if rng is not None else np.random.default_rng(0))
