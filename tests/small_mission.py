"""The small emulated mission the flight tests share: a ring of vehicles 15 m around the base,
fixed crews, a 100 m radio and the station's usual limits. Each test says only what differs."""

from __future__ import annotations

from typing import Any

from mission.format.schema import (
    EmulatedVehicles,
    Mission,
    Radio,
    RunSpec,
    Spawn,
    SpawnRing,
    Task,
    TrackPoint,
    Vehicles,
)

__all__ = ["small_mission", "crew"]


def crew(north_m: float, east_m: float, name: str | None = None) -> Task:
    """A crew standing still at (north_m, east_m) from the base."""
    track = (TrackPoint(t_s=0.0, north_m=north_m, east_m=east_m),)
    return Task(track=track) if name is None else Task(name=name, track=track)


def small_mission(
    name: str,
    run: RunSpec,
    *,
    count: int = 4,
    tasks: tuple[Task, ...] = (),
    personality: str | None = None,
    radio_m: float = 100.0,
    latency_s: float | None = None,
    **mission_fields: Any,
) -> Mission:
    """``count`` emulated vehicles (``personality`` or the schema's default) and ``tasks``
    (default: one crew at 60 m north, 40 m east); ``mission_fields`` (planner, attrition) pass
    through to :class:`Mission`."""
    emulated: dict[str, Any] = {} if personality is None else {"personality": personality}
    radio: dict[str, Any] = {} if latency_s is None else {"latency_s": latency_s}
    return Mission(
        name=name,
        vehicles=Vehicles(
            emulated=EmulatedVehicles(
                count=count,
                radio_range_m=radio_m,
                cruise_alt_m=20.0,
                climb_rate_m_s=5.0,
                max_speed_m_s=10.0,
                spawn=Spawn(ring=SpawnRing(radius_m=15.0, noise_m=0.0)),
                **emulated,
            )
        ),
        tasks=tasks or (crew(60.0, 40.0),),
        radio=Radio(range_m=radio_m, base_range_m=radio_m, **radio),
        run=run,
        **mission_fields,
    )
