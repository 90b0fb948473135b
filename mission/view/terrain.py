"""The ground as people see it: shaded relief with contours, and the profile of one link.

* :func:`hillshade`: the illumination of each post of a :class:`planner.terrain.Terrain` by a sun
  at a given azimuth and altitude (NumPy, the usual cartographic shading: the cosine of the angle
  between the ground's normal and the sun).
* :func:`draw_terrain`: the shaded relief, tinted by height, and labelled contours on a Matplotlib
  axes in the mission's east/north metres; the figures of a terrain run draw it under the map
  (:class:`mission.view.plots.FrameView`), the live page gets it as one PNG (:func:`terrain_png`).
* :func:`draw_link_profile`: a link's terrain profile, its line of sight and the part of the first
  Fresnel zone that must be clear (:func:`planner.terrain.link_profile`, docs/terrain.md §2).
"""

from __future__ import annotations

import io
import math

import numpy as np

from planner.terrain import LINK_STATUS_NAMES, LinkProfile, Terrain

__all__ = [
    "hillshade",
    "contour_step_m",
    "draw_terrain",
    "terrain_png",
    "terrain_bounds",
    "draw_link_profile",
    "SUN_AZIMUTH_DEG",
    "SUN_ALTITUDE_DEG",
]

#: The sun of shaded relief: from the north-west, 45 degrees up (the cartographic convention: a
#: light from the upper left reads as relief, not as its inverse).
SUN_AZIMUTH_DEG, SUN_ALTITUDE_DEG = 315.0, 45.0


def hillshade(
    height_m: np.ndarray,
    spacing_m: float,
    azimuth_deg: float = SUN_AZIMUTH_DEG,
    altitude_deg: float = SUN_ALTITUDE_DEG,
) -> np.ndarray:
    """(R, C) illumination in [0, 1] of a height grid whose rows go north and columns east.

    The cosine of the angle between the ground's unit normal (-dz/de, -dz/dn, 1) / norm and the
    unit vector to the sun (sin az cos alt, cos az cos alt, sin alt) in (east, north, up), clipped
    at 0 (ground turned away from the sun). Flat ground gives sin(altitude); ground sloping
    towards the sun at 90 - altitude degrees gives 1. Slopes by central differences
    (``np.gradient``), one-sided at the edges."""
    h = np.asarray(height_m, dtype=float)
    dz_dn, dz_de = np.gradient(h, spacing_m)
    az, alt = math.radians(azimuth_deg), math.radians(altitude_deg)
    sun = np.array([math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt)])
    norm = np.sqrt(dz_de**2 + dz_dn**2 + 1.0)
    lit = (-dz_de * sun[0] - dz_dn * sun[1] + sun[2]) / norm
    return np.clip(lit, 0.0, 1.0)


def contour_step_m(relief_m: float, lines: int = 15) -> float:
    """A round contour interval (1, 2, 2.5 or 5 times a power of ten) giving about ``lines``
    contours over ``relief_m`` metres of relief."""
    raw = max(relief_m, 1e-6) / lines
    p = 10.0 ** math.floor(math.log10(raw))
    for k in (1.0, 2.0, 2.5, 5.0, 10.0):
        if k * p >= raw:
            return k * p
    return 10.0 * p


def _extent(terrain: Terrain) -> tuple[float, float, float, float]:
    """(east_min, east_max, north_min, north_max) of the posts' cells (posts at cell centres)."""
    n0, n1, e0, e1 = terrain.extent_ne_m
    s = 0.5 * terrain.spacing_m
    return (e0 - s, e1 + s, n0 - s, n1 + s)


def _relief_rgb(terrain: Terrain) -> np.ndarray:
    """(R, C, 3) colours: a height tint (low green to high brown) darkened by the hillshade."""
    from matplotlib import colormaps

    h = terrain.height_amsl_m
    lo, hi = float(h.min()), float(h.max())
    tint = colormaps["terrain"](0.3 + 0.55 * (h - lo) / max(hi - lo, 1e-9))[..., :3]
    tint = 0.6 * tint + 0.4  # pale: the drones, links and labels drawn over it stay legible
    shade = hillshade(h, terrain.spacing_m)
    # Flat ground stays as light as its tint; slopes away from the sun darken to 45 % of it.
    flat = math.sin(math.radians(SUN_ALTITUDE_DEG))
    k = np.clip(0.45 + 0.55 * shade / flat, 0.0, 1.15)
    return np.clip(tint * k[..., None], 0.0, 1.0)


def draw_terrain(ax, terrain: Terrain, alpha: float = 0.85, labels: bool = True) -> list:
    """Shaded, tinted relief and contours of ``terrain`` on ``ax`` (east right, north up,
    metres), under everything else (zorder below 0). Returns the artists drawn."""
    ext = _extent(terrain)
    img = ax.imshow(
        _relief_rgb(terrain),
        origin="lower",
        extent=ext,
        alpha=alpha,
        zorder=-3,
        interpolation="bilinear",
    )
    h = terrain.height_amsl_m
    n0, n1, e0, e1 = terrain.extent_ne_m
    r, c = h.shape
    step = contour_step_m(float(h.max() - h.min()))
    # Each level 1 mm up, and only those inside the relief: a level at the very height of a flat
    # plain (a synthetic scene's plane, a lake in a DEM) would trace the plain's rounding noise.
    levels = np.arange(math.floor(h.min() / step) * step, h.max() + step, step) + 1e-3
    levels = levels[(levels > h.min()) & (levels < h.max())]
    cs = ax.contour(
        np.linspace(e0, e1, c),
        np.linspace(n0, n1, r),
        h,
        levels=levels,
        colors="#4a3520",
        linewidths=0.5,
        alpha=0.55,
        zorder=-2,
    )
    out = [img, cs]
    if labels and len(cs.levels):
        index = [v for v in cs.levels if abs(v / (5 * step) - round(v / (5 * step))) < 1e-4]
        out += ax.clabel(cs, levels=index or cs.levels[::5], fontsize=6, fmt="%.0f m")
    return out


def terrain_bounds(terrain: Terrain) -> dict:
    """Where :func:`terrain_png` lies and what it shows: ``{"n_min", "n_max", "e_min", "e_max",
    "contour_m", "h_min_m", "h_max_m"}`` (metres, the mission frame)."""
    e_min, e_max, n_min, n_max = _extent(terrain)
    h = terrain.height_amsl_m
    return {
        "n_min": n_min,
        "n_max": n_max,
        "e_min": e_min,
        "e_max": e_max,
        "contour_m": contour_step_m(float(h.max() - h.min())),
        "h_min_m": round(float(h.min()), 1),
        "h_max_m": round(float(h.max()), 1),
    }


def terrain_png(terrain: Terrain, max_px: int = 1400) -> tuple[bytes, dict]:
    """The relief and contours as a PNG covering exactly the grid's cells, and its bounds
    (:func:`terrain_bounds`): what the live page lays over its map. Uses no pyplot state (a
    server may render it off its event loop)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    e_min, e_max, n_min, n_max = _extent(terrain)
    w_m, h_m = e_max - e_min, n_max - n_min
    scale = max_px / max(w_m, h_m)
    dpi = 100
    fig = Figure(figsize=(w_m * scale / dpi, h_m * scale / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    draw_terrain(ax, terrain, alpha=1.0)
    ax.set_xlim(e_min, e_max)
    ax.set_ylim(n_min, n_max)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue(), terrain_bounds(terrain)


def draw_link_profile(ax, prof: LinkProfile, title: str | None = None) -> None:
    """The terrain under a link (lifted by the earth's bulge), its line of sight, the first
    Fresnel zone and the part of it that must be clear, and the verdict in the title."""
    d = prof.distance_m
    ground = prof.ground_amsl_m + prof.bulge_m
    floor = float(ground.min()) - 10.0
    ax.fill_between(d, floor, ground, color="#8c6d46", alpha=0.75, lw=0, label="ground (+ bulge)")
    ax.fill_between(
        d,
        prof.los_amsl_m - prof.fresnel_radius_m,
        prof.los_amsl_m + prof.fresnel_radius_m,
        color="#7fb0e8",
        alpha=0.25,
        lw=0,
        label="first Fresnel zone",
    )
    ax.plot(
        d,
        prof.los_amsl_m - prof.clear_fraction * prof.fresnel_radius_m,
        color="#1f6fd1",
        ls="--",
        lw=0.9,
        label=f"{prof.clear_fraction:.0%} of it: must stay clear",
    )
    ax.plot(d, prof.los_amsl_m, color="#111", lw=1.2, label="line of sight")
    if prof.worst >= 0:
        ax.plot(
            [d[prof.worst]],
            [ground[prof.worst]],
            marker="v",
            color="#d62728" if prof.margin_m[prof.worst] < 0 else "#2ca02c",
            ls="",
            label=f"least margin {prof.margin_m[prof.worst]:+.1f} m",
        )
    ax.set_xlabel("distance along the link (m)")
    ax.set_ylabel("height AMSL (m)")
    ax.set_xlim(0.0, float(d[-1]) if d[-1] > 0 else 1.0)
    ax.set_ylim(bottom=floor)
    verdict = LINK_STATUS_NAMES[prof.status]
    head = f"{title}: " if title else ""
    ax.set_title(
        f"{head}{verdict.upper()}\nslant {prof.slant_m:.0f} m of {prof.max_range_m:.0f} m; least "
        f"clearance {prof.least_clearance_ratio:.2f} of the first Fresnel radius "
        f"(needs {prof.clear_fraction:.2f})",
        fontsize=9,
    )
    ax.legend(fontsize=7, loc="best", frameon=False)
    ax.grid(alpha=0.25)
