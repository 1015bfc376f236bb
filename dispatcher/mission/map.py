"""Pictures of a farm: field outlines, roads, gates, swaths, routes, garage, legend, scale bar."""

from __future__ import annotations

import logging
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.transforms import ScaledTranslation  # noqa: E402
from shapely.geometry import LineString  # noqa: E402

from planner.farm import Farm  # noqa: E402
from planner.field_plan import FarmPlan, MachinePlan  # noqa: E402

logger = logging.getLogger(__name__)

COLOURS = [
    "#1f77b4",
    "#d62728",
    "#2ca02c",
    "#9467bd",
    "#ff7f0e",
    "#17becf",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
]


FIELD_EDGE = "#6b5b3e"  # a field's outline, in the pictures and on the live map
FIELD_FILL = "#f3efe0"


def colour(k: int) -> str:
    return COLOURS[k % len(COLOURS)]


ROAD_COLOUR = "#b4b4b4"
GATE_COLOUR = "#4d4d4d"
LANE_SPACING_PT = 2.2  # machines sharing a road are drawn side by side, this far apart


def draw_fields(ax: Axes, farm: Farm) -> None:
    """Roads, field polygons (holes too) with their ids, gates and the garage. The roads
    over the fields: a road drawn across a field (which the planner warns of) shows."""
    for road in farm.roads:
        xs, ys = road.line.xy
        ax.plot(xs, ys, color=ROAD_COLOUR, linewidth=4.0, solid_capstyle="round", zorder=1.5)
    for f in farm.fields:
        xs, ys = f.boundary.exterior.xy
        ax.fill(xs, ys, facecolor=FIELD_FILL, edgecolor=FIELD_EDGE, linewidth=1.0, zorder=1)
        for hole in f.boundary.interiors:
            hx, hy = hole.xy
            ax.fill(hx, hy, facecolor="white", edgecolor=FIELD_EDGE, linewidth=0.8, zorder=1)
        c = f.boundary.representative_point()
        ax.annotate(
            f.id,
            (c.x, c.y),
            ha="center",
            va="center",
            fontsize=8,
            color="#3d3325",
            fontweight="bold",
            zorder=6,
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7},
        )
    if farm.gates:
        ax.plot(
            [g.xy[0] for g in farm.gates],
            [g.xy[1] for g in farm.gates],
            linestyle="",
            marker="D",
            markersize=4.5,
            markerfacecolor="white",
            markeredgecolor=GATE_COLOUR,
            zorder=5,
        )
    gx, gy = farm.garage
    ax.plot([gx], [gy], marker="s", markersize=11, color="black", zorder=7)
    ax.annotate(
        "garage", (gx, gy), xytext=(6, -14), textcoords="offset points", fontsize=9, zorder=7
    )


def draw_scale_bar(ax: Axes) -> None:
    """A bar of a round length in the lower left corner."""
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    span = (x1 - x0) / 5
    length = next(v for v in (5000, 2000, 1000, 500, 200, 100, 50, 20, 10, 5, 2, 1) if v <= span)
    bx, by = x0 + 0.04 * (x1 - x0), y0 + 0.05 * (y1 - y0)
    ax.plot(
        [bx, bx + length], [by, by], color="black", linewidth=3, solid_capstyle="butt", zorder=8
    )
    label = f"{length // 1000} km" if length >= 1000 else f"{length} m"
    ax.text(
        bx + length / 2,
        by + 0.02 * (y1 - y0),
        label,
        ha="center",
        va="bottom",
        fontsize=9,
        zorder=8,
    )
    ax.annotate(
        "N",
        xy=(x1 - 0.04 * (x1 - x0), y1 - 0.05 * (y1 - y0)),
        xytext=(x1 - 0.04 * (x1 - x0), y1 - 0.14 * (y1 - y0)),
        ha="center",
        fontsize=10,
        fontweight="bold",
        arrowprops={"arrowstyle": "-|>", "color": "black"},
    )


def draw_plan(ax: Axes, plan: FarmPlan, planned_style: str = "--") -> list[Line2D]:
    """Each machine's swaths (thin) and transit legs as driven (``planned_style``, an
    arrow mid-leg) in its own colour, machines on the same road side by side; returns the
    legend handles."""
    handles = []
    garage = plan.farm.garage
    count = len(plan.machines)
    for k, route in enumerate(plan.machines):
        col = colour(k)
        shift = (k - (count - 1) / 2) * LANE_SPACING_PT
        lane = ax.transData + ScaledTranslation(
            shift / 72.0, shift / 72.0, ax.figure.dpi_scale_trans
        )
        for visit in route.visits:
            for s in visit.swaths:
                ax.plot(
                    [s.start[0], s.end[0]],
                    [s.start[1], s.end[1]],
                    color=col,
                    linewidth=0.5,
                    alpha=0.8,
                    zorder=2,
                )
            for ring in visit.headland:
                ax.plot(
                    [p[0] for p in ring],
                    [p[1] for p in ring],
                    color=col,
                    linewidth=0.5,
                    alpha=0.8,
                    zorder=2,
                )
        for leg in transit_legs(route, garage):
            ax.plot(
                [p[0] for p in leg],
                [p[1] for p in leg],
                color=col,
                linewidth=1.6,
                linestyle=planned_style,
                transform=lane,
                zorder=4,
            )
            a, b = _middle_step(leg)
            ax.annotate(
                "",
                xy=b,
                xytext=a,
                xycoords=lane,
                textcoords=lane,
                zorder=4,
                arrowprops={
                    "arrowstyle": "-|>",
                    "color": col,
                    "linewidth": 1.6,
                    "mutation_scale": 14,
                    "shrinkA": 0,
                    "shrinkB": 0,
                },
            )
        label = (
            f"{route.machine.id} ({route.machine.working_width_m:g} m): "
            f"{len(route.visits)} fields, {route.time_h:.1f} h, {route.road_m / 1000:.1f} km road"
        )
        handles.append(Line2D([], [], color=col, linewidth=2, label=label))
    return handles


def transit_legs(
    route: MachinePlan, garage: tuple[float, float]
) -> list[list[tuple[float, float]]]:
    """The polylines driven between fields: garage -> first entry, exit -> next entry, ...,
    last exit -> garage (through the approach and return points)."""
    legs = []
    where = garage
    for visit in route.visits:
        legs.append([where, *visit.approach, visit.entry])
        where = visit.exit
    if route.visits:
        legs.append([where, *route.return_path, garage])
    return legs


def _middle_step(
    leg: list[tuple[float, float]],
) -> tuple[tuple[float, float], tuple[float, float]]:
    """A short piece around the middle of a polyline, in its direction (for an arrow)."""
    line = LineString(leg)
    if line.length <= 0.0:
        return leg[0], leg[-1]
    half = line.length / 2
    step = min(1.0, half)
    a, b = line.interpolate(half - step), line.interpolate(half + step)
    return (a.x, a.y), (b.x, b.y)


def figure_for(farm: Farm, width_in: float = 12.0, extra_height_in: float = 1.6):  # type: ignore[no-untyped-def]
    """A figure whose map area has the farm's aspect ratio, with room below for a legend."""
    xs = [c for f in farm.fields for c in f.boundary.exterior.xy[0]] + [farm.garage[0]]
    ys = [c for f in farm.fields for c in f.boundary.exterior.xy[1]] + [farm.garage[1]]
    aspect = (max(ys) - min(ys) + 1.0) / (max(xs) - min(xs) + 1.0)
    height = min(max(width_in * aspect * 1.1, 3.5), 14.0)
    return plt.subplots(figsize=(width_in, height + extra_height_in), dpi=110)


def draw_plan_map(plan: FarmPlan, path: str | Path, title: str = "") -> None:
    """The plan as one picture someone new to the tool can read."""
    fig, ax = figure_for(plan.farm)
    draw_fields(ax, plan.farm)
    handles = draw_plan(ax, plan)
    ax.set_aspect("equal")
    ax.margins(0.05)
    ax.set_xticks([])
    ax.set_yticks([])
    draw_scale_bar(ax)
    handles.append(
        Line2D(
            [],
            [],
            color="grey",
            linestyle="--",
            linewidth=1.6,
            label="transit between fields (arrow: driving direction)",
        )
    )
    handles.append(Line2D([], [], color="grey", linewidth=0.6, label="swaths worked in a field"))
    if plan.farm.roads:
        handles.append(Line2D([], [], color=ROAD_COLOUR, linewidth=4.0, label="road"))
    if plan.farm.gates:
        handles.append(
            Line2D(
                [],
                [],
                color=GATE_COLOUR,
                marker="D",
                markerfacecolor="white",
                markersize=4.5,
                linestyle="",
                label="field gate",
            )
        )
    handles.append(Line2D([], [], color="black", marker="s", linestyle="", label="garage"))
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.02),
        fontsize=9,
        frameon=False,
        ncol=2,
    )
    ax.set_title(
        f"{title}: {len(plan.machines)} machines, {len(plan.farm.fields)} fields — "
        f"all done in {plan.makespan_h:.1f} h, {plan.distance_m / 1000:.1f} km on roads, "
        f"{plan.fuel_l:.0f} L fuel (objective: {plan.objective.name.lower()})",
        fontsize=11,
    )
    save_figure(fig, path, tight=True)


def save_figure(fig: plt.Figure, path: str | Path, tight: bool = False) -> None:
    """Lay ``fig`` out (``tight``: matplotlib's tight layout), write it to ``path`` and
    close it. Names in scripts the installed fonts lack (a field called 畑 on a machine
    without CJK fonts) are drawn as boxes, said once, not in one matplotlib warning per
    character and drawing."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if tight:
            fig.tight_layout()
        fig.savefig(path)
    plt.close(fig)
    missing = [w for w in caught if "missing from font" in str(w.message)]
    for w in caught:
        if w not in missing:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if missing:
        logger.warning(
            "%s: %d character(s) of the names have no glyph in the installed fonts; drawn as "
            "boxes (install a font with them, e.g. Noto Sans CJK, for such names)",
            Path(path).name,
            len({str(w.message) for w in missing}),
        )
