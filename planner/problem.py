"""The RTNUA problem: one typed configuration and the paper's presets (Table III).

Lengths are metres and one simulation step lasts ``dt_s`` seconds (1 s by default), so the paper's
dimensionless lengths and "per step" speeds read directly as metres and metres per step. This
module is the single home of the problem's defaults (docs/design/model.md §5.5).

The *scaled* reading (default) multiplies every length (r, q, v, R, ring radius and noise, task
sigma) by ``field_half_width / 5``, so that every size is the S geometry with more drones and tasks;
the *literal* reading keeps the paper's lengths as printed. docs/design/model.md §6.4 and §9.1 show that only
the scaled reading can produce the paper's M, L and XL numbers.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

__all__ = [
    "ProblemConfig",
    "SIZES",
    "ATTRITION_LEVELS",
    "READINGS",
    "BORDER_POLICIES",
    "PAPER_UNIT_HALF_WIDTH_M",
    "problem_preset",
]

#: Half-width of the S field, the geometry the paper's lengths were written for.
PAPER_UNIT_HALF_WIDTH_M = 5.0

#: Table III: size -> (drones, tasks, field half-width in paper units).
SIZES: dict[str, tuple[int, int, float]] = {
    "XS": (20, 5, 2.0),
    "S": (50, 10, 5.0),
    "M": (100, 20, 10.0),
    "L": (200, 50, 20.0),
    "XL": (500, 100, 50.0),
}

#: The paper's per-step attrition probabilities.
ATTRITION_LEVELS: tuple[float, ...] = (0.0, 0.005, 0.01, 0.02, 0.05)

READINGS = ("scaled", "literal")
BORDER_POLICIES = ("none", "clip", "reflect")


@dataclass(frozen=True)
class ProblemConfig:
    """One RTNUA scenario family (everything except the seed)."""

    n_drones: int = 50
    """Number of drones."""
    n_tasks: int = 10
    """Number of tasks."""
    field_half_width_m: float = 5.0
    """Tasks start uniform in [-w, w]^2, metres."""
    radio_range_m: float = 2.0
    """Communication radius r of every drone, metres (links use <=, task links use <)."""
    base_range_m: float = 2.0
    """Base-station radius R, metres (a drone reaches the base if |x| <= min(R, r))."""
    max_speed_m_s: float = 0.15
    """Speed limit v, metres per second (per step at dt = 1 s)."""
    ring_radius_m: float = 1.0
    """Drones start evenly spaced on this ring around the base, metres."""
    ring_noise_m: float = 0.2
    """Standard deviation of the Gaussian noise added to the ring positions, metres."""
    task_walk_sigma_m: float = 0.1
    """Per-step, per-axis standard deviation of the task random walk, metres."""
    task_border: str = "clip"
    """What tasks do at the field border: 'none', 'clip' or 'reflect' (docs/design/model.md §7 #13)."""
    attrition_per_step: float = 0.01
    """Independent per-drone, per-step probability of irreversible loss."""
    n_steps: int = 200
    """Episode length tau, in steps."""
    dt_s: float = 1.0
    """Duration of one step, seconds."""
    length_unit_m: float = 1.0
    """Metres per paper length unit (the scaled reading's half-width / 5); planners work in it."""
    size: str = "S"
    """Name of the preset this came from, for reports."""
    reading: str = "scaled"
    """'scaled' or 'literal', for reports."""

    def __post_init__(self) -> None:
        problems = []
        if self.n_drones < 1:
            problems.append(f"n_drones must be >= 1, got {self.n_drones}")
        if self.n_tasks < 1:
            problems.append(f"n_tasks must be >= 1, got {self.n_tasks}")
        for name in (
            "field_half_width_m",
            "radio_range_m",
            "base_range_m",
            "max_speed_m_s",
            "dt_s",
            "length_unit_m",
        ):
            if not getattr(self, name) > 0:
                problems.append(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("ring_radius_m", "ring_noise_m", "task_walk_sigma_m"):
            if not getattr(self, name) >= 0:
                problems.append(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.attrition_per_step <= 1.0:
            problems.append(f"attrition_per_step must be in [0, 1], got {self.attrition_per_step}")
        if self.n_steps < 1:
            problems.append(f"n_steps must be >= 1, got {self.n_steps}")
        if self.task_border not in BORDER_POLICIES:
            problems.append(
                f"task_border must be one of {BORDER_POLICIES}, got {self.task_border!r}"
            )
        if problems:
            raise ValueError("; ".join(problems))

    def replace(self, **changes: Any) -> ProblemConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


def problem_preset(
    size: str = "S", attrition_per_step: float = 0.01, reading: str = "scaled", **overrides: Any
) -> ProblemConfig:
    """The paper's configuration for ``size`` (Table III) at the given attrition rate.

    Parameters
    ----------
    size : {'XS', 'S', 'M', 'L', 'XL'}
    attrition_per_step : float
        Per-drone, per-step loss probability (the paper uses 0, 0.005, 0.01, 0.02, 0.05).
    reading : {'scaled', 'literal'}
        'scaled' multiplies every length by half-width / 5 (docs/design/model.md §6.4); 'literal' keeps the
        printed lengths.
    **overrides
        Any other :class:`ProblemConfig` field, in metres / seconds (applied after scaling).

    Raises
    ------
    ValueError
        Unknown size or reading, or an invalid override.
    """
    key = size.upper()
    if key not in SIZES:
        raise ValueError(f"unknown size {size!r}; valid sizes: {', '.join(SIZES)}")
    if reading not in READINGS:
        raise ValueError(f"unknown reading {reading!r}; valid readings: {', '.join(READINGS)}")
    n_drones, n_tasks, half_width = SIZES[key]
    unit_m = half_width / PAPER_UNIT_HALF_WIDTH_M if reading == "scaled" else 1.0
    base = ProblemConfig()
    cfg = ProblemConfig(
        n_drones=n_drones,
        n_tasks=n_tasks,
        field_half_width_m=half_width,
        radio_range_m=base.radio_range_m * unit_m,
        base_range_m=base.base_range_m * unit_m,
        max_speed_m_s=base.max_speed_m_s * unit_m,
        ring_radius_m=base.ring_radius_m * unit_m,
        ring_noise_m=base.ring_noise_m * unit_m,
        task_walk_sigma_m=base.task_walk_sigma_m * unit_m,
        attrition_per_step=attrition_per_step,
        length_unit_m=unit_m,
        size=key,
        reading=reading,
    )
    return cfg.replace(**overrides) if overrides else cfg
