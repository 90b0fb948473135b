"""The emulator answers every lost-link parameter the station audits, and passes the audit."""

from gcs.audit import AUDIT_PARAMS, OPTIONAL_PARAMS, audit_vehicle, params_still_needed
from gcs.autopilot import ARDUPILOT, PX4
from vehicle_emu.params import ParamTable, defaults_for

#: Names the emulated firmware does not have: PX4 <= 1.13's COM_OBL_ACT, and ArduPilot's newer
#: GCS-sysid spelling (the emulator has SYSID_MYGCS).
ABSENT = {"COM_OBL_ACT", "MAV_GCS_SYSID", "MAV_GCS_SYSID_HI"}


def _read(personality, autopilot):
    table = ParamTable(defaults_for(personality))
    return {n: table[n] for n in AUDIT_PARAMS[autopilot] if n in table}


def test_every_audited_parameter_exists_in_the_emulator():
    for personality, autopilot in (("ardupilot", ARDUPILOT), ("px4", PX4)):
        got = _read(personality, autopilot)
        assert set(AUDIT_PARAMS[autopilot]) - set(got) <= ABSENT, personality
        # Nothing left that the operator would re-request (optional ones are asked once).
        assert set(params_still_needed(autopilot, got)) <= OPTIONAL_PARAMS


def test_emulator_defaults_pass_the_audit():
    for personality, autopilot in (("ardupilot", ARDUPILOT), ("px4", PX4)):
        audit = audit_vehicle(0, 1, autopilot, _read(personality, autopilot))
        assert audit.safe, audit


def test_float_params_are_stored_as_written_integers_held_in_range():
    # The firmware stores a float beyond its documented range (the range is GCS metadata:
    # ArduPilot handle_param_set -> set_float): a mission flying 25 m/s gets WPNAV_SPEED 2500.
    ap = ParamTable(defaults_for("ardupilot"))
    assert ap.set("WPNAV_SPEED", 2500.0) == 2500.0 and ap["WPNAV_SPEED"] == 2500.0
    assert ap.set("FS_GCS_ENABLE", 9) == 7.0  # an integer: rounded and held in its range
    px4 = ParamTable(defaults_for("px4"))
    name = next(n for n in px4.names() if n == "MPC_XY_VEL_MAX")
    assert px4.set(name, 40.0) == 40.0
