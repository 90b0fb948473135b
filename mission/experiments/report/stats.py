"""The report's statistics: per-configuration samples and the one-tailed t-tests.

Every section of the report (Table II, the paper comparison, the significance pattern, the
ablations, the heatmaps) reads its numbers through :class:`Sample` and tests them with
:func:`p_greater` / :func:`p_greater_paired` at :data:`ALPHA`, so a change here changes them all
at once. All statistics are on percentages (TU × 100).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from mission.experiments.sim import mean_ci95
from mission.experiments.sweep import ConfigSpec


#: Significance level of every test in the report (the paper's).
ALPHA = 0.05


@dataclass
class Sample:
    """The ok runs of one configuration: per-seed TU1/TU2 in percent."""

    spec: ConfigSpec
    by_seed: dict[str, dict[int, float]] = field(default_factory=lambda: {"tu1": {}, "tu2": {}})
    n_error: int = 0
    errors: Counter = field(default_factory=Counter)
    code_versions: Counter = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.by_seed["tu1"])

    def values(self, metric: str) -> np.ndarray:
        d = self.by_seed[metric]
        return np.array([d[s] for s in sorted(d)], dtype=float)

    def mean_ci(self, metric: str) -> tuple[float, float]:
        return mean_ci95(self.values(metric))

    def mean(self, metric: str) -> float:
        return self.mean_ci(metric)[0]


def _p(result) -> float:
    p = float(result.pvalue)
    return 1.0 if math.isnan(p) else p


def _quiet(test, *args, **kwargs):
    """Run a scipy test without its precision warnings for (nearly) constant data; nan -> p = 1."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return _p(test(*args, **kwargs))


def p_greater(a: Sample, b: Sample, metric: str) -> float:
    """One-tailed unpaired Student's t-test (equal variances) that ``a`` > ``b``: the paper's test."""
    from scipy import stats

    x, y = a.values(metric), b.values(metric)
    if len(x) < 2 or len(y) < 2:
        return 1.0
    if np.ptp(np.concatenate([x, y])) == 0:
        return 1.0
    return _quiet(stats.ttest_ind, x, y, alternative="greater")


def p_greater_paired(a: Sample, b: Sample, metric: str) -> float:
    """One-tailed paired t-test that ``a`` > ``b`` on the seeds both share (common random numbers)."""
    from scipy import stats

    common = sorted(set(a.by_seed[metric]) & set(b.by_seed[metric]))
    if len(common) < 2:
        return 1.0
    x = np.array([a.by_seed[metric][s] for s in common])
    y = np.array([b.by_seed[metric][s] for s in common])
    if np.all(x == y):
        return 1.0
    return _quiet(stats.ttest_rel, x, y, alternative="greater")


@dataclass
class Verdict:
    best: str | None
    """The method with the highest mean (None when fewer than two methods have data)."""
    p: float
    """The largest of the best method's p-values against each other method."""
    significant: bool


def best_of(samples: dict[str, Sample | None], metric: str, paired: bool = False) -> Verdict:
    """Does the best method beat *every* other one at p < ALPHA (one-tailed)?"""
    present = {m: s for m, s in samples.items() if s is not None and s.n >= 2}
    if len(present) < 2:
        return Verdict(None, float("nan"), False)
    best = max(present, key=lambda m: present[m].mean(metric))
    test = p_greater_paired if paired else p_greater
    p = max(test(present[best], s, metric) for m, s in present.items() if m != best)
    return Verdict(best, p, p < ALPHA)


def rank_samples(samples: list[Sample]) -> list[Sample]:
    """Best first: by TU1 mean, then TU2 mean (configurations without ok runs last)."""

    def key(s: Sample):
        if s.n == 0:
            return (1, 0.0, 0.0)
        return (0, -s.mean("tu1"), -s.mean("tu2"))

    return sorted(samples, key=key)
