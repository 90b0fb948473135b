"""What a pilot watches, for :class:`gcs.link.StationLink`: GPS fix, sensor health, the navigation
filter's status, the telemetry radio's signal, and packet loss from sequence gaps.

Folded into events only with :attr:`gcs.link_config.StationConfig.health_telemetry` (the live
page asks for it); without it these messages stay ignored exactly as before (counted, and stopped
when unused), so a flight without the page keeps its event stream bit for bit. The packet-loss
counter (:class:`gcs.link_quality.SeqCounter`) runs on every frame of a vehicle's autopilot
either way: one integer update, no event.
"""

from __future__ import annotations

import math
from typing import Any

from gcs import wire
from gcs.events import (
    EstimatorReceived,
    Event,
    GpsReceived,
    RadioStatusReceived,
    SensorsReceived,
)
from gcs.link_quality import SeqCounter
from gcs.link_state import _Vehicle
from gcs.link_streams import StreamRequests

__all__ = ["VehicleHealth", "health_event"]


def health_event(link_id: int, sysid: int, t_s: float, msg: Any) -> Event:
    """The event of one health message (GPS_RAW_INT, SYS_STATUS's sensor masks,
    EKF_STATUS_REPORT, ESTIMATOR_STATUS, RADIO_STATUS), converted at the codec edge; the live
    link and the replay of a .tlog (mission.view.live.replay) both use it.

    Raises ValueError for values no event accepts (counted as invalid telemetry by the link)
    and KeyError for another message."""
    kind = msg.get_type()
    if kind == "GPS_RAW_INT":
        return GpsReceived(
            link_id,
            sysid,
            t_s,
            fix_type=int(msg.fix_type),
            satellites=wire.satellites_or_none(msg.satellites_visible),
            hdop=wire.dop_or_none(msg.eph),
        )
    if kind == "SYS_STATUS":
        return SensorsReceived(
            link_id,
            sysid,
            t_s,
            present=int(msg.onboard_control_sensors_present),
            enabled=int(msg.onboard_control_sensors_enabled),
            health=int(msg.onboard_control_sensors_health),
        )
    if kind == "EKF_STATUS_REPORT":
        # ArduPilot AP_NavEKF3_Outputs.cpp NavEKF3_core::send_status_report: the variances
        # are the square roots of the innovation test ratios (1.0: the filter rejects).
        ratios = (
            msg.velocity_variance,
            msg.pos_horiz_variance,
            msg.pos_vert_variance,
            msg.compass_variance,
        )
    elif kind == "ESTIMATOR_STATUS":
        # PX4 src/modules/mavlink/streams/ESTIMATOR_STATUS.hpp MavlinkStreamEstimatorStatus:
        # flags from the estimator's solution status; the ratios are innovation test ratios.
        ratios = (msg.vel_ratio, msg.pos_horiz_ratio, msg.pos_vert_ratio, msg.mag_ratio)
    elif kind == "RADIO_STATUS":
        return RadioStatusReceived(
            link_id,
            sysid,
            t_s,
            rssi=wire.rssi_or_none(msg.rssi),
            remrssi=wire.rssi_or_none(msg.remrssi),
            noise=wire.rssi_or_none(msg.noise),
            remnoise=wire.rssi_or_none(msg.remnoise),
            rxerrors=int(msg.rxerrors),
            fixed=int(msg.fixed),
        )
    else:
        raise KeyError(f"not a health message: {kind}")
    finite = [float(r) for r in ratios if math.isfinite(r)]
    return EstimatorReceived(
        link_id,
        sysid,
        t_s,
        source=kind,
        flags=int(msg.flags),
        variance=max(finite) if finite else None,
    )


class VehicleHealth(StreamRequests):
    """Health reports (a mixin of :class:`gcs.link.StationLink`)."""

    def seq_counter(self, sysid: int) -> SeqCounter:
        """The sequence-gap counter of vehicle ``sysid``'s autopilot (:mod:`gcs.link_quality`)."""
        return self._get(sysid).seq

    def _emit_health(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        self._emit_converted(health_event, v, msg, now_s)

    def _on_health(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        """GPS_RAW_INT, EKF_STATUS_REPORT, ESTIMATOR_STATUS: folded with health telemetry,
        else treated as unhandled (counted, stopped when unused)."""
        if self.config.health_telemetry:
            self._emit_health(v, msg, now_s)
            return
        self.stats.ignored_messages += 1
        if self.config.disable_unused_messages:
            self._note_unused(v, msg.get_msgId(), now_s)

    def _on_sensors(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        """SYS_STATUS's sensor masks (its battery fields: gcs.link_discovery)."""
        if self.config.health_telemetry:
            self._emit_health(v, msg, now_s)

    def _on_radio_status(self, v: _Vehicle, msg: Any, now_s: float) -> None:
        """RADIO_STATUS with this vehicle's sysid (a radio in MAVLink mode that stamps its
        vehicle's sysid; SiK radios send their own sysid 51, a system the station never
        attributes to a vehicle). Never stopped: a radio's message, not an autopilot stream."""
        if self.config.health_telemetry:
            self._emit_health(v, msg, now_s)
        else:
            self.stats.ignored_messages += 1
