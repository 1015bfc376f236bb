"""A local metric frame around a farm: WGS84 longitude/latitude <-> metres.

The planner works in metres on a flat plane. :class:`LocalFrame` maps WGS84 degrees to the
UTM zone of a reference point (EPSG 326xx north, 327xx south) and shifts the result so that
the reference point is ``(0, 0)``: local ``x`` is UTM easting (grid east), ``y`` is UTM
northing, both in metres, and the numbers stay small. Within ~50 km of the origin a round
trip is exact to well under a centimetre.

The frame holds only numbers, so it is cheap to copy, compare, hash and pickle; the pyproj
transformers are built once per UTM zone and cached (pyproj >= 3.1 transformers are
thread-safe).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pyproj import Transformer

from planner.errors import GeometryError

FloatArray = NDArray[np.float64]

WGS84_EPSG = 4326


def check_wgs84(lon: ArrayLike, lat: ArrayLike, where: str) -> None:
    """Raise :class:`GeometryError` naming ``where`` unless every lon/lat is finite and in range.

    ``lon`` must lie in [-180, 180] and ``lat`` in [-90, 90] degrees; scalars or arrays.
    """
    lon_arr = np.asarray(lon, dtype=np.float64)
    lat_arr = np.asarray(lat, dtype=np.float64)
    for name, values, limit in (("longitude", lon_arr, 180.0), ("latitude", lat_arr, 90.0)):
        bad = ~np.isfinite(values) | (np.abs(values) > limit)
        if np.any(bad):
            first = float(values.reshape(-1)[np.flatnonzero(bad.reshape(-1))[0]])
            hint = (
                "these look like projected metres (UTM or another CRS): GeoJSON wants WGS84 "
                "longitude and latitude in degrees"
                if np.isfinite(first) and abs(first) > 1000.0
                else "are longitude and latitude swapped?"
            )
            raise GeometryError(
                f"{where}: {name} {first!r} is not a finite WGS84 value in "
                f"[-{limit:g}, {limit:g}] degrees ({hint})"
            )


def utm_epsg(lon: float, lat: float) -> int:
    """EPSG code of the WGS84 UTM zone holding ``(lon, lat)``: 326xx north, 327xx south.

    Follows the standard zone grid, including the Norway (32V) and Svalbard (31X-37X)
    exceptions, so the choice is deterministic for points on a zone border.
    """
    check_wgs84(lon, lat, "UTM zone")
    zone = min(int(math.floor((lon + 180.0) / 6.0)) + 1, 60)
    if 56.0 <= lat < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    elif 72.0 <= lat <= 84.0 and 0.0 <= lon < 42.0:
        zone = 31 if lon < 9.0 else 33 if lon < 21.0 else 35 if lon < 33.0 else 37
    return (32600 if lat >= 0.0 else 32700) + zone


@lru_cache(maxsize=32)
def _forward(epsg: int) -> Transformer:
    """WGS84 lon/lat -> UTM easting/northing (built once per zone)."""
    return Transformer.from_crs(WGS84_EPSG, epsg, always_xy=True)


@lru_cache(maxsize=32)
def _inverse(epsg: int) -> Transformer:
    """UTM easting/northing -> WGS84 lon/lat (built once per zone)."""
    return Transformer.from_crs(epsg, WGS84_EPSG, always_xy=True)


@dataclass(frozen=True)
class LocalFrame:
    """UTM coordinates of one zone, shifted so that a reference point is the origin.

    Build it with :meth:`around`. ``x`` points to grid east and ``y`` to grid north of the
    zone (they differ from true east/north by the meridian convergence, under a few degrees).
    """

    epsg: int
    origin_lon: float
    origin_lat: float
    origin_easting: float
    origin_northing: float

    @classmethod
    def around(cls, lon: float, lat: float) -> LocalFrame:
        """The frame of the UTM zone holding ``(lon, lat)``, with that point as origin."""
        check_wgs84(lon, lat, "local frame origin")
        epsg = utm_epsg(lon, lat)
        easting, northing = _forward(epsg).transform(float(lon), float(lat))
        return cls(epsg, float(lon), float(lat), float(easting), float(northing))

    @overload
    def to_local(self, lon: float, lat: float) -> tuple[float, float]: ...
    @overload
    def to_local(self, lon: FloatArray, lat: FloatArray) -> tuple[FloatArray, FloatArray]: ...

    def to_local(
        self, lon: float | FloatArray, lat: float | FloatArray
    ) -> tuple[float, float] | tuple[FloatArray, FloatArray]:
        """WGS84 degrees -> local metres ``(x, y)``; floats or numpy arrays of any shape."""
        easting, northing = _forward(self.epsg).transform(lon, lat)
        if np.ndim(easting) == 0:
            return float(easting) - self.origin_easting, float(northing) - self.origin_northing
        return (
            np.asarray(easting, dtype=np.float64) - self.origin_easting,
            np.asarray(northing, dtype=np.float64) - self.origin_northing,
        )

    def convergence_deg(self, lon: float, lat: float) -> float:
        """How far grid north is turned from true north at ``(lon, lat)``, in degrees
        counter-clockwise: a direction ``a`` degrees counter-clockwise from true east is
        ``a + convergence`` from the frame's ``x`` axis (UTM is conformal: locally a
        rotation). Zero on the zone's central meridian; ~2.7 degrees at 70 N, 3 degrees
        of longitude from it."""
        step = 1e-4  # degrees of latitude, ~11 m: the meridian's direction here
        x0, y0 = self.to_local(float(lon), float(lat) - step / 2)
        x1, y1 = self.to_local(float(lon), float(lat) + step / 2)
        return math.degrees(math.atan2(y1 - y0, x1 - x0)) - 90.0

    @overload
    def to_lonlat(self, x: float, y: float) -> tuple[float, float]: ...
    @overload
    def to_lonlat(self, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]: ...

    def to_lonlat(
        self, x: float | FloatArray, y: float | FloatArray
    ) -> tuple[float, float] | tuple[FloatArray, FloatArray]:
        """Local metres -> WGS84 degrees ``(lon, lat)``; floats or numpy arrays of any shape."""
        easting = np.add(x, self.origin_easting)
        northing = np.add(y, self.origin_northing)
        lon, lat = _inverse(self.epsg).transform(easting, northing)
        if np.ndim(lon) == 0:
            return float(lon), float(lat)
        return np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
