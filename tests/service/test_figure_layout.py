"""Every plan figure drawn for three plans (the paper's line with adaptive damping, the raster
preset at dt 0.5 s, the paper's line with the plain inverse, which fails), checked on the
matplotlib objects themselves: axis labels and their units, scales and limits, legends outside
the data, tick labels that do not overprint, text inside the figure; the units of det J_g
against a rescaled robot; the landscape's heatmap without seams in SVG; PNG size per dpi, PDF.

In process (no server): the plans are planned with the engine and stored as the service stores
them (:func:`service.usecases.plans.record_of`)."""

from __future__ import annotations

import copy
import itertools
import re
import time
from typing import Any

import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.transforms import Bbox

from engine import PlanSetup, RobotModel, State, generalized_jacobian, run_plan, table1_robot, urdf_robot
from engine.model import table1_with_geometry
from engine.robustness import robustness
from service import figures
from service.schemas.methods import MethodOut
from service.schemas.plans import PlanRequest, metrics_out
from service.usecases import presets
from service.usecases.plans import record_of, robustness_record

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _plan(body: dict[str, Any], plan_id: str, model: RobotModel | None = None) -> figures.PlanData:
    request = PlanRequest.model_validate({"robot_id": "table1", **body})
    model = model or table1_robot()
    task = request.task.to_engine(model)
    setup = PlanSetup(model, task, request.options())
    result = run_plan(setup, request.method.to_engine())
    record = record_of(result, model)
    if request.uncertainty is not None:  # the robustness figure's bands
        robust = robustness(setup, request.method.to_engine(), result, request.uncertainty.to_engine())
        record.update(robustness_record(robust))
    data = figures.PlanData(
        record,
        plan_id=plan_id,
        method=MethodOut.from_engine(result.inverse, result.secondary).model_dump(mode="json"),
        metrics=metrics_out(result.metrics),
        request=request.model_dump(mode="json"),
        robot=model.to_dict(),
    )
    data.obstacles = task.scene.obstacles
    return data


@pytest.fixture(scope="module")
def plans() -> dict[str, figures.PlanData]:
    started = time.perf_counter()
    paper = presets.PRESETS["paper-line"].task.model_dump()
    raster, target = presets.PRESETS["raster-patch"], presets.PRESETS["raster-target"]
    assert raster.method is not None and target.method is not None
    out = {
        "paper": _plan(
            {
                "task": paper,
                "method": {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}},
                "uncertainty": {"carrier_mass_rel": 0.1, "carrier_inertia_rel": 0.1, "samples": 8},
            },
            "a" * 32,
        ),
        "raster": _plan({"task": {**raster.task.model_dump(), "dt_s": 0.5}, "method": raster.method.model_dump()}, "b" * 32),
        "inverse": _plan({"task": paper, "method": {"name": "inverse"}}, "c" * 32),
        # collision geometry: the clearance figure and the obstacles in the 3D scene
        "target": _plan(
            {
                "robot_id": "table1-geometry",
                "task": {**target.task.model_dump(), "dt_s": 0.5},
                "method": target.method.model_dump(),
                "uncertainty": {"link_mass_rel": 0.1, "link_com_m": 0.01, "q0_deg": 0.2, "samples": 4},
            },
            "d" * 32,
            table1_with_geometry(),
        ),
    }
    print(f"\nthree plans in {time.perf_counter() - started:.1f} s")
    return out


def drawn(fig: Figure) -> Any:
    """Draw ``fig`` (Agg) and return its renderer, so text and legends have their extents."""
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def overlap(a: Bbox, b: Bbox, slack: float = 0.5) -> bool:
    return a.x0 < b.x1 - slack and b.x0 < a.x1 - slack and a.y0 < b.y1 - slack and b.y0 < a.y1 - slack


def data_extent(ax: Axes) -> Bbox | None:
    """The display extent of the plotted lines' finite points (shading excluded)."""
    points = [
        np.column_stack([line.get_xdata(), line.get_ydata()]).astype(float)
        for line in ax.get_lines()
        if len(np.atleast_1d(line.get_xdata())) > 2  # not the axhlines (two points)
    ]
    if not points:
        return None
    xy = np.concatenate(points)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    display = ax.transData.transform(xy)
    return Bbox.from_extents(*display.min(axis=0), *display.max(axis=0))


def time_axes(fig: Figure) -> list[Axes]:
    return [ax for ax in fig.axes if ax.name == "rectilinear" and ax.get_label() != "<colorbar>"]


def check_text_inside_and_apart(fig: Figure, renderer: Any) -> None:
    """Axis labels and tick labels lie inside the figure; the tick labels of one axis do not overprint."""
    box = fig.bbox
    for ax in fig.axes:
        axes_of = [ax.xaxis, ax.yaxis] + ([ax.zaxis] if hasattr(ax, "zaxis") else [])
        for axis in axes_of:
            label = axis.label
            if label.get_text():
                extent = label.get_window_extent(renderer)
                assert box.x0 - 1 <= extent.x0 and extent.x1 <= box.x1 + 1, label.get_text()
                assert box.y0 - 1 <= extent.y0 and extent.y1 <= box.y1 + 1, label.get_text()
            ticks = [t for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]
            extents = [t.get_window_extent(renderer) for t in ticks]
            for (a, ta), (b, tb) in itertools.combinations(zip(extents, ticks, strict=True), 2):
                assert not overlap(a, b, slack=1.0), (ta.get_text(), tb.get_text())


@pytest.mark.parametrize("name", list(figures.PLAN_FIGURES))
@pytest.mark.parametrize("key", ["paper", "raster", "inverse", "target"])
def test_every_figure_has_units_and_legends_off_the_data(plans: dict[str, figures.PlanData], key: str, name: str) -> None:
    fig = figures.PLAN_FIGURES[name](plans[key])
    renderer = drawn(fig)
    check_text_inside_and_apart(fig, renderer)
    if name == "scene-3d":
        labels = fig.legends[0].get_texts() if fig.legends else []
        assert any(t.get_text() == "obstacles" for t in labels) == (key == "target")
        return
    if name == "clearance" and plans[key].clearance is None:  # no geometry: it says so
        (ax,) = time_axes(fig)
        assert "no collision geometry" in " ".join(t.get_text() for t in ax.texts)
        return
    if name == "robustness" and not plans[key].robust_bands:  # planned without uncertainty: it says so
        assert "planned without uncertainty" in " ".join(t.get_text() for ax in time_axes(fig) for t in ax.texts)
        return
    axes = time_axes(fig)
    assert axes[-1].get_xlabel() == "time t [s]"
    for ax in axes:
        assert re.search(r"\[.+\]", ax.get_ylabel()), (name, ax.get_ylabel())  # every y axis says its unit
        legend = ax.get_legend()
        assert legend is not None, name
        frame = legend.get_window_extent(renderer)
        assert not overlap(frame, ax.get_window_extent(renderer)), name  # outside the axes, so off the data
        extent = data_extent(ax)
        assert extent is None or not overlap(frame, extent)


def test_speeds_spanning_decades_go_on_a_symmetric_log_axis(plans: dict[str, figures.PlanData]) -> None:
    for key in ("paper", "raster", "inverse"):
        data = plans[key]
        (ax,) = time_axes(figures.PLAN_FIGURES["joint-velocities"](data))
        limit = data.speed_limit_deg_s
        assert limit == pytest.approx(6.0)
        peak = float(np.nanmax(np.abs(data.qd_deg_s)))
        low, high = ax.get_ylim()
        assert low <= -limit and limit <= high and low <= -peak * 0.999 and peak * 0.999 <= high  # limit and peaks shown
        if peak > figures.SYMLOG_FACTOR * limit:  # the plain inverse: thousands of deg/s
            assert key == "inverse"
            assert ax.get_yscale() == "symlog" and ax.yaxis.get_transform().linthresh == limit
            assert "symmetric log" in ax.get_ylabel()
        else:
            assert ax.get_yscale() == "linear"
        # the limit stands clear of zero: at least a tenth of the axis height
        y0, y6 = ax.transData.transform([(0.0, 0.0), (0.0, limit)])[:, 1]
        assert (y6 - y0) > 0.1 * ax.get_window_extent().height, key
    assert float(np.nanmax(np.abs(plans["inverse"].qd_deg_s))) > 1000.0  # the case the axis is for


def test_gjm_units_are_stated_and_det_scales_as_length_cubed(plans: dict[str, figures.PlanData]) -> None:
    fig = figures.PLAN_FIGURES["gjm-determinant"](plans["paper"])
    ax_d, ax_s = time_axes(fig)
    assert ax_d.get_ylabel() == "det J_g [m³/rad³]"
    assert "mixed" in ax_s.get_ylabel()
    assert "m/rad" in ax_d.get_title(loc="left") and "m³/rad³" in ax_d.get_title(loc="left")
    # independent truth: every length of the robot times s (inertias times s²) scales det J_g by s³
    model = table1_robot()
    scaled = scale_lengths(model.to_dict(), 10.0)
    q = np.radians([175.0, -60.0, -60.0, 0.0, 210.0, 5.0])
    det1 = generalized_jacobian(model, State(q)).determinant
    det10 = generalized_jacobian(RobotModel.from_dict(scaled), State(q)).determinant
    assert det1 is not None and det10 is not None
    assert det10 / det1 == pytest.approx(10.0**3, rel=1e-9)
    assert figures.gjm_units(np.zeros(6, dtype=bool), 6) == "m³/rad³"
    assert figures.gjm_units(np.array([False, False, True]), 3) == "m²/rad²"  # a position task, one prismatic joint
    assert figures.gjm_units(np.array([True, True, True, False, False, False]), 6) == "1"


def scale_lengths(robot: dict[str, Any], s: float) -> dict[str, Any]:
    out = copy.deepcopy(robot)
    for body in [out["base"], *out["links"]]:
        for key in ("a", "b"):
            if key in body:
                body[key] = [s * v for v in body[key]]
        body["inertia"] = [[s * s * v for v in row] for row in body["inertia"]]
    ee = out.get("end_effector") or {}
    for key, value in list(ee.items()):
        if key != "C_e" and isinstance(value, list) and len(value) == 3 and not isinstance(value[0], list):
            ee[key] = [s * v for v in value]
    return out


def test_damping_draws_equal_curves_once(plans: dict[str, figures.PlanData]) -> None:
    for key in ("paper", "raster", "inverse"):
        data = plans[key]
        ax_l, _ = time_axes(figures.PLAN_FIGURES["damping"](data))
        # independent count of distinct columns
        distinct = {tuple(np.round(np.nan_to_num(col), 12)) for col in data.damping.T}
        lines = [line for line in ax_l.get_lines() if len(line.get_xdata()) > 2]
        assert len(lines) == len(distinct), key
        labels = [line.get_label() for line in lines]
        never = [label for label in labels if "never damped" in label]
        zero_columns = int(np.sum(np.all(np.nan_to_num(data.damping) == 0.0, axis=0)))
        assert bool(never) == (zero_columns > 0)
    ax_l, _ = time_axes(figures.PLAN_FIGURES["damping"](plans["paper"]))
    assert [line.get_label() for line in ax_l.get_lines()][:2] == ["λ_1…λ_5 = 0 (never damped)", "λ_6 (σ_min's direction)"]


def test_scene_draws_the_paths_over_the_arm(plans: dict[str, figures.PlanData]) -> None:
    for key in ("paper", "raster"):
        fig = figures.PLAN_FIGURES["scene-3d"](plans[key])
        (ax,) = fig.axes
        assert ax.computed_zorder is False
        lines = {line.get_label(): line.get_zorder() for line in ax.get_lines()}
        arms = [z for label, z in lines.items() if label.startswith("arm at")]
        assert len(arms) == figures.SCENE_INSTANTS
        assert lines["desired end-effector path"] > max(arms) and lines["achieved end-effector path"] > max(arms)
        renderer = drawn(fig)
        legend = fig.legends[0].get_window_extent(renderer)
        assert not overlap(legend, ax.get_tightbbox(renderer))
        assert not overlap(legend, fig._suptitle.get_window_extent(renderer))  # type: ignore[union-attr]


def test_convergence_says_what_b_is_made_of() -> None:
    job = {
        "id": "j" * 32,
        "status": "succeeded",
        "progress": {"generation": 3, "generations": 3},
        "history": [{"phase": "adaptive", "generation": g, "best": 0.003 / (g + 1), "mean": 0.01 / (g + 1)} for g in range(3)],
    }
    for term, unit in (("eq18", "m·rad (eq. 18)"), ("angle", "rad (angle)")):
        (ax,) = figures.fig_convergence({**job, "objective": {"attitude_term": term}}).axes
        assert unit in ax.get_ylabel() and ax.get_yscale() == "log"
        assert "m + rad" not in ax.get_ylabel()


def test_landscape_heatmap_is_one_image_and_one_hatched_path() -> None:
    x, y = np.linspace(0.001, 0.2, 12), np.geomspace(0.001, 1.0, 10)
    X, Y = np.meshgrid(x, y, indexing="ij")
    feasible = (X > 0.03) | (Y > 0.2) | ((X > 0.01) & (Y < 0.01))  # an irregular infeasible region
    b = 0.002 + 0.01 * (X - 0.04) ** 2 + 0.001 * np.abs(np.log10(Y / 0.3))
    data = {
        "method": "adaptive",
        "x_name": "lambda_max",
        "y_name": "epsilon",
        "x_scale": "linear",
        "y_scale": "log",
        "objective": {"attitude_term": "eq18"},
        "grids": {"x": x, "y": y, "objective_b": np.where(feasible, b, np.nan), "feasible": feasible.astype(float)},
    }
    svg = figures.render_landscape_figure(data, "svg").decode()
    assert svg.count("<image") == 2  # the heatmap and the colour bar, each one raster: no seams between cells
    hatches = set(re.findall(r"url\(#(h[0-9a-f]+)\)", svg))
    assert len(hatches) == 1
    (hatch,) = hatches
    assert svg.count(f"url(#{hatch})") == 2  # one path over every infeasible cell, and its legend entry
    path = figures.cells_path(figures._cell_edges(x, False), figures._cell_edges(y, True), ~feasible)
    assert np.count_nonzero(path.codes == path.MOVETO) < np.count_nonzero(~feasible)  # runs merged
    assert "m·rad (eq. 18)" in svg


def test_png_pixels_follow_the_dpi_and_pdf_renders(plans: dict[str, figures.PlanData]) -> None:
    def size(png: bytes) -> tuple[int, int]:
        assert png.startswith(PNG_MAGIC)
        return int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")

    data = plans["paper"]
    w, h = figures.FIGSIZE
    assert size(figures.render_plan_figure(data, "joint-angles", "png")) == (round(w * figures.DPI), round(h * figures.DPI))
    assert size(figures.render_plan_figure(data, "joint-angles", "png", dpi=300)) == (round(w * 300), round(h * 300))
    pdf = figures.render_plan_figure(data, "joint-velocities", "pdf")
    assert pdf.startswith(b"%PDF-") and pdf == figures.render_plan_figure(data, "joint-velocities", "pdf")
    assert figures.render_plan_figure(data, "scene-3d", "svg") == figures.render_plan_figure(data, "scene-3d", "svg")


def test_compare_puts_plans_side_by_side_on_shared_axes(plans: dict[str, figures.PlanData]) -> None:
    pair = [plans["paper"], plans["inverse"]]
    fig = figures.fig_compare(pair, "joint-velocities")
    left, right = time_axes(fig)
    assert left.get_shared_y_axes().joined(left, right)
    assert left.get_yscale() == right.get_yscale() == "symlog"  # the inverse's speeds set the shared scale
    assert left.get_legend() is None and right.get_legend() is not None
    assert "a" * 8 in left.get_title() and "c" * 8 in right.get_title() and "ε = 0.12" in left.get_title()
    renderer = drawn(fig)
    check_text_inside_and_apart(fig, renderer)
    for name in figures.COMPARE_FIGURES:
        fig = figures.fig_compare(pair, name)
        drawn(fig)
        assert len(fig.axes) >= 2


def test_prismatic_joints_keep_their_legend_clear_of_the_second_axis() -> None:
    """A prismatic joint's curve has its own y axis (m or m/s) on the right: the legend moves above
    the axes, clear of that axis' ticks and label; det J_g's unit follows the joints."""
    preset = presets.PRESETS["arm3-position"]
    data = _plan({"task": preset.task.model_dump(), "method": {"name": "adaptive"}}, "d" * 32, urdf_robot("arm3"))
    assert data.prismatic.tolist() == [False, False, True]
    for name in ("joint-velocities", "joint-angles"):
        fig = figures.PLAN_FIGURES[name](data)
        renderer = drawn(fig)
        check_text_inside_and_apart(fig, renderer)
        main, twin = fig.axes
        assert re.search(r"\[m(/s)?\]", twin.get_ylabel())
        frame = main.get_legend().get_window_extent(renderer)
        for box in (main.get_window_extent(renderer), twin.yaxis.get_tightbbox(renderer), main.yaxis.get_tightbbox(renderer)):
            assert not overlap(frame, box), name
        assert "joint 3 [m" in " ".join(t.get_text() for t in main.get_legend().get_texts())
    ax_d, _ = time_axes(figures.PLAN_FIGURES["gjm-determinant"](data))
    assert ax_d.get_ylabel() == "det J_g [m²/rad²]"  # 3 position rows; 2 revolute joints and a boom


def test_compared_torques_of_a_revolute_and_a_prismatic_joint_keep_their_units_apart() -> None:
    """Comparing the paper plan with an arm3 plan: joint 3 is revolute (N m) in one and a
    prismatic boom (N) in the other, so its panel draws the boom's force on a second y axis,
    dashed, with the boom's limit there; the torque axis keeps N m (it said "[N]" for both)."""
    paper = _plan({"task": presets.PRESETS["paper-line"].task.model_dump(), "method": {"name": "adaptive"}}, "a" * 32)
    preset = presets.PRESETS["arm3-position"]
    boom = _plan({"task": preset.task.model_dump(), "method": {"name": "adaptive"}}, "d" * 32, urdf_robot("arm3"))
    fig = figures.fig_compare_torques([paper, boom])
    check_text_inside_and_apart(fig, drawn(fig))
    panels = fig.axes[:6]
    assert [ax.get_ylabel() for ax in panels] == [f"joint {j + 1} [N m]" for j in range(6)]
    (twin,) = fig.axes[6:]  # joint 3's, the only panel with both kinds
    assert twin.get_ylabel() == "prismatic, dashed [N]" and twin.get_shared_x_axes().joined(twin, panels[2])
    (force,) = [line for line in twin.get_lines() if len(line.get_ydata()) == len(boom.t)]
    assert force.get_linestyle() == "--"
    np.testing.assert_array_equal(force.get_ydata(), boom.dynamics.tau[:, 2])
    limits = sorted(float(line.get_ydata()[0]) for line in twin.get_lines() if line is not force)
    assert limits == (
        [-float(boom.dynamics.limit[2]), float(boom.dynamics.limit[2])] if np.isfinite(boom.dynamics.limit[2]) else []
    )
    (torque,) = [line for line in panels[2].get_lines() if len(line.get_ydata()) == len(paper.t)]
    np.testing.assert_array_equal(torque.get_ydata(), paper.dynamics.tau[:, 2])
    labels = [text.get_text() for text in panels[0].get_legend().get_texts()]
    assert [label for label in labels if "a" * 8 in label or "d" * 8 in label] == [  # each plan once, whatever its axes
        f"{paper.label} [{'a' * 8}]",
        f"{boom.label} [{'d' * 8}]",
    ]
