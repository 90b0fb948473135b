"""The ground on the live page and its replay: relief overlay, link status, link profiles.

A mission with ``radio.model: terrain`` (docs/terrain.md) gets, from one :class:`TerrainView`
per source (the live station, a replay):

* the shaded relief with contours as one PNG, rendered once and served at ``/api/terrain.png``
  with its bounds in the mission frame (``meta.terrain``), which ``static/terrain.js`` lays under
  the map as an image overlay;
* a status for every drawn link (:meth:`TerrainView.frame_links`): ``ok``, ``blocked by
  terrain`` or ``out of range``, by the planner's own model (:meth:`planner.terrain.TerrainRadio.
  link_status`), vectorised over the frame's pairs;
* the profile of one link (:meth:`TerrainView.profile`, ``/api/profile``): terrain, line of
  sight, first Fresnel zone and verdict, from :func:`planner.terrain.link_profile`.

Antenna heights are what the picture holds: a vehicle at its position's altitude (the mission
origin's altitude less its NED down), a crew's radio ``radio.link.crew_antenna_agl_m`` above the
ground under it, the base's antenna ``radio.link.base_antenna_agl_m`` above its ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mission.view.live.state import radio_links
from planner.terrain import (
    LINK_OK,
    LINK_STATUS_NAMES,
    TerrainRadio,
    link_profile,
)

__all__ = ["TerrainView", "parse_end"]


def parse_end(text: str) -> tuple[float, float, float]:
    """``"N,E,H"`` (north, east, height AMSL, metres) -> a tuple; ValueError otherwise."""
    parts = [float(x) for x in str(text).split(",")]
    if len(parts) != 3 or not all(math.isfinite(x) for x in parts):
        raise ValueError(f"expected N,E,H (metres, height AMSL), got {text!r}")
    return parts[0], parts[1], parts[2]


def _r(a: np.ndarray, nd: int = 1) -> list:
    return np.round(np.asarray(a, dtype=float), nd).tolist()


@dataclass
class TerrainView:
    """A mission's terrain as the page shows it (module docstring)."""

    radio: TerrainRadio
    origin_alt_amsl_m: float
    """Altitude AMSL of the mission frame's origin (the base), metres."""
    crew_antenna_agl_m: float
    base_antenna_agl_m: float
    _png: bytes | None = field(default=None, repr=False)

    @classmethod
    def of_mission(cls, mission) -> TerrainView | None:
        """The view of a ``radio.model: terrain`` mission; None for the disc radio."""
        from mission.format.terrain import terrain_radio

        radio = terrain_radio(mission)
        if radio is None:
            return None
        link = mission.radio.terrain_link
        return cls(
            radio,
            float(mission.origin.alt_amsl_m),
            float(link.crew_antenna_agl_m),
            float(link.base_antenna_agl_m),
        )

    # ------------------------------------------------------------------ the overlay

    def png(self) -> bytes:
        """The relief and contours (:func:`mission.view.terrain.terrain_png`), rendered once
        (about a second of CPU for the canyon's 301 x 301 posts: the server calls it off its
        event loop)."""
        if self._png is None:
            from mission.view.terrain import terrain_png

            self._png = terrain_png(self.radio.terrain)[0]
        return self._png

    def meta(self) -> dict:
        """``meta.terrain``: the overlay's address and bounds, the budget's range, the status
        names (index = the code in ``links.*_status``)."""
        from mission.view.terrain import terrain_bounds

        b = self.radio.budget
        return {
            "url": "/api/terrain.png",
            **terrain_bounds(self.radio.terrain),
            "max_range_m": round(b.max_range_m, 1),
            "clear_fraction": b.fresnel_clear_fraction,
            "frequency_mhz": b.frequency_hz / 1e6,
            "status_names": list(LINK_STATUS_NAMES),
        }

    # ------------------------------------------------------------------ heights

    def base_amsl_m(self) -> float:
        """The base's antenna, metres AMSL."""
        ground = float(self.radio.terrain.height_m(np.zeros((1, 2)))[0])
        return ground + self.base_antenna_agl_m

    def crew_amsl_m(self, crews_ne_m: np.ndarray) -> np.ndarray:
        """(M,) each crew's radio, metres AMSL (NaN for a crew with no position)."""
        c = np.asarray(crews_ne_m, dtype=float).reshape(-1, 2)
        ok = np.isfinite(c).all(axis=1)
        out = np.full(len(c), np.nan)
        if ok.any():
            out[ok] = self.radio.terrain.height_m(c[ok]) + self.crew_antenna_agl_m
        return out

    # ------------------------------------------------------------------ a frame's links

    def frame_links(
        self,
        ne_m: np.ndarray,
        amsl_m: np.ndarray,
        heard: np.ndarray,
        crews_ne_m: np.ndarray,
        radio_range_m: float,
        base_range_m: float,
    ) -> dict:
        """The frame's links with their status, and which crews are connected.

        Candidates are the pairs closer horizontally than the larger of the disc's range (what
        the planner assumes) and the budget's range (what could close): vehicle-vehicle among the
        ``heard`` rows, vehicle-crew, vehicle-base (``base_range_m``). Returns ``vv``, ``vv_total``,
        ``vc``, ``vb`` as :func:`mission.view.live.state.frame_dict` draws them, plus
        ``vv_status``, ``vc_status``, ``vb_status`` (codes of :data:`planner.terrain.
        LINK_STATUS_NAMES`), ``connected`` (M,) bool (some heard vehicle's link to the crew is
        ok), ``amsl`` (N,) the vehicles' antenna heights, ``crew_amsl`` (M,), ``base_amsl``."""
        ne = np.asarray(ne_m, dtype=float).reshape(-1, 2)
        heard = np.asarray(heard, dtype=bool) & np.isfinite(amsl_m)
        reach = max(radio_range_m, self.radio.budget.max_range_m)
        ne_ok = np.where(heard[:, None], ne, 0.0)
        h = np.where(heard, amsl_m, 0.0)
        pos3 = np.column_stack([ne_ok, h])
        vv, total = radio_links(ne_ok, heard, reach)
        vv_status = (
            self.radio.link_status(pos3[vv[:, 0]], pos3[vv[:, 1]])
            if len(vv)
            else np.zeros(0, np.int8)
        )
        crews = np.asarray(crews_ne_m, dtype=float).reshape(-1, 2)
        crew_h = self.crew_amsl_m(crews)
        crew_ok = np.isfinite(crew_h)
        rows = np.flatnonzero(heard)
        cols = np.flatnonzero(crew_ok)
        vi = np.repeat(rows, len(cols))  # every (heard vehicle, crew with a position)
        ci = np.tile(cols, len(rows))
        near = np.hypot(*(ne[vi] - crews[ci]).T) <= reach if len(vi) else np.zeros(0, bool)
        vi, ci = vi[near], ci[near]
        crew3 = np.column_stack([crews[ci], crew_h[ci]]) if len(ci) else np.empty((0, 3))
        vc_status = self.radio.link_status(pos3[vi], crew3) if len(vi) else np.zeros(0, np.int8)
        connected = np.zeros(len(crews), dtype=bool)
        connected[ci[vc_status == LINK_OK]] = True
        base_h = self.base_amsl_m()
        b_reach = max(base_range_m, self.radio.budget.max_range_m)
        vb = rows[np.linalg.norm(ne[rows], axis=1) <= b_reach] if len(rows) else rows
        vb_status = (
            self.radio.link_status(pos3[vb], np.broadcast_to([0.0, 0.0, base_h], (len(vb), 3)))
            if len(vb)
            else np.zeros(0, np.int8)
        )
        return {
            "vv": vv.ravel().tolist(),
            "vv_total": int(total),
            "vc": np.column_stack([vi, ci]).ravel().tolist(),
            "vb": vb.tolist(),
            "vv_status": vv_status.tolist(),
            "vc_status": vc_status.tolist(),
            "vb_status": vb_status.tolist(),
            "connected": connected,
            "amsl": np.where(heard, amsl_m, np.nan),
            "crew_amsl": crew_h,
            "base_amsl": round(base_h, 1),
        }

    # ------------------------------------------------------------------ one link's profile

    def profile(self, a_m: tuple[float, float, float], b_m: tuple[float, float, float]) -> dict:
        """The JSON profile of the link a -> b (each (north, east, height AMSL), metres): samples
        (distance, ground, bulge, line of sight, Fresnel radius, margin) and the verdict."""
        p = link_profile(self.radio.terrain, self.radio.budget, a_m, b_m)
        k = p.worst
        ratio = p.least_clearance_ratio
        return {
            "a": [round(float(x), 1) for x in a_m],
            "b": [round(float(x), 1) for x in b_m],
            "d": _r(p.distance_m),
            "ground": _r(p.ground_amsl_m, 2),
            "bulge": _r(p.bulge_m, 3),
            "los": _r(p.los_amsl_m, 2),
            "r1": _r(p.fresnel_radius_m, 2),
            "margin": _r(p.margin_m, 2),
            "clear_fraction": p.clear_fraction,
            "slant_m": round(p.slant_m, 1),
            "max_range_m": round(p.max_range_m, 1),
            "status": p.status,
            "status_name": LINK_STATUS_NAMES[p.status],
            "worst": k,
            "worst_margin_m": None if k < 0 else round(float(p.margin_m[k]), 2),
            "clearance_ratio": None if not math.isfinite(ratio) else round(ratio, 3),
        }
