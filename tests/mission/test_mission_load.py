"""Mission schema + loader: examples, paper presets, unit conversions, round trips."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import math

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from mission.format import schema
from mission.cli import main
from mission.format.examples import example_path, example_text, list_examples
from mission.format.load import (
    MissionError,
    dump_mission,
    load_mission,
    loads_mission,
    resolved_dict,
    validate_mission,
)
from mission.format.schema import (
    Attrition,
    Circle,
    HazardZone,
    LocalPoint,
    Mission,
    Origin,
    Position,
    Task,
    TrackPoint,
    paper_mission,
    per_step_from_rate,
    rate_from_per_step,
)

EXAMPLES = [
    "canyon",
    "canyon_camp",
    "canyon_deep",
    "hazard_zone",
    "paper_S",
    "real_links_template",
    "scripted_losses",
    "sitl_ardupilot",
    "sitl_px4",
    "wildfire",
    "wildfire_2h",
]
SIZES = ["XS", "S", "M", "L", "XL"]


# ------------------------------------------------------------------ shipped examples


def test_examples_are_shipped():
    assert list_examples() == EXAMPLES
    for name in EXAMPLES:
        assert example_path(name).is_file()
        assert example_path(f"{name}.yaml") == example_path(name)
    with pytest.raises(KeyError, match="examples: canyon, canyon_camp, canyon_deep, hazard_zone"):
        example_path("nope")


@pytest.mark.parametrize("name", EXAMPLES)
def test_every_example_passes_check(name, capsys):
    assert main(["check", str(example_path(name))]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("OK: ") and err == ""
    assert main(["check", name]) == 0  # shipped examples also work by name
    capsys.readouterr()


def test_wildfire_is_the_S_sized_default():
    m = load_mission(example_path("wildfire"))
    emu = m.vehicles.emulated
    assert (emu.count, emu.personality, m.n_tasks) == (50, "ardupilot", 10)
    kinds = [t.kind for t in m.tasks]
    assert kinds.count("track") >= 3 and kinds.count("random_walk") >= 3
    assert m.radio.range_m == 100.0 and emu.max_speed_m_s == 7.5
    assert m.run.duration_s == 200.0 and m.run.control_period_s == 1.0
    assert m.attrition.per_step(m.run.control_period_s) == pytest.approx(0.01, rel=1e-3)
    assert 32 < m.origin.lat_deg < 42 and -125 < m.origin.lon_deg < -114  # California


def test_hazard_and_scripted_examples_have_what_they_say():
    hz = load_mission(example_path("hazard_zone"))
    assert {z.set_alternative() for z in hz.attrition.hazard_zones} == {"circle", "polygon"}
    sl = load_mission(example_path("scripted_losses"))
    assert len(sl.attrition.scripted) >= 5 and sl.attrition.rate_per_s == 0
    real = load_mission(example_path("real_links_template"))
    assert real.vehicles.real is not None and len(real.vehicles.real.connections) >= 2


def test_paper_S_example_is_what_mission_new_writes(capsys):
    assert main(["mission", "new", "--preset", "S", "--attrition", "0.01", "--unit-m", "50"]) == 0
    out, _ = capsys.readouterr()
    assert out == example_text("paper_S")


# ------------------------------------------------------------------ mission new


@pytest.mark.parametrize("reading", ["scaled", "literal"])
@pytest.mark.parametrize("size", SIZES)
def test_mission_new_reloads_for_every_size(size, reading, capsys):
    from planner.problem import SIZES as TABLE

    rc = main(
        [
            "mission",
            "new",
            "--preset",
            size,
            "--attrition",
            "0.02",
            "--unit-m",
            "50",
            "--reading",
            reading,
            "--seed",
            "9",
        ]
    )
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert out.startswith("# PhiIREMAN / RTNUA paper configuration")
    m = loads_mission(out)
    n_drones, n_tasks, hw = TABLE[size]
    unit = 50.0 * (hw / 5.0 if reading == "scaled" else 1.0)
    emu = m.vehicles.emulated
    assert emu.count == n_drones and m.n_tasks == n_tasks
    (task,) = m.tasks
    assert task.kind == "random" and task.random.border == "clip"
    assert task.random.field_half_width_m == pytest.approx(hw * 50.0)
    assert task.random.sigma_m_per_sqrt_s == pytest.approx(0.1 * unit)
    assert m.radio.range_m == pytest.approx(2 * unit) == emu.radio_range_m
    assert emu.max_speed_m_s == pytest.approx(0.15 * unit)
    assert emu.spawn.ring.radius_m == pytest.approx(unit)
    assert emu.spawn.ring.noise_m == pytest.approx(0.2 * unit)
    assert m.attrition.rate_per_s == pytest.approx(-math.log(0.98))
    assert m.run.duration_s == 200 and m.run.n_steps == 200 and m.run.seed == 9


def test_mission_new_step_changes_time_units(capsys):
    assert main(["mission", "new", "--step-s", "0.5", "--attrition", "0.01"]) == 0
    m = loads_mission(capsys.readouterr()[0])
    assert m.run.control_period_s == 0.5 and m.run.duration_s == 100 and m.run.n_steps == 200
    assert m.vehicles.emulated.max_speed_m_s == pytest.approx(15.0)  # 7.5 m per 0.5 s step
    assert m.tasks[0].random.sigma_m_per_sqrt_s == pytest.approx(5.0 / math.sqrt(0.5))
    assert m.attrition.per_step(0.5) == pytest.approx(0.01)


def test_mission_new_out_file(tmp_path, capsys):
    out = tmp_path / "m.yaml"
    assert main(["mission", "new", "--preset", "xs", "--out", str(out)]) == 0
    assert load_mission(out).vehicles.emulated.count == 20
    assert main(["mission", "new", "--out", str(out)]) == 2  # refuses to overwrite
    assert "exists" in capsys.readouterr()[1]
    assert main(["mission", "new", "--out", str(out), "--force"]) == 0


@pytest.mark.parametrize(
    "args, message",
    [
        (["--attrition", "1.0"], "--attrition"),
        (["--attrition", "-0.1"], "--attrition"),
        (["--unit-m", "0"], "--unit-m"),
        (["--step-s", "-1"], "--step-s"),
    ],
)
def test_mission_new_bad_arguments(args, message, capsys):
    assert main(["mission", "new", *args]) == 2
    assert message in capsys.readouterr()[1]


def test_mission_without_subcommand_and_show(capsys):
    assert main(["mission"]) == 2
    assert "subcommand" in capsys.readouterr()[1]
    assert main(["mission", "show", "scripted_losses"]) == 0
    shown = capsys.readouterr()[0]
    assert loads_mission(shown) == load_mission(example_path("scripted_losses"))


# ------------------------------------------------------------------ unit conversions


def test_per_step_attrition_to_rate():
    assert rate_from_per_step(0.01, 1.0) == pytest.approx(0.010050335853501)
    assert rate_from_per_step(0.01, 0.5) == pytest.approx(2 * 0.010050335853501)
    assert rate_from_per_step(0.0, 1.0) == 0.0
    assert rate_from_per_step(0.05, 2.0) == pytest.approx(-math.log(0.95) / 2.0)
    assert per_step_from_rate(0.010050335853501, 1.0) == pytest.approx(0.01)
    with pytest.raises(ValueError):
        rate_from_per_step(1.0, 1.0)
    with pytest.raises(ValueError):
        per_step_from_rate(-1.0, 1.0)


@given(p=st.floats(0.0, 0.99), dt=st.floats(0.01, 100.0))
def test_attrition_conversion_round_trips(p, dt):
    rate = rate_from_per_step(p, dt)
    assert math.exp(-rate * dt) == pytest.approx(1.0 - p, rel=1e-12, abs=1e-15)  # survive one step
    assert per_step_from_rate(rate, dt) == pytest.approx(p, rel=1e-9, abs=1e-15)


def test_default_mission_is_paper_S_without_attrition():
    default = loads_mission("{}")
    paper = validate_mission(paper_mission("S", 0.0, unit_m=50.0))
    assert default.vehicles == paper.vehicles
    assert default.tasks == paper.tasks
    assert default.radio == paper.radio
    assert default.attrition == paper.attrition
    assert default.run == paper.run
    assert schema.paper_length_unit_m(default.radio.range_m) == 50.0


# ------------------------------------------------------------------ dump / load


@pytest.mark.parametrize("name", EXAMPLES)
def test_dump_load_round_trip_examples(name):
    m = load_mission(example_path(name))
    text = dump_mission(m)
    assert loads_mission(text) == m
    assert yaml.safe_load(text) == resolved_dict(m)
    assert loads_mission(dump_mission(loads_mission(text))) == m


def test_dump_load_round_trip_built_mission():
    m = Mission(
        name="built",
        origin=Origin(lat_deg=10.0, lon_deg=20.0, alt_amsl_m=5.0),
        tasks=(
            Task(
                name="a",
                track=(
                    TrackPoint(t_s=0.0, north_m=1.0, east_m=2.0),
                    TrackPoint(t_s=3.5, lat_deg=10.001, lon_deg=20.001),
                ),
            ),
        ),
        attrition=Attrition(
            rate_per_s=0.1,
            hazard_zones=(
                HazardZone(
                    circle=Circle(center=LocalPoint(north_m=1.0, east_m=2.0), radius_m=3.0),
                    rate_per_s=0.2,
                    start_s=1.0,
                    end_s=2.0,
                ),
            ),
        ),
    )
    resolved = validate_mission(m)
    assert resolved.vehicles.emulated.radio_range_m == resolved.radio.range_m  # filled in
    assert loads_mission(dump_mission(m)) == resolved
    text = dump_mission(m, header="hello\n\nworld")
    assert text.startswith("# hello\n#\n# world\n")
    assert "{t_s: 0.0, north_m: 1.0, east_m: 2.0}" in text  # points on one line, t_s first


def test_validate_mission_rejects_bad_built_mission():
    bad = Mission(tasks=(Task(),), attrition=Attrition(rate_per_s=-2.0))
    with pytest.raises(MissionError) as info:
        validate_mission(bad)
    assert len(info.value.errors) == 2
    assert "tasks[0]: must have exactly one of" in str(info.value)


# ------------------------------------------------------------------ schema helpers and rules


def test_track_is_piecewise_linear_and_holds_at_the_ends():
    origin = Origin()
    task = Task(
        track=(
            TrackPoint(t_s=10.0, north_m=0.0, east_m=0.0),
            TrackPoint(t_s=20.0, north_m=100.0, east_m=-50.0),
        )
    )
    assert task.track_position_m(0.0, origin) == (0.0, 0.0)
    assert task.track_position_m(15.0, origin) == pytest.approx((50.0, -25.0))
    assert task.track_position_m(99.0, origin) == (100.0, -50.0)


def test_geo_positions_convert_near_the_origin():
    origin = Origin(lat_deg=39.7596, lon_deg=-121.6219, alt_amsl_m=540.0)
    lat, lon = origin.to_geo_deg(150.0, -200.0)
    n, e = Position(lat_deg=lat, lon_deg=lon).local_m(origin)
    assert (n, e) == pytest.approx((150.0, -200.0), abs=0.01)
    assert schema._approx_local_m(origin, lat, lon) == pytest.approx(
        (150.0, -200.0), rel=0.01
    )  # spherical


def test_hazard_zone_geometry_and_window():
    square = HazardZone(
        polygon=tuple(
            LocalPoint(north_m=n, east_m=e) for n, e in [(0, 0), (0, 10), (10, 10), (10, 0)]
        ),
        start_s=5.0,
        end_s=10.0,
    )
    assert square.contains(5.0, 5.0) and not square.contains(15.0, 5.0)
    assert not square.active(4.9) and square.active(5.0) and not square.active(10.0)
    disc = HazardZone(circle=Circle(center=LocalPoint(north_m=0.0, east_m=0.0), radius_m=2.0))
    assert disc.contains(1.0, 1.0) and not disc.contains(2.0, 2.0) and disc.active(1e9)


def _schema_classes():
    return [
        c
        for _, c in inspect.getmembers(schema, inspect.isclass)
        if dataclasses.is_dataclass(c) and c.__module__ == schema.__name__
    ]


@pytest.mark.parametrize("cls", _schema_classes(), ids=lambda c: c.__name__)
def test_every_schema_field_has_a_docstring_and_a_frozen_class(cls):
    assert cls.__dataclass_params__.frozen
    tree = ast.parse(inspect.getsource(cls))
    body = tree.body[0].body
    for i, node in enumerate(body):
        if isinstance(node, ast.AnnAssign):
            after = body[i + 1] if i + 1 < len(body) else None
            assert isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant), (
                f"{cls.__name__}.{node.target.id} has no attribute docstring"
            )


def test_numeric_keys_carry_units():
    allowed_unitless = {
        "count",
        "n_layers",
        "seed",
        "sysid",
        "vehicle",
        "loss_prob",
        "speedup",
        "fresnel_clear_fraction",
        "k_factor",
    }
    for cls in _schema_classes():
        for f in dataclasses.fields(cls):
            hint = str(f.type)
            if "float" in hint and "str" not in hint and f.name not in allowed_unitless:
                radio_units = ("_mhz", "_dbm", "_dbi", "_db")
                assert f.name.endswith(
                    ("_m", "_s", "_deg", "_per_s", "_m_s", "_per_sqrt_s", "_frac") + radio_units
                ), f"{cls.__name__}.{f.name} has no unit suffix"


@pytest.mark.parametrize("size", SIZES)
def test_problem_config_of_a_paper_mission_matches_the_preset(size):
    from planner.problem import problem_preset

    for step_s in (1.0, 0.5):
        cfg = paper_mission(size, 0.02, unit_m=1.0, step_s=step_s).problem_config()
        ref = problem_preset(size, 0.02)
        assert (cfg.n_drones, cfg.n_tasks, cfg.n_steps) == (ref.n_drones, ref.n_tasks, ref.n_steps)
        assert cfg.attrition_per_step == pytest.approx(0.02)
        assert cfg.dt_s == step_s
        assert cfg.length_unit_m == pytest.approx(ref.length_unit_m)
        for name in (
            "field_half_width_m",
            "radio_range_m",
            "base_range_m",
            "ring_radius_m",
            "ring_noise_m",
            "task_walk_sigma_m",
        ):
            assert getattr(cfg, name) == pytest.approx(getattr(ref, name)), name
        assert cfg.max_speed_m_s * step_s == pytest.approx(ref.max_speed_m_s)  # metres per step
        assert cfg.task_border == "clip"
