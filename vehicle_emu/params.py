"""A small, real parameter table per personality (PARAM_REQUEST_LIST / READ / SET).

Values are kept in the autopilot's native units (ArduPilot speeds in cm/s, PX4 in m/s) so a
ground station reads exactly what it would read from the firmware; the vehicle core converts to
SI when it uses them.

Deviations from firmware defaults, chosen so the emulator reproduces the paper's behaviour
("a disconnected drone flies home") out of the box, are marked ``# emulator default``:

* ArduPilot ``FS_GCS_ENABLE`` defaults to 0 in the firmware; here 1 (RTL).
* PX4 ``NAV_DLL_ACT`` defaults to 0 (disabled) in the firmware; here 2 (Return), and
  ``COM_DL_LOSS_T`` keeps its firmware default of 10 s (configurable).

The lost-link parameters the station audits (``gcs.audit.AUDIT_PARAMS``) are all here, so an
emulated vehicle answers every read; the ones only older firmware has (PX4 ``COM_OBL_ACT``,
ArduPilot ``MAV_GCS_SYSID`` / ``MAV_GCS_SYSID_HI``) are absent, as on the firmware emulated.

Every default can be overridden per vehicle (``Swarm(params=...)`` or PARAM_SET on the wire).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

from .wire import dialect

__all__ = [
    "ParamSpec",
    "ParamTable",
    "ARDUPILOT_PARAMS",
    "PX4_PARAMS",
    "ARDUPILOT_BATTERY_PARAMS",
    "PX4_BATTERY_PARAMS",
    "defaults_for",
]

_F = dialect.MAV_PARAM_TYPE_REAL32
_I8 = dialect.MAV_PARAM_TYPE_INT8
_I16 = dialect.MAV_PARAM_TYPE_INT16
_I32 = dialect.MAV_PARAM_TYPE_INT32


@dataclass(frozen=True)
class ParamSpec:
    """One parameter definition."""

    name: str
    """Parameter id (at most 16 characters)."""
    default: float
    """Default value, native units."""
    param_type: int
    """MAV_PARAM_TYPE_*."""
    min_value: float = float("-inf")
    max_value: float = float("inf")


# ArduCopter (4.x) names and defaults: ArduCopter/Parameters.cpp, libraries/AC_WPNav/AC_WPNav.cpp,
# ArduCopter/mode_rtl.cpp. Units are the firmware's.
ARDUPILOT_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("SYSID_THISMAV", 1, _I16, 1, 255),
    ParamSpec("SYSID_MYGCS", 255, _I16, 1, 255),
    ParamSpec("FS_GCS_ENABLE", 1, _I8, 0, 7),  # emulator default (firmware: 0)
    ParamSpec("FS_GCS_TIMEOUT", 5.0, _F, 2, 120),  # s
    ParamSpec("FS_OPTIONS", 16, _I32, 0, 2**31 - 1),  # bit 4: continue pilot modes on GCS failsafe
    ParamSpec("GUID_TIMEOUT", 3.0, _F, 0.1, 5),  # s
    ParamSpec("WPNAV_SPEED", 1000.0, _F, 10, 2000),  # cm/s
    ParamSpec("WPNAV_SPEED_UP", 250.0, _F, 10, 1000),  # cm/s
    ParamSpec("WPNAV_SPEED_DN", 150.0, _F, 10, 500),  # cm/s
    ParamSpec("LAND_SPEED", 50.0, _F, 30, 200),  # cm/s
    ParamSpec("LAND_SPEED_HIGH", 0.0, _F, 0, 500),  # cm/s above LAND_ALT_LOW; 0 = WPNAV_SPEED_DN
    ParamSpec("LAND_ALT_LOW", 1000.0, _F, 100, 10000),  # cm: LAND_SPEED below, WPNAV_SPEED_DN above
    ParamSpec("RTL_ALT", 1500.0, _F, 200, 300000),  # cm above home
    ParamSpec("RTL_ALT_FINAL", 0.0, _F, 0, 1000),  # cm; 0 = land at home
    ParamSpec("RTL_SPEED", 0.0, _F, 0, 2000),  # cm/s; 0 = WPNAV_SPEED
    ParamSpec("DISARM_DELAY", 10, _I8, 0, 127),  # s
    # libraries/AP_Rally/AP_Rally.cpp, Copter defaults (RTL to the nearest rally point or home).
    ParamSpec("RALLY_LIMIT_KM", 0.3, _F, 0, 1000),  # km; 0 = no limit
    ParamSpec("RALLY_INCL_HOME", 1, _I8, 0, 1),
)

# PX4 (v1.14+) names and defaults: src/modules/commander/commander_params.yaml,
# src/modules/mc_pos_control/multicopter_*_params.c, src/modules/navigator/rtl_params.c.
PX4_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("MAV_SYS_ID", 1, _I32, 1, 250),
    ParamSpec("COM_OF_LOSS_T", 1.0, _F, 0, 60),  # s
    ParamSpec(
        "COM_OBL_RC_ACT", 0, _I32, 0, 7
    ),  # 0 Position, 1 Altitude, 2 Manual, 3 RTL, 4 Land, 5 Hold
    ParamSpec("NAV_RCL_ACT", 2, _I32, 0, 7),  # 2 Return (offboard-loss action without RC)
    ParamSpec("NAV_DLL_ACT", 2, _I32, 0, 7),  # emulator default (firmware: 0 disabled)
    ParamSpec("COM_DL_LOSS_T", 10, _I32, 5, 300),  # s
    ParamSpec("COM_RC_IN_MODE", 3, _I32, 0, 8),  # 3 RC or MAVLink, keep first
    ParamSpec("COM_RCL_EXCEPT", 0, _I32, 0, 31),  # bitmask; 0 no exceptions
    ParamSpec("COM_DLL_EXCEPT", 0, _I32, 0, 31),  # bitmask; 0 no exceptions
    ParamSpec("COM_FAIL_ACT_T", 0.0, _F, 0, 25),  # s in Hold before a failsafe action
    ParamSpec("COM_DISARM_PRFLT", 10.0, _F, -1, 20),  # s
    ParamSpec("MPC_XY_CRUISE", 5.0, _F, 3, 20),  # m/s (auto modes)
    ParamSpec("MPC_XY_VEL_MAX", 12.0, _F, 0, 20),  # m/s (offboard / position limit)
    ParamSpec("MPC_Z_VEL_MAX_UP", 3.0, _F, 0.5, 8),  # m/s
    ParamSpec("MPC_Z_VEL_MAX_DN", 1.5, _F, 0.5, 4),  # m/s
    ParamSpec("MPC_Z_V_AUTO_DN", 1.5, _F, 0.5, 4),  # m/s: auto modes (RTL, Land) descend at most
    ParamSpec("MPC_LAND_SPEED", 0.7, _F, 0.6, 4),  # m/s
    ParamSpec("MPC_LAND_ALT1", 10.0, _F, 0, 122),  # m: slowing down below (takeoff_land_params.c)
    ParamSpec("MPC_LAND_ALT2", 5.0, _F, 0, 122),  # m: MPC_LAND_SPEED below
    ParamSpec("MIS_TAKEOFF_ALT", 2.5, _F, 0, 80),  # m above home
    ParamSpec("RTL_RETURN_ALT", 60.0, _F, 0, 150),  # m above home
    ParamSpec("RTL_DESCEND_ALT", 30.0, _F, 2, 100),  # m (used as hover height if RTL_LAND_DELAY<0)
    ParamSpec("RTL_LAND_DELAY", 0.0, _F, -1, 300),  # s; -1 = hover at RTL_DESCEND_ALT
    ParamSpec("RTL_TYPE", 0, _I32, 0, 5),  # 0 closest of home / rally points (rtl_params.c)
)


# The battery monitor's parameters, present only when the emulator's batteries are on
# (vehicle_emu.battery; without them the tables above are unchanged). docs/design/endurance.md §6.
# ArduCopter: libraries/AP_BattMonitor/AP_BattMonitor_Params.cpp (var_info; DEFAULT_LOW_BATTERY_VOLTAGE
# is 10.5 V for Copter, 0 for the other vehicles), types as declared in AP_BattMonitor_Params.h.
ARDUPILOT_BATTERY_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("BATT_MONITOR", 4, _I8, 0, 30),  # emulator default (firmware 0; SITL copter 4)
    ParamSpec("BATT_CAPACITY", 3300, _I32, 0, 2**31 - 1),  # mAh (the emulator's pack)
    ParamSpec("BATT_LOW_TIMER", 10, _I8, 0, 120),  # s; 0 disables the voltage failsafes
    ParamSpec("BATT_FS_VOLTSRC", 0, _I8, 0, 1),  # 0 raw voltage, 1 sag compensated
    ParamSpec("BATT_LOW_VOLT", 10.5, _F, 0, 1000),  # V (Copter default); 0 disables
    ParamSpec("BATT_LOW_MAH", 0, _I32, 0, 2**31 - 1),  # mAh left; 0 disables
    ParamSpec("BATT_CRT_VOLT", 0.0, _F, 0, 1000),  # V; 0 disables
    ParamSpec("BATT_CRT_MAH", 0, _I32, 0, 2**31 - 1),  # mAh left; 0 disables
    ParamSpec("BATT_FS_LOW_ACT", 0, _I8, 0, 7),  # Copter: 0 None, 1 Land, 2 RTL, 3 SmartRTL
    ParamSpec("BATT_FS_CRT_ACT", 0, _I8, 0, 7),  # or RTL, 4 SmartRTL or Land, 5 Terminate, ...
)

# PX4: src/lib/battery/battery_params.c (BAT_*_THR), module.yaml (BAT1_*),
# src/modules/commander/commander_params.yaml (COM_LOW_BAT_ACT).
PX4_BATTERY_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("BAT_LOW_THR", 0.15, _F, 0.12, 0.5),  # fraction: BATTERY_WARNING_LOW below
    ParamSpec("BAT_CRIT_THR", 0.07, _F, 0.05, 0.5),  # fraction: BATTERY_WARNING_CRITICAL below
    ParamSpec("BAT_EMERGEN_THR", 0.05, _F, 0.03, 0.5),  # fraction: BATTERY_WARNING_EMERGENCY
    ParamSpec("BAT_AVRG_CURRENT", 15.0, _F, 0, 500),  # A, time-remaining estimate at rest
    ParamSpec("BAT1_N_CELLS", 3, _I32, 1, 14),  # emulator default: the emulator's pack
    ParamSpec("BAT1_CAPACITY", 3300.0, _F, -1, 100000),  # mAh; emulator default (firmware -1)
    ParamSpec("COM_LOW_BAT_ACT", 0, _I32, 0, 3),  # 0 Warning, 2 Land, 3 Return then Land
)


def defaults_for(personality: str, battery: bool = False) -> tuple[ParamSpec, ...]:
    """The parameter table of ``personality``, with the battery monitor's when ``battery``."""
    if personality == "ardupilot":
        return ARDUPILOT_PARAMS + (ARDUPILOT_BATTERY_PARAMS if battery else ())
    if personality == "px4":
        return PX4_PARAMS + (PX4_BATTERY_PARAMS if battery else ())
    raise ValueError(f"personality must be 'ardupilot' or 'px4', got {personality!r}")


#: Stamps of table contents, unique across every table of the process (see ParamTable.stamp).
_STAMPS = itertools.count(1)


class ParamTable:
    """Ordered parameter table with typed values (integer ones held in their range).

    Parameters
    ----------
    specs : sequence of ParamSpec
    overrides : mapping name -> value, optional
        Applied after the defaults; unknown names raise ``KeyError`` (a local programming error).
    """

    def __init__(self, specs, overrides=None) -> None:
        self._specs = {s.name: s for s in specs}
        self._names = [s.name for s in specs]
        self._values = {s.name: float(s.default) for s in specs}
        for name, value in (overrides or {}).items():
            if name not in self._specs:
                raise KeyError(f"unknown parameter {name!r}; valid: {', '.join(self._names)}")
            self._values[name] = self._coerce(self._specs[name], float(value))
        self.stamp = next(_STAMPS)
        """Changes on every :meth:`set`, and differs from any other table's: a value derived
        from the table (the core's GCS failsafe config) is still valid while this is equal."""

    @staticmethod
    def _coerce(spec: ParamSpec, value: float) -> float:
        # A float parameter is stored as written: the ranges are GCS metadata, not checks made by
        # the firmware (ArduPilot GCS_Param.cpp handle_param_set refuses only NaN / inf and
        # read-only names, then vp->set_float; PX4 param_set in src/lib/parameters does not
        # compare with the metadata's min / max). Integer parameters are rounded and held in
        # their range, standing in for the firmware's conversion to its integer type.
        if spec.param_type == _F:
            return value
        value = float(int(round(value)))
        return min(max(value, spec.min_value), spec.max_value)

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name: str) -> bool:
        return name in self._specs

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def names(self) -> list[str]:
        return list(self._names)

    def index_of(self, name: str) -> int:
        return self._names.index(name)

    def name_at(self, index: int) -> str | None:
        return self._names[index] if 0 <= index < len(self._names) else None

    def param_type(self, name: str) -> int:
        return self._specs[name].param_type

    def set(self, name: str, value: float) -> float:
        """Set (integer types rounded and held in their range); return the stored value."""
        stored = self._coerce(self._specs[name], float(value))
        self._values[name] = stored
        self.stamp = next(_STAMPS)
        return stored
