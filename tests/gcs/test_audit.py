from gcs.audit import AUDIT_PARAMS, audit_fleet, audit_vehicle, params_to_read

AP, PX4 = 3, 12
GOOD_AP = {"FS_GCS_ENABLE": 1, "FS_GCS_TIMEOUT": 5, "GUID_TIMEOUT": 3, "SYSID_MYGCS": 255}
GOOD_PX4 = {"NAV_DLL_ACT": 2, "COM_OBL_RC_ACT": 0, "COM_OF_LOSS_T": 1.0, "COM_DL_LOSS_T": 10}


def test_good_settings_clear_the_fleet():
    report = audit_fleet({(0, 1): (AP, GOOD_AP), (0, 2): (PX4, GOOD_PX4)})
    assert report.cleared_to_fly and not report.overridden and report.unsafe == ()
    assert "cleared to fly" in report.summary()


def test_unsafe_settings_are_refused():
    cases = [
        (AP, {**GOOD_AP, "FS_GCS_ENABLE": 0}, "FS_GCS_ENABLE"),
        (AP, {**GOOD_AP, "SYSID_MYGCS": 254}, "SYSID_MYGCS"),
        (AP, {k: v for k, v in GOOD_AP.items() if k != "FS_GCS_ENABLE"}, "FS_GCS_ENABLE"),
        (PX4, {**GOOD_PX4, "NAV_DLL_ACT": 0}, "NAV_DLL_ACT"),
        (PX4, {**GOOD_PX4, "NAV_DLL_ACT": 5}, "NAV_DLL_ACT"),
        (PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": 6}, "COM_OBL_RC_ACT"),
        (0, {}, "-"),
    ]
    for autopilot, params, culprit in cases:
        audit = audit_vehicle(0, 1, autopilot, params)
        assert not audit.safe and [f.param for f in audit.blocking] == [culprit], (params, audit)
        report = audit_fleet({(0, 1): (autopilot, params), (0, 2): (AP, GOOD_AP)})
        assert not report.cleared_to_fly and "REFUSED" in report.summary()
        forced = audit_fleet({(0, 1): (autopilot, params)}, override=True)
        assert forced.cleared_to_fly and forced.overridden and "OVERRIDDEN" in forced.summary()


def test_new_gcs_sysid_names_and_ranges():
    new = {"FS_GCS_ENABLE": 5, "MAV_GCS_SYSID": 250, "MAV_GCS_SYSID_HI": 255}
    assert audit_vehicle(0, 1, AP, new, gcs_sysid=255).safe
    assert not audit_vehicle(0, 1, AP, new, gcs_sysid=249).safe
    assert audit_vehicle(0, 1, AP, {**GOOD_AP, "SYSID_MYGCS": 200}, gcs_sysid=200).safe


def test_warnings_do_not_block():
    audit = audit_vehicle(0, 1, AP, {**GOOD_AP, "FS_GCS_TIMEOUT": 30, "FS_GCS_ENABLE": 2})
    assert audit.safe and {f.severity for f in audit.findings} >= {"warning"}
    px = audit_vehicle(0, 1, PX4, {**GOOD_PX4, "COM_OBL_RC_ACT": 2})
    assert px.safe and any(f.severity == "warning" for f in px.findings)


def test_params_to_read():
    assert "SYSID_MYGCS" in params_to_read(AP) and "MAV_GCS_SYSID" in params_to_read(AP)
    assert set(params_to_read(PX4)) == {"COM_OF_LOSS_T", "COM_OBL_RC_ACT", "NAV_DLL_ACT",
                                        "COM_DL_LOSS_T"}
    assert params_to_read(99) == () and set(AUDIT_PARAMS) == {AP, PX4}
