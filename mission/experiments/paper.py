"""The paper's published numbers as data: Table II, its bolding, and the ablation table.

Source: the LaTeX of Kent, Stefani, Plancher, "Robust Geospatial Coordination of Multi-Agent
Communications Networks Under Attrition" (IEEE RA-L 2026, arXiv:2512.02079), tables
``tab:delta`` (Table II) and ``tab:param_results`` (ablations); the same values are in
docs/design/model.md §6.1 and §6.3. The bold cells of Table II are read from the ``\\textbf`` entries of the
LaTeX (exact, not approximated). In the ablation table the paper italicises the scores that are
significantly below the default (p < 0.05).

All values are percentages; ``ci`` is the half-width of the 95 % confidence interval about the mean.
Attrition levels are per-step probabilities (0.005 = 0.5 %/step), the same floats as
``planner.problem.ATTRITION_LEVELS``.
"""

from __future__ import annotations

__all__ = [
    "PAPER_METHODS",
    "METHOD_LABELS",
    "METRICS",
    "TABLE_II",
    "TABLE_II_BOLD",
    "ABLATIONS",
    "ABLATION_DEFAULT",
    "AblationRow",
    "paper_value",
    "paper_bold",
    "TOLERANCE_PP",
    "FIVE_PERCENT_NOTE",
    "SOURCE",
]

from dataclasses import dataclass

SOURCE = (
    "J. S. Kent, E. Stefani, B. Plancher, RA-L 2026 (arXiv:2512.02079), LaTeX tables "
    "tab:delta and tab:param_results"
)

#: The three methods of Table II, in the paper's column order (registry names).
PAPER_METHODS: tuple[str, ...] = ("phireman", "dccrs", "mccst")

#: Display names.
METHOD_LABELS: dict[str, str] = {"phireman": "ΦIREMAN", "dccrs": "DCCRS", "mccst": "MCCST"}

METRICS: tuple[str, ...] = ("tu1", "tu2")

#: How close (percentage points) our means should be to the paper's: the issue's targets.
TOLERANCE_PP: dict[str, float] = {"phireman": 3.0, "dccrs": 5.0, "mccst": 5.0}

#: Table II: (size, attrition per step) -> method -> ((TU1 mean, TU1 ci), (TU2 mean, TU2 ci)), %.
TABLE_II: dict[tuple[str, float], dict[str, tuple[tuple[float, float], tuple[float, float]]]] = {
    ("XS", 0.0): {
        "phireman": ((92.79, 0.98), (98.69, 0.48)),
        "dccrs": ((89.32, 1.65), (96.46, 1.01)),
        "mccst": ((84.59, 1.75), (96.58, 0.99)),
    },
    ("XS", 0.005): {
        "phireman": ((79.73, 2.62), (86.97, 2.25)),
        "dccrs": ((76.66, 2.98), (85.11, 2.44)),
        "mccst": ((56.79, 3.84), (70.04, 3.54)),
    },
    ("XS", 0.01): {
        "phireman": ((61.63, 3.14), (70.51, 3.05)),
        "dccrs": ((55.58, 3.55), (64.37, 3.25)),
        "mccst": ((42.49, 3.24), (57.12, 3.37)),
    },
    ("XS", 0.02): {
        "phireman": ((38.96, 3.43), (48.60, 3.48)),
        "dccrs": ((31.78, 3.10), (41.70, 3.09)),
        "mccst": ((29.10, 3.32), (44.37, 3.67)),
    },
    ("XS", 0.05): {
        "phireman": ((21.54, 2.64), (32.64, 3.08)),
        "dccrs": ((19.00, 2.47), (30.48, 3.09)),
        "mccst": ((18.17, 2.91), (35.13, 4.25)),
    },
    ("S", 0.0): {
        "phireman": ((95.62, 0.26), (99.95, 0.02)),
        "dccrs": ((95.66, 0.27), (99.91, 0.09)),
        "mccst": ((89.03, 0.77), (98.66, 0.37)),
    },
    ("S", 0.005): {
        "phireman": ((93.86, 0.57), (98.22, 0.42)),
        "dccrs": ((92.47, 0.63), (96.78, 0.52)),
        "mccst": ((74.57, 2.30), (85.49, 2.10)),
    },
    ("S", 0.01): {
        "phireman": ((80.83, 1.63), (85.34, 1.51)),
        "dccrs": ((78.21, 1.84), (82.78, 1.66)),
        "mccst": ((56.07, 2.84), (68.18, 2.66)),
    },
    ("S", 0.02): {
        "phireman": ((52.39, 2.28), (57.59, 2.05)),
        "dccrs": ((49.12, 2.27), (54.32, 2.09)),
        "mccst": ((36.58, 2.36), (49.48, 2.14)),
    },
    ("S", 0.05): {
        "phireman": ((25.57, 1.69), (32.93, 1.57)),
        "dccrs": ((23.39, 1.83), (31.03, 1.91)),
        "mccst": ((20.42, 1.79), (34.99, 2.03)),
    },
    ("M", 0.0): {
        "phireman": ((95.96, 0.17), (99.98, 0.01)),
        "dccrs": ((95.95, 0.17), (99.97, 0.01)),
        "mccst": ((90.58, 0.56), (98.67, 0.24)),
    },
    ("M", 0.005): {
        "phireman": ((95.74, 0.19), (99.80, 0.07)),
        "dccrs": ((95.78, 0.18), (99.83, 0.06)),
        "mccst": ((84.84, 1.16), (93.66, 0.98)),
    },
    ("M", 0.01): {
        "phireman": ((90.96, 0.72), (95.05, 0.65)),
        "dccrs": ((90.66, 0.79), (94.74, 0.71)),
        "mccst": ((70.31, 1.76), (79.86, 1.51)),
    },
    ("M", 0.02): {
        "phireman": ((64.62, 1.56), (68.78, 1.48)),
        "dccrs": ((61.25, 1.62), (65.34, 1.54)),
        "mccst": ((46.65, 1.70), (57.43, 1.51)),
    },
    ("M", 0.05): {
        "phireman": ((30.33, 1.32), (35.43, 1.19)),
        "dccrs": ((28.62, 1.39), (33.70, 1.25)),
        "mccst": ((24.37, 1.34), (37.18, 1.36)),
    },
    ("L", 0.0): {
        "phireman": ((96.12, 0.10), (99.97, 0.01)),
        "dccrs": ((96.13, 0.10), (99.97, 0.01)),
        "mccst": ((93.35, 0.27), (99.01, 0.13)),
    },
    ("L", 0.005): {
        "phireman": ((96.09, 0.10), (99.97, 0.01)),
        "dccrs": ((96.10, 0.10), (99.97, 0.01)),
        "mccst": ((92.00, 0.35), (97.88, 0.23)),
    },
    ("L", 0.01): {
        "phireman": ((95.41, 0.17), (99.26, 0.12)),
        "dccrs": ((95.51, 0.15), (99.37, 0.11)),
        "mccst": ((85.29, 0.80), (91.42, 0.70)),
    },
    ("L", 0.02): {
        "phireman": ((75.86, 1.11), (79.75, 1.06)),
        "dccrs": ((73.43, 1.37), (77.31, 1.34)),
        "mccst": ((57.90, 1.31), (65.37, 1.26)),
    },
    ("L", 0.05): {
        "phireman": ((36.15, 0.97), (40.27, 0.92)),
        "dccrs": ((34.02, 0.92), (38.06, 0.89)),
        "mccst": ((28.55, 0.84), (38.26, 0.89)),
    },
    ("XL", 0.0): {
        "phireman": ((96.21, 0.06), (99.97, 0.00)),
        "dccrs": ((96.22, 0.07), (99.97, 0.00)),
        "mccst": ((96.29, 0.07), (99.93, 0.02)),
    },
    ("XL", 0.005): {
        "phireman": ((96.22, 0.07), (99.97, 0.00)),
        "dccrs": ((96.21, 0.06), (99.97, 0.00)),
        "mccst": ((96.13, 0.07), (99.80, 0.04)),
    },
    ("XL", 0.01): {
        "phireman": ((96.20, 0.07), (99.97, 0.00)),
        "dccrs": ((96.19, 0.06), (99.97, 0.01)),
        "mccst": ((95.26, 0.15), (98.97, 0.13)),
    },
    ("XL", 0.02): {
        "phireman": ((88.63, 0.64), (92.41, 0.63)),
        "dccrs": ((85.56, 0.99), (89.33, 0.98)),
        "mccst": ((77.80, 0.85), (81.65, 0.84)),
    },
    ("XL", 0.05): {
        "phireman": ((43.79, 0.70), (47.60, 0.68)),
        "dccrs": ((39.82, 0.86), (43.63, 0.83)),
        "mccst": ((37.85, 0.59), (42.96, 0.57)),
    },
}

#: Cells the paper prints in bold: (size, attrition, metric, method). From the LaTeX \textbf
#: entries; 13 ΦIREMAN TU1 cells, 10 ΦIREMAN TU2 cells and MCCST TU2 at M / 5 %, as the caption says.
TABLE_II_BOLD: frozenset[tuple[str, float, str, str]] = frozenset(
    {
        ("XS", 0.0, "tu1", "phireman"),
        ("XS", 0.0, "tu2", "phireman"),
        ("XS", 0.01, "tu1", "phireman"),
        ("XS", 0.01, "tu2", "phireman"),
        ("XS", 0.02, "tu1", "phireman"),
        ("S", 0.005, "tu1", "phireman"),
        ("S", 0.005, "tu2", "phireman"),
        ("S", 0.01, "tu1", "phireman"),
        ("S", 0.01, "tu2", "phireman"),
        ("S", 0.02, "tu1", "phireman"),
        ("S", 0.02, "tu2", "phireman"),
        ("S", 0.05, "tu1", "phireman"),
        ("M", 0.02, "tu1", "phireman"),
        ("M", 0.02, "tu2", "phireman"),
        ("M", 0.05, "tu1", "phireman"),
        ("M", 0.05, "tu2", "mccst"),
        ("L", 0.02, "tu1", "phireman"),
        ("L", 0.02, "tu2", "phireman"),
        ("L", 0.05, "tu1", "phireman"),
        ("L", 0.05, "tu2", "phireman"),
        ("XL", 0.02, "tu1", "phireman"),
        ("XL", 0.02, "tu2", "phireman"),
        ("XL", 0.05, "tu1", "phireman"),
        ("XL", 0.05, "tu2", "phireman"),
    }
)


@dataclass(frozen=True)
class AblationRow:
    """One row of the paper's ablation table (S, 1 %/step)."""

    label: str
    """Display label (also the ``label`` the paper-ablations grid gives its runs)."""
    tu1: float
    tu1_ci: float
    tu2: float
    tu2_ci: float
    tu1_below: bool
    """The paper reports TU1 significantly below the default (p < 0.05; italic in the paper)."""
    tu2_below: bool


#: The default configuration's row (Table II, S / 1 %; the ablation table prints no CI for it).
ABLATION_DEFAULT = AblationRow("default", 80.83, 1.63, 85.34, 1.51, False, False)

#: The ablation table in the paper's order.
ABLATIONS: tuple[AblationRow, ...] = (
    ABLATION_DEFAULT,
    AblationRow("Þ = 0", 75.76, 1.84, 80.79, 1.66, True, True),
    AblationRow("nodes only", 75.21, 1.67, 80.16, 1.52, True, True),
    AblationRow("v = 0.1", 78.45, 1.69, 85.30, 1.44, True, False),
    AblationRow("v = 0.2", 82.06, 1.56, 85.64, 1.47, False, False),
    AblationRow("σ = 0", 80.37, 1.81, 85.11, 1.61, False, False),
    AblationRow("σ = 0.2", 80.18, 1.47, 84.48, 1.39, False, False),
)

#: Why the 5 % column is not a correctness target (docs/design/model.md §9.5).
FIVE_PERCENT_NOTE = (
    "The 5 %/step column is not reproducible with independent per-step Bernoulli attrition "
    "(docs/design/model.md §9.5). An independent implementation comes out 5–9 points below the paper at "
    "every size (S ≈ 19 against 25.6) and no modelling variant closes the gap; the paper's 5 % "
    "behaves like about 4 % here, and the paper's own baselines score 20–23 on S / 5 %. The column "
    "is reported for completeness, with a gap below the paper expected for every method; it is "
    "not counted in the agreement targets."
)


def _key(size: str, attrition: float) -> tuple[str, float]:
    return size.upper(), round(float(attrition), 6)


_TABLE = {_key(s, p): v for (s, p), v in TABLE_II.items()}
_BOLD = {(_key(s, p), m, meth) for (s, p, m, meth) in TABLE_II_BOLD}


def paper_value(
    size: str, attrition: float, method: str, metric: str
) -> tuple[float, float] | None:
    """The paper's (mean, ci) in % for one Table II cell, or None when the paper has no such cell."""
    row = _TABLE.get(_key(size, attrition), {}).get(method)
    if row is None:
        return None
    return row[METRICS.index(metric)]


def paper_bold(size: str, attrition: float, metric: str) -> str | None:
    """The method the paper prints in bold for this (configuration, metric), or None."""
    key = _key(size, attrition)
    for method in PAPER_METHODS:
        if (key, metric, method) in _BOLD:
            return method
    return None
