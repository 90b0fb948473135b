"""``phireman replay RUN --serve / --export`` and the live page's task tree, driven as a user drives
them: the ``phireman`` command in a subprocess, its exit status, messages, files and HTTP port
(issue 28: both replay options were accepted and ignored from the command line, and the tree was
drawn 50x too small, while the functions behind them passed their own tests)."""

from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from user_cli import PHIREMAN, Served, http_get, run


@pytest.fixture(scope="module")
def fly_run(tmp_path_factory) -> Path:
    """A short emulated flight of the shipped wildfire mission (its run directory)."""
    out = tmp_path_factory.mktemp("fly")
    res = run(
        [PHIREMAN, "fly", "wildfire", "--duration-s", "30", "--speedup", "60", "--no-wait"],
        cwd=out,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    (run_dir,) = [p for p in (out / "runs").iterdir() if p.is_dir()]
    return run_dir


@pytest.fixture
def run_copy(fly_run: Path, tmp_path: Path) -> Path:
    """The flight's run directory copied, so what a test writes into it stays its own."""
    return Path(shutil.copytree(fly_run, tmp_path / fly_run.name))


def _pngs(d: Path) -> list[Path]:
    return sorted(d.rglob("*.png")) + sorted(d.rglob("*.gif"))


def test_replay_serve_serves_the_run(run_copy: Path, tmp_path: Path) -> None:
    with Served([PHIREMAN, "replay", str(run_copy), "--serve", "0"], cwd=tmp_path) as s:
        url = s.wait_for(r"replay of \S+ at (http://\S+)").group(1)
        meta = s.get_json(url + "api/meta")
        frame = s.get_json(url + "api/frame?i=0")
        status, body = http_get(url)
        assert s.proc.poll() is None, "the page must stay up until Ctrl-C"
    assert status == 200 and b"<html" in body.lower()
    assert meta["crews"], meta
    assert len(frame["v"]["id"]) == 50  # the wildfire mission's 50 vehicles
    assert _pngs(run_copy) == [], "--serve draws no pictures"


def test_replay_export_geojson_at(run_copy: Path, tmp_path: Path) -> None:
    res = run([PHIREMAN, "replay", str(run_copy), "--export", "geojson", "--at", "5"], tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    out = run_copy / "export.geojson"
    assert f"wrote {out}" in res.stdout
    doc = json.loads(out.read_text())
    assert doc["type"] == "FeatureCollection"
    kinds = {f["properties"]["kind"] for f in doc["features"]}
    assert {"base", "vehicle", "crew"} <= kinds, kinds
    at = {
        f["properties"]["t_mission_s"] for f in doc["features"] if "t_mission_s" in f["properties"]
    }
    assert len(at) == 1 and abs(at.pop() - 5.0) < 2.0  # the one --at snapshot
    assert _pngs(run_copy) == [], "--export draws no pictures"


def test_replay_export_kml_out_file(run_copy: Path, tmp_path: Path) -> None:
    res = run([PHIREMAN, "replay", str(run_copy), "--export", "kml", "--out", "wf.kml"], tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    out = tmp_path / "wf.kml"
    assert out.is_file(), "--out FILE is the KML file (not a directory of pictures)"
    root = ET.parse(out).getroot()
    assert root.tag.endswith("kml")
    names = [e.text for e in root.iter() if e.tag.endswith("}name") or e.tag == "name"]
    assert any(n and n.startswith("t+") for n in names), names[:20]  # the snapshot folders
    assert _pngs(tmp_path) == [], "--export draws no pictures"


def test_live_page_tree_is_in_metres(tmp_path: Path) -> None:
    """The task tree on ``fly --serve``'s page is PhiIREMAN's semi-Steiner tree in metres: its
    task nodes (rows 1..m) are where the crews are. The planner keeps the tree in paper units
    (planner/units.py); drawn without the conversion it is 50x too small (issue 28)."""
    cmd = [PHIREMAN, "fly", "wildfire", "--duration-s", "120", "--speedup", "10", "--no-wait"]
    with Served([*cmd, "--serve", "0", "--serve-actions", "off"], cwd=tmp_path) as s:
        url = s.wait_for(r"live view \(read-only\): (http://\S+)").group(1)
        s.wait_for(r"flying \d+/120s", deadline_s=180)
        frame = s.get_json(url + "api/frame")
    tree = frame["tree"]
    assert tree is not None and tree["source"].startswith("the planner's task tree"), tree
    m = tree["n_tasks"]
    crews = np.column_stack([frame["crews"]["n"], frame["crews"]["e"]]).astype(float)
    nodes = np.asarray(tree["nodes"], float)
    assert m == len(crews) == 10
    # Crews walk between the planner's tick and the frame: a few metres, never a factor of 50.
    err = np.linalg.norm(nodes[1 : m + 1] - crews, axis=1)
    assert err.max() < 25.0, (nodes[1 : m + 1], crews)
    assert np.linalg.norm(crews, axis=1).max() > 200.0  # crews far enough to tell the scales apart
