"""Terrain and a radio over it: heights on a grid, and links that need line of sight.

The paper's world is flat and its radio a disc (:func:`planner.geometry.active_mask`). In the
mountains a ridge cuts a link at 50 m that would hold at 500 m over open ground. This module is
the other radio model (a mission's ``radio.model: terrain``, docs/terrain.md):

* :class:`Terrain`: heights AMSL on a regular grid in the mission's local north/east frame,
  bilinear between the posts, vectorised (:meth:`Terrain.height_m`). Known to the truth and to the
  planner alike (a map). Built from a GeoTIFF by the mission loader, or from a few parametric
  features (:func:`synthetic_terrain`) for tests and demos.
* :class:`LinkBudget`: a link closes when the free-space path loss over the slant distance is
  within the budget (transmit power + antenna gains - receiver sensitivity - fade margin) and the
  terrain profile, lifted by the earth's bulge at k = 4/3, stays out of the given fraction of the
  first Fresnel zone (docs/terrain.md §2).
* :class:`TerrainRadio`: the two together, with the connectivity the world measures:
  :meth:`TerrainRadio.active_mask` and :meth:`TerrainRadio.tasks_connected`, the terrain twins of
  :func:`planner.geometry.active_mask` and :func:`planner.geometry.tasks_connected`.

Positions with a height are (P, 3) arrays (north, east, height AMSL), metres. The compiled line of
sight test (:mod:`planner._terrain_kernels`) has the slow loop :func:`links_clear_reference`
beside it (tests/planner/test_terrain.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from planner import _terrain_kernels
from planner.geometry import radio_pairs

__all__ = [
    "Terrain",
    "Ridge",
    "Canyon",
    "Hill",
    "synthetic_terrain",
    "LinkBudget",
    "TerrainRadio",
    "free_space_loss_db",
    "links_clear_reference",
    "path_clearance_m",
    "path_agl_m",
    "LinkProfile",
    "link_profile",
    "LINK_OK",
    "LINK_BLOCKED",
    "LINK_OUT_OF_RANGE",
    "LINK_STATUS_NAMES",
    "SPEED_OF_LIGHT_M_S",
    "EARTH_RADIUS_M",
]

SPEED_OF_LIGHT_M_S = 299_792_458.0
#: A link's status (:meth:`TerrainRadio.link_status`): it closes; the budget closes over the slant
#: distance but the terrain enters the cleared part of the first Fresnel zone; the budget does not
#: close (too far, whatever lies between).
LINK_OK, LINK_BLOCKED, LINK_OUT_OF_RANGE = 0, 1, 2
#: The words for each status code, in code order (what the operator reads).
LINK_STATUS_NAMES: tuple[str, ...] = ("ok", "blocked by terrain", "out of range")
#: Mean earth radius, metres (the bulge uses k times this).
EARTH_RADIUS_M = 6_371_008.8


@dataclass(frozen=True)
class Terrain:
    """Heights on a regular grid in the mission's local frame.

    Post (i, j) is at north ``north0_m + i * spacing_m``, east ``east0_m + j * spacing_m``;
    between posts heights are bilinear, outside the grid they are the nearest edge's.
    """

    height_amsl_m: np.ndarray
    """(R, C) float64, R, C >= 2: ground height above mean sea level at each post, metres."""
    north0_m: float
    """North of row 0, metres."""
    east0_m: float
    """East of column 0, metres."""
    spacing_m: float
    """Distance between posts, metres (> 0)."""

    def __post_init__(self) -> None:
        grid = np.ascontiguousarray(self.height_amsl_m, dtype=np.float64)
        if grid.ndim != 2 or min(grid.shape) < 2:
            raise ValueError(f"terrain grid must be (R, C) with R, C >= 2, got {grid.shape}")
        if not np.isfinite(grid).all():
            raise ValueError("terrain grid has non-finite heights (fill the DEM's voids first)")
        if not self.spacing_m > 0:
            raise ValueError(f"terrain spacing_m must be > 0, got {self.spacing_m}")
        object.__setattr__(self, "height_amsl_m", grid)

    def height_m(self, ne_m: np.ndarray) -> np.ndarray:
        """Ground height AMSL at points, metres.

        Parameters
        ----------
        ne_m : (..., 2) float64, (north, east) metres in the mission frame

        Returns
        -------
        (...) float64, metres above mean sea level
        """
        ne = np.asarray(ne_m, dtype=float)
        flat = ne.reshape(-1, 2)
        fast = _terrain_kernels.heights(
            self.height_amsl_m, self.north0_m, self.east0_m, self.spacing_m, flat
        )
        out = fast if fast is not None else self._height_numpy(flat)
        return out.reshape(ne.shape[:-1])

    def _height_numpy(self, flat: np.ndarray) -> np.ndarray:
        """The vectorised NumPy bilinear (the kernel's operation order)."""
        g = self.height_amsl_m
        r, c = g.shape
        fi = np.clip((flat[:, 0] - self.north0_m) / self.spacing_m, 0.0, r - 1.0)
        fj = np.clip((flat[:, 1] - self.east0_m) / self.spacing_m, 0.0, c - 1.0)
        i0 = np.minimum(np.floor(fi).astype(np.int64), r - 2)
        j0 = np.minimum(np.floor(fj).astype(np.int64), c - 2)
        t, u = fi - i0, fj - j0
        return (1.0 - t) * ((1.0 - u) * g[i0, j0] + u * g[i0, j0 + 1]) + t * (
            (1.0 - u) * g[i0 + 1, j0] + u * g[i0 + 1, j0 + 1]
        )

    def height_m_reference(self, north_m: float, east_m: float) -> float:
        """One point's height by the textbook bilinear formula (for tests)."""
        g = self.height_amsl_m
        r, c = g.shape
        fi = min(max((north_m - self.north0_m) / self.spacing_m, 0.0), r - 1.0)
        fj = min(max((east_m - self.east0_m) / self.spacing_m, 0.0), c - 1.0)
        i0, j0 = min(int(math.floor(fi)), r - 2), min(int(math.floor(fj)), c - 2)
        t, u = fi - i0, fj - j0
        return float(
            (1.0 - t) * ((1.0 - u) * g[i0, j0] + u * g[i0, j0 + 1])
            + t * ((1.0 - u) * g[i0 + 1, j0] + u * g[i0 + 1, j0 + 1])
        )

    @property
    def extent_ne_m(self) -> tuple[float, float, float, float]:
        """(north_min, north_max, east_min, east_max) of the grid, metres."""
        r, c = self.height_amsl_m.shape
        return (
            self.north0_m,
            self.north0_m + (r - 1) * self.spacing_m,
            self.east0_m,
            self.east0_m + (c - 1) * self.spacing_m,
        )


# --------------------------------------------------------------------------------------------
# Synthetic scenes: a few parametric features summed over a flat plane


def _distance_to_path_m(points: np.ndarray, path_ne_m: np.ndarray) -> np.ndarray:
    """(P,) distance from each of the (P, 2) points to the polyline (K, 2), metres."""
    best = np.full(len(points), np.inf)
    if len(path_ne_m) == 1:
        return np.linalg.norm(points - path_ne_m[0], axis=1)
    for a, b in zip(path_ne_m[:-1], path_ne_m[1:]):  # a handful of segments
        ab = b - a
        t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * ab), axis=1))
    return best


@dataclass(frozen=True)
class Ridge:
    """A ridge along a polyline: ``height_m`` on its crest, a raised-cosine flank falling to 0 at
    ``half_width_m`` from the crest line."""

    path_ne_m: Sequence[tuple[float, float]]
    height_m: float
    half_width_m: float

    def relief_m(self, points: np.ndarray) -> np.ndarray:
        d = _distance_to_path_m(points, np.asarray(self.path_ne_m, dtype=float))
        x = np.clip(d / self.half_width_m, 0.0, 1.0)
        return self.height_m * 0.5 * (1.0 + np.cos(np.pi * x))


@dataclass(frozen=True)
class Canyon:
    """A river canyon along a polyline: a flat floor ``depth_m`` down, ``floor_half_width_m``
    wide each side of the river, straight walls up to the rims at ``rim_half_width_m``."""

    path_ne_m: Sequence[tuple[float, float]]
    depth_m: float
    floor_half_width_m: float
    rim_half_width_m: float

    def relief_m(self, points: np.ndarray) -> np.ndarray:
        d = _distance_to_path_m(points, np.asarray(self.path_ne_m, dtype=float))
        wall = max(self.rim_half_width_m - self.floor_half_width_m, 1e-9)
        x = np.clip((self.rim_half_width_m - d) / wall, 0.0, 1.0)  # 1 on the floor, 0 beyond
        return -self.depth_m * x


@dataclass(frozen=True)
class Hill:
    """A round hill (or a basin, with a negative height): Gaussian, ``radius_m`` its sigma."""

    center_ne_m: tuple[float, float]
    height_m: float
    radius_m: float

    def relief_m(self, points: np.ndarray) -> np.ndarray:
        d2 = np.sum((points - np.asarray(self.center_ne_m, dtype=float)) ** 2, axis=1)
        return self.height_m * np.exp(-0.5 * d2 / self.radius_m**2)


def synthetic_terrain(
    features: Sequence[Ridge | Canyon | Hill],
    half_width_m: float,
    spacing_m: float,
    plane_amsl_m: float = 0.0,
) -> Terrain:
    """A square grid ``[-half_width_m, half_width_m]^2`` (around the origin) of posts
    ``spacing_m`` apart: the plane at ``plane_amsl_m`` plus every feature's relief."""
    n = int(math.ceil(2 * half_width_m / spacing_m)) + 1
    axis = -half_width_m + spacing_m * np.arange(n)
    nn, ee = np.meshgrid(axis, axis, indexing="ij")
    pts = np.column_stack([nn.ravel(), ee.ravel()])
    h = np.full(len(pts), float(plane_amsl_m))
    for f in features:  # a few features, each vectorised over the posts
        h = h + f.relief_m(pts)
    return Terrain(h.reshape(n, n), float(axis[0]), float(axis[0]), float(spacing_m))


# --------------------------------------------------------------------------------------------
# The radio


def free_space_loss_db(distance_m: np.ndarray | float, frequency_hz: float) -> np.ndarray:
    """Free-space path loss 20 log10(4 pi d f / c), dB (Friis)."""
    d = np.maximum(np.asarray(distance_m, dtype=float), 1e-3)
    return np.asarray(20.0 * np.log10(4.0 * np.pi * d * frequency_hz / SPEED_OF_LIGHT_M_S))


@dataclass(frozen=True)
class LinkBudget:
    """A point-to-point link's budget and clearance rule. Defaults: a common 2.4 GHz mesh radio
    (docs/terrain.md §2: 20 dBm out, 2 dBi dipoles, -90 dBm sensitivity at a low mesh rate, 10 dB
    fade margin: about 1.6 km in free space)."""

    frequency_hz: float = 2.4e9
    """Carrier frequency, Hz."""
    tx_power_dbm: float = 20.0
    """Transmit power, dBm."""
    tx_gain_dbi: float = 2.0
    """Transmit antenna gain, dBi."""
    rx_gain_dbi: float = 2.0
    """Receive antenna gain, dBi."""
    sensitivity_dbm: float = -90.0
    """Receiver sensitivity, dBm."""
    fade_margin_db: float = 10.0
    """Margin kept for fading, body and foliage losses, dB."""
    fresnel_clear_fraction: float = 0.6
    """Fraction of the first Fresnel zone's radius the terrain must stay out of (0.6: the usual
    rule for a link that sees no diffraction loss)."""
    k_factor: float = 4.0 / 3.0
    """Effective earth radius factor (standard atmosphere refraction)."""
    profile_step_m: float | None = None
    """Horizontal spacing of the profile samples, metres; None: the terrain's post spacing."""

    def __post_init__(self) -> None:
        if not self.frequency_hz > 0 or not self.k_factor > 0:
            raise ValueError("frequency_hz and k_factor must be > 0")
        if not 0.0 <= self.fresnel_clear_fraction <= 1.0:
            raise ValueError("fresnel_clear_fraction must be in [0, 1]")
        if self.max_path_loss_db <= 0:
            raise ValueError("the link budget is not positive: no link closes")

    @property
    def max_path_loss_db(self) -> float:
        """The largest path loss a link survives, dB."""
        return (
            self.tx_power_dbm
            + self.tx_gain_dbi
            + self.rx_gain_dbi
            - self.sensitivity_dbm
            - self.fade_margin_db
        )

    @property
    def max_range_m(self) -> float:
        """The slant distance at which the free-space loss uses up the budget, metres."""
        return float(
            10.0 ** (self.max_path_loss_db / 20.0)
            * SPEED_OF_LIGHT_M_S
            / (4.0 * np.pi * self.frequency_hz)
        )

    @property
    def wavelength_m(self) -> float:
        return SPEED_OF_LIGHT_M_S / self.frequency_hz


def links_clear_reference(
    terrain: Terrain, budget: LinkBudget, a_m: np.ndarray, b_m: np.ndarray
) -> np.ndarray:
    """(P,) bool by plain loops: the link a -> b closes (slant distance within
    ``budget.max_range_m``) and at every profile sample the line of sight, less the earth's bulge
    d1 d2 / (2 k R), clears the ground by ``fresnel_clear_fraction`` x the first Fresnel radius
    sqrt(lambda d1 d2 / d). ``a_m``, ``b_m``: (P, 3) (north, east, height AMSL), metres.
    Samples every ``profile_step_m`` (default: the post spacing) between the ends."""
    step = budget.profile_step_m or terrain.spacing_m
    two_k_re = 2.0 * budget.k_factor * EARTH_RADIUS_M
    out = np.zeros(len(a_m), dtype=bool)
    for p in range(len(a_m)):
        an, ae, ah = (float(v) for v in a_m[p])
        bn, be, bh = (float(v) for v in b_m[p])
        dn, de, dz = bn - an, be - ae, bh - ah
        dh = math.sqrt(dn * dn + de * de)
        if math.sqrt(dh * dh + dz * dz) > budget.max_range_m:
            continue
        n_seg = int(math.ceil(dh / step))
        ok = True
        for k in range(1, n_seg):
            f = k / n_seg
            ground = terrain.height_m_reference(an + f * dn, ae + f * de)
            d1 = f * dh
            d2 = dh - d1
            line = ah + f * dz
            r1 = math.sqrt(budget.wavelength_m * d1 * d2 / dh)
            if line - (ground + d1 * d2 / two_k_re) < budget.fresnel_clear_fraction * r1:
                ok = False
                break
        out[p] = ok
    return out


def path_clearance_m(
    terrain: Terrain,
    from_ne_m: np.ndarray,
    to_ne_m: np.ndarray,
    from_amsl_m: np.ndarray,
    to_amsl_m: np.ndarray,
    n_samples: int = 16,
) -> np.ndarray:
    """(N,) the lowest height above the ground along straight flights (linear in height too),
    metres; negative: the flight went into the ground. Sampled at ``n_samples + 1`` points."""
    return np.asarray(
        path_agl_m(terrain, from_ne_m, to_ne_m, from_amsl_m, to_amsl_m, n_samples).min(axis=1)
    )


def path_agl_m(
    terrain: Terrain,
    from_ne_m: np.ndarray,
    to_ne_m: np.ndarray,
    from_amsl_m: np.ndarray,
    to_amsl_m: np.ndarray,
    n_samples: int = 16,
) -> np.ndarray:
    """(N, n_samples + 1) the height above the ground along straight flights (linear in height
    too), metres, at ``n_samples + 1`` evenly spaced points from each start to its end."""
    f = np.linspace(0.0, 1.0, n_samples + 1)  # (S,)
    pts = from_ne_m[:, None, :] + f[None, :, None] * (to_ne_m - from_ne_m)[:, None, :]
    alt = from_amsl_m[:, None] + f[None, :] * (to_amsl_m - from_amsl_m)[:, None]
    return np.asarray(alt - terrain.height_m(pts))


@dataclass(frozen=True)
class LinkProfile:
    """The terrain between the two ends of one link, sample by sample (:func:`link_profile`).

    Samples ``k = 0 .. S-1`` lie at horizontal distance ``distance_m[k]`` from end a, evenly from
    a (k = 0) to b (k = S-1); only the inner samples are tested, as in
    :func:`links_clear_reference`, whose verdict this is."""

    distance_m: np.ndarray
    """(S,) horizontal distance from end a, metres."""
    ground_amsl_m: np.ndarray
    """(S,) the map's ground height, metres AMSL."""
    bulge_m: np.ndarray
    """(S,) the earth's bulge d1 d2 / (2 k R) that lifts the ground under the line, metres."""
    los_amsl_m: np.ndarray
    """(S,) the straight line of sight between the antennas, metres AMSL."""
    fresnel_radius_m: np.ndarray
    """(S,) the first Fresnel zone's radius sqrt(lambda d1 d2 / d), metres (0 at the ends)."""
    clear_fraction: float
    """The part of the first Fresnel radius that must stay clear of the ground (0.6)."""
    slant_m: float
    """Distance between the antennas, metres."""
    max_range_m: float
    """The budget's range over free space, metres."""
    status: int
    """:data:`LINK_OK`, :data:`LINK_BLOCKED` or :data:`LINK_OUT_OF_RANGE`."""
    worst: int
    """Index of the inner sample with the least margin (-1: no inner sample)."""

    @property
    def margin_m(self) -> np.ndarray:
        """(S,) line of sight - (ground + bulge) - ``clear_fraction`` x Fresnel radius, metres:
        negative where the ground enters the zone that must be clear."""
        return (
            self.los_amsl_m
            - (self.ground_amsl_m + self.bulge_m)
            - (self.clear_fraction * self.fresnel_radius_m)
        )

    @property
    def least_clearance_ratio(self) -> float:
        """min over the inner samples of (line of sight - ground - bulge) / Fresnel radius: the
        link is clear when this is at least ``clear_fraction`` (inf: no inner sample)."""
        inner = slice(1, len(self.distance_m) - 1)
        r = self.fresnel_radius_m[inner]
        if not len(r):
            return math.inf
        gap = self.los_amsl_m[inner] - self.ground_amsl_m[inner] - self.bulge_m[inner]
        return float(np.min(gap / np.maximum(r, 1e-12)))


def link_profile(
    terrain: Terrain, budget: LinkBudget, a_m: Sequence[float], b_m: Sequence[float]
) -> LinkProfile:
    """The profile of the link a -> b (each (north, east, height AMSL), metres) as the radio
    model sees it: the samples of :func:`links_clear_reference` (one every ``profile_step_m``,
    default the post spacing), plus both ends, and the same verdict (docs/terrain.md §2)."""
    a = np.asarray(a_m, dtype=float).reshape(3)
    b = np.asarray(b_m, dtype=float).reshape(3)
    step = budget.profile_step_m or terrain.spacing_m
    dn, de, dz = b - a
    dh = math.hypot(dn, de)
    slant = math.hypot(dh, dz)
    n_seg = max(1, int(math.ceil(dh / step)))
    f = np.arange(n_seg + 1) / n_seg
    d1 = f * dh
    d2 = dh - d1
    ground = terrain.height_m(np.column_stack([a[0] + f * dn, a[1] + f * de]))
    bulge = d1 * d2 / (2.0 * budget.k_factor * EARTH_RADIUS_M)
    los = a[2] + f * dz
    r1 = np.sqrt(budget.wavelength_m * d1 * d2 / dh) if dh > 0 else np.zeros_like(f)
    margin = los - (ground + bulge) - budget.fresnel_clear_fraction * r1
    inner = margin[1:-1]
    worst = int(np.argmin(inner)) + 1 if len(inner) else -1
    if slant > budget.max_range_m:
        status = LINK_OUT_OF_RANGE
    elif len(inner) and inner.min() < 0.0:
        status = LINK_BLOCKED
    else:
        status = LINK_OK
    return LinkProfile(
        distance_m=d1,
        ground_amsl_m=ground,
        bulge_m=bulge,
        los_amsl_m=los,
        fresnel_radius_m=r1,
        clear_fraction=budget.fresnel_clear_fraction,
        slant_m=slant,
        max_range_m=budget.max_range_m,
        status=status,
        worst=worst,
    )


@dataclass(frozen=True)
class TerrainRadio:
    """Links over terrain: the truth's and a terrain-aware planner's radio model."""

    terrain: Terrain
    budget: LinkBudget = field(default_factory=LinkBudget)

    def links_clear(self, a_m: np.ndarray, b_m: np.ndarray) -> np.ndarray:
        """(P,) bool: which links a -> b close; ``a_m``, ``b_m`` (P, 3) (north, east, height
        AMSL), metres (:func:`links_clear_reference`, compiled)."""
        a = np.asarray(a_m, dtype=float).reshape(-1, 3)
        b = np.asarray(b_m, dtype=float).reshape(-1, 3)
        t, bud = self.terrain, self.budget
        fast = _terrain_kernels.links_clear(
            t.height_amsl_m,
            t.north0_m,
            t.east0_m,
            t.spacing_m,
            a,
            b,
            bud.max_range_m,
            bud.wavelength_m,
            bud.fresnel_clear_fraction,
            2.0 * bud.k_factor * EARTH_RADIUS_M,
            bud.profile_step_m or t.spacing_m,
        )
        return fast if fast is not None else links_clear_reference(t, bud, a, b)

    def link_status(self, a_m: np.ndarray, b_m: np.ndarray) -> np.ndarray:
        """(P,) int8 status of the links a -> b (:data:`LINK_OK`, :data:`LINK_BLOCKED`,
        :data:`LINK_OUT_OF_RANGE`): out of range when the slant distance exceeds the budget's
        range, blocked when it does not and :meth:`links_clear` still fails (the terrain)."""
        a = np.asarray(a_m, dtype=float).reshape(-1, 3)
        b = np.asarray(b_m, dtype=float).reshape(-1, 3)
        far = np.linalg.norm(b - a, axis=1) > self.budget.max_range_m
        out = np.full(len(a), LINK_BLOCKED, dtype=np.int8)
        out[far] = LINK_OUT_OF_RANGE
        near = np.flatnonzero(~far)
        out[near[self.links_clear(a[near], b[near])]] = LINK_OK
        return out

    def candidate_pairs(self, pos_ne_m: np.ndarray) -> np.ndarray:
        """(P, 2) pairs i < j within the budget's range horizontally (a superset of the links)."""
        return radio_pairs(np.asarray(pos_ne_m, dtype=float), self.budget.max_range_m, False)

    def link_pairs(self, pos_ne_m: np.ndarray, height_amsl_m: np.ndarray) -> np.ndarray:
        """(K, 2) the pairs i < j whose link closes, drones at (N, 2) ``pos_ne_m`` and (N,)
        antenna heights AMSL."""
        pos3 = np.column_stack([pos_ne_m, height_amsl_m])
        pairs = self.candidate_pairs(pos_ne_m)
        if len(pairs) == 0:
            return pairs
        return pairs[self.links_clear(pos3[pairs[:, 0]], pos3[pairs[:, 1]])]

    def active_mask(
        self,
        pos_ne_m: np.ndarray,
        height_amsl_m: np.ndarray,
        alive: np.ndarray,
        base_ne_m: np.ndarray,
        base_height_amsl_m: float,
    ) -> np.ndarray:
        """(N,) bool: alive drones joined to the base by a chain of closing links (the terrain
        twin of :func:`planner.geometry.active_mask`)."""
        alive = np.asarray(alive, dtype=bool)
        out = np.zeros(len(alive), dtype=bool)
        idx = np.flatnonzero(alive)
        if len(idx) == 0:
            return out
        p = np.asarray(pos_ne_m, dtype=float)[idx]
        h = np.asarray(height_amsl_m, dtype=float)[idx]
        base3 = np.array([base_ne_m[0], base_ne_m[1], base_height_amsl_m], dtype=float)
        at_base = self.links_clear(np.column_stack([p, h]), np.broadcast_to(base3, (len(p), 3)))
        if not at_base.any():
            return out
        pairs = self.link_pairs(p, h)
        k = len(p)  # node k is the base
        base_nodes = np.flatnonzero(at_base)
        rows = np.concatenate([pairs[:, 0], np.full(len(base_nodes), k)])
        cols = np.concatenate([pairs[:, 1], base_nodes])
        graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(k + 1, k + 1))
        _, labels = connected_components(graph, directed=False)
        out[idx] = labels[:k] == labels[k]
        return out

    def tasks_connected(
        self,
        task_ne_m: np.ndarray,
        task_height_amsl_m: np.ndarray,
        pos_ne_m: np.ndarray,
        height_amsl_m: np.ndarray,
        active: np.ndarray,
    ) -> np.ndarray:
        """(M,) bool: some active drone's link to each task's radio closes."""
        act = np.flatnonzero(np.asarray(active, dtype=bool))
        m = len(task_ne_m)
        if len(act) == 0 or m == 0:
            return np.zeros(m, dtype=bool)
        t3 = np.column_stack([task_ne_m, task_height_amsl_m])
        d3 = np.column_stack([np.asarray(pos_ne_m, float)[act], np.asarray(height_amsl_m)[act]])
        ti, di = np.divmod(np.arange(m * len(act)), len(act))  # every (task, active drone)
        near = np.hypot(*(t3[ti, :2] - d3[di, :2]).T) <= self.budget.max_range_m
        ok = np.zeros(len(ti), dtype=bool)
        ok[near] = self.links_clear(d3[di[near]], t3[ti[near]])
        return np.asarray(np.bincount(ti[ok], minlength=m) > 0)
