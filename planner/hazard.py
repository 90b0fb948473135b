"""Hazard zones as the planner sees them: where, how dangerous, when (beyond the paper, issue 15).

The paper treats uniform attrition only and names "geographically localized attrition" as future
work; a mission's ``attrition.hazard_zones`` (mission/format/schema.py ``HazardZone``) raise the loss
rate of drones inside them. This module is the planner-side mirror of those zones (the planner
imports nothing of ours; :func:`mission.format.scenario.hazard_map` converts) and the geometry the
hazard-aware planner (planner/resilient.py, ``hazard_*`` parameters) needs:

* :func:`hazard_rate_per_s` - the extra loss rate at each position (the rate field);
* :func:`segment_lengths_per_zone` / :func:`segment_length_in_zones` - how much of each segment lies
  inside the zones (prices tree edges; a segment that crosses no zone interior has length 0);
* :func:`signed_depth` - how deep each point is inside each zone and the inward direction (the
  push potential);
* :func:`route_tree` - the task tree routed around the active zones: each edge crossing a zone
  whose ends are outside every zone is replaced by the shortest path around the zones through
  waypoints just outside them (a visibility graph), when that path is at most ``cap`` times the
  edge.

Every fast (vectorised) function has a loop reference next to it (``*_reference``) that
tests/planner/test_hazard.py compares with. Positions are (north, east) metres in the mission
frame; times are seconds on the mission clock. Zones are known to the station from the mission
file (the information assumption: nothing is learnt in flight).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planner.steiner import TaskTree

__all__ = [
    "HazardZone",
    "HazardMap",
    "hazard_rate_per_s",
    "hazard_rate_per_s_reference",
    "segment_lengths_per_zone",
    "segment_lengths_per_zone_reference",
    "segment_length_in_zones",
    "signed_depth",
    "signed_depth_reference",
    "push_gradient",
    "waypoints",
    "route_tree",
]

#: Sides of the polygon a disc is walked around by (its edges touch the disc grown by the margin).
DISC_SIDES = 16

#: A segment counts as crossing a zone when more than this fraction of its length is inside.
_CROSS_RTOL = 1e-9


@dataclass(frozen=True)
class HazardZone:
    """One zone: a disc (``center_m``, ``radius_m``) or a simple polygon (``polygon_m``), an extra
    loss rate and an activity window [start_s, end_s). Mirrors mission/format/schema.py ``HazardZone``."""

    rate_per_s: float
    """Extra loss rate of a drone inside the zone, 1/s."""
    center_m: tuple[float, float] | None = None
    """Disc centre (north, east), metres."""
    radius_m: float = 0.0
    """Disc radius, metres."""
    polygon_m: tuple[tuple[float, float], ...] | None = None
    """Polygon vertices (north, east) in order, metres (closing edge implied)."""
    start_s: float = 0.0
    """Active from this mission time, seconds."""
    end_s: float = math.inf
    """Active until (excluded) this mission time, seconds."""

    def __post_init__(self) -> None:
        if (self.center_m is None) == (self.polygon_m is None):
            raise ValueError("a hazard zone is exactly one of a disc or a polygon")
        if self.center_m is not None and not self.radius_m > 0:
            raise ValueError(f"radius_m must be > 0, got {self.radius_m}")
        if self.polygon_m is not None and len(self.polygon_m) < 3:
            raise ValueError("a polygon needs at least 3 vertices")
        if not self.rate_per_s >= 0:
            raise ValueError(f"rate_per_s must be >= 0, got {self.rate_per_s}")

    @property
    def is_disc(self) -> bool:
        return self.center_m is not None

    def active(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.end_s


@dataclass(frozen=True)
class _Packed:
    """The zones as arrays (built once per map)."""

    disc: np.ndarray  # (Z,) bool
    center: np.ndarray  # (Z, 2), NaN for polygons
    radius: np.ndarray  # (Z,)
    rate: np.ndarray  # (Z,)
    start: np.ndarray  # (Z,)
    end: np.ndarray  # (Z,)
    edge_a: np.ndarray  # (E, 2) polygon edge starts, every polygon's edges concatenated
    edge_b: np.ndarray  # (E, 2) polygon edge ends
    edge_zone: np.ndarray  # (E,) zone index of each edge


@dataclass(frozen=True)
class HazardMap:
    """The mission's hazard zones (hashable: the zones are tuples; arrays are derived)."""

    zones: tuple[HazardZone, ...] = ()
    _packed: _Packed = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        z = self.zones
        disc = np.array([q.is_disc for q in z], dtype=bool)
        center = np.array(
            [q.center_m if q.center_m is not None else (np.nan, np.nan) for q in z], float
        ).reshape(-1, 2)
        ea, eb, ez = [], [], []
        for k, q in enumerate(z):
            if q.polygon_m is not None:
                pts = np.asarray(q.polygon_m, float)
                ea.append(pts)
                eb.append(np.roll(pts, -1, axis=0))
                ez.append(np.full(len(pts), k))
        packed = _Packed(
            disc,
            center,
            np.array([q.radius_m for q in z], float),
            np.array([q.rate_per_s for q in z], float),
            np.array([q.start_s for q in z], float),
            np.array([q.end_s for q in z], float),
            np.concatenate(ea) if ea else np.zeros((0, 2)),
            np.concatenate(eb) if eb else np.zeros((0, 2)),
            np.concatenate(ez).astype(np.int64) if ez else np.zeros(0, np.int64),
        )
        object.__setattr__(self, "_packed", packed)

    def __len__(self) -> int:
        return len(self.zones)

    def active_mask(self, t_s: float) -> np.ndarray:
        """(Z,) bool: the zones active at ``t_s``."""
        pk = self._packed
        return (pk.start <= t_s) & (t_s < pk.end)

    def active(self, t_s: float) -> HazardMap:
        """The map of the zones active at ``t_s``."""
        return HazardMap(tuple(q for q in self.zones if q.active(t_s)))


# --------------------------------------------------------------------------------------------
# Point in zone, the rate field
# --------------------------------------------------------------------------------------------


def _inside(hmap: HazardMap, pos_m: np.ndarray) -> np.ndarray:
    """(N, Z) bool: point n inside zone z (discs: closed; polygons: even-odd ray casting, as
    mission/format/schema.py ``HazardZone.contains_ne``)."""
    pk = hmap._packed
    pos = np.asarray(pos_m, float).reshape(-1, 2)
    n, nz = len(pos), len(hmap)
    out = np.zeros((n, nz), dtype=bool)
    if pk.disc.any():
        d = np.hypot(
            pos[:, None, 0] - pk.center[None, :, 0], pos[:, None, 1] - pk.center[None, :, 1]
        )
        out |= pk.disc[None, :] & (d <= pk.radius[None, :])
    if len(pk.edge_a):
        north, east = pos[:, 0:1], pos[:, 1:2]
        a, b = pk.edge_a, pk.edge_b
        crosses = (a[None, :, 0] > north) != (b[None, :, 0] > north)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = a[None, :, 1] + (north - a[None, :, 0]) * (b[None, :, 1] - a[None, :, 1]) / (
                b[None, :, 0] - a[None, :, 0]
            )
        flips = (crosses & (east < x)).astype(np.int64)  # (N, E)
        counts = np.zeros((n, nz), dtype=np.int64)
        np.add.at(counts.T, pk.edge_zone, flips.T)
        out |= (counts % 2 == 1) & ~pk.disc[None, :]
    return out


def _inside_one_reference(zone: HazardZone, north: float, east: float) -> bool:
    if zone.center_m is not None:
        return math.hypot(north - zone.center_m[0], east - zone.center_m[1]) <= zone.radius_m
    assert zone.polygon_m is not None
    pts, inside = zone.polygon_m, False
    for i in range(len(pts)):
        (an, ae), (bn, be) = pts[i], pts[(i + 1) % len(pts)]
        if (an > north) != (bn > north):
            x = ae + (north - an) * (be - ae) / (bn - an)
            if east < x:
                inside = not inside
    return inside


def hazard_rate_per_s(hmap: HazardMap | None, pos_m: np.ndarray, t_s: float) -> np.ndarray:
    """(N,) extra loss rate (1/s) at each position: the sum of the rates of the zones active at
    ``t_s`` that contain it (0 without zones). What the redundancy mechanism can weight a relay's
    criticality by."""
    pos = np.asarray(pos_m, float).reshape(-1, 2)
    if hmap is None or len(hmap) == 0:
        return np.zeros(len(pos))
    live = hmap.active_mask(t_s)
    return _inside(hmap, pos).astype(float) @ np.where(live, hmap._packed.rate, 0.0)


def hazard_rate_per_s_reference(
    hmap: HazardMap | None, pos_m: np.ndarray, t_s: float
) -> np.ndarray:
    """Per-point, per-zone loop transcription of :func:`hazard_rate_per_s` (for tests)."""
    pos = np.asarray(pos_m, float).reshape(-1, 2)
    out = np.zeros(len(pos))
    for i, (north, east) in enumerate(pos):
        for zone in hmap.zones if hmap is not None else ():
            if zone.active(t_s) and _inside_one_reference(zone, float(north), float(east)):
                out[i] += zone.rate_per_s
    return out


# --------------------------------------------------------------------------------------------
# Length of a segment inside the zones
# --------------------------------------------------------------------------------------------


def segment_lengths_per_zone(hmap: HazardMap, a_m: np.ndarray, b_m: np.ndarray) -> np.ndarray:
    """(S, Z): length of segment s (``a_m[s]`` -> ``b_m[s]``) inside zone z, metres (ignores the
    activity windows: pass ``hmap.active(t_s)`` for the zones of one instant).

    Discs: the chord, by the segment-circle intersection parameters clipped to [0, 1]. Polygons:
    the segment is cut at its crossings with every edge of the polygon; each piece is inside or
    outside as a whole, decided at its midpoint (even-odd rule).
    """
    pk = hmap._packed
    a = np.asarray(a_m, float).reshape(-1, 2)
    b = np.asarray(b_m, float).reshape(-1, 2)
    s, nz = len(a), len(hmap)
    out = np.zeros((s, nz))
    d = b - a
    seg_len = np.hypot(d[:, 0], d[:, 1])
    zd = np.flatnonzero(pk.disc)
    if len(zd):
        f = a[:, None, :] - pk.center[None, zd, :]  # (S, D, 2)
        aa = np.maximum((d**2).sum(-1), 1e-300)[:, None]
        bb = (f * d[:, None, :]).sum(-1)
        cc = (f**2).sum(-1) - pk.radius[None, zd] ** 2
        disc_ = bb**2 - aa * cc
        root = np.sqrt(np.maximum(disc_, 0.0))
        t0 = np.clip((-bb - root) / aa, 0.0, 1.0)
        t1 = np.clip((-bb + root) / aa, 0.0, 1.0)
        out[:, zd] = np.where(disc_ > 0, (t1 - t0), 0.0) * seg_len[:, None]
    zp = np.flatnonzero(~pk.disc)
    if len(zp) and s:
        ea, eb = pk.edge_a, pk.edge_b
        e = eb - ea  # (E, 2)
        denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (S, E)
        w = ea[None, :, :] - a[:, None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / denom
            u = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / denom
        hit = (denom != 0) & (t > 0) & (t < 1) & (u >= 0) & (u <= 1)
        for z in zp:  # loop over polygons (few), vectorised over segments and edges
            cols = pk.edge_zone == z
            tz = np.where(hit[:, cols], t[:, cols], np.nan)
            cuts = np.sort(np.concatenate([np.zeros((s, 1)), tz, np.ones((s, 1))], axis=1), axis=1)
            cuts = np.where(np.isnan(cuts), 1.0, cuts)  # NaN sort last: pad with the end
            lo, hi = cuts[:, :-1], cuts[:, 1:]
            mid = a[:, None, :] + 0.5 * (lo + hi)[..., None] * d[:, None, :]  # (S, P, 2)
            sub = HazardMap((hmap.zones[z],))
            ins = _inside(sub, mid.reshape(-1, 2))[:, 0].reshape(mid.shape[:2])
            out[:, z] = ((hi - lo) * ins).sum(1) * seg_len
    return out


def segment_lengths_per_zone_reference(
    hmap: HazardMap, a_m: np.ndarray, b_m: np.ndarray
) -> np.ndarray:
    """Per-segment, per-zone loop transcription of :func:`segment_lengths_per_zone` (for tests)."""
    a = np.asarray(a_m, float).reshape(-1, 2)
    b = np.asarray(b_m, float).reshape(-1, 2)
    out = np.zeros((len(a), len(hmap)))
    for s in range(len(a)):
        (an, ae), (bn, be) = a[s], b[s]
        dn, de = bn - an, be - ae
        length = math.hypot(dn, de)
        if length == 0:
            continue
        for z, zone in enumerate(hmap.zones):
            cuts = [0.0, 1.0]
            if zone.center_m is not None:
                cn, ce = zone.center_m
                qa = dn * dn + de * de
                qb = (an - cn) * dn + (ae - ce) * de
                qc = (an - cn) ** 2 + (ae - ce) ** 2 - zone.radius_m**2
                disc = qb * qb - qa * qc
                if disc > 0:
                    for t in ((-qb - math.sqrt(disc)) / qa, (-qb + math.sqrt(disc)) / qa):
                        if 0 < t < 1:
                            cuts.append(t)
            else:
                assert zone.polygon_m is not None
                pts = zone.polygon_m
                for i in range(len(pts)):
                    (pn, pe), (qn, qe) = pts[i], pts[(i + 1) % len(pts)]
                    en, ee = qn - pn, qe - pe
                    den = dn * ee - de * en
                    if den == 0:
                        continue
                    t = ((pn - an) * ee - (pe - ae) * en) / den
                    u = ((pn - an) * de - (pe - ae) * dn) / den
                    if 0 < t < 1 and 0 <= u <= 1:
                        cuts.append(t)
            cuts.sort()
            for lo, hi in zip(cuts, cuts[1:]):
                m = 0.5 * (lo + hi)
                if _inside_one_reference(zone, an + m * dn, ae + m * de):
                    out[s, z] += (hi - lo) * length
    return out


def segment_length_in_zones(
    hmap: HazardMap | None, a_m: np.ndarray, b_m: np.ndarray, t_s: float
) -> np.ndarray:
    """(S,) length of each segment inside the zones active at ``t_s``, metres (summed over zones:
    a piece inside two overlapping zones counts twice, as its loss rate does)."""
    a = np.asarray(a_m, float).reshape(-1, 2)
    if hmap is None or len(hmap) == 0:
        return np.zeros(len(a))
    live = hmap.active_mask(t_s)
    return segment_lengths_per_zone(hmap, a, b_m)[:, live].sum(1)


# --------------------------------------------------------------------------------------------
# Depth inside a zone, the push potential
# --------------------------------------------------------------------------------------------


def signed_depth(hmap: HazardMap, pos_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, Z) signed depth of each point in each zone, metres (distance to the zone's boundary,
    positive inside, negative outside), and (N, Z, 2) the unit inward direction (the gradient of
    the depth; 0 where undefined: a point on a polygon's boundary; a disc's centre gets north)."""
    pk = hmap._packed
    pos = np.asarray(pos_m, float).reshape(-1, 2)
    n, nz = len(pos), len(hmap)
    depth = np.zeros((n, nz))
    inward = np.zeros((n, nz, 2))
    zd = np.flatnonzero(pk.disc)
    if len(zd):
        off = pk.center[None, zd, :] - pos[:, None, :]  # toward the centre
        dist = np.hypot(off[..., 0], off[..., 1])
        depth[:, zd] = pk.radius[None, zd] - dist
        safe = np.where(dist > 0, dist, 1.0)
        unit = off / safe[..., None]
        unit[dist == 0] = (-1.0, 0.0)  # at the centre: inward = south, so the push goes north
        inward[:, zd] = unit
    if len(pk.edge_a) and n:
        ea, e = pk.edge_a, pk.edge_b - pk.edge_a
        e2 = np.maximum((e**2).sum(-1), 1e-300)
        w = pos[:, None, :] - ea[None, :, :]  # (N, E, 2)
        t = np.clip((w * e[None]).sum(-1) / e2[None], 0.0, 1.0)
        foot = ea[None] + t[..., None] * e[None]  # nearest point of each edge
        gap = pos[:, None, :] - foot
        dist = np.hypot(gap[..., 0], gap[..., 1])  # (N, E)
        inside = _inside(hmap, pos)
        for z in np.flatnonzero(~pk.disc):  # loop over polygons, vectorised over points
            cols = np.flatnonzero(pk.edge_zone == z)
            j = cols[np.argmin(dist[:, cols], axis=1)]
            dz = dist[np.arange(n), j]
            g = gap[np.arange(n), j] / np.where(dz > 0, dz, 1.0)[:, None]  # away from the boundary
            sign = np.where(inside[:, z], 1.0, -1.0)
            depth[:, z] = sign * dz
            inward[:, z] = np.where((dz > 0)[:, None], sign[:, None] * g, 0.0)
    return depth, inward


def signed_depth_reference(hmap: HazardMap, pos_m: np.ndarray) -> np.ndarray:
    """(N, Z) loop transcription of the depth of :func:`signed_depth` (for tests)."""
    pos = np.asarray(pos_m, float).reshape(-1, 2)
    out = np.zeros((len(pos), len(hmap)))
    for i, (north, east) in enumerate(pos):
        for z, zone in enumerate(hmap.zones):
            if zone.center_m is not None:
                cn, ce = zone.center_m
                out[i, z] = zone.radius_m - math.hypot(north - cn, east - ce)
                continue
            assert zone.polygon_m is not None
            pts, best = zone.polygon_m, math.inf
            for k in range(len(pts)):
                (pn, pe), (qn, qe) = pts[k], pts[(k + 1) % len(pts)]
                en, ee = qn - pn, qe - pe
                t = ((north - pn) * en + (east - pe) * ee) / (en * en + ee * ee)
                t = min(max(t, 0.0), 1.0)
                best = min(best, math.hypot(north - (pn + t * en), east - (pe + t * ee)))
            out[i, z] = best if _inside_one_reference(zone, float(north), float(east)) else -best
    return out


def push_gradient(
    hmap: HazardMap, pos_m: np.ndarray, weight: np.ndarray, margin_m: float
) -> np.ndarray:
    """(N, 2) gradient of Σ_z weight[n, z] · max(0, depth_z(x) + margin_m): a drone inside a zone,
    or within ``margin_m`` outside it, is pushed out along the shortest way (descending it moves
    the drone toward the nearest boundary). ``weight``: (N, Z) >= 0 (0: no push)."""
    depth, inward = signed_depth(hmap, pos_m)
    on = (depth > -margin_m) & (weight > 0)
    return (np.where(on, weight, 0.0)[..., None] * inward).sum(1)


# --------------------------------------------------------------------------------------------
# Routing the task tree around the zones
# --------------------------------------------------------------------------------------------


def waypoints(hmap: HazardMap, margin_m: float) -> np.ndarray:
    """(V, 2) the corners a path around the zones may turn at, metres: each polygon vertex moved
    ``margin_m`` out along its outward bisector, and the corners of a :data:`DISC_SIDES`-gon whose
    sides touch each disc grown by ``margin_m``; corners inside (or within half the margin of) any
    zone are dropped."""
    pk = hmap._packed
    pts = []
    k = DISC_SIDES
    ang = 2 * np.pi * np.arange(k) / k
    ring = np.stack([np.cos(ang), np.sin(ang)], 1)
    for z in np.flatnonzero(pk.disc):
        rad = (pk.radius[z] + margin_m) / math.cos(math.pi / k)
        pts.append(pk.center[z] + rad * ring)
    for zone in hmap.zones:
        if zone.polygon_m is None:
            continue
        v = np.asarray(zone.polygon_m, float)
        area2 = float(np.sum(v[:, 1] * np.roll(v[:, 0], -1) - np.roll(v[:, 1], -1) * v[:, 0]))
        e_in = v - np.roll(v, 1, axis=0)  # edge arriving at each vertex
        e_out = np.roll(v, -1, axis=0) - v  # edge leaving it
        # Outward normals: with (north, east) as (y, x), a counter-clockwise polygon in (x, y)
        # has area2 > 0 here and its outward normal of edge (dn, de) is (-de, dn) ... fixed by sign.
        sgn = 1.0 if area2 > 0 else -1.0
        n_in = sgn * np.stack([-e_in[:, 1], e_in[:, 0]], 1)
        n_out = sgn * np.stack([-e_out[:, 1], e_out[:, 0]], 1)
        n_in /= np.maximum(np.hypot(n_in[:, 0], n_in[:, 1]), 1e-300)[:, None]
        n_out /= np.maximum(np.hypot(n_out[:, 0], n_out[:, 1]), 1e-300)[:, None]
        bis = n_in + n_out
        norm = np.hypot(bis[:, 0], bis[:, 1])
        bis = np.where((norm > 1e-9)[:, None], bis / np.maximum(norm, 1e-300)[:, None], n_out)
        cos_half = np.maximum((bis * n_out).sum(1), 0.2)  # reach margin from both sides
        cand = v + (margin_m / cos_half)[:, None] * bis
        # The orientation convention is checked, not trusted: flip corners that landed inside.
        inside_here = _inside(HazardMap((zone,)), cand)[:, 0]
        cand[inside_here] = (v - (margin_m / cos_half)[:, None] * bis)[inside_here]
        pts.append(cand)
    if not pts:
        return np.zeros((0, 2))
    out = np.concatenate(pts)
    depth, _ = signed_depth(hmap, out)
    return out[(depth <= -0.5 * margin_m).all(axis=1)]


def _crosses(hmap: HazardMap, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(S,) bool: the segment runs through the inside of some zone."""
    if len(a) == 0:
        return np.zeros(0, dtype=bool)
    seg = np.hypot(*(b - a).T)
    inside = segment_lengths_per_zone(hmap, a, b).sum(1)
    return inside > _CROSS_RTOL * np.maximum(seg, 1e-300)


def route_tree(
    tree: TaskTree, hmap: HazardMap, margin_m: float, cap: float
) -> tuple[TaskTree, int]:
    """The task tree routed around the zones of ``hmap`` (pass the active ones), and the number
    of edges rerouted.

    1. A Steiner node inside a zone moves out, along the shortest way, to ``margin_m`` outside it
       (when that point is inside no zone).
    2. Each edge that crosses a zone and whose two ends are outside every zone is replaced by the
       shortest path between its ends through :func:`waypoints` (a visibility graph: legs that cross
       no zone), when that path is at most ``cap`` times the edge. Its waypoints become new
       Steiner nodes of degree 2, appended after the existing nodes (node order: base, tasks,
       Steiner nodes, as ``TaskTree`` wants). An edge with an end inside a zone (a task in it) is
       kept: it cannot be avoided.

    Same length unit as ``tree`` and ``hmap`` (metres here; the caller converts).
    """
    if len(hmap) == 0 or tree.n_nodes < 2:
        return tree, 0
    nodes = tree.nodes_m.copy()
    parent = tree.parent.copy()
    # 1. Steiner nodes out of the zones.
    st = np.flatnonzero(tree.is_steiner)
    if len(st):
        depth, inward = signed_depth(hmap, nodes[st])
        deep = np.argmax(depth, axis=1)
        d = depth[np.arange(len(st)), deep]
        move = d > 0
        if move.any():
            moved = nodes[st] - (d + margin_m)[:, None] * inward[np.arange(len(st)), deep]
            ok = move & (signed_depth(hmap, moved)[0] < 0).all(axis=1)
            nodes[st[ok]] = moved[ok]
    # 2. Edges through the zones.
    child = np.arange(1, len(nodes))
    a, b = nodes[child], nodes[parent[child]]
    crossing = _crosses(hmap, a, b)
    if not crossing.any():
        return TaskTree(nodes, parent, tree.n_tasks), 0
    outside = np.asarray((signed_depth(hmap, nodes)[0] < 0).all(axis=1))
    cand = crossing & outside[child] & outside[parent[child]]
    wp = waypoints(hmap, margin_m)
    if not cand.any() or len(wp) == 0:
        return TaskTree(nodes, parent, tree.n_tasks), 0
    v = len(wp)
    # Shortest paths between waypoints: visible legs, then Floyd-Warshall with successors.
    ii, jj = np.triu_indices(v, 1)
    vis = ~_crosses(hmap, wp[ii], wp[jj])
    dist = np.full((v, v), np.inf)
    np.fill_diagonal(dist, 0.0)
    leg = np.hypot(*(wp[ii] - wp[jj]).T)
    dist[ii[vis], jj[vis]] = leg[vis]
    dist[jj[vis], ii[vis]] = leg[vis]
    nxt = np.where(np.isfinite(dist), np.arange(v)[None, :], -1)
    for k in range(v):  # loop over intermediate waypoints, vectorised over pairs
        via = dist[:, k : k + 1] + dist[k : k + 1, :]
        better = via < dist
        dist = np.where(better, via, dist)
        nxt = np.where(better, nxt[:, k : k + 1], nxt)
    rows = np.flatnonzero(cand)
    ea, eb = a[rows], b[rows]
    r = len(rows)
    vis_a = ~_crosses(hmap, np.repeat(ea, v, 0), np.tile(wp, (r, 1))).reshape(r, v)
    vis_b = ~_crosses(hmap, np.repeat(eb, v, 0), np.tile(wp, (r, 1))).reshape(r, v)
    da = np.where(vis_a, np.hypot(*(ea[:, None, :] - wp[None]).transpose(2, 0, 1)), np.inf)
    db = np.where(vis_b, np.hypot(*(eb[:, None, :] - wp[None]).transpose(2, 0, 1)), np.inf)
    total = da[:, :, None] + dist[None] + db[:, None, :]  # (R, V, V): a -> i ~> j -> b
    flat = total.reshape(r, -1).argmin(1)
    best = total.reshape(r, -1)[np.arange(r), flat]
    edge_len = np.hypot(*(ea - eb).T)
    new_nodes, rerouted = [nodes], 0
    n_next = len(nodes)
    for q in range(r):  # loop over rerouted edges (few)
        if not best[q] <= cap * edge_len[q]:
            continue
        i, j = divmod(int(flat[q]), v)
        path = [i]
        while path[-1] != j:
            path.append(int(nxt[path[-1], j]))
        c = int(child[rows[q]])
        top = int(parent[c])
        # child -> wp[path[0]] -> ... -> wp[path[-1]] -> parent
        ids = list(range(n_next, n_next + len(path)))
        new_nodes.append(wp[path])
        parent = np.concatenate([parent, np.zeros(len(path), np.int64)])
        parent[c] = ids[0]
        for s_id, s_next in zip(ids, ids[1:]):
            parent[s_id] = s_next
        parent[ids[-1]] = top
        n_next += len(path)
        rerouted += 1
    return TaskTree(np.concatenate(new_nodes), parent, tree.n_tasks), rerouted
