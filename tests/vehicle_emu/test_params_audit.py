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
