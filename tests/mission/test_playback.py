"""In-process playback of mission files: determinism, scripted losses, hazard zones, replay."""

import json

import numpy as np
import pytest
from scipy import stats

from mission.format.load import loads_mission
from mission.experiments.playback import loss_probability, run_inprocess, write_run_dir, zone_mask

BASE = """
name: test
vehicles:
  emulated: {count: 20, spawn: {ring: {radius_m: 50, noise_m: 10}}}
tasks:
  - random: {count: 4, field_half_width_m: 200, sigma_m_per_sqrt_s: 5}
  - track: [{t_s: 0, north_m: 150, east_m: 0}, {t_s: 60, north_m: 0, east_m: 150}]
run: {duration_s: 60, control_period_s: 1, seed: 3}
"""


def test_same_seed_same_results_every_time():
    m = loads_mission(BASE + "attrition: {rate_per_s: 0.01}\n")
    a, b = run_inprocess(m), run_inprocess(m)
    assert (a.tu1, a.tu2) == (b.tu1, b.tu2)
    assert np.array_equal(a.record.pos_m, b.record.pos_m)
    c = run_inprocess(m, seed=4)
    assert not np.array_equal(a.record.pos_m, c.record.pos_m)


def test_scripted_losses_happen_at_their_times():
    m = loads_mission(
        BASE
        + """
attrition:
  scripted: [{vehicle: 2, t_s: 5}, {vehicle: 7, t_s: 12.5}, {vehicle: 11, t_s: 30}]
"""
    )
    r = run_inprocess(m)
    got = {e["index"]: e["t_s"] for e in r.losses}
    # a loss scripted at t dies during the step that starts at floor(t / dt): gone from t_s = step + 1
    assert got == {2: 6.0, 7: 13.0, 11: 31.0}
    assert r.record.alive[5, 2] and not r.record.alive[6, 2]
    assert all(e["scripted"] for e in r.losses)
    # a lost drone never moves again
    assert np.allclose(r.record.pos_m[6:, 2], r.record.pos_m[6, 2])


def test_zone_mask_circle_and_polygon():
    m = loads_mission(
        BASE
        + """
attrition:
  hazard_zones:
    - circle: {center: {north_m: 0, east_m: 100}, radius_m: 50}
    - polygon: [{north_m: 0, east_m: 0}, {north_m: 0, east_m: 10}, {north_m: 10, east_m: 10}, {north_m: 10, east_m: 0}]
      start_s: 10
      end_s: 20
"""
    )
    pts = np.array([[0, 100], [0, 160], [5, 5], [15, 5]], dtype=float)
    circle, square = m.attrition.hazard_zones
    assert zone_mask(circle, pts).tolist() == [True, False, False, False]
    assert zone_mask(square, pts).tolist() == [False, False, True, False]
    assert [square.contains(*p) for p in pts] == [False, False, True, False]
    # a concave (L-shaped) zone: the notch is outside
    ell = loads_mission(
        BASE
        + """
attrition:
  hazard_zones:
    - polygon: [{north_m: 0, east_m: 0}, {north_m: 0, east_m: 20}, {north_m: 10, east_m: 20},
                {north_m: 10, east_m: 10}, {north_m: 20, east_m: 10}, {north_m: 20, east_m: 0}]
"""
    ).attrition.hazard_zones[0]
    probe = np.array([[5, 5], [5, 15], [15, 5], [15, 15], [-1, 5], [25, 5]], dtype=float)
    assert zone_mask(ell, probe).tolist() == [True, True, True, False, False, False]
    assert loss_probability(m, 0.0, pts)[2] == 0.0  # window not open yet
    assert loss_probability(m, 15.0, pts)[2] > 0.0
    assert loss_probability(m, 20.0, pts)[2] == 0.0  # end_s is exclusive


def test_losses_are_higher_inside_a_hazard_zone_than_outside():
    m = loads_mission(
        BASE
        + """
attrition:
  rate_per_s: 0.002
  hazard_zones:
    - circle: {center: {north_m: 0, east_m: 0}, radius_m: 120}
      rate_per_s: 0.03
"""
    )
    zone = m.attrition.hazard_zones[0]
    inside_exp = outside_exp = inside_loss = outside_loss = 0
    for seed in range(8):
        r = run_inprocess(m, seed=seed)
        rec = r.record
        for t in range(len(rec.alive) - 1):
            alive = rec.alive[t]
            inside = zone_mask(zone, rec.pos_m[t]) & alive
            lost = alive & ~rec.alive[t + 1]
            inside_exp += inside.sum()
            outside_exp += (alive & ~inside).sum()
            inside_loss += (lost & inside).sum()
            outside_loss += (lost & ~inside).sum()
    assert inside_exp > 100 and outside_exp > 100
    # one-sided test that the per-exposure loss rate inside exceeds the rate outside
    table = [[inside_loss, inside_exp - inside_loss], [outside_loss, outside_exp - outside_loss]]
    _, p = stats.fisher_exact(table, alternative="greater")
    assert p < 1e-3, (table, p)


def test_live_mavlink_tasks_are_refused_in_process():
    m = loads_mission(BASE.replace("  - random:", "  - mavlink: {sysid: 42}\n  - random:"))
    with pytest.raises(ValueError, match="MAVLink task"):
        run_inprocess(m)


def test_run_directory_and_replay(tmp_path):
    from mission.view.replay import load_run, replay

    m = loads_mission(BASE + "attrition: {rate_per_s: 0.01}\n")
    r = run_inprocess(m)
    write_run_dir(m, r, tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["tu1"] == r.tu1 and summary["seed"] == 3 and "code_version" in summary
    run = load_run(tmp_path)
    assert run.pos_m.shape == (61, 20, 2) and run.connected.shape == (61, 5)
    files = replay(tmp_path, animation="gif", max_frames=4)
    assert [f.name for f in files] == ["fig2_timeseries.png", "frames.png", "animation.gif"]
    assert all(f.stat().st_size > 1000 for f in files)


def test_geofence_section_is_validated_and_reaches_the_station_config():
    from mission.format.load import MissionError
    from mission.flight.runners import control_config

    m = loads_mission(BASE + "geofence: {half_width_m: 300, max_alt_m: 120}\n")
    fence = control_config(m).geofence
    assert (fence.north_max_m, fence.east_min_m, fence.max_alt_m) == (300.0, -300.0, 120.0)
    with pytest.raises(MissionError) as exc:
        loads_mission(BASE + "geofence: {half_width_m: 300, max_alt_m: 20}\n")
    assert any(
        e.startswith("geofence.max_alt_m:") and "cruise layer" in e for e in exc.value.errors
    )


def test_in_process_drones_stay_inside_the_geofence():
    """Tasks at 150 m, fence at 60 m: the in-process backend clips targets as the station does."""
    free = run_inprocess(loads_mission(BASE))
    fenced = run_inprocess(loads_mission(BASE + "geofence: {half_width_m: 60}\n"))
    assert np.abs(free.record.pos_m).max() > 100.0  # unfenced, drones go out to the tasks
    # (the ring spawn itself reaches ~70 m; from step 10 on every drone is inside)
    assert np.abs(fenced.record.pos_m[10:]).max() <= 60.0 + 1e-9
    assert fenced.tu1 < free.tu1
