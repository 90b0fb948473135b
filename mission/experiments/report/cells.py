"""Table II's cells: one (size, attrition) configuration, its samples per method and verdicts."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mission.experiments import paper
from mission.experiments.report.selection import Selector
from mission.experiments.report.stats import Sample, Verdict, best_of
from mission.experiments.sweep import paper_table_grid


@dataclass
class Cell:
    size: str
    attrition: float
    samples: dict[str, Sample | None]
    unpaired: dict[str, Verdict] = field(default_factory=dict)
    paired: dict[str, Verdict] = field(default_factory=dict)

    def delta(self, method: str, metric: str) -> float:
        s = self.samples.get(method)
        ref = paper.paper_value(self.size, self.attrition, method, metric)
        if s is None or s.n == 0 or ref is None:
            return float("nan")
        return s.mean(metric) - ref[0]

    def within(self, method: str, metric: str) -> bool | None:
        d = self.delta(method, metric)
        if math.isnan(d):
            return None
        return abs(d) <= paper.TOLERANCE_PP[method] + 1e-9


def analyse_table(
    selector: Selector,
    reading: str,
    params: dict,
    problem_overrides: dict,
    methods=paper.PAPER_METHODS,
) -> list[Cell]:
    """Table II cells (size-major, then attrition) with their samples and both significance verdicts."""
    grid = paper_table_grid(
        seeds=[],
        methods=methods,
        reading=reading,
        params=params,
        problem_overrides=problem_overrides,
    )
    cells: dict[tuple[str, float], Cell] = {}
    for spec in grid.configs:
        key = (spec.size, spec.attrition)
        cell = cells.setdefault(key, Cell(spec.size, spec.attrition, {}))
        cell.samples[spec.method] = selector.sample(spec)
    for cell in cells.values():
        for metric in paper.METRICS:
            cell.unpaired[metric] = best_of(cell.samples, metric, paired=False)
            cell.paired[metric] = best_of(cell.samples, metric, paired=True)
    return list(cells.values())
