"""One picture of a reviewed run: the map of what was driven beside a Gantt chart of who
worked which field when.

Left, the farm in metres around the garage (WGS84 projected with
:class:`planner.geo.LocalFrame`): fields tinted in the colour of the vehicle that finished
them (hatched grey if not done), each vehicle's planned road legs dashed and its driven
track solid, the garage, a scale bar. Right, one row per vehicle over hours since it set
off: a bar per field worked, labelled with the field id, road and standing time between
them, the plan's field windows as thin strips under the bars, and the makespan.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from shapely.geometry import Polygon  # noqa: E402

from dispatcher.mission.map import colour, draw_scale_bar, save_figure  # noqa: E402
from dispatcher.review.report import FieldReview, Review, VehicleReview  # noqa: E402
from planner.geo import LocalFrame  # noqa: E402

FIELD_FACE = "#f3efe0"
FIELD_EDGE = "#6b5b3e"
ROAD_GREY = "#555555"
STOPPED_GREY = "#c8c8c8"


_FIG_W_IN = 17.0
_TOP_IN = 1.15  # title (and the cut-short notice), panel titles
_BOTTOM_IN = 1.45  # legends
_MAP_LEFT_IN, _MAP_W_IN = 0.25, 7.7
_GANTT_LEFT_IN, _GANTT_W_IN = 8.75, 7.95


def plot_review(review: Review, path: str | Path, title: str = "") -> Path:
    """Draw ``review`` as one PNG at ``path`` (map beside Gantt chart); returns the path."""
    path = Path(path)
    colours = {v.id: colour(k) for k, v in enumerate(review.vehicles)}
    frame = _frame(review)
    aspect = _map_aspect(review, frame) if frame is not None else 0.6
    axes_h = min(max(_MAP_W_IN * aspect, 0.9 * len(review.vehicles) + 0.9, 3.0), 9.0)
    top_in = _TOP_IN + (0.0 if review.complete else 0.3)
    fig_h = top_in + axes_h + _BOTTOM_IN
    fig = plt.figure(figsize=(_FIG_W_IN, fig_h), dpi=110)

    def box(left_in: float, width_in: float) -> tuple[float, float, float, float]:
        return (
            left_in / _FIG_W_IN,
            _BOTTOM_IN / fig_h,
            width_in / _FIG_W_IN,
            axes_h / fig_h,
        )

    map_ax = fig.add_axes(box(_MAP_LEFT_IN, _MAP_W_IN))
    gantt_ax = fig.add_axes(box(_GANTT_LEFT_IN, _GANTT_W_IN))
    if frame is not None:
        _draw_map(map_ax, review, frame, colours)
    else:
        map_ax.text(0.5, 0.5, "nothing to map", ha="center", va="center")
        map_ax.set_axis_off()
    _draw_gantt(gantt_ax, review, colours, axes_h)
    fig.text(0.5, 1 - 0.3 / fig_h, title or _title(review), ha="center", va="center", fontsize=13)
    if not review.complete:
        fig.text(
            0.5,
            1 - 0.62 / fig_h,
            "The log ends early (the run was cut short): everything after its last record is "
            "missing; the figures cover what was recorded.",
            ha="center",
            va="center",
            fontsize=11,
            color="#b00000",
        )
    save_figure(fig, path)
    return path


def _map_aspect(review: Review, frame: LocalFrame) -> float:
    """Height over width of everything on the map, in metres."""
    lats = [lat for f in review.fields for _, lat in f.polygon]
    lons = [lon for f in review.fields for lon, _ in f.polygon]
    for v in review.vehicles:
        lats += [p[1] for p in v.track]
        lons += [p[2] for p in v.track]
    if review.garage is not None:
        lats.append(review.garage[0])
        lons.append(review.garage[1])
    if len(lats) < 2:
        return 0.6
    xy = _xy(frame, lats, lons)
    w, h = np.ptp(xy[:, 0]) + 1.0, np.ptp(xy[:, 1]) + 1.0
    return float(min(max(h / w, 0.2), 1.5)) * 1.08


def _h(hours: float) -> str:
    """Hours to one decimal, or two for short runs."""
    return f"{hours:.1f} h" if hours >= 2.0 else f"{hours:.2f} h"


def _title(review: Review) -> str:
    vs = review.vehicles
    farm = review.farm_id or "farm"
    if not vs:
        return f"{farm}: no plan in the log"
    planned = (
        f" (planned {_h(review.planned_makespan_h)})"
        if review.planned_makespan_h is not None
        else ""
    )
    done = "all done" if review.makespan_final else "so far"
    return (
        f"{farm}, plan {review.plan_id or '?'}: {review.fields_done}/{len(review.fields)} fields "
        f"done by {len(vs)} vehicles, {done} in {_h(review.makespan_h)}{planned}, "
        f"{sum(v.distance_m for v in vs) / 1000:.1f} km driven"
        + (
            f", {sum(v.fuel_l or 0.0 for v in vs):.0f} L fuel"
            if any(v.fuel_l is not None for v in vs)
            else ""
        )
    )


# --- map -----------------------------------------------------------------------------------


def _frame(review: Review) -> LocalFrame | None:
    """A metric frame around the garage (else the first field corner or track point)."""
    if review.garage is not None:
        lat, lon = review.garage
        return LocalFrame.around(lon, lat)
    for f in review.fields:
        if f.polygon:
            return LocalFrame.around(*f.polygon[0])
    for v in review.vehicles:
        if v.track:
            return LocalFrame.around(v.track[0][2], v.track[0][1])
    return None


def _xy(frame: LocalFrame, lats: Sequence[float], lons: Sequence[float]) -> np.ndarray:
    x, y = frame.to_local(np.asarray(lons, dtype=float), np.asarray(lats, dtype=float))
    return np.column_stack([x, y])


def _ring_xy(frame: LocalFrame, ring: Sequence[tuple[float, float]]) -> np.ndarray:
    """A ring of (lon, lat) in the frame's metres, [corner, x|y]."""
    lons, lats = zip(*ring, strict=True)
    return _xy(frame, lats, lons)


def _draw_fields(ax: Axes, review: Review, frame: LocalFrame, colours: dict[str, str]) -> None:
    """Field outlines (and holes) with their ids, tinted by the vehicle that finished them;
    a field that changed hands in a re-plan says from whom to whom."""
    moved = {fid: (a, b) for rp in review.replans for fid, a, b in rp.taken_over}
    for f in review.fields:
        if len(f.polygon) < 3:
            continue
        xy = _ring_xy(frame, f.polygon)
        if f.done and f.vehicle in colours:
            ax.fill(xy[:, 0], xy[:, 1], facecolor=colours[f.vehicle], alpha=0.16, zorder=1)
            ax.fill(xy[:, 0], xy[:, 1], facecolor="none", edgecolor=FIELD_EDGE, lw=1.0, zorder=2)
        else:
            ax.fill(
                xy[:, 0],
                xy[:, 1],
                facecolor=FIELD_FACE,
                edgecolor=FIELD_EDGE,
                hatch="///" if not f.done else None,
                lw=1.0,
                zorder=1,
            )
        holes = [_ring_xy(frame, hole) for hole in f.holes if len(hole) >= 3]
        for hole in holes:  # not worked (a pond): the background, outlined
            ax.fill(*hole.T, facecolor="white", edgecolor=FIELD_EDGE, lw=0.8, zorder=2)
        c = Polygon(xy, holes).representative_point()
        label = f"{f.id}\n{moved[f.id][0]}→{moved[f.id][1]}" if f.id in moved else f.id
        ax.annotate(
            label,
            (c.x, c.y),
            ha="center",
            va="center",
            fontsize=8,
            fontweight="bold",
            color="#3d3325",
            zorder=9,
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.75},
        )


def _draw_vehicle(ax: Axes, v: VehicleReview, frame: LocalFrame, col: str) -> None:
    """The planned road legs (dashed) and the driven track (solid, bolder on the road)."""
    route = v.planned_route
    for a, b in zip(route, route[1:], strict=False):
        if b.role not in ("road", "transit", "return"):
            continue  # legs inside a field: covered by the track
        xy = _xy(frame, (a.lat, b.lat), (a.lon, b.lon))
        ax.plot(xy[:, 0], xy[:, 1], color=col, lw=1.6, ls=(0, (5, 3)), alpha=0.9, zorder=4)
    if len(v.track) < 2:
        return
    t = np.array([p[0] for p in v.track])
    xy = _xy(frame, [p[1] for p in v.track], [p[2] for p in v.track])
    ax.plot(xy[:, 0], xy[:, 1], color=col, lw=0.5, alpha=0.85, zorder=3)
    work = [(a.start_s, a.end_s) for a in v.activities if a.kind == "work"]
    mids = (t[:-1] + t[1:]) / 2
    on_road = np.array([not any(s <= m <= e for s, e in work) for m in mids], dtype=bool)
    for k in np.flatnonzero(on_road):
        ax.plot(xy[k : k + 2, 0], xy[k : k + 2, 1], color=col, lw=2.4, zorder=5)
    if not v.mission_complete:
        ax.plot(
            [xy[-1, 0]],
            [xy[-1, 1]],
            marker="o",
            markersize=9,
            markerfacecolor=col,
            markeredgecolor="black",
            zorder=11,
        )


def _draw_map(ax: Axes, review: Review, frame: LocalFrame, colours: dict[str, str]) -> None:
    _draw_fields(ax, review, frame, colours)
    for v in review.vehicles:
        _draw_vehicle(ax, v, frame, colours[v.id])
    for loss in review.losses:
        if loss.lat is None or loss.lon is None:
            continue
        lx, ly = frame.to_local(loss.lon, loss.lat)
        ax.plot(
            [lx],
            [ly],
            marker="X",
            markersize=13,
            markerfacecolor=colours.get(loss.vehicle, "grey"),
            markeredgecolor="black",
            zorder=12,
        )
        ax.annotate(
            f"{loss.vehicle} lost",
            (lx, ly),
            xytext=(8, 6),
            textcoords="offset points",
            fontsize=8,
            fontweight="bold",
            zorder=12,
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
        )
    if review.garage is not None:
        gx, gy = frame.to_local(review.garage[1], review.garage[0])
        ax.plot([gx], [gy], marker="s", markersize=10, color="black", zorder=10)
        ax.annotate(
            "garage", (gx, gy), xytext=(7, -13), textcoords="offset points", fontsize=9, zorder=10
        )
    ax.set_aspect("equal")
    ax.margins(0.06)
    ax.set_xticks([])
    ax.set_yticks([])
    draw_scale_bar(ax)
    handles: list[Line2D | Patch] = [
        Line2D(
            [],
            [],
            color=colours[v.id],
            lw=2.4,
            label=f"{v.id}: {len(v.fields_done)}/{len(v.fields_planned)} fields, "
            f"{v.distance_m / 1000:.1f} km, {_h(v.time_h)}",
        )
        for v in review.vehicles
    ]
    handles += [
        Line2D([], [], color="grey", lw=1.6, ls=(0, (5, 3)), label="planned road"),
        Line2D([], [], color="grey", lw=2.4, label="driven road (thin: driven in a field)"),
        Patch(facecolor="grey", alpha=0.25, edgecolor=FIELD_EDGE, label="field done (tint)"),
        Line2D([], [], color="black", marker="s", ls="", label="garage"),
    ]
    if review.losses:
        handles.append(
            Line2D(
                [],
                [],
                color="grey",
                marker="X",
                markeredgecolor="black",
                ls="",
                label="lost (its fields re-planned: field label from→to)",
            )
        )
    if not all(f.done for f in review.fields):
        handles.append(
            Patch(facecolor=FIELD_FACE, edgecolor=FIELD_EDGE, hatch="///", label="field not done")
        )
    if not all(v.mission_complete for v in review.vehicles):
        handles.append(
            Line2D(
                [],
                [],
                marker="o",
                ls="",
                markerfacecolor="white",
                markeredgecolor="black",
                markersize=8,
                label="where a vehicle was last heard of",
            )
        )
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.01),
        ncol=2,
        fontsize=8.5,
        frameon=False,
    )
    ax.set_title("where they drove", fontsize=11)


# --- Gantt ---------------------------------------------------------------------------------

_BAR_H = 0.5
_PLAN_H = 0.1


def _draw_gantt(ax: Axes, review: Review, colours: dict[str, str], height_in: float) -> None:
    """One row per vehicle; ``height_in`` is the axes' height in inches."""
    vs = review.vehicles
    if not vs:
        ax.text(0.5, 0.5, "no vehicles to chart", ha="center", va="center")
        ax.set_axis_off()
        return
    fields = {f.id: f for f in review.fields}
    span_h = max(
        [v.time_h for v in vs]
        + [(f.planned_finished_s or 0.0) / 3600 for f in review.fields]
        + [review.planned_makespan_h or 0.0, 0.1]
    )
    x_max = span_h * 1.13
    hours_per_char = x_max / _GANTT_W_IN * 8.5 * 0.62 / 72  # 8.5 pt characters
    for row, v in enumerate(vs):
        _draw_row(ax, row, v, colours[v.id], fields, hours_per_char, span_h)
    ax.set_yticks(range(len(vs)), [v.id for v in vs], fontsize=11)
    ax.set_ylim(len(vs) - 0.4, -0.6)
    ax.set_xlim(0, x_max)
    ax.set_xlabel("hours after the vehicle set off (its own clock)", fontsize=10)
    ax.grid(axis="x", color="#dddddd", lw=0.8)
    ax.set_axisbelow(True)
    ax.spines[["top", "right"]].set_visible(False)
    _draw_makespans(ax, review, hours_per_char, height_in)
    handles = [
        Patch(facecolor="#9a9a9a", edgecolor="white", label="working a field (id on the bar)"),
        Patch(facecolor=ROAD_GREY, label="on the road, implement up"),
        Patch(
            facecolor="none",
            edgecolor="#444444",
            label="planned time for that field (mission legs, set speeds)",
        ),
    ]
    acts = [a for v in vs for a in v.activities]
    if any(a.kind == "stopped" for a in acts):
        handles.append(Patch(facecolor=STOPPED_GREY, label="standing still"))
    if any(a.kind == "work" and a.field_id not in v.fields_done for v in vs for a in v.activities):
        handles.append(
            Patch(facecolor="#cfcfcf", edgecolor="#777777", hatch="////", label="field unfinished")
        )
    ax.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, -0.62 / height_in),
        ncol=3,
        fontsize=8.5,
        frameon=False,
    )
    ax.set_title("who worked which field when", fontsize=11, pad=24)


def _draw_makespans(ax: Axes, review: Review, hours_per_char: float, height_in: float) -> None:
    """The actual and planned makespans as vertical lines, labelled above the chart."""
    if not review.vehicles:
        return
    actual = review.makespan_h
    planned = review.planned_makespan_h
    top = ax.get_xaxis_transform()  # x in hours, y in axes fraction
    label = "makespan" if review.makespan_final else "last report"
    ax.axvline(actual, color="black", lw=1.3, zorder=1)
    text = f"{label} {_h(actual)} "
    ax.text(
        actual,
        1.005,
        text,
        transform=top,
        ha="right",
        va="bottom",
        fontsize=9,
        fontweight="bold",
    )
    if planned is not None:
        ax.axvline(planned, color="black", lw=1.0, ls=":", zorder=1)
        crowded = abs(actual - planned) < (len(text) + 2) * hours_per_char * 1.1
        ax.text(
            planned,
            1.005 + (0.2 / height_in if crowded else 0.0),
            f"planned {_h(planned)} ",
            transform=top,
            ha="right",
            va="bottom",
            fontsize=9,
        )


def _draw_row(
    ax: Axes,
    row: int,
    v: VehicleReview,
    col: str,
    fields: dict[str, FieldReview],
    hours_per_char: float,
    span_h: float,
) -> None:
    # The plan's time for each field: a thin outlined strip under the bar (the plan of the
    # vehicle that has the field, after any re-plan).
    for fid in v.fields_planned:
        f = fields.get(fid)
        if f is None or f.planned_started_s is None or f.planned_finished_s is None:
            continue
        if f.vehicle is not None and f.vehicle != v.id:
            continue
        a, b = f.planned_started_s / 3600, f.planned_finished_s / 3600
        ax.broken_barh(
            [(a, b - a)],
            (row + _BAR_H / 2 + 0.05, _PLAN_H),
            facecolors="none",
            edgecolors="#444444",
            linewidth=0.8,
        )
        if f.started_s is None and (b - a) >= (len(fid) + 1.5) * hours_per_char:
            ax.text(  # not worked at all: name it on the plan's strip
                (a + b) / 2,
                row + _BAR_H / 2 + 0.07 + _PLAN_H,
                fid,
                ha="center",
                va="top",
                fontsize=7,
                color="#555555",
            )
    labels_up = 0
    min_w = span_h * 0.004  # short road legs still show
    for act in v.activities:
        a, b = act.start_s / 3600, act.end_s / 3600
        if act.kind != "work":
            mid, w = (a + b) / 2, max(b - a, min_w)
            height = 0.3 if act.kind == "transit" else 0.14
            ax.broken_barh(
                [(mid - w / 2, w)],
                (row - height / 2, height),
                facecolors=ROAD_GREY if act.kind == "transit" else STOPPED_GREY,
                zorder=4,
            )
            continue
        done = act.field_id is not None and act.field_id in v.fields_done
        ax.broken_barh(
            [(a, b - a)],
            (row - _BAR_H / 2, _BAR_H),
            facecolors=col,
            edgecolors="white",
            linewidth=1.0,
            hatch=None if done else "////",
            alpha=1.0 if done else 0.45,
            zorder=3,
        )
        label = act.field_id or "?"
        if (b - a) >= (len(label) + 1.5) * hours_per_char:
            ax.text(
                (a + b) / 2,
                row,
                label,
                ha="center",
                va="center",
                fontsize=8.5,
                color="white" if done else "black",
                fontweight="bold",
                zorder=5,
                bbox=None
                if done
                else {"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
            )
        else:  # too narrow: above the bar, staggered
            y = row - _BAR_H / 2 - 0.03 - 0.13 * (labels_up % 2)
            ax.text((a + b) / 2, y, label, ha="center", va="bottom", fontsize=7.5, zorder=5)
            labels_up += 1
    end_h = v.time_h
    if v.mission_complete:
        ax.plot([end_h], [row], marker="|", markersize=18, mew=2, color="black", zorder=6)
        text, colour_ = f"back {_h(end_h)}", "black"
    elif v.started:
        ax.plot([end_h], [row], marker="x", markersize=9, color="#b00000", mew=2, zorder=6)
        text, colour_ = f"last report {_h(end_h)}", "#b00000"
    else:
        ax.text(0.1, row, "never set off", va="center", fontsize=9, color="#b00000")
        return
    ax.annotate(
        text,
        (end_h, row),
        xytext=(8, 0),
        textcoords="offset points",
        va="center",
        fontsize=8,
        color=colour_,
        zorder=7,
        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85},
    )
