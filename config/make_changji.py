"""Generate config/changji.geojson: a demo farm built from the paper's Table 11.

The paper's Changji Huaxing farm (Fig. 1) has 15 fields whose sizes it lists in Table 11 but
whose coordinates it does not publish. This lays out 15 fields of those sizes near
44.0 N 87.3 E, three rows of five along roads 24 m wide, each a rectangle of Table 11's
width (east-west) and length (north-south), turned by a small angle and with its corners
nudged a few metres, so they are realistic quadrilaterals rather than a perfect grid. The
garage sits on the road west of the middle row. Deterministic: run it again and the file is
identical. Usage: python config/make_changji.py > config/changji.geojson
"""

import json
import math
import random

from pyproj import Transformer

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


def main() -> None:
    rnd = random.Random(11)
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32645", always_xy=True)
    to_wgs = Transformer.from_crs("EPSG:32645", "EPSG:4326", always_xy=True)
    ox, oy = to_utm.transform(*ORIGIN)
    features = []
    for k, (task, width, length) in enumerate(TABLE11):
        row, col = divmod(k, 5)
        cx = ox + col * COLUMN_PITCH + COLUMN_PITCH / 2
        cy = oy + row * ROW_PITCH + ROW_PITCH / 2
        angle = math.radians(rnd.uniform(-3.0, 3.0))
        corners = []
        for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            x = sx * width / 2 + rnd.uniform(-3.0, 3.0)
            y = sy * length / 2 + rnd.uniform(-3.0, 3.0)
            rx = cx + x * math.cos(angle) - y * math.sin(angle)
            ry = cy + x * math.sin(angle) + y * math.cos(angle)
            lon, lat = to_wgs.transform(rx, ry)
            corners.append([round(lon, 7), round(lat, 7)])
        corners.append(corners[0])
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
    glon, glat = to_wgs.transform(ox - 40.0, oy + 1.5 * ROW_PITCH)
    features.append(
        {
            "type": "Feature",
            "properties": {"kind": "garage", "name": "machine yard"},
            "geometry": {"type": "Point", "coordinates": [round(glon, 7), round(glat, 7)]},
        }
    )
    print(json.dumps({"type": "FeatureCollection", "features": features}, indent=1))


if __name__ == "__main__":
    main()
