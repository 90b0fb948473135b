"""The pictures of ``phireman replay RUN_DIR`` explain themselves (issue 28.11): the mission end and
the flight home after it are marked, hazard zones are drawn active only inside their time window
(in the strip and in every animation frame), crews have readable names whose labels do not
cover each other."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mission.cli import main

MISSION = """\
name: mini
origin: {lat_deg: 39.7596, lon_deg: -121.6219, alt_amsl_m: 540.0}
vehicles:
  emulated: {count: 12}
tasks:
  - random: {count: 6, field_half_width_m: 120.0, sigma_m_per_sqrt_s: 2.0, border: clip}
attrition:
  hazard_zones:
    - circle: {center: {north_m: 60.0, east_m: 50.0}, radius_m: 40.0}
      rate_per_s: 0.0
      start_s: 8.0
      end_s: 14.0
run: {duration_s: 24.0, control_period_s: 1.0, seed: 2}
"""
END_S = 16.0  # the mission "ended" here; the recorded samples go on to 24 s (the flight home)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A recorded run whose samples go on after its mission end, as a ``phireman fly`` run's do
    (its summary says when the mission ended and run.json what the vehicles did then)."""
    tmp = tmp_path_factory.mktemp("pictures")
    (tmp / "m.yaml").write_text(MISSION)
    out = tmp / "run"
    assert main(["sim", "--mission", str(tmp / "m.yaml"), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    summary.update(duration_s=END_S, mission_s_flown=END_S + 0.5)
    (out / "summary.json").write_text(json.dumps(summary))
    (out / "run.json").write_text(json.dumps({"seed": 2, "options": {"end": "rtl"}}))
    return out


def test_the_mission_end_is_marked_on_the_time_series(run_dir, tmp_path):
    from PIL import Image

    assert main(["replay", str(run_dir), "--animation", "none", "--out", str(tmp_path)]) == 0
    rgb = np.asarray(Image.open(tmp_path / "fig2_timeseries.png").convert("RGB")).astype(int)
    # The shading after the end: tab:orange at 12 % over white.
    orange = np.array([255, 240, 226])
    shaded = (np.abs(rgb - orange) <= 3).all(axis=2)
    cols = np.flatnonzero(shaded.sum(axis=0) > 50)  # columns mostly shaded (the axes' height)
    assert len(cols) > 20, "no shading after the mission end"
    # It lies right of the end, inside the axes: the last third of the time axis (16 of 24 s).
    w = rgb.shape[1]
    assert cols.min() > 0.5 * w and cols.max() < 0.99 * w, (cols.min(), cols.max(), w)


def test_zones_are_active_only_in_their_window_in_strip_and_animation(run_dir, tmp_path):
    import mission.view.plots as plots

    seen = []
    real = plots.FrameView.update

    def spy(self, *a, **kw):
        out = real(self, *a, **kw)
        for _, patch in getattr(self, "zones", []):
            seen.append((kw.get("t_s"), patch.get_linestyle() == "-"))
        return out

    plots.FrameView.update = spy
    try:
        assert (
            main(
                ["replay", str(run_dir), "--animation", "gif", "--max-frames", "25"]
                + ["--out", str(tmp_path)]
            )
            == 0
        )
    finally:
        plots.FrameView.update = real
    assert seen and all(t is not None for t, _ in seen), seen[:5]
    # Active exactly in [8, 14): the mission's window (and never after the mission end).
    for t, on in seen:
        assert on == (8.0 <= t < 14.0), (t, on)
    assert any(on for _, on in seen) and any(not on for _, on in seen)


def test_crews_have_readable_names_and_labels_that_do_not_collide(run_dir):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mission.view.plots import FrameView
    from mission.view.replay import _scene, load_run

    run = load_run(run_dir)
    scene = _scene(run)
    assert scene.task_names == [f"Task {k}" for k in range(1, 7)]
    fig, ax = plt.subplots(figsize=(5.2, 5.2))
    view = FrameView(ax, scene)
    # Crews bunched together (a few metres apart): their labels must not cover each other.
    crews = np.array([[0.0, 0.0], [3.0, 2.0], [-2.0, 4.0], [4.0, -3.0], [1.0, 6.0], [-4.0, -2.0]])
    crews += [40.0, 40.0]
    k = 0
    view.update(run.pos_m[k], run.alive[k], run.active[k], crews, np.ones(6, bool), None, t_s=0.0)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    boxes = []
    for t in view.labels:
        t.set_visible(True)  # drawn by the layout, which hides them between draws
        bb = t.get_window_extent(renderer)
        boxes.append(bb)
    drawn = [bb for bb, k in zip(boxes, range(6)) if k not in _hidden(view)]
    hidden = view.label_layout.hidden_rows
    assert len(drawn) + len(hidden) == 6 and len(drawn) >= 4, hidden
    for i in range(len(drawn)):
        for j in range(i + 1, len(drawn)):
            assert not drawn[i].overlaps(drawn[j]), (i, j, drawn[i], drawn[j])
    plt.close(fig)


def _hidden(view) -> set[int]:
    """Labels the layout left out at its last draw (it hides them with no position change)."""
    return set(view.label_layout.hidden_rows)
