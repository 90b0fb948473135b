"""Personalities (issue 13.2): firmware differences live in vehicle_emu/personality only."""

import ast
import pathlib

import pytest

from mavedge import mavlink
from mavedge.modes import ARDUCOPTER_MODES, PX4_MODES as WIRE_PX4, px4_custom_mode
from vehicle_emu.link import VehicleCore
from vehicle_emu.personality import PERSONALITIES, ArduPilot, PX4, personality_for

PKG = pathlib.Path(__file__).resolve().parents[2] / "vehicle_emu"


def test_no_personality_branches_outside_the_personality_package():
    offenders = [
        f"{p.relative_to(PKG)}:{i}"
        for p in PKG.rglob("*.py")
        if "personality" not in p.parts
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if "is_px4" in line
    ]
    assert offenders == []


def test_long_modules_say_why():
    for p in PKG.rglob("*.py"):
        text = p.read_text()
        if text.count("\n") > 650:
            doc = ast.get_docstring(ast.parse(text)) or ""
            assert "on purpose" in doc or "reason" in doc, f"{p.name} is long without a reason"


def test_mode_tables_agree_with_the_wire_tables():
    for key, (name, _) in ArduPilot.modes.items():
        assert ARDUCOPTER_MODES[name] == key
    for key, (name, _) in PX4.modes.items():
        assert px4_custom_mode(*WIRE_PX4[name]) == key
    assert PX4.modes[PX4.boot_mode][0] == "AUTO.LOITER"
    assert ArduPilot.modes[ArduPilot.boot_mode][0] == "STABILIZE"


@pytest.mark.parametrize("name", PERSONALITIES)
def test_core_reports_its_personality(name):
    core = VehicleCore(5, name)
    assert core.pers.name == name and isinstance(core.pers, (ArduPilot, PX4))
    assert core.params[core.pers.sysid_param] == 5
    assert core.custom_mode == core.pers.boot_mode
    out = b"".join(d for d, _ in (core.handle_timer(0.0) or core.datagrams_to_send(0.0)))
    hb = mavlink.MAVLink(None, 1, 1).parse_buffer(out)[0]
    assert hb.autopilot == core.pers.autopilot


def test_unknown_personality_is_refused():
    with pytest.raises(ValueError):
        personality_for("inav", None)
    with pytest.raises(ValueError):
        VehicleCore(1, "inav")
