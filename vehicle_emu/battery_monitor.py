"""Each firmware's battery monitor: what it reports of the pack, and its battery failsafes.

The pack itself is the truth of :mod:`vehicle_emu.battery` (a row of ``core.physics.battery``);
a monitor is bound to one :class:`vehicle_emu.link.VehicleCore` (``core.batt``) and reads its
parameters (:data:`vehicle_emu.params.ARDUPILOT_BATTERY_PARAMS`, ``PX4_BATTERY_PARAMS``) on every
check, so a PARAM_SET takes effect at once, as on the firmware. docs/design/endurance.md §6 lists
every parameter with its default and source.

* :class:`ArduPilotBatteryMonitor` - ArduCopter 4.x: libraries/AP_BattMonitor/ (the analog monitor
  SITL uses: voltage and current, no cell voltages, no temperature, no time remaining) and
  ArduCopter/events.cpp ``Copter::handle_battery_failsafe`` / ``do_failsafe_action``;
* :class:`PX4BatteryMonitor` - PX4 1.15: src/lib/battery/battery.cpp (state of charge and warning
  levels), src/modules/commander/failsafe/failsafe.cpp (``fromBatteryWarningActParam``) and the
  mavlink streams ``SYS_STATUS.hpp`` / ``BATTERY_STATUS.hpp``.

Wire integers are made here the way each firmware's C code makes them (a float assigned to an
integer field truncates toward zero), so a station reads exactly the firmware's numbers.
"""

from __future__ import annotations

import math

from mavedge.modes import px4_custom_mode

from . import events as ev
from .wire import dialect as mavlink

__all__ = ["ArduPilotBatteryMonitor", "PX4BatteryMonitor", "monitor_for", "BATTERY_SENSOR"]

BATTERY_SENSOR = mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
_UINT16_MAX = 0xFFFF
_INT16_MAX = 0x7FFF


def _c_int(x: float) -> int:
    """C's float -> integer conversion (truncation toward zero)."""
    return int(math.trunc(x))


def _clamp(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else hi if v > hi else v


class _Monitor:
    default_rates_hz: dict[int, float] = {}
    """Streams the firmware sends unasked because it has a battery (msg id -> Hz)."""

    def __init__(self, core) -> None:
        self.core = core
        self._param_stamp = 0  # no table has stamp 0: read at the first check
        self._param_values: tuple = ()

    def _params(self) -> tuple:
        """:meth:`_read_params`, kept until the parameter table changes (its ``stamp``: any
        PARAM_SET, any ``params.set``, another table), so a PARAM_SET still takes effect at the
        next check, as on the firmware, without a dozen table reads per vehicle and tick."""
        stamp = self.core.params.stamp
        if stamp != self._param_stamp:
            self._param_values = self._read_params()
            self._param_stamp = stamp
        return self._param_values

    def _read_params(self) -> tuple:
        """The parameters the checks read, as the numbers they compare with."""
        return ()

    @property
    def pack(self):
        return self.core.physics.battery

    def voltage_v(self) -> float:
        return float(self.pack.voltage_v[self.core.index])

    def current_a(self) -> float:
        return float(self.pack.current_a[self.core.index])

    def consumed_mah(self) -> float:
        return float(self.pack.consumed_mah[self.core.index])

    def energy_wh(self) -> float:
        return float(self.pack.energy_wh[self.core.index])

    def _failsafe_event(self, now_s: float, kind: str, action: str) -> None:
        core = self.core
        core._events.append(ev.FailsafeTriggered(core.sysid, now_s, kind, action))


# ---------------------------------------------------------------------------------------------
# ArduPilot
# ---------------------------------------------------------------------------------------------

#: AP_BattMonitor::Failsafe (AP_BattMonitor.h): None < Low < Critical.
AP_FS_NONE, AP_FS_LOW, AP_FS_CRITICAL = 0, 1, 2
#: ArduCopter/Copter.h ``_failsafe_priorities`` (highest first): TERMINATE, LAND, RTL,
#: SMARTRTL_LAND, SMARTRTL, NONE; an action not in the list (6 AUTO_DO_LAND_START, 7 BRAKE_LAND)
#: gets the sentinel's index (AP_BattMonitor::check_failsafes walks to the -1).
_AP_PRIORITIES = (5, 1, 2, 4, 3, 0)
#: Copter mode numbers (mavedge.modes.ARDUCOPTER_MODES).
_AP_LAND, _AP_RTL, _AP_BRAKE, _AP_SMART_RTL = 9, 6, 17, 21
#: ArduCopter FailsafeAction (Copter.h) -> the mode ``do_failsafe_action`` ends in, here:
#: 1 LAND (set_mode_land_with_pause), 2 RTL (set_mode_RTL_or_land_with_pause), 3 SMARTRTL
#: (set_mode_SmartRTL_or_RTL), 4 SMARTRTL_LAND (set_mode_SmartRTL_or_land_with_pause),
#: 6 AUTO_DO_LAND_START (set_mode_auto_do_land_start_or_RTL: no landing sequence is ever stored
#: in the emulator, so RTL), 7 BRAKE_LAND (set_mode_brake_or_land_with_pause). 5 TERMINATE
#: disarms (no advanced failsafe). LAND's 4-second pause before descending is not modelled;
#: SMART_RTL is flown as the emulator's RTL (straight home: no breadcrumb path is kept).
_AP_ACTION_MODE = {
    1: _AP_LAND,
    2: _AP_RTL,
    3: _AP_SMART_RTL,
    4: _AP_SMART_RTL,
    6: _AP_RTL,
    7: _AP_BRAKE,
}
#: FS_OPTIONS bit 3 (Copter.h FailsafeOption::CONTINUE_IF_LANDING).
_AP_CONTINUE_IF_LANDING = 8


class ArduPilotBatteryMonitor(_Monitor):
    """AP_BattMonitor with one analog monitor (BATT_MONITOR 4), as ArduCopter runs it."""

    def __init__(self, core) -> None:
        super().__init__(core)
        self.failsafe = AP_FS_NONE
        """``state[0].failsafe``: latched until the next boot."""
        self.has_triggered_failsafe = False
        """``AP_BattMonitor::_has_triggered_failsafe`` (SYS_STATUS battery health)."""
        self._highest_priority = 127  # INT8_MAX, AP_BattMonitor::_highest_failsafe_priority
        self._low_voltage_start_s: float | None = None
        self._critical_voltage_start_s: float | None = None

    def _read_params(self) -> tuple:
        # (sag compensated, BATT_CAPACITY, BATT_CRT_VOLT, BATT_LOW_VOLT, BATT_CRT_MAH,
        # BATT_LOW_MAH, BATT_LOW_TIMER), as _failsafe_types / _update_failsafes compare them.
        P = self.core.params
        return (
            int(P["BATT_FS_VOLTSRC"]) == 1,
            float(P["BATT_CAPACITY"]),
            float(P["BATT_CRT_VOLT"]),
            float(P["BATT_LOW_VOLT"]),
            float(P["BATT_CRT_MAH"]),
            float(P["BATT_LOW_MAH"]),
            float(P["BATT_LOW_TIMER"]),
        )

    # -- state the GCS sees -----------------------------------------------------------------

    def remaining_pct(self) -> int:
        """AP_BattMonitor_Backend::capacity_remaining_pct, then GCS_MAVLINK::battery_remaining_pct
        (``MIN(percentage, INT8_MAX)``): from BATT_CAPACITY and the consumed mAh, truncated."""
        capacity = self._params()[1]
        if capacity <= 0:
            return -1  # "unreliable if ... the capacity is zero"
        pct = _clamp(100.0 * (capacity - self.consumed_mah()) / capacity, 0.0, 255.0)
        return min(_c_int(pct), 127)

    def charge_state(self) -> int:
        """AP_BattMonitor::get_mavlink_charge_state: from the failsafe state."""
        if self.failsafe == AP_FS_CRITICAL:
            return mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL
        if self.failsafe == AP_FS_LOW:
            return mavlink.MAV_BATTERY_CHARGE_STATE_LOW
        return mavlink.MAV_BATTERY_CHARGE_STATE_OK

    def sys_status_fields(self) -> tuple[int, int, int, int, int]:
        """(present/enabled bits, health bits, voltage_battery mV, current_battery cA,
        battery_remaining %) of SYS_STATUS: GCS_Common.cpp ``send_sys_status`` (mV of
        ``battery.gcs_voltage()``, cA constrained to +-INT16_MAX) and
        ``update_sensor_status_flags`` (BATTERY present and enabled; healthy unless a battery
        failsafe has triggered, ``battery.has_failsafed()``)."""
        health = 0 if self.has_triggered_failsafe else BATTERY_SENSOR
        current_ca = _c_int(_clamp(self.current_a() * 100.0, -_INT16_MAX, _INT16_MAX))
        voltage_mv = _c_int(self.voltage_v() * 1000.0) & 0xFFFF
        return BATTERY_SENSOR, health, voltage_mv, current_ca, self.remaining_pct()

    def battery_status(self, now_s: float):
        """GCS_Common.cpp ``GCS_MAVLINK::send_battery_status``: no cell voltages (analog
        monitor), so the pack voltage goes in the first cell (at most 0xFFFE mV each, the rest
        UINT16_MAX) and ``voltages_ext`` is zeros; no temperature (INT16_MAX); consumed Wh x 36
        = hJ; no time remaining (0, only smart batteries estimate it); function and type
        UNKNOWN; id = instance 0."""
        voltage_mv = self.voltage_v() * 1e3
        cells = []
        for _ in range(10):
            if voltage_mv < 0.001:
                cells.append(_UINT16_MAX)
            else:
                cells.append(_c_int(min(voltage_mv, 0xFFFE)))
                voltage_mv -= 0xFFFE
        current_ca = _c_int(_clamp(self.current_a() * 100.0, -_INT16_MAX, _INT16_MAX))
        return mavlink.MAVLink_battery_status_message(
            0,
            mavlink.MAV_BATTERY_FUNCTION_UNKNOWN,
            mavlink.MAV_BATTERY_TYPE_UNKNOWN,
            _INT16_MAX,
            cells,
            current_ca,
            _c_int(self.consumed_mah()),
            _c_int(self.energy_wh() * 36.0),
            max(-1, min(100, self.remaining_pct())),
            0,
            self.charge_state(),
            [0, 0, 0, 0],
            0,
            0,
        )

    # -- failsafes ----------------------------------------------------------------------------

    def _failsafe_types(self) -> tuple[bool, bool, bool, bool]:
        """AP_BattMonitor_Backend::check_failsafe_types: (low_voltage, low_capacity,
        critical_voltage, critical_capacity); strict ``<`` everywhere; a threshold of 0 is off.
        BATT_FS_VOLTSRC 1 (sag compensated) uses the resting voltage (pack OCV here)."""
        sag_compensated, capacity, crt_v, low_v, crt_mah, low_mah, _ = self._params()
        pack, i = self.pack, self.core.index
        v = float(pack.voltage_v[i])
        if sag_compensated:
            v = max(v, v + float(pack.current_a[i]) * pack.config.internal_resistance_ohm)
        left_mah = capacity - float(pack.consumed_mah[i])
        return (
            v > 0 and low_v > 0 and v < low_v,
            low_mah > 0 and left_mah < low_mah,
            v > 0 and crt_v > 0 and v < crt_v,
            crt_mah > 0 and left_mah < crt_mah,
        )

    def _update_failsafes(self, now_s: float) -> int:
        """AP_BattMonitor_Backend::update_failsafes: a voltage below its threshold for more than
        BATT_LOW_TIMER seconds (timer started at the first reading below; 0 disables), or a
        capacity below its threshold at once; critical first."""
        low_v, low_mah, crt_v, crt_mah = self._failsafe_types()
        timeout_s = self._params()[6]
        if crt_v:
            if self._critical_voltage_start_s is None:
                self._critical_voltage_start_s = now_s
            elif timeout_s > 0 and now_s - self._critical_voltage_start_s > timeout_s:
                return AP_FS_CRITICAL
        else:
            self._critical_voltage_start_s = None
        if crt_mah:
            return AP_FS_CRITICAL
        if low_v:
            if self._low_voltage_start_s is None:
                self._low_voltage_start_s = now_s
            elif timeout_s > 0 and now_s - self._low_voltage_start_s > timeout_s:
                return AP_FS_LOW
        else:
            self._low_voltage_start_s = None
        if low_mah:
            return AP_FS_LOW
        return AP_FS_NONE

    def update(self, now_s: float) -> None:
        """AP_BattMonitor::check_failsafes (run from ``read()`` at 10 Hz): only while armed; a
        new, worse failsafe state sends "Battery 1 is low 10.50V used 4000 mAh" (WARNING), and
        runs the vehicle's handler when its action's priority is at least the highest so far."""
        core = self.core
        if not core.armed:
            return
        fs = self._update_failsafes(now_s)
        if fs <= self.failsafe:
            return
        P = core.params
        if fs == AP_FS_LOW:
            action, type_str = int(P["BATT_FS_LOW_ACT"]), "low"
        else:
            action, type_str = int(P["BATT_FS_CRT_ACT"]), "critical"
        core._statustext(
            now_s,
            mavlink.MAV_SEVERITY_WARNING,
            f"Battery 1 is {type_str} {self.voltage_v():.2f}V used {self.consumed_mah():.0f} mAh",
        )
        self.has_triggered_failsafe = True
        self.failsafe = fs
        priority = _AP_PRIORITIES.index(action) if action in _AP_PRIORITIES else len(_AP_PRIORITIES)
        if priority <= self._highest_priority:
            self._highest_priority = priority
            taken = self._handle_battery_failsafe(now_s, action)
        else:
            taken = "NONE"
        self._failsafe_event(now_s, f"battery_{type_str}", taken)

    def _handle_battery_failsafe(self, now_s: float, action: int) -> str:
        """ArduCopter/events.cpp ``Copter::handle_battery_failsafe``: on the ground disarm
        ("Battery Failsafe - Disarming"); landing with FS_OPTIONS CONTINUE_IF_LANDING keeps
        landing; else "Battery Failsafe" and ``do_failsafe_action``. Returns what was done."""
        core = self.core
        if core.physics.landed[core.index]:  # should_disarm_on_failsafe: ap.land_complete
            core._disarm(now_s, "failsafe")
            core._statustext(now_s, mavlink.MAV_SEVERITY_WARNING, "Battery Failsafe - Disarming")
            return "DISARM"
        landing = core._behaviour == "land" or (
            core._behaviour == "rtl" and core._rtl_phase == "land"
        )
        if landing and int(core.params["FS_OPTIONS"]) & _AP_CONTINUE_IF_LANDING and action != 0:
            core._statustext(
                now_s, mavlink.MAV_SEVERITY_WARNING, "Battery Failsafe - Continuing Landing"
            )
            action = 1
        else:
            core._statustext(now_s, mavlink.MAV_SEVERITY_WARNING, "Battery Failsafe")
        if action == 5:
            core._disarm(now_s, "failsafe", force=True)
            return "DISARM"
        mode = _AP_ACTION_MODE.get(action)
        if mode is None:  # 0 NONE (and values ArduCopter does not define)
            return "NONE"
        core._set_mode(mode, now_s, "failsafe")
        return core.mode_name


# ---------------------------------------------------------------------------------------------
# PX4
# ---------------------------------------------------------------------------------------------

#: battery_status_s::BATTERY_WARNING_* (msg/BatteryStatus.msg).
PX4_WARN_NONE, PX4_WARN_LOW, PX4_WARN_CRITICAL, PX4_WARN_EMERGENCY = 0, 1, 2, 3
_PX4_CHARGE_STATE = {
    PX4_WARN_NONE: mavlink.MAV_BATTERY_CHARGE_STATE_OK,
    PX4_WARN_LOW: mavlink.MAV_BATTERY_CHARGE_STATE_LOW,
    PX4_WARN_CRITICAL: mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL,
    PX4_WARN_EMERGENCY: mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY,
}
_PX4_RTL, _PX4_LAND = px4_custom_mode(4, 5), px4_custom_mode(4, 6)
#: failsafe.cpp ``fromBatteryWarningActParam`` (LowBatteryAction: 0 Warning, 1 Return
#: (deprecated), 2 Land, 3 ReturnOrLand): LOW only warns; CRITICAL: 1, 3 Return, 2 Land;
#: EMERGENCY: 1 Return, 2, 3 Land; 0 warns at every level.
_PX4_ACTION = {
    PX4_WARN_CRITICAL: {1: _PX4_RTL, 3: _PX4_RTL, 2: _PX4_LAND},
    PX4_WARN_EMERGENCY: {1: _PX4_RTL, 2: _PX4_LAND, 3: _PX4_LAND},
}
#: framework.cpp ``FailsafeBase::notifyUser``, the Warn action's events for each cause.
_PX4_WARN_TEXT = {
    PX4_WARN_LOW: (mavlink.MAV_SEVERITY_WARNING, "Low battery level, return advised"),
    PX4_WARN_CRITICAL: (mavlink.MAV_SEVERITY_CRITICAL, "Critical battery level, land now"),
    PX4_WARN_EMERGENCY: (
        mavlink.MAV_SEVERITY_EMERGENCY,
        "Emergency battery level, land immediately",
    ),
}
_PX4_KIND = {PX4_WARN_LOW: "battery_low", PX4_WARN_CRITICAL: "battery_critical"}


class PX4BatteryMonitor(_Monitor):
    """PX4's battery library (one analog battery, BAT1_*) and the commander's battery failsafe."""

    #: mavlink_main.cpp ``configure_streams_to_default`` (MAVLINK_MODE_NORMAL):
    #: ``configure_stream_local("BATTERY_STATUS", 0.5f)``.
    default_rates_hz = {mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5}

    def __init__(self, core) -> None:
        super().__init__(core)
        self.warning = PX4_WARN_NONE
        """``battery_status.warning``."""
        self._warning_at_arming = PX4_WARN_NONE
        self._was_armed = False
        self._acted = PX4_WARN_NONE
        """The worst warning the failsafe has acted on since arming (each level acts once:
        failsafe.cpp keeps one caller id and last state per level)."""

    def remaining(self) -> float:
        """battery.cpp ``estimateStateOfCharge`` with BAT1_CAPACITY set: the charge-counted
        ``1 - discharged / capacity`` (the slow fusion with the voltage-based estimate is not
        modelled); without a capacity the voltage-based estimate, for which the pack's true
        state of charge stands in."""
        capacity = self._params()[0]
        if capacity > 0:
            return max(0.0, 1.0 - self.consumed_mah() / capacity)
        return float(self.pack.soc[self.core.index])

    def _read_params(self) -> tuple:
        # (BAT1_CAPACITY, BAT_EMERGEN_THR, BAT_CRIT_THR, BAT_LOW_THR) as floats.
        P = self.core.params
        return (
            float(P["BAT1_CAPACITY"]),
            float(P["BAT_EMERGEN_THR"]),
            float(P["BAT_CRIT_THR"]),
            float(P["BAT_LOW_THR"]),
        )

    def _determine_warning(self, soc: float) -> int:
        # battery.cpp Battery::determineWarning: strict ``<`` against each threshold.
        _, emergency, critical, low = self._params()
        if soc < emergency:
            return PX4_WARN_EMERGENCY
        if soc < critical:
            return PX4_WARN_CRITICAL
        if soc < low:
            return PX4_WARN_LOW
        return PX4_WARN_NONE

    def time_remaining_s(self) -> float:
        """battery.cpp remaining flight time: remaining capacity over the average current (the
        current drawn here; BAT_AVRG_CURRENT at rest, the filter's initial value)."""
        capacity = self._params()[0]
        if capacity <= 0:
            return math.nan
        current = self.current_a()
        if current <= 0:
            current = float(self.core.params["BAT_AVRG_CURRENT"])
        if current <= 0:
            return math.nan
        return self.remaining() * capacity * 3.6 / current

    def sys_status_fields(self) -> tuple[int, int, int, int, int]:
        """SYS_STATUS.hpp: ``voltage_filtered_v * 1000`` mV, ``current_filtered_a * 100`` cA,
        ``ceilf(remaining * 100)`` % (the emulator's current and voltage are smooth: no extra
        filter); the battery's health-report bits present, enabled and healthy."""
        voltage_mv = _c_int(self.voltage_v() * 1000.0) & 0xFFFF
        current_ca = _c_int(self.current_a() * 100.0)
        return (
            BATTERY_SENSOR,
            BATTERY_SENSOR,
            voltage_mv,
            current_ca,
            int(math.ceil(self.remaining() * 100.0)),
        )

    def battery_status(self, now_s: float):
        """BATTERY_STATUS.hpp: id ``battery_status.id - 1`` = 0, function ALL, type LIPO,
        consumed mAh, energy -1 (not measured), ``ceilf(remaining * 100)``, time remaining
        ``max((int)time_remaining_s, 1)`` (0 when unknown), charge state from the warning, no
        temperature (INT16_MAX); no cell voltages, so the pack voltage in the first cell and
        UINT16_MAX in the others (extension included)."""
        t_rem = self.time_remaining_s()
        cells = [_c_int(self.voltage_v() * 1000.0) & 0xFFFF] + [_UINT16_MAX] * 9
        return mavlink.MAVLink_battery_status_message(
            0,
            mavlink.MAV_BATTERY_FUNCTION_ALL,
            mavlink.MAV_BATTERY_TYPE_LIPO,
            _INT16_MAX,
            cells,
            _c_int(self.current_a() * 100.0),
            _c_int(self.consumed_mah()),
            -1,
            int(math.ceil(self.remaining() * 100.0)),
            max(_c_int(t_rem), 1) if math.isfinite(t_rem) else 0,
            _PX4_CHARGE_STATE.get(self.warning, mavlink.MAV_BATTERY_CHARGE_STATE_UNDEFINED),
            [_UINT16_MAX] * 4,
            0,
            0,
        )

    def update(self, now_s: float) -> None:
        """The battery's warning level, then the commander's battery failsafe.

        battery.cpp: the warning follows the state of charge on the ground and only gets worse
        in the air. failsafe.cpp ``checkStateAndMode``: a level acts only when it is worse than
        the warning at arming (arming with a low battery does not fail safe at once), once per
        level, through ``fromBatteryWarningActParam(COM_LOW_BAT_ACT, warning)``."""
        core = self.core
        armed = core.armed
        new = self._determine_warning(self.remaining())
        if not armed or new > self.warning:
            self.warning = new
        if armed and not self._was_armed:
            self._warning_at_arming = self.warning
            self._acted = PX4_WARN_NONE
        self._was_armed = armed
        if not armed or self.warning <= self._warning_at_arming or self.warning <= self._acted:
            return
        level = self.warning
        self._acted = level
        mode = _PX4_ACTION.get(level, {}).get(int(core.params["COM_LOW_BAT_ACT"]))
        kind = _PX4_KIND.get(level, "battery_emergency")
        if mode is None:
            core._statustext(now_s, *_PX4_WARN_TEXT[level])
            self._failsafe_event(now_s, kind, "NONE")
            return
        # The mode switch of a failsafe action (framework.cpp notifyUser: "Failsafe activated").
        name = "Return" if mode == _PX4_RTL else "Land"
        core._statustext(now_s, mavlink.MAV_SEVERITY_CRITICAL, f"Failsafe activated: {name}")
        core._set_mode(mode, now_s, "failsafe")
        self._failsafe_event(now_s, kind, core.mode_name)


_MONITORS = {"ardupilot": ArduPilotBatteryMonitor, "px4": PX4BatteryMonitor}


def monitor_for(personality: str, core):
    """The battery monitor of ``personality`` bound to ``core``."""
    return _MONITORS[personality](core)
