"""The paper's figures rendered from stored plan and tuning-job JSON (matplotlib, Agg backend).

Every plan figure is a function of the plan's stored record (its SI arrays, see
:class:`PlanData`), so figures never re-run the planner. Conventions:

* time on the x axis in s; joint angles and speeds in deg and deg/s; positions in mm;
  attitudes in deg (rotation vectors); one legend entry per joint / component.
* The *singular region* (where the smallest singular value of the GJM is below a threshold)
  is shaded on every time plot. The threshold is the plan's own ``epsilon`` for ``adaptive``
  and ``wdls``, ``sigma0`` for ``svf``, and otherwise :data:`DEFAULT_SINGULAR_THRESHOLD`
  (the default ``epsilon`` of the paper's adaptive damping, 0.0677).
* Long plans are decimated for drawing with a min/max envelope per bucket
  (:data:`MAX_POINTS` samples per series at most), which keeps every peak while rendering a
  20,000-step plan in a fraction of a second per figure.

Rendered figures are cached per plan in a process-wide LRU (:data:`CACHE`, bounded by entries
and bytes): plans are immutable, so ``(plan_id, name, format)`` is a complete key; the decoded
arrays of the last few plans are kept too (:func:`plan_data`). Job figures are keyed by the
job's progress too, so a running job's convergence figure is refreshed every generation.
"""

from __future__ import annotations

import io
import itertools
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from functools import cached_property
from typing import Any

import matplotlib
import matplotlib.lines
import matplotlib.patches

matplotlib.use("Agg")

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from engine.errors import ParameterError
from engine.inverses import METHODS
from engine.kinematics import kinematics_batch
from engine.model import RobotModel
from engine.spatial import log_so3, quaternion_to_matrix

FORMATS = {"svg": "image/svg+xml", "png": "image/png"}
MAX_POINTS = 2000
DEFAULT_SINGULAR_THRESHOLD = METHODS["adaptive"].param("epsilon").default
#: How a threshold parameter is written on the figures.
SYMBOLS = {"epsilon": "ε", "sigma0": "σ0"}
SHADE_COLOR = "#f4a261"
FIGSIZE = (8.0, 5.6)
DPI = 110

matplotlib.rcParams.update(
    {
        "svg.fonttype": "none",  # text stays text: smaller SVG, selectable labels
        "axes.grid": True,
        "grid.alpha": 0.3,
        "font.size": 9,
        "legend.fontsize": 8,
        "path.simplify": True,
    }
)


class PlanData:
    """A stored plan as the figures read it: its SI record (:func:`service.usecases.plans.record_of`:
    joints in rad or m, attitudes as quaternions) and what describes it (method, metrics, request,
    and the robot's parameters, to draw the arm)."""

    def __init__(
        self,
        record: dict[str, np.ndarray],
        *,
        plan_id: str = "",
        method: dict[str, Any] | None = None,
        metrics: dict[str, Any] | None = None,
        request: dict[str, Any] | None = None,
        robot: dict[str, Any] | None = None,
    ) -> None:
        self.id = plan_id
        self.method: dict[str, Any] = method or {}
        self.metrics: dict[str, Any] = metrics or {}
        self.request: dict[str, Any] = request or {}
        self.robot = robot
        self.t = _arr(record["t"])
        self.q = _arr(record["q"], 2)
        self.qd = _arr(record["qd"], 2)
        #: ``(n,)`` which joints are prismatic (positions in m, not drawn in degrees)
        self.prismatic = np.asarray(record["prismatic"], dtype=float).reshape(-1).astype(bool)
        self.q_deg = np.where(self.prismatic, np.nan, np.degrees(self.q))
        self.qd_deg_s = np.where(self.prismatic, np.nan, np.degrees(self.qd))
        self.base_position = _arr(record["base_position"], 2)
        self.base_quat = _arr(record["base_attitude"], 2)
        self.ee_position = _arr(record["ee_position"], 2)
        self.ee_position_desired = _arr(record["ee_position_desired"], 2)
        self.ee_quat = _arr(record["ee_attitude"], 2)
        self.ee_quat_desired = _arr(record["ee_attitude_desired"], 2)
        self.singular_values = _arr(record["singular_values"], 2)
        self.det = _arr(record["det_J_g"])
        self.damping = _arr(record["damping"], 2)
        self.position_error = _arr(record["position_error"])
        self.attitude_error = _arr(record["attitude_error"])

    @property
    def label(self) -> str:
        name = str(self.method.get("name", "?"))
        params = self.method.get("params") or {}
        text = ", ".join(f"{k}={_fmt(v)}" for k, v in params.items())
        return f"{name} ({text})" if text else name

    @cached_property
    def sigma_min(self) -> np.ndarray:
        if self.singular_values.size == 0:
            return np.full(self.t.shape, np.nan)
        return np.nanmin(np.where(np.isfinite(self.singular_values), self.singular_values, np.inf), axis=1)

    @cached_property
    def threshold(self) -> tuple[float, str]:
        return singular_threshold(self.method)

    @property
    def speed_limit_deg_s(self) -> float | None:
        value = self.metrics.get("joint_speed_limit_deg_s")
        if value is None:
            value = (self.request.get("task") or {}).get("joint_speed_limit_deg_s")
        return None if value is None else float(value)


def singular_threshold(method: dict[str, Any]) -> tuple[float, str]:
    """The singular-region threshold on the smallest singular value for a plan's ``method``
    (``{"name", "params"}``): the parameter the method's registry entry names (its
    ``threshold``), and its symbol."""
    params = method.get("params") or {}
    spec = METHODS.get(str(method.get("name")))
    name = spec.threshold if spec is not None else None
    if name is not None and params.get(name) is not None:
        return float(params[name]), SYMBOLS.get(name, name)
    return DEFAULT_SINGULAR_THRESHOLD, "ε (default)"


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _arr(values: Any, ndim: int = 1) -> np.ndarray:
    """A float array with ``None`` as NaN (stored trajectories are arrays already)."""
    if isinstance(values, np.ndarray):
        return values.astype(float, copy=False).reshape((-1,) if ndim == 1 else (values.shape[0], -1))
    if ndim == 1:
        return np.array([np.nan if v is None else v for v in values], dtype=float)
    rows = [[np.nan if v is None else v for v in row] for row in values]
    width = max((len(r) for r in rows), default=0)
    out = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
    return out


def _rotations(quats: np.ndarray) -> np.ndarray:
    """Rotation matrices of ``[w, x, y, z]`` rows (NaN rows stay NaN)."""
    out = np.full(quats.shape[:-1] + (3, 3), np.nan)
    ok = np.all(np.isfinite(quats), axis=-1)
    if np.any(ok):
        q = quats[ok] / np.linalg.norm(quats[ok], axis=-1, keepdims=True)
        out[ok] = quaternion_to_matrix(q)
    return out


def _rotvec(R: np.ndarray) -> np.ndarray:
    out = np.full(R.shape[:-2] + (3,), np.nan)
    ok = np.all(np.isfinite(R), axis=(-2, -1))
    if np.any(ok):
        out[ok] = log_so3(R[ok])
    return out


# --- drawing helpers ------------------------------------------------------------------------


def decimate(t: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_points`` samples of ``y(t)`` keeping each bucket's min and max (peaks survive)."""
    n = len(t)
    if n <= max_points:
        return t, y
    buckets = max_points // 2
    edges = np.linspace(0, n, buckets + 1).astype(int)
    filled = np.where(np.isfinite(y), y, np.nan)
    idx: list[int] = []
    for a, b in itertools.pairwise(edges):
        seg = filled[a:b]
        if b <= a:
            continue
        if np.all(np.isnan(seg)):
            idx.append(a)
            continue
        i, j = int(np.nanargmin(seg)) + a, int(np.nanargmax(seg)) + a
        idx.extend(sorted({i, j}))
    index = np.array(sorted(set(idx) | {0, n - 1}))
    return t[index], y[index]


def _line(ax: Axes, t: np.ndarray, y: np.ndarray, **kw: Any) -> None:
    tt, yy = decimate(t, y)
    ax.plot(tt, yy, linewidth=1.2, **kw)


def singular_intervals(t: np.ndarray, sigma_min: np.ndarray, threshold: float) -> list[tuple[float, float]]:
    """Time intervals where ``sigma_min < threshold`` (each sample stands for its step)."""
    mask = np.isfinite(sigma_min) & (sigma_min < threshold)
    if not np.any(mask) or len(t) == 0:
        return []
    change = np.diff(mask.astype(np.int8))
    starts = [int(i) for i in np.flatnonzero(change == 1) + 1]
    ends = [int(i) for i in np.flatnonzero(change == -1) + 1]
    if mask[0]:
        starts.insert(0, 0)
    if mask[-1]:
        ends.append(len(mask))
    dt = float(t[1] - t[0]) if len(t) > 1 else 0.0
    end = float(t[-1])
    return [(float(t[s]), min(float(t[e - 1]) + dt, end)) for s, e in zip(starts, ends, strict=True)]


def _shade(axes: Sequence[Axes], data: PlanData, legend_on: Axes | None = None) -> None:
    threshold, source = data.threshold
    intervals = singular_intervals(data.t, data.sigma_min, threshold)
    if len(intervals) > 500:  # a flickering signal: merge to the covered span
        intervals = [(intervals[0][0], intervals[-1][1])]
    for ax in axes:
        for k, (a, b) in enumerate(intervals):
            label = f"singular region (σ_min < {source} = {threshold:.3g})" if (ax is legend_on and k == 0) else None
            ax.axvspan(a, b, color=SHADE_COLOR, alpha=0.22, linewidth=0, label=label)


def _legend(ax: Axes, ncol: int = 1) -> None:
    handles, _ = ax.get_legend_handles_labels()
    if handles:
        ax.legend(loc="best", ncol=ncol, framealpha=0.85)


def _new(rows: int, title: str) -> tuple[Figure, list[Axes]]:
    fig = Figure(figsize=FIGSIZE, dpi=DPI, layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0].tolist()
    fig.suptitle(title, fontsize=10)
    axes[-1].set_xlabel("time t [s]")
    return fig, axes


def _title(data: PlanData, what: str) -> str:
    return f"{what} — {data.label}"


# --- plan figures ---------------------------------------------------------------------------


def fig_ee_velocity(data: PlanData) -> Figure:
    """Desired end-effector linear and angular velocity (mean over each planner step, from the
    stored desired path) and its norm (paper Fig. 4)."""
    fig, (ax_v, ax_w) = _new(2, _title(data, "Desired end-effector velocity"))
    t = data.t
    if len(t) >= 2:
        dt = np.diff(t)
        v = np.diff(data.ee_position_desired, axis=0) / dt[:, None] * 1e3  # mm/s
        R = _rotations(data.ee_quat_desired)
        dR = R[1:] @ np.swapaxes(R[:-1], -1, -2)  # world-frame increment
        w = np.degrees(_rotvec(dR)) / dt[:, None]  # deg/s
        tm = t[:-1]
        for i, axis in enumerate("xyz"):
            _line(ax_v, tm, v[:, i], label=f"v_{axis}", drawstyle="steps-post")
            _line(ax_w, tm, w[:, i], label=f"ω_{axis}", drawstyle="steps-post")
        _line(ax_v, tm, np.linalg.norm(v, axis=1), label="|v|", color="k", linestyle="--", drawstyle="steps-post")
        _line(ax_w, tm, np.linalg.norm(w, axis=1), label="|ω|", color="k", linestyle="--", drawstyle="steps-post")
    ax_v.set_ylabel("linear velocity [mm/s]")
    ax_w.set_ylabel("angular velocity [deg/s]")
    _shade([ax_v, ax_w], data, legend_on=ax_v)
    _legend(ax_v, 2)
    _legend(ax_w, 2)
    return fig


def fig_gjm_determinant(data: PlanData) -> Figure:
    """det J_g and the smallest singular value over time (paper Fig. 5)."""
    fig, (ax_d, ax_s) = _new(2, _title(data, "Generalized Jacobian: determinant and smallest singular value"))
    if np.any(np.isfinite(data.det)):
        _line(ax_d, data.t, data.det, label="det J_g", color="C0")
    else:
        ax_d.text(0.5, 0.5, "det J_g undefined (GJM not square)", transform=ax_d.transAxes, ha="center")
    ax_d.axhline(0.0, color="k", linewidth=0.6)
    ax_d.set_ylabel("det J_g [m³]")
    _line(ax_s, data.t, data.sigma_min, label="σ_min(J_g)", color="C1")
    threshold, source = data.threshold
    ax_s.axhline(threshold, color="C3", linestyle="--", linewidth=1, label=f"{source} = {threshold:.3g}")
    ax_s.set_ylabel("smallest singular value σ_min [–]")
    ax_s.set_ylim(bottom=0)
    _shade([ax_d, ax_s], data, legend_on=ax_d)
    _legend(ax_d)
    _legend(ax_s)
    return fig


def _joint_lines(ax: Axes, data: PlanData, degrees: np.ndarray, si: np.ndarray, unit: str, what: str, **kw: Any) -> None:
    """One line per joint: revolute joints from ``degrees (N+1, n)`` on ``ax``, prismatic ones
    from ``si (N+1, n)`` (``unit``, m or m/s) on a second y axis labelled ``what``."""
    prismatic = data.prismatic
    for j in np.flatnonzero(~prismatic):
        _line(ax, data.t, degrees[:, j], label=f"joint {j + 1}", color=f"C{j % 10}", **kw)
    if prismatic.any():
        ax_m = ax.twinx()
        for j in np.flatnonzero(prismatic):
            _line(ax_m, data.t, si[:, j], label=f"joint {j + 1} [{unit}]", color=f"C{j % 10}", linestyle="--", **kw)
        ax_m.set_ylabel(f"prismatic {what} [{unit}]")
        _legend(ax_m, 1)


def fig_joint_velocities(data: PlanData) -> Figure:
    """Joint speeds in deg/s (prismatic joints in m/s) with the speed limit (paper Figs. 6 and 9)."""
    fig, (ax,) = _new(1, _title(data, "Joint velocities"))
    _joint_lines(ax, data, data.qd_deg_s, data.qd, "m/s", "joint velocity", drawstyle="steps-post")
    limit = data.speed_limit_deg_s
    if limit is not None:
        ax.axhline(limit, color="C3", linestyle="--", linewidth=1, label=f"limit ±{limit:g} deg/s")
        ax.axhline(-limit, color="C3", linestyle="--", linewidth=1)
    ax.set_ylabel("joint velocity [deg/s]")
    _shade([ax], data, legend_on=ax)
    _legend(ax, 2)
    return fig


def fig_joint_angles(data: PlanData) -> Figure:
    """Joint angles in deg (prismatic joints in m) (paper Fig. 8)."""
    fig, (ax,) = _new(1, _title(data, "Joint angles"))
    _joint_lines(ax, data, data.q_deg, data.q, "m", "joint position")
    ax.set_ylabel("joint angle [deg]")
    _shade([ax], data, legend_on=ax)
    _legend(ax, 2)
    return fig


def _tracking(data: PlanData) -> tuple[np.ndarray, np.ndarray]:
    """Position error components (mm) and attitude error rotation vector (deg), actual minus desired."""
    dp = (data.ee_position - data.ee_position_desired) * 1e3
    R = _rotations(data.ee_quat)
    Rd = _rotations(data.ee_quat_desired)
    dphi = np.degrees(_rotvec(R @ np.swapaxes(Rd, -1, -2)))
    return dp, dphi


def fig_tracking_errors(data: PlanData) -> Figure:
    """Position (x, y, z) and attitude errors over time (paper Fig. 11)."""
    fig, (ax_p, ax_a) = _new(2, _title(data, "End-effector tracking errors"))
    dp, dphi = _tracking(data)
    for i, axis in enumerate("xyz"):
        _line(ax_p, data.t, dp[:, i], label=f"e_{axis}")
        _line(ax_a, data.t, dphi[:, i], label=f"δφ_{axis}")
    _line(ax_p, data.t, data.position_error * 1e3, label="|e_p|", color="k", linestyle="--")
    _line(ax_a, data.t, np.degrees(data.attitude_error), label="|δφ| (angle)", color="k", linestyle="--")
    ax_p.set_ylabel("position error [mm]")
    ax_a.set_ylabel("attitude error [deg]")
    _shade([ax_p, ax_a], data, legend_on=ax_p)
    _legend(ax_p, 2)
    _legend(ax_a, 2)
    return fig


def fig_base_motion(data: PlanData) -> Figure:
    """Base position drift from its start (mm) and base attitude drift (rotation vector, deg)."""
    fig, (ax_p, ax_a) = _new(2, _title(data, "Base motion (drift from the initial pose)"))
    if len(data.t):
        p = (data.base_position - data.base_position[0]) * 1e3
        R = _rotations(data.base_quat)
        drift = np.degrees(_rotvec(R @ np.swapaxes(R[0], -1, -2)))
        for i, axis in enumerate("xyz"):
            _line(ax_p, data.t, p[:, i], label=f"Δr0_{axis}")
            _line(ax_a, data.t, drift[:, i], label=f"Δφ0_{axis}")
    ax_p.set_ylabel("base position drift [mm]")
    ax_a.set_ylabel("base attitude drift [deg]")
    _shade([ax_p, ax_a], data, legend_on=ax_p)
    _legend(ax_p, 2)
    _legend(ax_a, 2)
    return fig


def fig_damping(data: PlanData) -> Figure:
    """The effective damping per singular direction applied at each step (0 = undamped)."""
    fig, (ax_l, ax_s) = _new(2, _title(data, "Damping applied per step"))
    for i in range(data.damping.shape[1]):
        _line(ax_l, data.t, data.damping[:, i], label=f"λ_{i + 1} (direction {i + 1})", drawstyle="steps-post")
    ax_l.set_ylabel("effective damping λ_i [–]")
    _line(ax_s, data.t, data.sigma_min, label="σ_min(J_g)", color="C1")
    threshold, source = data.threshold
    ax_s.axhline(threshold, color="C3", linestyle="--", linewidth=1, label=f"{source} = {threshold:.3g}")
    ax_s.set_ylabel("σ_min [–]")
    ax_s.set_ylim(bottom=0)
    _shade([ax_l, ax_s], data, legend_on=ax_s)
    _legend(ax_l, 2)
    _legend(ax_s)
    return fig


SCENE_INSTANTS = 5
#: The carrier's drift is drawn magnified to this fraction of the scene's size (and labelled so).
DRIFT_SCENE_FRACTION = 0.15


def _stride(n: int, max_points: int = MAX_POINTS) -> np.ndarray:
    """Indices of at most ``max_points`` evenly strided samples of ``n`` (first and last kept)."""
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(int))


def arm_polylines(data: PlanData, count: int = SCENE_INSTANTS) -> tuple[np.ndarray, list[np.ndarray]]:
    """Times ``(K,)`` and the arm at ``K`` (at most ``count``) evenly spread finite samples: each
    ``(n + 2, 3)`` points base CoM, joints 1..n, end effector (m, world), from the plan's joint
    angles and base pose and the robot's forward kinematics. Empty without the robot."""
    if not data.robot or data.q.size == 0:
        return np.zeros(0), []
    try:
        model = RobotModel.from_dict(data.robot)
    except (ParameterError, KeyError, TypeError, ValueError):
        return np.zeros(0), []
    R = _rotations(data.base_quat)
    finite = np.flatnonzero(
        np.all(np.isfinite(data.q), axis=1)
        & np.all(np.isfinite(data.base_position), axis=1)
        & np.all(np.isfinite(R), axis=(1, 2))
    )
    if finite.size == 0 or data.q.shape[1] != model.n_joints:
        return np.zeros(0), []
    index = finite[np.unique(np.linspace(0, finite.size - 1, min(count, finite.size)).round().astype(int))]
    kin = kinematics_batch(model, data.q[index], R[index], data.base_position[index])
    lines = [
        np.concatenate([data.base_position[k][None], kin.joint_positions[i], kin.ee_position[i][None]])
        for i, k in enumerate(index)
    ]
    return data.t[index], lines


def fig_scene_3d(data: PlanData) -> Figure:
    """The counterpart of the paper's Fig. 10: the desired and achieved end-effector paths in
    3D, the arm drawn as links (base CoM, joints, end effector) at a few instants, and the
    carrier's CoM drift, magnified (the factor is in the legend) since it is millimetres."""
    fig = Figure(figsize=(8.0, 6.4), dpi=DPI, layout="constrained")
    ax = fig.add_subplot(projection="3d")
    fig.suptitle(_title(data, "3D view: end-effector path, arm and carrier"), fontsize=10)
    idx = _stride(len(data.t))
    desired, achieved = data.ee_position_desired[idx], data.ee_position[idx]
    ax.plot(*desired.T, color="C0", linewidth=3.0, alpha=0.45, label="desired end-effector path")
    ax.plot(*achieved.T, color="C1", linewidth=1.0, label="achieved end-effector path")
    times, arms = arm_polylines(data)
    for k, (t, arm) in enumerate(zip(times, arms, strict=True)):
        shade = 0.35 + 0.65 * k / max(1, len(arms) - 1)
        ax.plot(*arm.T, color=(0.2, 0.2, 0.2, shade), linewidth=2.0, marker="o", markersize=3, label=f"arm at t = {t:.3g} s")
    points = [p for p in (desired, achieved, *arms) if p.size]
    cloud = np.concatenate(points) if points else np.zeros((1, 3))
    cloud = cloud[np.all(np.isfinite(cloud), axis=1)]
    base = data.base_position[np.all(np.isfinite(data.base_position), axis=1)]
    if base.shape[0]:
        drift = base - base[0]
        size = float(np.ptp(cloud, axis=0).max()) if cloud.shape[0] else 1.0
        largest = float(np.linalg.norm(drift, axis=1).max())
        factor = 1.0 if largest == 0.0 else max(1.0, DRIFT_SCENE_FRACTION * size / largest)
        path = base[0] + factor * drift[_stride(len(drift))]
        ax.plot(
            *path.T,
            color="C2",
            linewidth=1.6,
            label=f"carrier CoM drift ×{factor:.3g} (max {largest * 1e3:.3g} mm)",
        )
        ax.scatter(*base[0], color="C2", marker="s", s=30, label="carrier CoM at t = 0")
        cloud = np.concatenate([cloud, path]) if cloud.shape[0] else path
    if cloud.shape[0]:
        low, high = cloud.min(axis=0), cloud.max(axis=0)
        span = np.maximum(high - low, 1e-3 * max(1.0, float((high - low).max())))
        ax.set_xlim(low[0], low[0] + span[0])
        ax.set_ylim(low[1], low[1] + span[1])
        ax.set_zlim(low[2], low[2] + span[2])
        ax.set_box_aspect(tuple(span))  # true proportions: metres are metres on every axis
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.legend(loc="upper left", fontsize=7, framealpha=0.85)
    return fig


PLAN_FIGURES: dict[str, Callable[[PlanData], Figure]] = {
    "ee-velocity": fig_ee_velocity,
    "gjm-determinant": fig_gjm_determinant,
    "joint-velocities": fig_joint_velocities,
    "joint-angles": fig_joint_angles,
    "tracking-errors": fig_tracking_errors,
    "base-motion": fig_base_motion,
    "damping": fig_damping,
    "scene-3d": fig_scene_3d,
}
FIGURE_TITLES = {
    "ee-velocity": "Desired end-effector velocity (Fig. 4)",
    "gjm-determinant": "det J_g and smallest singular value (Fig. 5)",
    "joint-velocities": "Joint velocities (Figs. 6, 9)",
    "joint-angles": "Joint angles (Fig. 8)",
    "tracking-errors": "Tracking errors (Fig. 11)",
    "base-motion": "Base motion",
    "damping": "Damping",
    "scene-3d": "3D view: path, arm and carrier (Fig. 10)",
}
JOB_FIGURES = ("convergence",)
COMPARE_FIGURES = ("tracking-errors",)


def fig_compare_tracking(plans: Sequence[PlanData]) -> Figure:
    """Position and attitude error norms of several plans on one figure (DLS versus GA-tuned)."""
    fig, (ax_p, ax_a) = _new(2, "Tracking errors compared")
    for k, data in enumerate(plans):
        label = f"{data.label} [{data.id[:8]}]"
        _line(ax_p, data.t, data.position_error * 1e3, label=label, color=f"C{k % 10}")
        _line(ax_a, data.t, np.degrees(data.attitude_error), label=label, color=f"C{k % 10}")
    ax_p.set_ylabel("position error |e_p| [mm]")
    ax_a.set_ylabel("attitude error |δφ| [deg]")
    _legend(ax_p)
    _legend(ax_a)
    return fig


def fig_convergence(job: dict[str, Any]) -> Figure:
    """Best-so-far and mean objective B per generation (paper Fig. 7), one pair of curves per GA
    phase (the tuned method and the DLS baseline), from the job's generation rows (``history``:
    ``phase``, ``role``, ``generation``, ``best``, ``mean`` each), written as each generation ends;
    a finished job without them falls back to its result's history."""
    history = _job_history(job)
    fig = Figure(figsize=(8.0, 4.4), dpi=DPI, layout="constrained")
    ax = fig.subplots()
    status = job.get("status", "?")
    progress = job.get("progress") or {}
    fig.suptitle(
        f"GA convergence — job {str(job.get('id', ''))[:8]} ({status}, generation "
        f"{progress.get('generation', 0)}/{progress.get('generations', 0)})",
        fontsize=10,
    )
    plotted = False
    for k, (phase, rows) in enumerate(history.items()):
        gens = np.array([r["generation"] for r in rows], dtype=float)
        best = np.array([np.nan if r.get("best") is None else r["best"] for r in rows], dtype=float)
        mean = np.array([np.nan if r.get("mean") is None else r["mean"] for r in rows], dtype=float)
        ax.plot(gens, best, marker="o", markersize=3, color=f"C{k}", label=f"{phase}: best B")
        ax.plot(gens, mean, linestyle="--", color=f"C{k}", alpha=0.7, label=f"{phase}: mean B (feasible)")
        plotted = plotted or bool(np.any(np.isfinite(best)) or np.any(np.isfinite(mean)))
    if not plotted:
        ax.text(0.5, 0.5, f"no generation finished yet ({status})", transform=ax.transAxes, ha="center", va="center")
    elif _positive(ax):
        ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("generation")
    ax.set_ylabel("objective B [m + rad, weighted]")
    _legend(ax, 2)
    return fig


def _positive(ax: Axes) -> bool:
    values = np.concatenate([np.asarray(line.get_ydata(), dtype=float) for line in ax.get_lines()] or [np.zeros(0)])
    values = values[np.isfinite(values)]
    return bool(values.size) and bool(np.all(values > 0))


def _job_history(job: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    rows = job.get("history") or []
    for r in rows:
        name = str(r.get("phase") or job.get("method") or "GA")
        out.setdefault("DLS baseline" if r.get("role") == "dls_baseline" else name, []).append(r)
    if not out and job.get("result"):
        method = str(job.get("method") or "GA")
        out[method] = list((job.get("result") or {}).get("history") or [])
    return out


# --- rendering and the cache ----------------------------------------------------------------


def render(fig: Figure, fmt: str) -> bytes:
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}")
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, metadata={"Date": None} if fmt == "svg" else None)
    return buf.getvalue()


def render_plan_figure(data: PlanData, name: str, fmt: str = "svg") -> bytes:
    return render(PLAN_FIGURES[name](data), fmt)


def render_compare_figure(data: Sequence[PlanData], fmt: str = "svg") -> bytes:
    return render(fig_compare_tracking(data), fmt)


def render_job_figure(job: dict[str, Any], fmt: str = "svg") -> bytes:
    return render(fig_convergence(job), fmt)


def _cell_edges(values: np.ndarray, log: bool) -> np.ndarray:
    """Edges of the cells centred on ``values`` (midpoints, in log space on a log axis)."""
    v = np.log10(values) if log else values
    mid = (v[1:] + v[:-1]) / 2.0
    edges = np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])
    out: np.ndarray = 10.0**edges if log else edges
    return out


def fig_landscape(data: dict[str, Any]) -> Figure:
    """log10 B over two parameters (x along the horizontal axis), the infeasible region hatched
    grey, the grid's best cell, and from a tuning job its GA optimum and the contour
    ``B = B(tuned DLS)`` (inside it the method beats the tuned DLS)."""
    grids = data["grids"]
    x, y = np.asarray(grids["x"], dtype=float), np.asarray(grids["y"], dtype=float)
    b = np.asarray(grids["objective_b"], dtype=float)
    feasible = np.asarray(grids["feasible"], dtype=float) > 0.5
    x_log, y_log = data.get("x_scale") == "log", data.get("y_scale") == "log"
    fig = Figure(figsize=(8.0, 6.0), dpi=DPI, layout="constrained")
    ax = fig.subplots()
    xe, ye = _cell_edges(x, x_log), _cell_edges(y, y_log)
    shown = np.where(feasible & (b > 0), np.log10(np.where(b > 0, b, 1.0)), np.nan)
    mesh = ax.pcolormesh(xe, ye, shown.T, cmap="viridis", shading="flat")
    fig.colorbar(mesh, ax=ax, label="log10 B (objective, m + weighted attitude term)")
    infeasible = np.where(feasible, np.nan, 1.0)
    ax.pcolor(xe, ye, np.ma.masked_invalid(infeasible.T), hatch="///", color="0.75", alpha=0.6, shading="flat")
    handles: list[Any] = [matplotlib.patches.Patch(facecolor="0.75", hatch="///", label="infeasible (speed limit or diverged)")]
    best = data.get("best_params") or {}
    xn, yn = data["x_name"], data["y_name"]
    if best:
        handles += ax.plot(
            best[xn],
            best[yn],
            "x",
            color="white",
            markersize=10,
            mew=2,
            label=f"best cell, B = {_fmt(data.get('best_objective_b'))}",
        )
    marks = data.get("marks")
    if marks:
        dls_b = marks.get("dls_objective_b")
        if dls_b and np.isfinite(dls_b) and np.nanmin(b) < dls_b < np.nanmax(np.where(feasible, b, np.nan)):
            ax.contour(x, y, np.where(feasible, b, np.nan).T, levels=[dls_b], colors="white", linestyles="--", linewidths=1.2)
            handles.append(
                matplotlib.lines.Line2D([], [], color="white", linestyle="--", label=f"B of the tuned DLS ({_fmt(dls_b)})")
            )
        opt = marks.get("ga_optimum") or {}
        if xn in opt and yn in opt:
            handles += ax.plot(
                opt[xn],
                opt[yn],
                "*",
                color="#e76f51",
                markersize=14,
                mec="black",
                label=f"GA optimum, B = {_fmt(marks.get('ga_objective_b'))}",
            )
    if x_log:
        ax.set_xscale("log")
    if y_log:
        ax.set_yscale("log")
    ax.set_xlabel(xn)
    ax.set_ylabel(yn)
    ax.grid(False)
    fixed = ", ".join(f"{k} = {_fmt(v)}" for k, v in (data.get("fixed") or {}).items())
    fig.suptitle(
        f"Objective landscape — {data.get('method')} ({x.size} x {y.size} cells{'; ' + fixed if fixed else ''})", fontsize=10
    )
    ax.legend(handles=handles, loc="upper right", fontsize=8, facecolor="0.3", labelcolor="white", framealpha=0.8)
    return fig


def render_landscape_figure(data: dict[str, Any], fmt: str = "svg") -> bytes:
    return render(fig_landscape(data), fmt)


class LRUCache:
    """A thread-safe LRU of rendered figures, bounded by total bytes and entries."""

    def __init__(self, max_entries: int = 256, max_bytes: int = 64 * 2**20) -> None:
        self.max_entries = max_entries
        self.max_bytes = max_bytes
        self._data: OrderedDict[tuple[Any, ...], bytes] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def get(self, key: tuple[Any, ...]) -> bytes | None:
        with self._lock:
            value = self._data.get(key)
            if value is None:
                self.misses += 1
                return None
            self._data.move_to_end(key)
            self.hits += 1
            return value

    def put(self, key: tuple[Any, ...], value: bytes) -> None:
        with self._lock:
            old = self._data.pop(key, None)
            if old is not None:
                self._bytes -= len(old)
            self._data[key] = value
            self._bytes += len(value)
            while self._data and (len(self._data) > self.max_entries or self._bytes > self.max_bytes):
                _, dropped = self._data.popitem(last=False)
                self._bytes -= len(dropped)

    def __len__(self) -> int:
        return len(self._data)


CACHE = LRUCache()

_DATA: OrderedDict[str, PlanData] = OrderedDict()
_DATA_LOCK = threading.Lock()
DATA_CACHE_PLANS = 4  # decoded plans kept for rendering their other figures (a 20,000-step plan is ~8 MB)


def plan_data(plan_id: str, load: Callable[[], PlanData]) -> PlanData:
    """The decoded arrays of a plan, from a small LRU (decoding a long plan's JSON costs more
    than drawing one figure, and a plan page asks for all of them at once)."""
    with _DATA_LOCK:
        data = _DATA.get(plan_id)
        if data is not None:
            _DATA.move_to_end(plan_id)
            return data
    data = load()
    with _DATA_LOCK:
        _DATA[plan_id] = data
        while len(_DATA) > DATA_CACHE_PLANS:
            _DATA.popitem(last=False)
    return data


def cached(key: tuple[Any, ...], make: Callable[[], bytes]) -> tuple[bytes, bool]:
    """``(bytes, hit)``; renders with ``make`` on a miss."""
    value = CACHE.get(key)
    if value is not None:
        return value, True
    value = make()
    CACHE.put(key, value)
    return value, False
