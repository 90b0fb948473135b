from gcs.audit import (
    AUDIT_PARAMS,
    OPTIONAL_PARAMS,
    OPTIONAL_REASONS,
    audit_fleet,
    audit_vehicle,
    failsafe_fixes,
    params_still_needed,
    params_to_read,
)

AP, PX4 = 3, 12
GOOD_AP = {
    "FS_GCS_ENABLE": 1,
    "FS_GCS_TIMEOUT": 5,
    "FS_OPTIONS": 16,
    "GUID_TIMEOUT": 3,
    "SYSID_MYGCS": 255,
}
GOOD_PX4 = {
    "NAV_DLL_ACT": 2,
    "COM_OBL_RC_ACT": 0,
    "NAV_RCL_ACT": 2,
    "COM_OF_LOSS_T": 1.0,
    "COM_DL_LOSS_T": 10,
    "COM_RC_IN_MODE": 3,
    "COM_RCL_EXCEPT": 0,
    "COM_DLL_EXCEPT": 0,
    "COM_FAIL_ACT_T": 0.0,
}


def _messages(audit, param):
    return [f.message for f in audit.findings if f.param == param]


def test_good_settings_clear_the_fleet():
    report = audit_fleet(
        {
            (0, 1): (AP, GOOD_AP),
            (0, 2): (PX4, GOOD_PX4),
            (0, 3): (PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": 3, "NAV_RCL_ACT": 3}),
        }
    )
    assert report.cleared_to_fly and not report.overridden and report.unsafe == ()
    assert "cleared to fly" in report.summary()


def test_unsafe_settings_are_refused():
    cases = [
        (AP, {**GOOD_AP, "FS_GCS_ENABLE": 0}, "FS_GCS_ENABLE"),
        (AP, {**GOOD_AP, "FS_GCS_ENABLE": 4}, "FS_GCS_ENABLE"),  # SmartRTL or Land
        (AP, {**GOOD_AP, "FS_GCS_ENABLE": 5}, "FS_GCS_ENABLE"),  # Land
        (AP, {**GOOD_AP, "FS_GCS_ENABLE": 7}, "FS_GCS_ENABLE"),  # Brake or Land
        (AP, {**GOOD_AP, "SYSID_MYGCS": 254}, "SYSID_MYGCS"),
        (AP, {k: v for k, v in GOOD_AP.items() if k != "FS_GCS_ENABLE"}, "FS_GCS_ENABLE"),
        (PX4, {**GOOD_PX4, "NAV_DLL_ACT": 0}, "NAV_DLL_ACT"),
        (PX4, {**GOOD_PX4, "NAV_DLL_ACT": 1}, "NAV_DLL_ACT"),  # Hold away from home
        (PX4, {**GOOD_PX4, "NAV_DLL_ACT": 3}, "NAV_DLL_ACT"),  # Land
        (PX4, {**GOOD_PX4, "NAV_DLL_ACT": 5}, "NAV_DLL_ACT"),
        (PX4, {**GOOD_PX4, "NAV_DLL_ACT": 7}, "NAV_DLL_ACT"),  # Hold, no failsafe
        (PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": 4}, "COM_OBL_RC_ACT"),
        (PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": 5}, "COM_OBL_RC_ACT"),
        (PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": 6}, "COM_OBL_RC_ACT"),
        (PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": 7}, "COM_OBL_RC_ACT"),
        (PX4, {**GOOD_PX4, "NAV_RCL_ACT": 3}, "NAV_RCL_ACT"),  # a killed station -> land
        (PX4, {**GOOD_PX4, "NAV_RCL_ACT": 6}, "NAV_RCL_ACT"),  # disarmed at 18.6 m
        (PX4, {**GOOD_PX4, "NAV_RCL_ACT": 0}, "NAV_RCL_ACT"),
        (PX4, {**GOOD_PX4, "NAV_RCL_ACT": 1}, "NAV_RCL_ACT"),
        (PX4, {k: v for k, v in GOOD_PX4.items() if k != "NAV_RCL_ACT"}, "NAV_RCL_ACT"),
        (PX4, {**GOOD_PX4, "COM_DLL_EXCEPT": 4}, "COM_DLL_EXCEPT"),
        (PX4, {**GOOD_PX4, "COM_OBL_ACT": 0}, "COM_OBL_ACT"),  # PX4 <= 1.13: Land
        (0, {}, "-"),
    ]
    for autopilot, params, culprit in cases:
        audit = audit_vehicle(0, 1, autopilot, params)
        assert not audit.safe and [f.param for f in audit.blocking] == [culprit], (params, audit)
        report = audit_fleet({(0, 1): (autopilot, params), (0, 2): (AP, GOOD_AP)})
        assert not report.cleared_to_fly and "REFUSED" in report.summary()
        forced = audit_fleet({(0, 1): (autopilot, params)}, override=True)
        assert forced.cleared_to_fly and forced.overridden and "OVERRIDDEN" in forced.summary()


def test_findings_say_what_happens():
    px = audit_vehicle(0, 1, PX4, {**GOOD_PX4, "NAV_RCL_ACT": 6})
    assert _messages(px, "NAV_RCL_ACT") == [
        "offboard loss: without RC, PX4 uses NAV_RCL_ACT=6: Disarm in the air"
    ]
    land = audit_vehicle(0, 1, PX4, {**GOOD_PX4, "NAV_RCL_ACT": 3})
    assert "Land where it is" in _messages(land, "NAV_RCL_ACT")[0]
    # No more "(without RC: return)" guess: the 0-2 fallback names both firmware behaviours.
    obl = _messages(audit_vehicle(0, 1, PX4, GOOD_PX4), "COM_OBL_RC_ACT")[0]
    assert "NAV_RCL_ACT" in obl and "hovers" in obl and "(without RC: return)" not in obl
    # With Return on offboard loss NAV_RCL_ACT is only the RC-loss action: not blocking.
    ret = audit_vehicle(0, 1, PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": 3, "NAV_RCL_ACT": 6})
    assert ret.safe and "Return, with or without RC" in _messages(ret, "COM_OBL_RC_ACT")[0]
    ap = audit_vehicle(0, 1, AP, {**GOOD_AP, "FS_GCS_ENABLE": 7})
    assert "Land where it is" in _messages(ap, "FS_GCS_ENABLE")[0]


def test_old_px4_uses_com_obl_act_without_rc():
    # PX4 <= v1.13 has COM_OBL_ACT: it, not NAV_RCL_ACT, is the no-RC offboard-loss action.
    old = {**GOOD_PX4, "COM_OBL_ACT": 2, "NAV_RCL_ACT": 3}
    audit = audit_vehicle(0, 1, PX4, old)
    assert audit.safe and "Return" in _messages(audit, "COM_OBL_ACT")[0]


def test_new_gcs_sysid_names_and_ranges():
    new = {"FS_GCS_ENABLE": 3, "MAV_GCS_SYSID": 250, "MAV_GCS_SYSID_HI": 255}
    assert audit_vehicle(0, 1, AP, new, gcs_sysid=255).safe
    assert not audit_vehicle(0, 1, AP, new, gcs_sysid=249).safe
    assert audit_vehicle(0, 1, AP, {**GOOD_AP, "SYSID_MYGCS": 200}, gcs_sysid=200).safe


def test_warnings_do_not_block():
    audit = audit_vehicle(
        0, 1, AP, {**GOOD_AP, "FS_GCS_TIMEOUT": 30, "FS_GCS_ENABLE": 6, "FS_OPTIONS": 2}
    )
    assert audit.safe and {f.param for f in audit.findings if f.severity == "warning"} == {
        "FS_GCS_TIMEOUT",
        "FS_GCS_ENABLE",
        "FS_OPTIONS",
    }
    # No FS_OPTIONS bit changes the GCS failsafe in GUIDED (events.cpp failsafe_gcs_on_event).
    for opts in (4, 8, 16, 31):
        assert audit_vehicle(0, 1, AP, {**GOOD_AP, "FS_OPTIONS": opts}).safe
    px = audit_vehicle(
        0, 1, PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": 2, "COM_DLL_EXCEPT": 2, "COM_FAIL_ACT_T": 30}
    )
    assert px.safe and {f.param for f in px.findings if f.severity == "warning"} == {
        "COM_OBL_RC_ACT",
        "COM_DLL_EXCEPT",
        "COM_FAIL_ACT_T",
    }


def test_optional_params_absent_on_older_firmware_do_not_block():
    ap3 = {k: v for k, v in GOOD_AP.items() if k not in ("FS_GCS_TIMEOUT", "FS_OPTIONS")}
    assert audit_vehicle(0, 1, AP, ap3).safe
    px = {
        k: v
        for k, v in GOOD_PX4.items()
        if k not in ("COM_DLL_EXCEPT", "COM_FAIL_ACT_T", "COM_RCL_EXCEPT")
    }
    assert audit_vehicle(0, 1, PX4, px).safe
    assert set(OPTIONAL_REASONS) == set(OPTIONAL_PARAMS)
    from gcs.landing import LANDING_ONLY_PARAMS  # read with a relay rotation

    read = {n for names in AUDIT_PARAMS.values() for n in names} | LANDING_ONLY_PARAMS
    assert OPTIONAL_PARAMS <= read
    # Required ones are never optional: losing them must block.
    assert not {"FS_GCS_ENABLE", "NAV_DLL_ACT", "COM_OBL_RC_ACT", "NAV_RCL_ACT"} & OPTIONAL_PARAMS


def test_every_blocking_fixable_finding_is_fixed():
    cases = [(AP, {**GOOD_AP, "FS_GCS_ENABLE": fs}) for fs in (0, 4, 5, 7)]
    cases += [(AP, {**GOOD_AP, "SYSID_MYGCS": 9})]
    cases += [(PX4, {**GOOD_PX4, "NAV_DLL_ACT": v}) for v in (0, 1, 3, 5, 6, 7, 42)]
    cases += [(PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": v}) for v in (4, 5, 6, 7, -1)]
    cases += [(PX4, {**GOOD_PX4, "NAV_RCL_ACT": v}) for v in (0, 1, 3, 5, 6, 7)]
    cases += [(PX4, {**GOOD_PX4, "COM_DLL_EXCEPT": 7}), (PX4, {**GOOD_PX4, "COM_OBL_ACT": 4})]
    for ap, params in cases:
        assert not audit_vehicle(0, 1, ap, params).safe
        fixes = failsafe_fixes(ap, params)
        assert fixes and all(isinstance(v, float) for _, v in fixes)
        fixed = {**params, **dict(fixes)}
        assert audit_vehicle(0, 1, ap, fixed).safe, (params, fixes)
        assert failsafe_fixes(ap, fixed) == ()
    # COM_DLL_EXCEPT: only the Offboard bit is cleared.
    assert dict(failsafe_fixes(PX4, {**GOOD_PX4, "COM_DLL_EXCEPT": 7}))["COM_DLL_EXCEPT"] == 3.0
    # An unread parameter is never written; it still blocks.
    missing = {k: v for k, v in GOOD_PX4.items() if k != "NAV_RCL_ACT"}
    assert failsafe_fixes(PX4, missing) == () and not audit_vehicle(0, 1, PX4, missing).safe


def test_params_to_read():
    assert "SYSID_MYGCS" in params_to_read(AP) and "MAV_GCS_SYSID" in params_to_read(AP)
    assert {"FS_GCS_ENABLE", "FS_OPTIONS", "GUID_TIMEOUT"} <= set(params_to_read(AP))
    assert {
        "COM_OF_LOSS_T",
        "COM_OBL_RC_ACT",
        "NAV_RCL_ACT",
        "NAV_DLL_ACT",
        "COM_DL_LOSS_T",
        "COM_RC_IN_MODE",
        "COM_DLL_EXCEPT",
        "COM_OBL_ACT",
    } <= set(params_to_read(PX4))
    assert params_to_read(99) == () and set(AUDIT_PARAMS) == {AP, PX4}
    # The GCS-sysid range follows the new spelling only.
    assert "MAV_GCS_SYSID_HI" not in params_still_needed(AP, {})
    assert "MAV_GCS_SYSID_HI" in params_still_needed(AP, {"MAV_GCS_SYSID": 255})
