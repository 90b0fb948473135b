"""Compiled terrain kernels (Numba): bilinear heights and the line-of-sight / Fresnel test of a
radio link over a height grid.

The rules of :mod:`planner._kernels` hold: no ``fastmath``; each kernel is the fast twin of a
slow, obviously-correct loop in :mod:`planner.terrain` (``*_reference``) that
``tests/planner/test_terrain.py`` compares it with; when Numba is missing or switched off
(``_kernels.ENABLED`` False) the callers run the references. The kernels are written in the same
floating-point operation order as the references, so their answers are the same bits.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numpy as np

from planner import _kernels

__all__ = ["heights", "links_clear"]

_F = TypeVar("_F", bound=Callable[..., Any])


def _jit(func: _F) -> _F:
    """``numba.njit(cache=True)`` keeping the signature for the type checker (planner._kernels)."""
    if not _kernels.NUMBA:  # pragma: no cover
        return func
    from numba import njit

    return cast(_F, njit(cache=True)(func))


def _bilinear(
    grid: np.ndarray, north0: float, east0: float, spacing: float, north: float, east: float
) -> float:
    n_rows = grid.shape[0]
    n_cols = grid.shape[1]
    fi = (north - north0) / spacing
    fj = (east - east0) / spacing
    fi = min(max(fi, 0.0), n_rows - 1.0)  # outside the grid: the edge's height
    fj = min(max(fj, 0.0), n_cols - 1.0)
    i0 = min(int(math.floor(fi)), n_rows - 2)
    j0 = min(int(math.floor(fj)), n_cols - 2)
    t = fi - i0
    u = fj - j0
    h00 = grid[i0, j0]
    h01 = grid[i0, j0 + 1]
    h10 = grid[i0 + 1, j0]
    h11 = grid[i0 + 1, j0 + 1]
    return (1.0 - t) * ((1.0 - u) * h00 + u * h01) + t * ((1.0 - u) * h10 + u * h11)


_bilinear_jit = _jit(_bilinear)


def _heights(
    grid: np.ndarray, north0: float, east0: float, spacing: float, n: np.ndarray, e: np.ndarray
) -> np.ndarray:
    out = np.empty(len(n))
    for k in range(len(n)):
        out[k] = _bilinear_jit(grid, north0, east0, spacing, n[k], e[k])
    return out


_heights_jit = _jit(_heights)


def heights(
    grid: np.ndarray, north0: float, east0: float, spacing: float, ne_m: np.ndarray
) -> np.ndarray | None:
    """(P,) bilinear heights at the (P, 2) points; None without Numba (the caller runs NumPy)."""
    if not (_kernels.NUMBA and _kernels.ENABLED):
        return None
    return _heights_jit(
        grid,
        float(north0),
        float(east0),
        float(spacing),
        np.ascontiguousarray(ne_m[:, 0], dtype=np.float64),
        np.ascontiguousarray(ne_m[:, 1], dtype=np.float64),
    )


def _link_clear(
    grid: np.ndarray,
    north0: float,
    east0: float,
    spacing: float,
    an: float,
    ae: float,
    ah: float,
    bn: float,
    be: float,
    bh: float,
    max_range: float,
    wavelength: float,
    clear_fraction: float,
    two_k_re: float,
    step: float,
) -> bool:
    dn = bn - an
    de = be - ae
    dz = bh - ah
    dh = math.sqrt(dn * dn + de * de)
    if math.sqrt(dh * dh + dz * dz) > max_range:
        return False
    n_seg = int(math.ceil(dh / step))
    for k in range(1, n_seg):
        f = k / n_seg
        ground = _bilinear_jit(grid, north0, east0, spacing, an + f * dn, ae + f * de)
        d1 = f * dh
        d2 = dh - d1
        bulge = d1 * d2 / two_k_re  # the earth's bulge at k x its radius (ITU-R P.526)
        line = ah + f * dz
        r1 = math.sqrt(wavelength * d1 * d2 / dh)  # first Fresnel zone radius
        if line - (ground + bulge) < clear_fraction * r1:
            return False
    return True


_link_clear_jit = _jit(_link_clear)


def _links_clear(
    grid: np.ndarray,
    north0: float,
    east0: float,
    spacing: float,
    a: np.ndarray,
    b: np.ndarray,
    max_range: float,
    wavelength: float,
    clear_fraction: float,
    two_k_re: float,
    step: float,
) -> np.ndarray:
    out = np.empty(a.shape[0], dtype=np.bool_)
    for p in range(a.shape[0]):
        out[p] = _link_clear_jit(
            grid,
            north0,
            east0,
            spacing,
            a[p, 0],
            a[p, 1],
            a[p, 2],
            b[p, 0],
            b[p, 1],
            b[p, 2],
            max_range,
            wavelength,
            clear_fraction,
            two_k_re,
            step,
        )
    return out


_links_clear_jit = _jit(_links_clear)


def links_clear(
    grid: np.ndarray,
    north0: float,
    east0: float,
    spacing: float,
    a: np.ndarray,
    b: np.ndarray,
    max_range: float,
    wavelength: float,
    clear_fraction: float,
    two_k_re: float,
    step: float,
) -> np.ndarray | None:
    """(P,) bool: the link from each row of ``a`` to the row of ``b`` (north, east, height AMSL,
    metres) is within ``max_range`` and clears the terrain by ``clear_fraction`` of its first
    Fresnel zone at every profile sample (:func:`planner.terrain.links_clear_reference`). None
    without Numba: the caller runs the reference."""
    if not (_kernels.NUMBA and _kernels.ENABLED):
        return None
    return _links_clear_jit(
        grid,
        float(north0),
        float(east0),
        float(spacing),
        np.ascontiguousarray(a, dtype=np.float64),
        np.ascontiguousarray(b, dtype=np.float64),
        float(max_range),
        float(wavelength),
        float(clear_fraction),
        float(two_k_re),
        float(step),
    )
