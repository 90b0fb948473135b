"""The operator's picture at one instant, as plain JSON-able dicts (live and replay share it).

Everything here is what the *station believes* (:class:`gcs.fleet.FleetSnapshot`, the planner's
tree, the mission file), never the emulator's truth:

* vehicle state, one of :data:`STATES` (first match wins): ``lost`` (silent past the fleet
  timeout), ``landed`` (heard, disarmed: on the ground, before launch or after landing),
  ``returning`` (RTL or LAND mode, or back from a loss in a failsafe mode), ``held`` (taken out of
  the plan by an operator: hold / release), ``reclaimed`` (in the plan again after the station
  switched it back from a failsafe), ``networked`` (heard, in the plan: the paper's D'(t));
* radio links: pairs of heard vehicles with a position closer than the radio range, a vehicle and
  a crew closer than the radio range, a vehicle and the base closer than the base's range (the
  paper's disc model, as the station sees positions);
* crews "connected": a heard vehicle within radio range of the crew (the station's own
  ``tasks_covered``, :func:`planner.geometry.tasks_connected`);
* the task tree: the planner's semi-Steiner tree when the planner exposes one (PhiIREMAN's
  ``tree``), otherwise a Euclidean minimum spanning tree of the base, the crews and the networked
  vehicles (``tree.source`` says which).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse.csgraph import minimum_spanning_tree
from scipy.spatial import cKDTree

from gcs.autopilot import adapter_for
from planner.geometry import tasks_connected
from planner.phireman import PhiremanPlanner

if TYPE_CHECKING:
    from gcs.fleet import FleetSnapshot

__all__ = [
    "STATES",
    "STATE_LABELS",
    "crew_names",
    "mission_meta",
    "classify",
    "Picture",
    "frame_dict",
    "radio_links",
    "mst_tree",
]

STATES = ("networked", "reclaimed", "held", "returning", "landed", "lost")
STATE_LABELS = {
    "networked": "networked (in the plan)",
    "reclaimed": "reclaimed (back in the plan after a failsafe)",
    "held": "held by the operator (out of the plan)",
    "returning": "returning (RTL / landing)",
    "landed": "on the ground",
    "lost": "lost (not heard)",
}

#: At most this many vehicle-vehicle links are drawn (the shortest); the total is reported.
MAX_LINKS = 3000


def crew_names(mission) -> list[str]:
    """One name per task column, in :func:`mission.experiments.playback.task_track_m` order.

    Counted from 1; the crews of an unnamed ``random`` entry are ``Task 3``, ``Task 4``, ...
    when it is the mission's only entry, else ``Task 2.1``, ``Task 2.2`` (entry, crew); a named
    one gives ``Engine 1``, ``Engine 2``."""
    names = []
    alone = len(mission.tasks) == 1
    for i, task in enumerate(mission.tasks):
        label = task.name or f"Task {i + 1}"
        if task.kind == "random" or task.count > 1:  # a generator, or a TAK pattern's slots
            names += [
                f"{label} {k + 1}"
                if task.name
                else (f"Task {k + 1}" if alone else f"Task {i + 1}.{k + 1}")
                for k in range(task.count)
            ]
        else:
            names.append(label)
    return names


def mission_meta(
    mission,
    geofence,
    *,
    mode: str,
    actions: bool,
    tiles: dict | None,
    duration_s: float | None = None,
    end_action: str | None = None,
) -> dict:
    """What does not change during a run: base, crews, hazard zones, geofence, ranges.

    ``end_action``: what the vehicles do once the mission time is over (``"rtl"`` or ``"land"``,
    ``OperationsConfig.end``); the page names the end phase with it."""
    zones = []
    for k, z in enumerate(mission.attrition.hazard_zones):
        when = (
            f"from t+{z.start_s:.0f} s" + (f" to t+{z.end_s:.0f} s" if z.end_s else "")
            if (z.start_s or z.end_s)
            else "whole mission"
        )
        d = {
            "label": f"Hazard zone {k + 1}: +{100 * z.rate_per_s:.1f} % losses/s, {when}",
            "start_s": z.start_s,
            "end_s": z.end_s,
            "rate_per_s": z.rate_per_s,
        }
        if z.circle is not None:
            d.update(
                kind="circle",
                n=z.circle.center.north_m,
                e=z.circle.center.east_m,
                r=z.circle.radius_m,
            )
        else:
            d.update(kind="polygon", pts=[[p.north_m, p.east_m] for p in z.polygon])
        zones.append(d)
    fence = None
    if geofence is not None:
        f = geofence
        fence = {
            k: (None if not math.isfinite(v) else v)
            for k, v in (
                ("n_min", f.north_min_m),
                ("n_max", f.north_max_m),
                ("e_min", f.east_min_m),
                ("e_max", f.east_max_m),
                ("max_alt_m", f.max_alt_m),
            )
        }
    lim = mission.vehicles.limits
    return {
        "mode": mode,
        "name": mission.name,
        "description": mission.description,
        "origin": {
            "lat_deg": mission.origin.lat_deg,
            "lon_deg": mission.origin.lon_deg,
            "alt_amsl_m": mission.origin.alt_amsl_m,
        },
        "radio_range_m": mission.radio.range_m,
        "base_range_m": mission.radio.base_range_m,
        "crews": crew_names(mission),
        "hazard_zones": zones,
        "geofence": fence,
        "layers": {
            "n": lim.n_layers,
            "cruise_alt_m": lim.cruise_alt_m,
            "spacing_m": lim.layer_spacing_m,
        },
        "duration_s": mission.run.duration_s if duration_s is None else duration_s,
        "end_action": end_action,
        "vehicles_expected": mission.vehicles.count,
        "actions": bool(actions),
        "tiles": tiles,
        "states": list(STATES),
        "state_labels": STATE_LABELS,
    }


def classify(snap, released: dict | set, reclaimed: set) -> np.ndarray:
    """(N,) state names of a :class:`~gcs.fleet.FleetSnapshot` (module docstring, first wins).

    ``released``: vehicle ids ``(link_id, sysid)`` an operator took out of the plan (-> action);
    ``reclaimed``: ids the station switched back from a failsafe."""
    n = snap.n_vehicles
    out = np.full(n, "networked", dtype=object)
    vids = list(zip(snap.link_id.tolist(), snap.sysid_of_index.tolist()))
    for i in range(n):
        ad = adapter_for(int(snap.autopilot[i]))
        mode = snap.mode[i]
        if snap.lost[i]:
            out[i] = "lost"
        elif not snap.armed[i]:
            out[i] = "landed"
        elif snap.returning[i] or (mode and mode in (ad.rtl_mode, ad.land_mode)):
            out[i] = "returning"
        elif vids[i] in released:
            out[i] = "held"
        elif vids[i] in reclaimed:
            out[i] = "reclaimed"
    return out


def radio_links(
    ne_m: np.ndarray, ok: np.ndarray, range_m: float, max_links: int = MAX_LINKS
) -> tuple[np.ndarray, int]:
    """Vehicle pairs closer than ``range_m`` among rows ``ok``: ((K, 2) rows, shortest first,
    at most ``max_links``; the total number of pairs)."""
    rows = np.flatnonzero(ok)
    if len(rows) < 2:
        return np.empty((0, 2), dtype=int), 0
    pairs = cKDTree(ne_m[rows]).query_pairs(range_m, output_type="ndarray")
    total = len(pairs)
    if total > max_links:
        d = np.linalg.norm(ne_m[rows[pairs[:, 0]]] - ne_m[rows[pairs[:, 1]]], axis=1)
        pairs = pairs[np.argpartition(d, max_links)[:max_links]]
    return rows[pairs].reshape(-1, 2), total


def mst_tree(base_ne: np.ndarray, crews_ne: np.ndarray, relays_ne: np.ndarray) -> dict:
    """Euclidean minimum spanning tree of base + crews + relays, rooted at the base: nodes
    (base, crews, relays) and each node's parent (-1 for the base)."""
    crews_ne = crews_ne[np.isfinite(crews_ne).all(axis=1)]
    nodes = np.vstack([base_ne.reshape(1, 2), crews_ne, relays_ne])
    k = len(nodes)
    parent = np.full(k, -1, dtype=int)
    if k > 1:
        d = np.linalg.norm(nodes[:, None, :] - nodes[None, :, :], axis=2)
        d[d == 0] = 1e-9  # csgraph treats 0 as "no edge"
        np.fill_diagonal(d, 0.0)
        t = minimum_spanning_tree(d).toarray()
        adj = (t + t.T) > 0
        seen = np.zeros(k, dtype=bool)
        seen[0] = True
        stack = [0]
        while stack:  # walk from the base to orient the edges
            u = stack.pop()
            for v in np.flatnonzero(adj[u] & ~seen).tolist():
                seen[v] = True
                parent[v] = u
                stack.append(v)
    return {
        "nodes": np.round(nodes, 1).tolist(),
        "parent": parent.tolist(),
        "n_tasks": int(len(crews_ne)),
        "source": "MST of base, crews and networked vehicles (station's belief; "
        "the planner exposes no tree)",
    }


def _col(a: np.ndarray, nd: int = 1) -> list:
    a = np.asarray(a, dtype=float)
    return [None if not math.isfinite(x) else x for x in np.round(a, nd).tolist()]


@dataclass
class Picture:
    """Inputs of :func:`frame_dict` (arrays by fleet row)."""

    t_s: float
    t_mission_s: float | None
    phase: str
    snap: FleetSnapshot
    """gcs.fleet.FleetSnapshot."""
    states: np.ndarray
    heading_deg: np.ndarray
    target_ned_m: np.ndarray
    """(N, 3) planned target per row (NaN: none)."""
    layer_alt_m: np.ndarray
    n_layers: int
    crews_ne_m: np.ndarray
    tree: dict | None
    tu1: float | None
    tu2: float | None
    series: dict
    events: list
    crew_tracks: list | None = None
    truth: dict | None = None
    released: dict | None = None
    health: dict | None = None
    """Per-vehicle health columns (:func:`mission.view.live.health.health_columns`)."""
    alerts: dict | None = None
    """``{"open": [...], "recent": [...]}`` (:class:`mission.view.live.alerts.AlertBook`)."""
    rotation: dict | None = None
    """The relay rotation (:func:`mission.view.live.rotation.rotation_frame`; None: no batteries)."""


def frame_dict(p: Picture, radio_range_m: float, base_range_m: float) -> dict:
    """The JSON frame the page draws (columnar: one list per field, one entry per vehicle)."""
    snap = p.snap
    n = snap.n_vehicles
    pos = snap.pos_ned_m
    ne = pos[:, :2] if n else np.empty((0, 2))
    heard_pos = ~snap.lost & snap.has_position
    ne_ok = np.where(heard_pos[:, None], ne, 0.0)
    vv, total_vv = radio_links(ne_ok, heard_pos, radio_range_m)
    crews = np.asarray(p.crews_ne_m, dtype=float).reshape(-1, 2)
    crew_ok = np.isfinite(crews).all(axis=1)
    vc = []
    if heard_pos.any() and crew_ok.any():
        rows = np.flatnonzero(heard_pos)
        near = cKDTree(ne[rows]).query_ball_point(
            np.where(crew_ok[:, None], crews, 1e12), radio_range_m
        )
        for k, lst in enumerate(near):
            for j in lst:
                vc += [int(rows[j]), k]  # flat pairs (vehicle row, crew column)
    vb = (
        np.flatnonzero(heard_pos & (np.linalg.norm(ne_ok, axis=1) < base_range_m)).tolist()
        if n
        else []
    )
    connected = (
        tasks_connected(
            np.where(crew_ok[:, None], crews, np.inf),
            np.where(heard_pos[:, None], ne, np.inf),
            heard_pos,
            radio_range_m,
        )
        if len(crews)
        else np.zeros(0, bool)
    )
    states = [str(s) for s in p.states]
    counts = {s: states.count(s) for s in STATES}
    labels = [
        f"{s}" if int(l) == 0 else f"{l}:{s}"
        for l, s in zip(snap.link_id.tolist(), snap.sysid_of_index.tolist())
    ]
    released = p.released or {}
    frame = {
        "t_s": round(float(p.t_s), 2),
        "t_mission_s": None if p.t_mission_s is None else round(float(p.t_mission_s), 2),
        "phase": p.phase,
        "v": {
            "id": [f"{l}:{s}" for l, s in zip(snap.link_id.tolist(), snap.sysid_of_index.tolist())],
            "label": labels,
            "state": states,
            "mode": list(snap.mode),
            "n": _col(pos[:, 0]),
            "e": _col(pos[:, 1]),
            "alt": _col(-pos[:, 2]),
            "layer": (np.arange(n) % max(1, p.n_layers)).tolist(),
            "layer_alt": _col(p.layer_alt_m, 0),
            "hdg": _col(p.heading_deg, 0),
            "tn": _col(p.target_ned_m[:, 0]),
            "te": _col(p.target_ned_m[:, 1]),
            "talt": _col(-p.target_ned_m[:, 2]),
            "released": [
                released.get((int(l), int(s)))
                for l, s in zip(snap.link_id.tolist(), snap.sysid_of_index.tolist())
            ],
        },
        "crews": {
            "n": _col(crews[:, 0]),
            "e": _col(crews[:, 1]),
            "connected": [bool(c) for c in connected],
        },
        "links": {"vv": vv.ravel().tolist(), "vv_total": int(total_vv), "vc": vc, "vb": vb},
        "tree": p.tree,
        "counts": counts,
        "crews_connected": int(np.sum(connected)),
        "tu1": p.tu1,
        "tu2": p.tu2,
        "series": p.series,
        "events": p.events,
    }
    if p.health is not None:
        columns: dict = frame["v"]  # type: ignore[assignment]  # the dict built above
        columns.update(p.health)
    if p.alerts is not None:
        frame["alerts"] = p.alerts
    if p.crew_tracks is not None:
        frame["crew_tracks"] = p.crew_tracks
    if p.truth is not None:
        frame["truth"] = p.truth
    if p.rotation is not None:
        frame["rotation"] = p.rotation
    return frame


def tree_from_planner(planner) -> dict | None:
    """The planner's task tree in metres; None for a planner without one (DCCRS, MCCST) and
    before PhiIREMAN's first tick.

    PhiIREMAN (and ``phireman-resilient``, its subclass) keeps the tree in paper units as
    ``tree`` and its scale in ``units`` (planner/units.py), read here without a fallback: a
    renamed attribute fails loudly instead of drawing the tree at the wrong scale."""
    if not isinstance(planner, PhiremanPlanner):
        return None
    tree = planner.units.tree_to_m(planner.tree)
    if tree is None:
        return None
    nodes = np.asarray(tree.nodes_m, dtype=float)
    return {
        "nodes": np.round(nodes, 1).tolist(),
        "parent": np.asarray(tree.parent).tolist(),
        "n_tasks": int(tree.n_tasks),
        "source": f"the planner's task tree ({type(planner).__name__}: semi-Steiner tree "
        "over base and crews)",
    }


def decimate(rows: list, max_points: int = 600) -> list:
    """Every k-th row so that at most ``max_points`` remain (the last one always kept)."""
    if len(rows) <= max_points:
        return rows
    k = math.ceil(len(rows) / max_points)
    out = rows[::k]
    if out[-1] is not rows[-1]:
        out.append(rows[-1])
    return out


__all__ += ["tree_from_planner", "decimate"]
