"""Paper length units: the one conversion between metres and the unit the planners compute in.

The paper writes every length for radio range r = 2, so one *paper unit* is r / 2 metres; the
problem carries it as ``ProblemConfig.length_unit_m`` (docs/design/model.md §5.5, §6.4). In paper
units the potential-field coefficients (Þ, ℳ, P), the descent step and the message layer's
distance cut-off are scale-free, so one set of defaults serves every size. Planners convert each
tick's inputs to paper units on the way in and their instructions back to metres on the way out,
with :class:`PaperUnits` (built once per planner from its problem).

The arithmetic is exactly the planners' earlier inline code (``x_m / unit``, ``x_u * unit``,
``v * dt / unit``), so results are bit for bit the same.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:  # imported for the annotations only: this module stays light (numpy)
    from planner.problem import ProblemConfig
    from planner.steiner import TaskTree

__all__ = ["PaperUnits"]


@dataclass(frozen=True)
class PaperUnits:
    """Metres <-> paper units for one problem, and the problem's lengths in paper units."""

    unit_m: float
    """Metres per paper unit (``ProblemConfig.length_unit_m``, r / 2 in the paper's presets)."""
    radio_range_u: float
    """r, the link range, paper units."""
    base_reach_u: float
    """min(R, r): a drone reaches the base within this distance, paper units."""
    max_step_u: float
    """v dt: the farthest a drone moves in one tick, paper units."""

    @classmethod
    def of(cls, problem: ProblemConfig) -> PaperUnits:
        """The units of ``problem`` (its ``length_unit_m``, ranges and speed limit per tick)."""
        unit = problem.length_unit_m
        return cls(
            unit_m=unit,
            radio_range_u=problem.radio_range_m / unit,
            base_reach_u=min(problem.base_range_m, problem.radio_range_m) / unit,
            max_step_u=problem.max_speed_m_s * problem.dt_s / unit,
        )

    def to_u(self, x_m: ArrayLike) -> np.ndarray:
        """Positions or lengths in metres -> paper units (float64 array)."""
        return np.asarray(x_m, float) / self.unit_m

    def to_m(self, x_u: np.ndarray) -> np.ndarray:
        """Positions, displacements or lengths in paper units -> metres."""
        return x_u * self.unit_m

    def tree_to_m(self, tree: TaskTree | None) -> TaskTree | None:
        """A task tree built in paper units, with its nodes in metres (None stays None)."""
        if tree is None:
            return None
        return tree.scaled(self.unit_m)
