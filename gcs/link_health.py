"""What a pilot watches, for :class:`gcs.link.StationLink`: GPS fix, sensor health, the navigation
filter's status, the telemetry radio's signal, and packet loss from sequence gaps.

Folded into events only with :attr:`gcs.link_config.StationConfig.health_telemetry` (the live
page asks for it); without it these messages stay ignored exactly as before (counted, and stopped
when unused), so a flight without the page keeps its event stream bit for bit. The packet-loss
counter (:class:`gcs.link_quality.SeqCounter`) runs on every frame of a vehicle's autopilot
either way: one integer update, no event.
"""

from __future__ import annotations

from typing import Any

from gcs import wire
from gcs.events import EstimatorReceived, GpsReceived, RadioStatusReceived, SensorsReceived
from gcs.link_quality import SeqCounter
from gcs.link_state import _Vehicle
from gcs.link_streams import StreamRequests

__all__ = ["VehicleHealth"]


class VehicleHealth(StreamRequests):
    """Health reports (a mixin of :class:`gcs.link.StationLink`)."""

    def seq_counter(self, sysid: int) -> SeqCounter:
        """The sequence-gap counter of vehicle ``sysid``'s autopilot (:mod:`gcs.link_quality`)."""
        return self._get(sysid).seq

    def _health_ignored(self, v: _Vehicle, msg: Any, now_s: float) -> bool:
        """True (and the message treated as unhandled) without health telemetry."""
        if self.config.health_telemetry:
            return False
        self.stats.ignored_messages += 1
        if self.config.disable_unused_messages:
            self._note_unused(v, msg.get_msgId(), now_s)
        return True

    def _on_gps_raw(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        if self._health_ignored(v, msg, now_s):
            return
        try:
            ev = GpsReceived(
                self.link_id,
                v.sysid,
                now_s,
                fix_type=int(msg.fix_type),
                satellites=wire.satellites_or_none(msg.satellites_visible),
                hdop=wire.dop_or_none(msg.eph),
            )
        except ValueError:
            self.stats.invalid_telemetry += 1
            return
        self._emit(ev)

    def _on_sensors(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        """SYS_STATUS's sensor masks (its battery fields: gcs.link_discovery)."""
        if not self.config.health_telemetry:
            return  # the battery handler already counted it
        self._emit(
            SensorsReceived(
                self.link_id,
                v.sysid,
                now_s,
                present=int(msg.onboard_control_sensors_present),
                enabled=int(msg.onboard_control_sensors_enabled),
                health=int(msg.onboard_control_sensors_health),
            )
        )

    def _on_ekf_status(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        # ArduPilot AP_NavEKF3_Outputs.cpp NavEKF3_core::send_status_report: the variances are
        # the square roots of the innovation test ratios (1.0: the filter rejects the sensor).
        if self._health_ignored(v, msg, now_s):
            return
        self._emit_estimator(
            v,
            now_s,
            "EKF_STATUS_REPORT",
            int(msg.flags),
            (
                msg.velocity_variance,
                msg.pos_horiz_variance,
                msg.pos_vert_variance,
                msg.compass_variance,
            ),
        )

    def _on_estimator_status(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        # PX4 src/modules/mavlink/streams/ESTIMATOR_STATUS.hpp MavlinkStreamEstimatorStatus::send:
        # flags from the estimator's solution status, the ratios are innovation test ratios.
        if self._health_ignored(v, msg, now_s):
            return
        self._emit_estimator(
            v,
            now_s,
            "ESTIMATOR_STATUS",
            int(msg.flags),
            (msg.vel_ratio, msg.pos_horiz_ratio, msg.pos_vert_ratio, msg.mag_ratio),
        )

    def _emit_estimator(
        self, v: _Vehicle, now_s: float, source: str, flags: int, ratios: tuple[float, ...]
    ) -> None:
        finite = [float(r) for r in ratios if r == r and abs(r) != float("inf")]
        try:
            ev = EstimatorReceived(
                self.link_id,
                v.sysid,
                now_s,
                source=source,
                flags=flags,
                variance=max(finite) if finite else None,
            )
        except ValueError:
            self.stats.invalid_telemetry += 1
            return
        self._emit(ev)

    def _on_radio_status(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        """RADIO_STATUS with this vehicle's sysid (a radio in MAVLink mode that stamps its
        vehicle's sysid; SiK radios send their own sysid 51, a system the station never
        attributes to a vehicle)."""
        if not self.config.health_telemetry:
            self.stats.ignored_messages += 1
            return
        try:
            ev = RadioStatusReceived(
                self.link_id,
                v.sysid,
                now_s,
                rssi=wire.rssi_or_none(msg.rssi),
                remrssi=wire.rssi_or_none(msg.remrssi),
                noise=wire.rssi_or_none(msg.noise),
                remnoise=wire.rssi_or_none(msg.remnoise),
                rxerrors=int(msg.rxerrors),
                fixed=int(msg.fixed),
            )
        except ValueError:
            self.stats.invalid_telemetry += 1
            return
        self._emit(ev)
