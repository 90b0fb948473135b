"""The evaluation report: Table II, tests, comparison with the paper, ablations, Fig. 3 heatmaps.

:func:`build_report` reads a results store (``mission.experiments.store``) and writes into a directory:

* ``report.md``: Table II (mean ± 95 % CI; bold where the best method beats both others by the
  paper's one-tailed unpaired Student's t-test at p < 0.05, and a paired test beside it since the
  scenarios are shared), our numbers against the paper's (Δ = ours − paper), the agreement summary
  and every configuration that misses, the 5 % column with its expected gap, where our significance
  pattern differs from the paper's bolding, the ablation table, other configurations in the store;
* ``fig3_*.png``: heatmaps of differences (size × attrition, diverging colour map centred at 0);
* ``configs.csv``: per-configuration statistics.

Rows are selected by configuration: a Table II cell is the ``paper-table`` spec for (size, attrition,
method, reading) under the same ``--set`` overrides the sweep used, whichever grid produced the rows.
All statistics are on percentages (TU × 100).

The package is cut by what each part reports, over one reader of the store and one set of
statistics that every section shares (so a change to how a cell is selected or tested changes
every section at once):

* :mod:`.stats`: samples, the one-tailed t-tests and the verdicts (the bottom);
* :mod:`.selection`: a configuration's rows in the store; :mod:`.markdown`: number and table
  formatting;
* :mod:`.cells`: Table II's cells with their samples and verdicts;
* :mod:`.table_ii` (Table II, Δ against the paper, misses, the 5 % column), :mod:`.significance`
  (our bolding against the paper's), :mod:`.paired` (central vs asynchronous information, your
  planner against ΦIREMAN), :mod:`.ablations`, :mod:`.figures` (the heatmaps), :mod:`.configs`
  (other configurations, the CSV);
* :mod:`.build`: the Markdown assembly, :func:`build_report` (the top).

The order is an import-linter contract in ``pyproject.toml``.
"""

from __future__ import annotations

from mission.experiments.report.build import ReportResult, build_report
from mission.experiments.report.cells import Cell, analyse_table
from mission.experiments.report.configs import CSV_FIELDS
from mission.experiments.report.figures import heatmaps
from mission.experiments.report.markdown import _fmt as _fmt
from mission.experiments.report.markdown import _fmt_p as _fmt_p
from mission.experiments.report.selection import Selector
from mission.experiments.report.significance import _phireman_vs_each as _phireman_vs_each
from mission.experiments.report.stats import (
    ALPHA,
    Sample,
    best_of,
    p_greater,
    p_greater_paired,
    rank_samples,
)
from mission.experiments.sim import mean_ci95  # the one definition, re-exported
from mission.experiments.sweep import ConfigSpec as ConfigSpec

__all__ = [
    "Sample",
    "Selector",
    "mean_ci95",
    "p_greater",
    "p_greater_paired",
    "best_of",
    "build_report",
    "rank_samples",
    "ALPHA",
    "ReportResult",
    "heatmaps",
    "analyse_table",
    "Cell",
    "CSV_FIELDS",
]
