"""The local metric frame: UTM zone choice, round trips and WGS84 checks."""

import dataclasses
import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Geod

from planner.errors import GeometryError
from planner.geo import LocalFrame, check_wgs84, utm_epsg

GEOD = Geod(ellps="WGS84")
ROUND_TRIP = settings(derandomize=True, max_examples=60, deadline=None)

origins = st.tuples(
    st.floats(-179.99, 179.99, allow_nan=False),
    st.floats(-80.0, 84.0, allow_nan=False),
)
offsets_m = st.floats(-50_000.0, 50_000.0, allow_nan=False)


@ROUND_TRIP
@given(origin=origins, dx=offsets_m, dy=offsets_m)
def test_local_round_trip_is_under_a_centimetre(
    origin: tuple[float, float], dx: float, dy: float
) -> None:
    frame = LocalFrame.around(*origin)
    lon, lat = frame.to_lonlat(dx, dy)
    x, y = frame.to_local(lon, lat)
    assert math.hypot(x - dx, y - dy) < 0.01


@ROUND_TRIP
@given(origin=origins, bearing=st.floats(0.0, 360.0), distance=st.floats(0.0, 50_000.0))
def test_lonlat_round_trip_is_under_a_centimetre(
    origin: tuple[float, float], bearing: float, distance: float
) -> None:
    frame = LocalFrame.around(*origin)
    lon, lat, _ = GEOD.fwd(origin[0], origin[1], bearing, distance)
    back_lon, back_lat = frame.to_lonlat(*frame.to_local(lon, lat))
    _, _, error_m = GEOD.inv(lon, lat, back_lon, back_lat)
    assert error_m < 0.01


def test_origin_is_zero_and_metres_are_metres() -> None:
    frame = LocalFrame.around(10.5, 52.3)
    assert frame.to_local(10.5, 52.3) == pytest.approx((0.0, 0.0), abs=1e-9)
    lon, lat, _ = GEOD.fwd(10.5, 52.3, 45.0, 1000.0)
    x, y = frame.to_local(lon, lat)
    # UTM scale factor is within 0.9996..1.001 near the central meridian
    assert math.hypot(x, y) == pytest.approx(1000.0, rel=2e-3)


def test_arrays_keep_their_shape_and_scalars_stay_floats() -> None:
    frame = LocalFrame.around(-60.0, -33.0)
    x, y = frame.to_local(-60.0, -33.0)
    assert isinstance(x, float) and isinstance(y, float)
    lon = np.array([[-60.0, -59.9], [-60.1, -60.0]])
    lat = np.array([[-33.0, -33.1], [-32.9, -33.05]])
    xs, ys = frame.to_local(lon, lat)
    assert xs.shape == ys.shape == (2, 2)
    back_lon, back_lat = frame.to_lonlat(xs, ys)
    np.testing.assert_allclose(back_lon, lon, atol=1e-9)
    np.testing.assert_allclose(back_lat, lat, atol=1e-9)


@pytest.mark.parametrize(
    ("lon", "lat", "epsg"),
    [
        (10.5, 52.3, 32632),  # Lower Saxony
        (-61.0, -33.0, 32720),  # Pampas, south
        (-180.0, 10.0, 32601),
        (180.0, 10.0, 32660),
        (5.0, 60.0, 32632),  # Norway exception (would be 31)
        (15.0, 78.0, 32633),  # Svalbard
        (0.0, 0.0, 32631),  # the equator counts as north
    ],
)
def test_utm_zone(lon: float, lat: float, epsg: int) -> None:
    assert utm_epsg(lon, lat) == epsg
    assert LocalFrame.around(lon, lat).epsg == epsg


def test_frame_is_small_frozen_and_picklable() -> None:
    frame = LocalFrame.around(2.35, 48.85)
    assert pickle.loads(pickle.dumps(frame)) == frame
    assert hash(frame) == hash(LocalFrame.around(2.35, 48.85))
    with pytest.raises(dataclasses.FrozenInstanceError):
        frame.epsg = 1  # type: ignore[misc]


@pytest.mark.parametrize(
    ("lon", "lat"),
    [(0.0, 90.5), (0.0, -91.0), (180.5, 0.0), (-181.0, 0.0), (math.nan, 0.0), (0.0, math.inf)],
)
def test_check_wgs84_rejects_bad_values(lon: float, lat: float) -> None:
    with pytest.raises(GeometryError, match="field 'north-7'"):
        check_wgs84(lon, lat, "field 'north-7'")
    with pytest.raises(GeometryError, match="north-7"):
        check_wgs84(np.array([1.0, lon]), np.array([1.0, lat]), "field 'north-7'")


def test_check_wgs84_accepts_the_limits_and_arrays() -> None:
    check_wgs84(180.0, -90.0, "x")
    check_wgs84(np.array([-180.0, 0.0, 179.9]), np.array([90.0, 0.0, -45.0]), "x")


def test_frame_origin_is_checked() -> None:
    with pytest.raises(GeometryError, match="origin"):
        LocalFrame.around(10.0, 95.0)
