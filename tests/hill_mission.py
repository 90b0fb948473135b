"""The terrain scene the rotation-over-terrain and failsafe-over-terrain tests share: a base on a
plane, a 70 m round hill 250 m east of it and a crew behind the hill, 480 m east, that only a relay
on or past the hill sees. Each test says only what differs."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

__all__ = ["HILL_HEIGHT_M", "hill_mission"]

#: The hill's crest above the base's ground, metres.
HILL_HEIGHT_M = 70.0


def hill_mission(
    tmp_path: Path,
    name: str,
    *,
    count: int,
    cruise_agl_m: float,
    ceiling_agl_m: float,
    personality: str = "ardupilot",
    tasks: tuple[dict[str, Any], ...] = (),
    run: dict[str, Any] | None = None,
    **sections: Any,
) -> Path:
    """Write the hill mission ``name`` under ``tmp_path`` and return its path: ``count`` emulated
    vehicles holding ``cruise_agl_m`` under ``ceiling_agl_m`` (15 m clearance), the crew behind the
    hill plus ``tasks``; ``run`` updates the run section; ``sections`` (e.g. ``endurance``) are
    added as they are."""
    mission: dict[str, Any] = {
        "name": name,
        "origin": {"lat_deg": 39.76, "lon_deg": -121.62, "alt_amsl_m": 500.0},
        "terrain": {
            "synthetic": {
                "half_width_m": 800.0,
                "spacing_m": 10.0,
                "hills": [
                    {
                        "center": {"north_m": 0, "east_m": 250},
                        "height_m": HILL_HEIGHT_M,
                        "radius_m": 90.0,
                    }
                ],
            },
            "cruise_agl_m": cruise_agl_m,
            "ceiling_agl_m": ceiling_agl_m,
            "clearance_m": 15.0,
        },
        "vehicles": {
            "emulated": {
                "count": count,
                "personality": personality,
                "spawn": {"ring": {"radius_m": 20.0, "noise_m": 0.0}},
                "max_speed_m_s": 10.0,
                "climb_rate_m_s": 5.0,
                "descent_rate_m_s": 3.0,
                "cruise_alt_m": 40.0,
                "n_layers": 1,
            }
        },
        "tasks": [
            {"name": "Behind the hill", "track": [{"t_s": 0, "north_m": 0, "east_m": 480}]},
            *tasks,
        ],
        "radio": {
            "model": "terrain",
            "range_m": 250.0,
            "base_range_m": 250.0,
            "link": {"fade_margin_db": 20.0},
        },
        "geofence": {"half_width_m": 700.0, "max_alt_m": 120.0},
        "planner": {"method": "phireman", "info": "central"},
        "run": {"duration_s": 400.0, "control_period_s": 1.0, "seed": 1, **(run or {})},
        **sections,
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(mission, sort_keys=False))
    return path
