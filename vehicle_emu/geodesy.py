"""One WGS-84 geodetic point to local NED around a fixed origin, fast for scalars.

The emulator converts every SET_POSITION_TARGET_GLOBAL_INT it receives (one per vehicle per
control tick) with :func:`planner.geometry.geodetic_to_ned_m`, i.e. ``pymap3d.geodetic2ned``:
on a scalar that is some thirty NumPy calls, two of them for the origin (the same for every
call), a new ``Ellipsoid`` object and an ``np.stack`` of 0-d arrays. :class:`NedOrigin` keeps
the origin's part and repeats pymap3d's arithmetic for the target, operation for operation
with the same NumPy functions (``pymap3d.ecef.geodetic2ecef``, ``pymap3d.enu.geodetic2enu``,
``pymap3d.ecef.uvw2enu``, ``pymap3d.ned.geodetic2ned``), so the result is the reference's to
the bit: tests/vehicle_emu/test_geodesy.py compares them on random points.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pymap3d
from numpy import cos, hypot, radians, sin
from pymap3d.ellipsoid import Ellipsoid

__all__ = ["NedOrigin", "ned_origin"]


class NedOrigin:
    """Local NED (m) around ``(lat0_deg, lon0_deg, alt0_amsl_m)`` on the WGS-84 ellipsoid."""

    __slots__ = ("_a", "_b", "_a2", "_ratio2", "_x0", "_y0", "_z0", "_cla", "_sla", "_clo", "_slo")

    def __init__(self, lat0_deg: float, lon0_deg: float, alt0_amsl_m: float) -> None:
        ell = Ellipsoid.from_name("wgs84")  # pymap3d's default
        a, b = ell.semimajor_axis, ell.semiminor_axis
        self._a, self._b = a, b
        self._a2 = a**2
        self._ratio2 = (b / a) ** 2
        x0, y0, z0 = pymap3d.geodetic2ecef(lat0_deg, lon0_deg, alt0_amsl_m, ell)
        self._x0, self._y0, self._z0 = float(x0), float(y0), float(z0)
        lat0, lon0 = radians(lat0_deg), radians(lon0_deg)
        self._cla, self._sla = float(cos(lat0)), float(sin(lat0))
        self._clo, self._slo = float(cos(lon0)), float(sin(lon0))

    def ned_m(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> np.ndarray:
        """(3,) north, east, down (m): :func:`planner.geometry.geodetic_to_ned_m` of one point."""
        # NumPy's functions as pymap3d calls them, their results as Python floats (the same
        # IEEE doubles; + - * / on them round as on NumPy scalars, only faster)
        lat, lon = float(radians(lat_deg)), float(radians(lon_deg))
        clat, slat = float(cos(lat)), float(sin(lat))
        # geodetic2ecef
        n_m = self._a2 / float(hypot(self._a * clat, self._b * slat))
        x = (n_m + alt_amsl_m) * clat * float(cos(lon))
        y = (n_m + alt_amsl_m) * clat * float(sin(lon))
        z = (n_m * self._ratio2 + alt_amsl_m) * slat
        # geodetic2enu -> uvw2enu
        u, v, w = x - self._x0, y - self._y0, z - self._z0
        clo, slo, cla, sla = self._clo, self._slo, self._cla, self._sla
        t = clo * u + slo * v
        east = -slo * u + clo * v
        up = cla * t + sla * w
        north = -sla * t + cla * w
        return np.array((north, east, -up), dtype=float)


@lru_cache(maxsize=64)
def ned_origin(lat0_deg: float, lon0_deg: float, alt0_amsl_m: float) -> NedOrigin:
    """The :class:`NedOrigin` of an origin (shared: a swarm's vehicles share theirs)."""
    return NedOrigin(lat0_deg, lon0_deg, alt0_amsl_m)
