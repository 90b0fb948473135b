"""ArduPilot's terrain protocol for :class:`vehicle_emu.link.VehicleCore` (the vehicle's side).

An emulated ArduPilot in a terrain mission holds a :class:`vehicle_emu.terrain.TerrainDatabase`
(``terrain_db``): once a second it sends TERRAIN_REPORT and, at most every 2 s, a TERRAIN_REQUEST
for the sub-grids it lacks around it; it stores the TERRAIN_DATA that come back
(libraries/AP_Terrain/TerrainGCS.cpp ``send_request``, ``send_terrain_report``,
``handle_terrain_data``). Terrain-relative targets (MAV_FRAME_GLOBAL_TERRAIN_ALT_INT) are flown
above the ground the database holds, and refused where it holds none
(:meth:`vehicle_emu.personality.base.Personality.global_to_world`).
"""

from __future__ import annotations

from mavedge.units import deg_to_e7

from .core_setpoints import SetpointHandlers
from .terrain import TerrainDatabase
from .wire import dialect as mavlink

__all__ = ["TerrainProtocol", "TERRAIN_REPORT_PERIOD_S"]

#: TERRAIN_REPORT (and the request check) once a second unless the station sets the interval of
#: TERRAIN_REQUEST: ArduPilot sends them as MSG_TERRAIN, in its EXTRA3 stream or at the interval
#: SET_MESSAGE_INTERVAL gives TERRAIN_REQUEST (GCS_Common.cpp map_message_id_to_ap_message:
#: "request also does report").
TERRAIN_REPORT_PERIOD_S = 1.0


class TerrainProtocol(SetpointHandlers):
    """TERRAIN_REQUEST / TERRAIN_DATA / TERRAIN_REPORT (a mixin of VehicleCore)."""

    terrain_db: TerrainDatabase | None
    _terrain_next_s: float
    _terrain_period_s: float

    def enable_terrain(self, spacing_m: int, now_s: float) -> None:
        """Start the terrain database (ArduPilot TERRAIN_ENABLE=1, TERRAIN_SPACING)."""
        self.terrain_db = TerrainDatabase(spacing_m)
        self._terrain_next_s = now_s
        self._terrain_period_s = TERRAIN_REPORT_PERIOD_S

    def _set_terrain_interval(self, interval_s: float) -> bool:
        """SET_MESSAGE_INTERVAL of TERRAIN_REQUEST: 0 the default period, < 0 off."""
        if interval_s == 0:
            interval_s = TERRAIN_REPORT_PERIOD_S
        self._terrain_period_s = interval_s if interval_s > 0 else float("inf")
        return True

    def _here_e7(self) -> tuple[int, int]:
        ph, i = self.physics, self.index
        return deg_to_e7(float(ph.lat_deg[i])), deg_to_e7(float(ph.lon_deg[i]))

    def _terrain_tick(self, now_s: float) -> None:
        db = self.terrain_db
        if db is None or now_s < self._terrain_next_s:
            return
        self._terrain_next_s = now_s + self._terrain_period_s
        lat, lon = self._here_e7()
        self._send_terrain_report(lat, lon)
        req = db.request(lat, lon, now_s)
        if req is not None:
            glat, glon, spacing, mask = req
            self._send(mavlink.MAVLink_terrain_request_message(glat, glon, spacing, mask))

    def _send_terrain_report(self, lat_e7: int, lon_e7: int) -> None:
        """TerrainGCS.cpp ``send_terrain_report``: the ground under (lat, lon) and the vehicle's
        height above it, spacing 0 while the database lacks it (or home's)."""
        db = self.terrain_db
        assert db is not None  # only with a database
        home_lat, home_lon = deg_to_e7(self.home_lla[0]), deg_to_e7(self.home_lla[1])
        h_home = db.height_amsl_m(home_lat, home_lon)
        h_here = db.height_amsl_m(lat_e7, lon_e7)
        spacing, terrain_h, current_h = 0, 0.0, 0.0
        if h_home is not None and h_here is not None:
            rel_alt = float(self.physics.alt_amsl_m[self.index]) - self.home_lla[2]
            spacing, terrain_h, current_h = db.spacing_m, h_here, rel_alt + h_home - h_here
        pending, loaded = db.statistics()
        self._send(
            mavlink.MAVLink_terrain_report_message(
                lat_e7, lon_e7, spacing, terrain_h, current_h, pending, loaded
            )
        )

    def _on_terrain_data(self, m, addr, now_s: float) -> None:
        if self.terrain_db is not None:
            self.terrain_db.on_data(m.lat, m.lon, m.grid_spacing, m.gridbit, m.data)

    def _on_terrain_check(self, m, addr, now_s: float) -> None:
        if self.terrain_db is not None:  # TerrainGCS.cpp handle_terrain_check
            self._send_terrain_report(m.lat, m.lon)
