"""Generate config/changji.geojson: a demo farm built from the paper's Table 11.

The paper's Changji Huaxing farm (Fig. 1) has 15 fields whose sizes it lists in Table 11 but
whose coordinates it does not publish. This lays out 15 fields of those sizes near
44.0 N 87.3 E, three rows of five along roads 24 m wide, each a rectangle of Table 11's
width (east-west) and length (north-south), turned by a small angle and with its corners
nudged a few metres, so they are realistic quadrilaterals rather than a perfect grid. The
roads run along the middle of the gaps (six north-south, four east-west, a grid around every
field); the garage sits 40 m west of the west road by the middle row, joined to it by a
lane. Each field has one gate, at the middle of its side facing the lane between its row and
the middle row (the middle row alternates north and south). Deterministic: run it again and
the file is identical. Usage: python config/make_changji.py > config/changji.geojson
"""

import json
import math
import random

from pyproj import Transformer
from shapely.geometry import LineString, Polygon

TABLE11 = [  # task, width m, length m (area = width * length as printed)
    (1, 241, 178),
    (2, 277, 172),
    (3, 216, 166),
    (4, 214, 160),
    (5, 234, 188),
    (6, 275, 183),
    (7, 212, 177),
    (8, 218, 174),
    (9, 233, 153),
    (10, 273, 153),
    (11, 207, 153),
    (12, 219, 153),
    (13, 307, 173),
    (14, 302, 172),
    (15, 316, 157),
]
ORIGIN = (87.3, 44.0)  # lon, lat of the farm's south-west corner
ROAD = 24.0
COLUMN_PITCH = 316 + ROAD + 10
ROW_PITCH = 188 + ROAD + 10
COLUMNS, ROWS = 5, 3
MIN_ROAD_CLEARANCE_M = 3.0  # between a road's centre line and any field


def main() -> None:
    rnd = random.Random(11)
    gates: list[tuple[str, tuple[float, float]]] = []
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32645", always_xy=True)
    to_wgs = Transformer.from_crs("EPSG:32645", "EPSG:4326", always_xy=True)
    ox, oy = to_utm.transform(*ORIGIN)
    features = []
    outlines = []
    for k, (task, width, length) in enumerate(TABLE11):
        row, col = divmod(k, 5)
        cx = ox + col * COLUMN_PITCH + COLUMN_PITCH / 2
        cy = oy + row * ROW_PITCH + ROW_PITCH / 2
        angle = math.radians(rnd.uniform(-3.0, 3.0))
        corners = []
        utm = []
        for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            x = sx * width / 2 + rnd.uniform(-3.0, 3.0)
            y = sy * length / 2 + rnd.uniform(-3.0, 3.0)
            rx = cx + x * math.cos(angle) - y * math.sin(angle)
            ry = cy + x * math.sin(angle) + y * math.cos(angle)
            utm.append((rx, ry))
            lon, lat = to_wgs.transform(rx, ry)
            corners.append([round(lon, 7), round(lat, 7)])
        corners.append(corners[0])
        outlines.append((f"F{task:02d}", Polygon(utm)))
        # The gate: the middle of the south side (corners 0-1) or the north side (2-3).
        north = row == 0 or (row == 1 and col % 2 == 1)
        a, b = (utm[2], utm[3]) if north else (utm[0], utm[1])
        gates.append((f"F{task:02d}", ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2)))
        features.append(
            {
                "type": "Feature",
                "properties": {
                    "kind": "field",
                    "id": f"F{task:02d}",
                    "name": f"Table 11 field {task}",
                    "paper_width_m": width,
                    "paper_length_m": length,
                },
                "geometry": {"type": "Polygon", "coordinates": [corners]},
            }
        )
    garage = (ox - 40.0, oy + 1.5 * ROW_PITCH)
    glon, glat = to_wgs.transform(*garage)
    features.append(
        {
            "type": "Feature",
            "properties": {"kind": "garage", "name": "machine yard"},
            "geometry": {"type": "Point", "coordinates": [round(glon, 7), round(glat, 7)]},
        }
    )
    roads = [
        (f"ns{c}", [(ox + c * COLUMN_PITCH, oy), (ox + c * COLUMN_PITCH, oy + ROWS * ROW_PITCH)])
        for c in range(COLUMNS + 1)
    ]
    roads += [
        (f"ew{r}", [(ox, oy + r * ROW_PITCH), (ox + COLUMNS * COLUMN_PITCH, oy + r * ROW_PITCH)])
        for r in range(ROWS + 1)
    ]
    roads.append(("yard", [garage, (ox, garage[1])]))
    for road_id, points in roads:
        line = LineString(points)
        for field_id, outline in outlines:
            gap = line.distance(outline)
            assert gap >= MIN_ROAD_CLEARANCE_M, f"road {road_id} is {gap:.1f} m from {field_id}"
        coords = [[round(v, 7) for v in to_wgs.transform(*p)] for p in points]
        features.append(
            {
                "type": "Feature",
                "properties": {"kind": "road", "id": road_id},
                "geometry": {"type": "LineString", "coordinates": coords},
            }
        )
    for field_id, (gx, gy) in gates:
        lon, lat = to_wgs.transform(gx, gy)
        features.append(
            {
                "type": "Feature",
                "properties": {"kind": "gate", "field": field_id},
                "geometry": {"type": "Point", "coordinates": [round(lon, 7), round(lat, 7)]},
            }
        )
    print(json.dumps({"type": "FeatureCollection", "features": features}, indent=1))


if __name__ == "__main__":
    main()
