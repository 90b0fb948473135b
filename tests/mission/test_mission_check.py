"""`phireman check`: a corpus of malformed missions, each rejected with its path and exit status 2."""

from __future__ import annotations

import textwrap

import pytest

from mission.cli import main

# (id, YAML document, text that must appear in the error output)
MALFORMED = [
    (
        "lat-out-of-range",
        "origin: {lat_deg: 95, lon_deg: 10}",
        "origin.lat_deg: must be within [-90, 90], got 95",
    ),
    (
        "lon-out-of-range",
        "origin: {lon_deg: -200}",
        "origin.lon_deg: must be within [-180, 180], got -200",
    ),
    (
        "t_s-not-a-number",
        "tasks:\n  - track: [{t_s: abc, north_m: 0, east_m: 0}]",
        "tasks[0].track[0].t_s: expected a number, got 'abc'",
    ),
    ("negative-rate", "attrition: {rate_per_s: -1}", "attrition.rate_per_s: must be >= 0, got -1"),
    (
        "times-not-increasing",
        "tasks:\n  - random: {count: 2}\n  - track:\n"
        "    - {t_s: 0, north_m: 0, east_m: 0}\n    - {t_s: 7, north_m: 1, east_m: 0}\n"
        "    - {t_s: 5, north_m: 2, east_m: 0}",
        "tasks[1].track[2].t_s: times must increase (got 5 after 7)",
    ),
    (
        "hazard-window-reversed",
        "attrition:\n  hazard_zones:\n    - circle: {center: {north_m: 0, east_m: 0}, radius_m: 10}\n"
        "      start_s: 50\n      end_s: 20",
        "attrition.hazard_zones[0]: end_s must be after start_s",
    ),
    (
        "unknown-key",
        "vehicles:\n  emulated: {count: 5, colour: red}",
        "vehicles.emulated.colour: unknown key; valid keys: count, personality, spawn",
    ),
    (
        "unknown-key-suggestion",
        "radio: {range: 100}",
        "radio.range: unknown key (did you mean 'range_m'?)",
    ),
    (
        "task-with-two-kinds",
        "tasks:\n  - track: [{t_s: 0, north_m: 0, east_m: 0}]\n    mavlink: {sysid: 3}",
        "tasks[0]: must have exactly one of track, random_walk, mavlink, tak, random; got track, mavlink",
    ),
    (
        "task-with-no-kind",
        "tasks:\n  - name: lonely",
        "tasks[0]: must have exactly one of track, random_walk, mavlink, tak, random; got none",
    ),
    (
        "unknown-planner",
        "planner: {method: phiremen}",
        "planner.method: unknown planner method 'phiremen' (did you mean 'phireman'?); valid methods: "
        "phireman",
    ),
    (
        "unknown-personality",
        "vehicles:\n  emulated: {personality: arducopter}",
        "vehicles.emulated.personality: must be one of ardupilot, px4, mixed; got 'arducopter' "
        "(did you mean 'ardupilot'?)",
    ),
    (
        "both-vehicle-kinds",
        "vehicles:\n  emulated: {count: 3}\n  real: {connections: ['udpin:0.0.0.0:14550']}",
        "vehicles: must have exactly one of emulated, real; got emulated, real",
    ),
    (
        "bad-connection",
        "vehicles:\n  real: {connections: ['udpin:0.0.0.0:99999']}",
        "vehicles.real.connections[0]: bad connection string",
    ),
    (
        "short-signing-key",
        "vehicles:\n  real: {connections: ['udpin:0.0.0.0:14550'], signing_key_hex: abcd}",
        "vehicles.real.signing_key_hex: must be 64 hex digits (32 bytes), got 4 characters",
    ),
    (
        "spawn-count-mismatch",
        "vehicles:\n  emulated:\n    count: 3\n    spawn:\n      positions:\n"
        "        - {north_m: 0, east_m: 0}\n        - {north_m: 5, east_m: 0}",
        "vehicles.emulated.spawn.positions: 2 positions for count 3",
    ),
    (
        "positional-coordinates",
        "vehicles:\n  emulated:\n    count: 1\n    spawn: {positions: [[1, 2]]}",
        "vehicles.emulated.spawn.positions[0]: expected a mapping, got a list",
    ),
    (
        "scripted-vehicle-out-of-range",
        "attrition:\n  scripted: [{vehicle: 60, t_s: 5}]",
        "attrition.scripted[0].vehicle: no vehicle 60: there are 50 (indices 0..49)",
    ),
    ("loss-prob-above-one", "radio: {loss_prob: 1.5}", "radio.loss_prob: must be <= 1, got 1.5"),
    (
        "count-not-integer",
        "vehicles:\n  emulated: {count: 2.5}",
        "vehicles.emulated.count: expected an integer, got 2.5",
    ),
    (
        "count-is-boolean",
        "vehicles:\n  emulated: {count: yes}",
        "vehicles.emulated.count: expected an integer, got true",
    ),
    ("no-tasks", "tasks: []", "tasks: needs at least 1 item, got 0"),
    (
        "walk-border-needs-field",
        "tasks:\n  - random_walk: {start: {north_m: 0, east_m: 0}, border: clip}",
        "tasks[0].random_walk.field_half_width_m: required when border is 'clip'",
    ),
    (
        "local-and-geo-position",
        "tasks:\n  - track: [{t_s: 0, north_m: 0, east_m: 0, lat_deg: 1, lon_deg: 2}]",
        "tasks[0].track[0]: give either north_m/east_m or lat_deg/lon_deg, not both",
    ),
    (
        "half-a-position",
        "tasks:\n  - track: [{t_s: 0, north_m: 3}]",
        "tasks[0].track[0]: missing east_m",
    ),
    (
        "polygon-too-small",
        "attrition:\n  hazard_zones:\n    - polygon: [{north_m: 0, east_m: 0}, {north_m: 1, east_m: 0}]",
        "attrition.hazard_zones[0].polygon: needs at least 3 items, got 2",
    ),
    (
        "zone-two-shapes",
        "attrition:\n  hazard_zones:\n    - circle: {center: {north_m: 0, east_m: 0}, radius_m: 10}\n"
        "      polygon: [{north_m: 0, east_m: 0}, {north_m: 1, east_m: 0}, {north_m: 0, east_m: 1}]",
        "attrition.hazard_zones[0]: must have exactly one of circle, polygon; got circle, polygon",
    ),
    (
        "sysid-zero",
        "tasks:\n  - mavlink: {sysid: 0}",
        "tasks[0].mavlink.sysid: must be >= 1, got 0",
    ),
    ("sysid-missing", "tasks:\n  - mavlink: {}", "tasks[0].mavlink.sysid: required key missing"),
    (
        "duration-below-period",
        "run: {duration_s: 0.5, control_period_s: 1}",
        "run.duration_s: must be at least control_period_s (1), got 0.5",
    ),
    ("negative-seed", "run: {seed: -3}", "run.seed: must be >= 0, got -3"),
    ("nan-rate", "attrition: {rate_per_s: .nan}", "attrition.rate_per_s: must be a finite number"),
    (
        "non-scalar-param",
        "planner: {params: {eta: [1, 2]}}",
        "planner.params.eta: expected a number, boolean or string, got a list",
    ),
    (
        "swapped-lat-lon",
        "tasks:\n  - track: [{t_s: 0, lat_deg: 149.16, lon_deg: -35.36}]",
        "tasks[0].track[0].lat_deg: must be within [-90, 90], got 149.16",
    ),
    (
        "far-from-origin",
        "tasks:\n  - track: [{t_s: 0, lat_deg: 48.85, lon_deg: 2.35}]",
        "km from the origin (limit 100 km); swapped lat/lon or wrong origin?",
    ),
    ("root-is-a-list", "- just\n- a list", "<top level>: expected a mapping, got a list"),
    ("section-is-a-string", "radio: loud", "radio: expected a mapping, got 'loud'"),
    ("duplicate-key", "radio: {range_m: 100}\nradio: {range_m: 200}", "duplicate key 'radio'"),
    ("not-yaml", "origin: [unclosed", "not valid YAML"),
    (
        "battery-too-small-for-the-posts",
        "tasks:\n  - track: [{t_s: 0, north_m: 300, east_m: 0}]\n"
        "endurance: {battery: {endurance_s: 60}}",
        "endurance: mission mission: a battery of 60 s cannot reach 150 m and come back with its "
        "reserve: no rotation is possible (endurance.battery.endurance_s, or --rotation off)",
    ),
    ("empty-document", "", "the document is empty"),
    ("python-tag", "origin: !!python/object/apply:os.getcwd []", "unsupported YAML tag"),
    ("custom-tag", "origin: !secret {lat_deg: 1}", "unsupported YAML tag"),
]


def _check(tmp_path, text, capsys, name="m.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    rc = main(["check", str(path)])
    out, err = capsys.readouterr()
    return rc, out, err, path


def test_corpus_is_large_enough():
    assert len(MALFORMED) >= 20
    assert len({case[0] for case in MALFORMED}) == len(MALFORMED)


@pytest.mark.parametrize(
    "text, expected", [c[1:] for c in MALFORMED], ids=[c[0] for c in MALFORMED]
)
def test_malformed_mission_is_rejected_with_its_path(tmp_path, capsys, text, expected):
    rc, out, err, path = _check(tmp_path, text, capsys)
    assert rc == 2
    assert "OK:" not in out
    assert expected in err, err
    assert "Traceback" not in err
    for line in err.strip().splitlines():  # every error line names the file
        assert line.startswith(f"{path}: "), line


def test_all_errors_are_reported_at_once(tmp_path, capsys):
    text = """\
    origin: {lat_deg: -91}
    attrition: {rate_per_s: -0.5}
    tasks:
      - track: [{t_s: 3, north_m: 0, east_m: 0}, {t_s: 1, north_m: 1, east_m: 1}]
    """
    rc, out, err, _ = _check(tmp_path, text, capsys)
    lines = err.strip().splitlines()
    assert rc == 2
    assert len(lines) == 3, err
    assert "origin.lat_deg" in lines[0]
    assert "tasks[0].track[1].t_s: times must increase (got 1 after 3)" in lines[1]
    assert "attrition.rate_per_s: must be >= 0, got -0.5" in lines[2]


def test_missing_file_is_a_clear_user_error(tmp_path, capsys):
    rc = main(["check", str(tmp_path / "nope.yaml")])
    out, err = capsys.readouterr()
    assert rc == 2
    assert "no such file" in err and "nope.yaml" in err
    assert "Traceback" not in err


def test_directory_is_a_clear_user_error(tmp_path, capsys):
    rc = main(["check", str(tmp_path)])
    _, err = capsys.readouterr()
    assert rc == 2 and "is a directory" in err


def test_binary_file_is_refused(tmp_path, capsys):
    path = tmp_path / "m.yaml"
    path.write_bytes(b"\xff\xfe\x00garbage")
    rc = main(["check", str(path)])
    _, err = capsys.readouterr()
    assert rc == 2 and "not UTF-8" in err


def test_python_tag_constructs_nothing(tmp_path, capsys):
    marker = tmp_path / "pwned"
    text = f"name: !!python/object/apply:os.system ['touch {marker}']\n"
    rc, _, err, _ = _check(tmp_path, text, capsys)
    assert rc == 2 and "unsupported YAML tag" in err
    assert not marker.exists()


BILLION_LAUGHS = """\
a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]
b: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]
c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]
d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]
e: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]
f: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]
g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]
h: &h [*g,*g,*g,*g,*g,*g,*g,*g,*g]
i: &i [*h,*h,*h,*h,*h,*h,*h,*h,*h]
"""


@pytest.mark.timeout(60)  # a bomb that expands hangs here; no wall-clock bound
def test_billion_laughs_is_refused_quickly(tmp_path, capsys):
    rc, _, err, _ = _check(tmp_path, BILLION_LAUGHS, capsys)
    assert rc == 2 and "refused" in err and "alias" in err


@pytest.mark.timeout(60)  # a bomb that expands hangs here; no wall-clock bound
def test_alias_bomb_under_the_alias_limit_is_refused_by_expanded_size(tmp_path, capsys):
    # 4 levels of 20 aliases (80 aliases, under the limit) expand to 20**4 = 160,000 leaves x 4.
    lines = [
        'a0: &a0 ["x","x","x","x","x","x","x","x","x","x","x","x","x","x","x","x","x","x","x","x"]'
    ]
    for level in range(1, 5):
        lines.append(f"a{level}: &a{level} [" + ",".join([f"*a{level - 1}"] * 20) + "]")
    rc, _, err, _ = _check(tmp_path, "\n".join(lines) + "\n", capsys)
    assert rc == 2 and "once aliases are expanded" in err


def test_deep_nesting_is_refused(tmp_path, capsys):
    rc, _, err, _ = _check(tmp_path, "name: " + "[" * 5000 + "]" * 5000, capsys)
    assert rc == 2 and "nested deeper" in err


@pytest.mark.timeout(60)  # a bomb that expands hangs here; no wall-clock bound
def test_oversized_document_is_refused_quickly(tmp_path, capsys):
    text = "description: |\n" + ("  " + "x" * 98 + "\n") * 12_000  # ~1.2 MB
    rc, _, err, _ = _check(tmp_path, text, capsys)
    assert rc == 2 and "limit" in err and "bytes" in err


def test_a_few_aliases_are_fine(tmp_path, capsys):
    text = """\
    tasks:
      - random_walk: {start: &home {north_m: 10, east_m: 20}, sigma_m_per_sqrt_s: 1}
      - random_walk: {start: *home, sigma_m_per_sqrt_s: 2}
    """
    rc, out, err, _ = _check(tmp_path, text, capsys)
    assert rc == 0, err
    assert out.startswith("OK: ")


def test_valid_mission_prints_ok_summary(tmp_path, capsys):
    rc, out, err, _ = _check(tmp_path, "name: tiny\nvehicles:\n  emulated: {count: 4}\n", capsys)
    assert rc == 0 and err == ""
    assert out.startswith("OK: tiny: 4 emulated ardupilot drones, 10 tasks")


@pytest.mark.timeout(
    30
)  # a guard that did not bite would run away; no wall-clock assertion (CONTRIBUTING)
@pytest.mark.parametrize(
    "text, expected",
    [
        (BILLION_LAUGHS, "alias"),
        ("name: " + "[" * 5000 + "]" * 5000, "nested deeper"),
        ("origin: !!python/object/apply:os.getcwd []", "unsupported YAML tag"),
        ("radio: {}\nradio: {}", "duplicate key 'radio'"),
    ],
)
def test_pure_python_loader_has_the_same_guards(monkeypatch, text, expected):
    """The libyaml-accelerated loader is optional; the fallback must be just as strict."""
    import mission.format.load as load

    monkeypatch.setattr(load, "_BoundedLoader", load._BoundedSafeLoader)
    with pytest.raises(load.MissionError, match=expected):
        load.loads_mission(text)
