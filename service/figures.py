"""The paper's figures rendered from stored plan and tuning-job JSON (matplotlib, Agg backend).

Every plan figure is a function of the plan's stored record (its SI arrays, see
:class:`PlanData`), so figures never re-run the planner. Conventions:

* time on the x axis in s; joint angles and speeds in deg and deg/s; positions in mm;
  attitudes in deg (rotation vectors); one legend entry per joint / component.
* Legends sit outside the axes, on their right: they never cover data.
* The *singular region* (where the smallest singular value of the GJM is below a threshold)
  is shaded on every time plot. The threshold is the plan's own ``epsilon`` for ``adaptive``
  and ``wdls``, ``sigma0`` for ``svf``, and otherwise :data:`DEFAULT_SINGULAR_THRESHOLD`
  (the default ``epsilon`` of the paper's adaptive damping, 0.0677).
* Joint speeds that span decades (a plain inverse near the singularity: thousands of deg/s
  against a 6 deg/s limit) are drawn on a symmetric-log axis, linear within the speed limit, so
  the limit stays visible beside the peaks.
* Units of the GJM (:func:`gjm_units`): it maps joint rates (rad/s, or m/s for a prismatic
  joint) to the end effector's ``[v (m/s); w (rad/s)]``, so its linear rows are in m/rad and its
  angular rows in rad/rad = 1; ``det J_g`` of the 6 x 6 GJM is in m^3/rad^3 (m^3 with the radian
  taken as 1). Its singular values mix both kinds of rows and have no single unit: they are the
  numbers of the GJM in SI units (m, rad), and their product is ``|det J_g|``.
* Long plans are decimated for drawing with a min/max envelope per bucket
  (:data:`MAX_POINTS` samples per series at most), which keeps every peak while rendering a
  20,000-step plan in a fraction of a second per figure.
* Every figure renders as SVG, PNG or PDF (:func:`render`) at any ``dpi``: sizes are in points,
  and the only raster part of a vector figure (a landscape's heatmap) follows the ``dpi`` too.

Rendered figures are cached per plan in a process-wide LRU (:data:`CACHE`, bounded by entries
and bytes): plans are immutable, so ``(plan_id, name, format, dpi)`` is a complete key; the
decoded arrays of the last few plans are kept too (:func:`plan_data`). Job figures are keyed by
the job's progress too, so a running job's convergence figure is refreshed every generation.
"""

from __future__ import annotations

import functools
import io
import itertools
import threading
import types
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from engine.errors import ParameterError
from engine.geometry import Shape, distance, shape_outline
from engine.inverses import METHODS
from engine.kinematics import kinematics_batch
from engine.model import RobotModel
from engine.spatial import log_so3, quaternion_to_matrix
from service.infra.lru import Lru

if TYPE_CHECKING:
    import matplotlib.path
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: The formats of the figure endpoints and their media types (:func:`render` writes them all;
#: PDF: vector, fonts embedded as TrueType).
FORMATS = {"svg": "image/svg+xml", "png": "image/png", "pdf": "application/pdf"}
RENDER_FORMATS = FORMATS
MAX_POINTS = 2000
DEFAULT_SINGULAR_THRESHOLD = METHODS["adaptive"].param("epsilon").default
#: How a threshold parameter is written on the figures.
SYMBOLS = {"epsilon": "ε", "sigma0": "σ0"}
SHADE_COLOR = "#f4a261"
#: Inches; at :data:`DPI` a PNG of a time figure is 1350 x 840 pixels.
FIGSIZE = (9.0, 5.6)
DPI = 150
#: Joint speeds peaking above this many times the speed limit go on a symmetric-log axis.
SYMLOG_FACTOR = 10.0


@functools.cache
def mpl() -> types.ModuleType:
    """matplotlib (Agg backend, our settings), imported by the first figure drawn rather than
    with this module: it costs a process about 30 MiB and a third of a second, which an API or
    worker that draws no figure need not pay."""
    import matplotlib
    import matplotlib.figure
    import matplotlib.lines
    import matplotlib.patches
    import matplotlib.path
    import matplotlib.ticker

    matplotlib.use("Agg")
    matplotlib.rcParams.update(
        {
            "svg.fonttype": "none",  # text stays text: smaller SVG, selectable labels
            "svg.hashsalt": "spacearm",  # stable element ids: the same plan gives the same SVG bytes
            "pdf.fonttype": 42,  # TrueType in PDFs: text stays text
            "axes.grid": True,
            "grid.alpha": 0.3,
            "font.size": 9,
            "legend.fontsize": 8,
            "path.simplify": True,
            "hatch.linewidth": 0.6,
        }
    )
    return matplotlib


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
        self.dynamics = Dynamics(record, self.q.shape)
        #: ``(N+1,)`` m, the smallest distance of the checked pairs; None without geometry
        self.clearance = _arr(record["clearance"]) if "clearance" in record else None
        #: ``{"open" | "closed": (position (N+1, 3) m, attitude (N+1, 3) rad)}``: the errors' smallest,
        #: median and largest over the sampled robots of a plan under uncertainty; empty without one
        self.robust_bands = {
            loop: (_arr(record[f"robust_{loop}_position_band"], 2), _arr(record[f"robust_{loop}_attitude_band"], 2))
            for loop in ("open", "closed")
            if f"robust_{loop}_position_band" in record
        }
        #: the task's obstacles (engine shapes, world frame; None for one that can no longer be
        #: read, a mesh deleted since), set by whoever loads the plan
        self.obstacles: tuple[Shape | None, ...] = ()

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


class Dynamics:
    """A plan's executed-trajectory dynamics as the figures read them: joint torques (forces for
    prismatic joints) ``(N+1, n)``, the mount wrench ``(N+1, 3)`` and the robot's effort limits
    ``(n,)`` when it was planned (inf: none); NaN for plans stored before they were computed."""

    def __init__(self, record: dict[str, np.ndarray], shape: tuple[int, ...]) -> None:
        def get(name: str, like: tuple[int, ...]) -> np.ndarray:
            return np.asarray(record[name], dtype=float).reshape(like) if name in record else np.full(like, np.nan)

        self.tau = get("tau", shape)
        self.force = get("mount_force", (shape[0], 3))
        self.torque = get("mount_torque", (shape[0], 3))
        self.limit = get("effort_limit", (shape[1],)) if "effort_limit" in record else np.full(shape[1], np.inf)

    @property
    def known(self) -> bool:
        return bool(np.any(np.isfinite(self.tau)))


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


def _power(unit: str, exponent: int) -> str:
    superscripts = {2: "²", 3: "³", 4: "⁴", 5: "⁵", 6: "⁶"}
    return unit if exponent == 1 else unit + superscripts.get(exponent, f"^{exponent}")


def gjm_units(prismatic: np.ndarray, rows: int) -> str:
    """The unit of ``det J_g`` of a square tracked GJM with ``rows`` rows (6: pose, 3: position)
    and joints flagged ``prismatic (n,)``: an entry of row i, column j is in (row unit) / (joint
    unit), rows in m (linear) or rad (angular), joints in rad (revolute) or m (prismatic), so the
    determinant is in m^(3 - n_prismatic) rad^(rows - 3 - n_revolute), e.g. m³/rad³ for the
    Table-1 robot (m³ with the radian taken as 1)."""
    n_prismatic = int(np.count_nonzero(prismatic))
    exponents = {"m": 3 - n_prismatic, "rad": rows - 3 - (len(prismatic) - n_prismatic)}
    top = [_power(u, e) for u, e in exponents.items() if e > 0]
    bottom = [_power(u, -e) for u, e in exponents.items() if e < 0]
    if not top and not bottom:
        return "1"
    text = "·".join(top) if top else "1"
    return text + ("/" + "·".join(bottom) if bottom else "")


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
            label = f"singular region\n(σ_min < {source} = {threshold:.3g})" if (ax is legend_on and k == 0) else None
            ax.axvspan(a, b, color=SHADE_COLOR, alpha=0.22, linewidth=0, label=label)


def _legend(ax: Axes, ncol: int = 1, extra: Sequence[Any] = ()) -> None:
    """The axes' legend (with ``extra`` handles: a second y axis' lines), outside the axes: on
    their right, or above them when a second y axis holds the right side. It never covers data,
    and the constrained layout makes room for it."""
    handles, _ = ax.get_legend_handles_labels()
    handles = [*handles, *extra]
    if not handles:
        return
    if extra:
        ax.legend(handles=handles, loc="lower left", bbox_to_anchor=(0.0, 1.02), borderaxespad=0.0, ncol=4, framealpha=0.9)
    else:
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, ncol=ncol, framealpha=0.9)


def _new(rows: int, title: str) -> tuple[Figure, list[Axes]]:
    fig = mpl().figure.Figure(figsize=FIGSIZE, dpi=DPI, layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0].tolist()
    fig.suptitle(title, fontsize=10)
    axes[-1].set_xlabel("time t [s]")
    return fig, axes


def _title(data: PlanData, what: str) -> str:
    return f"{what} — {data.label}"


# --- plan figures: each draws one plan into its axes (one column of rows) -------------------


def draw_ee_velocity(data: PlanData, axes: Sequence[Axes]) -> None:
    """Desired end-effector linear and angular velocity (mean over each planner step, from the
    stored desired path) and its norm (paper Fig. 4)."""
    ax_v, ax_w = axes
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
    _legend(ax_v)
    _legend(ax_w)


def draw_gjm_determinant(data: PlanData, axes: Sequence[Axes]) -> None:
    """det J_g and the smallest singular value over time (paper Fig. 5), with their units
    (:func:`gjm_units`)."""
    ax_d, ax_s = axes
    n = data.q.shape[1] if data.q.ndim == 2 else 0
    if np.any(np.isfinite(data.det)):
        _line(ax_d, data.t, data.det, label="det J_g", color="C0")
        ax_d.set_ylabel(f"det J_g [{gjm_units(data.prismatic, n)}]")
    else:
        ax_d.text(0.5, 0.5, "det J_g undefined (GJM not square)", transform=ax_d.transAxes, ha="center")
        ax_d.set_ylabel("det J_g")
    ax_d.axhline(0.0, color="k", linewidth=0.6)
    _line(ax_s, data.t, data.sigma_min, label="σ_min(J_g)", color="C1")
    threshold, source = data.threshold
    ax_s.axhline(threshold, color="C3", linestyle="--", linewidth=1, label=f"{source} = {threshold:.3g}")
    ax_s.set_ylabel("σ_min(J_g) [SI, mixed units]")
    ax_s.set_ylim(bottom=0)
    rows = "linear rows in m/rad" + (" (1 at prismatic joints)" if data.prismatic.any() else "")
    ax_d.set_title(
        f"J_g maps joint rates to [v (m/s); ω (rad/s)]: {rows}, angular rows unitless, so det J_g is in "
        f"{gjm_units(data.prismatic, n) if n in (3, 6) else '–'};\nits singular values mix both kinds of rows "
        "(SI numbers, their product |det J_g|)",
        fontsize=7,
        loc="left",
    )
    _shade([ax_d, ax_s], data, legend_on=ax_d)
    _legend(ax_d)
    _legend(ax_s)


def _joint_lines(ax: Axes, data: PlanData, degrees: np.ndarray, si: np.ndarray, unit: str, what: str, **kw: Any) -> list[Any]:
    """One line per joint: revolute joints from ``degrees (N+1, n)`` on ``ax``, prismatic ones
    from ``si (N+1, n)`` (``unit``, m or m/s) on a second y axis labelled ``what``; returns the
    second axis' legend handles (for the one legend)."""
    prismatic = data.prismatic
    for j in np.flatnonzero(~prismatic):
        _line(ax, data.t, degrees[:, j], label=f"joint {j + 1}", color=f"C{j % 10}", **kw)
    if not prismatic.any():
        return []
    ax_m = ax.twinx()
    ax_m.grid(False)
    for j in np.flatnonzero(prismatic):
        _line(ax_m, data.t, si[:, j], label=f"joint {j + 1} [{unit}]", color=f"C{j % 10}", linestyle="--", **kw)
    ax_m.set_ylabel(f"prismatic {what} [{unit}]")
    handles, _ = ax_m.get_legend_handles_labels()
    return list(handles)


def _speed_scale(ax: Axes, speeds_deg_s: np.ndarray, limit: float | None) -> None:
    """A symmetric-log y axis, linear within the speed limit, when the speeds span decades
    beyond it (a linear axis would put the limit on zero); otherwise linear."""
    finite = np.abs(speeds_deg_s[np.isfinite(speeds_deg_s)])
    peak = float(finite.max()) if finite.size else 0.0
    threshold = limit if limit else (peak / 1e3 if peak > 0 else 1.0)
    if peak > SYMLOG_FACTOR * threshold:
        ax.set_yscale("symlog", linthresh=threshold, linscale=1.0)
        # ticks at 0 and the powers of ten beyond the linear range (±1 would overprint 0)
        decades = 10.0 ** np.arange(np.ceil(np.log10(threshold)), np.ceil(np.log10(peak)) + 1)
        ax.yaxis.set_major_locator(mpl().ticker.FixedLocator([*(-decades[::-1]).tolist(), 0.0, *decades.tolist()]))
        ax.yaxis.set_major_formatter(mpl().ticker.FuncFormatter(lambda v, _: f"{v:g}".replace("-", "\u2212")))
        ax.yaxis.set_minor_locator(mpl().ticker.NullLocator())
        ax.set_ylabel(f"joint velocity [deg/s]\n(symmetric log; linear within ±{threshold:.3g})")


def draw_joint_velocities(data: PlanData, axes: Sequence[Axes]) -> None:
    """Joint speeds in deg/s (prismatic joints in m/s) with the speed limit (paper Figs. 6 and 9)."""
    (ax,) = axes
    extra = _joint_lines(ax, data, data.qd_deg_s, data.qd, "m/s", "joint velocity", drawstyle="steps-post")
    limit = data.speed_limit_deg_s
    if limit is not None:
        ax.axhline(limit, color="C3", linestyle="--", linewidth=1, label=f"limit ±{limit:g} deg/s")
        ax.axhline(-limit, color="C3", linestyle="--", linewidth=1)
    ax.set_ylabel("joint velocity [deg/s]")
    _speed_scale(ax, data.qd_deg_s, limit)
    _shade([ax], data, legend_on=ax)
    _legend(ax, extra=extra)


def draw_joint_angles(data: PlanData, axes: Sequence[Axes]) -> None:
    """Joint angles in deg (prismatic joints in m) (paper Fig. 8)."""
    (ax,) = axes
    extra = _joint_lines(ax, data, data.q_deg, data.q, "m", "joint position")
    ax.set_ylabel("joint angle [deg]")
    _shade([ax], data, legend_on=ax)
    _legend(ax, extra=extra)


def _tracking(data: PlanData) -> tuple[np.ndarray, np.ndarray]:
    """Position error components (mm) and attitude error rotation vector (deg), actual minus desired."""
    dp = (data.ee_position - data.ee_position_desired) * 1e3
    R = _rotations(data.ee_quat)
    Rd = _rotations(data.ee_quat_desired)
    dphi = np.degrees(_rotvec(R @ np.swapaxes(Rd, -1, -2)))
    return dp, dphi


def draw_tracking_errors(data: PlanData, axes: Sequence[Axes]) -> None:
    """Position (x, y, z) and attitude errors over time (paper Fig. 11)."""
    ax_p, ax_a = axes
    dp, dphi = _tracking(data)
    for i, axis in enumerate("xyz"):
        _line(ax_p, data.t, dp[:, i], label=f"e_{axis}")
        _line(ax_a, data.t, dphi[:, i], label=f"δφ_{axis}")
    _line(ax_p, data.t, data.position_error * 1e3, label="|e_p|", color="k", linestyle="--")
    _line(ax_a, data.t, np.degrees(data.attitude_error), label="|δφ| (angle)", color="k", linestyle="--")
    ax_p.set_ylabel("position error [mm]")
    ax_a.set_ylabel("attitude error [deg]")
    _shade([ax_p, ax_a], data, legend_on=ax_p)
    _legend(ax_p)
    _legend(ax_a)


def draw_base_motion(data: PlanData, axes: Sequence[Axes]) -> None:
    """Base position drift from its start (mm) and base attitude drift (rotation vector, deg)."""
    ax_p, ax_a = axes
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
    _legend(ax_p)
    _legend(ax_a)


def damping_groups(damping: np.ndarray) -> list[list[int]]:
    """The singular directions (columns of ``damping (N+1, m)``) grouped by equal damping over
    the whole plan, in order: directions never damped form one group, a constant damping of
    every direction (DLS) another, so equal curves are drawn once."""
    groups: list[list[int]] = []
    for i in range(damping.shape[1]):
        for group in groups:
            if np.allclose(damping[:, i], damping[:, group[0]], rtol=1e-9, atol=1e-12, equal_nan=True):
                group.append(i)
                break
        else:
            groups.append([i])
    return groups


def _directions(group: Sequence[int]) -> str:
    names = [f"λ_{i + 1}" for i in group]
    if len(names) > 2 and list(group) == list(range(group[0], group[-1] + 1)):
        return f"{names[0]}…{names[-1]}"
    return ", ".join(names)


def draw_damping(data: PlanData, axes: Sequence[Axes]) -> None:
    """The effective damping per singular direction applied at each step (0 = undamped), equal
    curves drawn once (:func:`damping_groups`); direction i is that of the i-th largest singular
    value, so the last one is σ_min's. The damping has the units of the singular values."""
    ax_l, ax_s = axes
    m = data.damping.shape[1]
    for k, group in enumerate(damping_groups(data.damping)):
        series = data.damping[:, group[0]]
        names = _directions(group)
        if np.all(np.nan_to_num(series) == 0.0):
            label = f"{names} = 0 (never damped)"
            _line(ax_l, data.t, series, label=label, color="0.45", linestyle=":", drawstyle="steps-post")
            continue
        if len(group) == m and m > 1:
            label = f"{names} (every direction)"
        elif group == [m - 1]:
            label = f"{names} (σ_min's direction)"
        else:
            label = names
        _line(ax_l, data.t, series, label=label, color=f"C{k % 10}", drawstyle="steps-post")
    ax_l.set_ylabel("damping λ_i [as σ]")
    _line(ax_s, data.t, data.sigma_min, label="σ_min(J_g)", color="C1")
    threshold, source = data.threshold
    ax_s.axhline(threshold, color="C3", linestyle="--", linewidth=1, label=f"{source} = {threshold:.3g}")
    ax_s.set_ylabel("σ_min(J_g) [SI, mixed units]")
    ax_s.set_ylim(bottom=0)
    _shade([ax_l, ax_s], data, legend_on=ax_s)
    _legend(ax_l)
    _legend(ax_s)


def _no_dynamics(ax: Axes) -> None:
    ax.text(
        0.5, 0.5, "no dynamics (a diverged plan, or stored before torques were computed)", transform=ax.transAxes, ha="center"
    )


def _effort_limits(ax: Axes, joints: np.ndarray, limit: np.ndarray, unit: str) -> None:
    """Dashed ±limit lines, one pair per distinct limit of ``joints`` (labelled with them)."""
    finite = [j for j in joints if np.isfinite(limit[j])]
    for k, value in enumerate(sorted({float(limit[j]) for j in finite})):
        which = ", ".join(str(j + 1) for j in finite if limit[j] == value)
        dashes = (0, (4, 2 + 2 * k))
        ax.axhline(value, color="C3", linestyle=dashes, linewidth=1, label=f"limit ±{value:g} {unit} (joint {which})")
        ax.axhline(-value, color="C3", linestyle=dashes, linewidth=1)


def draw_joint_torques(data: PlanData, axes: Sequence[Axes]) -> None:
    """Joint torques along the executed trajectory (N m; prismatic joints' forces in N on a second
    axis) with each joint's limit, and how much of its limit each joint uses (%)."""
    ax, use = axes
    dyn = data.dynamics
    if not dyn.known:
        _no_dynamics(ax)
    else:
        _joint_lines(ax, data, dyn.tau, dyn.tau, "N", "joint force")
        _effort_limits(ax, np.flatnonzero(~data.prismatic), dyn.limit, "N m")
    ax.set_ylabel("joint torque [N m]")
    if np.any(np.isfinite(dyn.limit)):
        with np.errstate(invalid="ignore", divide="ignore"):
            share = 100.0 * np.abs(dyn.tau) / dyn.limit
        for j in np.flatnonzero(np.isfinite(dyn.limit)):
            _line(use, data.t, share[:, j], label=f"joint {j + 1}", color=f"C{j % 10}")
        use.axhline(100.0, color="C3", linestyle="--", linewidth=1, label="the limit")
        _legend(use, 3)
    else:
        use.text(0.5, 0.5, "no joint has an effort limit", transform=use.transAxes, ha="center")
    use.set_ylabel("|torque| / limit [%]")
    use.set_ylim(bottom=0)
    _shade(axes, data, legend_on=ax)
    _legend(ax, 2)


def draw_carrier_wrench(data: PlanData, axes: Sequence[Axes]) -> None:
    """The wrench the arm exerts on the carrier at joint 1 (carrier frame): force (N) and torque
    about joint 1's origin (N m), components and norms."""
    ax_f, ax_t = axes
    dyn = data.dynamics
    if not dyn.known:
        _no_dynamics(ax_f)
    for ax, values, symbol in ((ax_f, dyn.force, "F"), (ax_t, dyn.torque, "T")):
        for i, axis in enumerate("xyz"):
            _line(ax, data.t, values[:, i], label=f"{symbol}_{axis}")
        _line(ax, data.t, np.linalg.norm(values, axis=1), label=f"|{symbol}|", color="k", linestyle="--")
    ax_f.set_ylabel("force [N]")
    ax_t.set_ylabel("torque about joint 1 [N m]")
    _shade([ax_f, ax_t], data, legend_on=ax_f)
    _legend(ax_f, 2)
    _legend(ax_t, 2)


def draw_clearance(data: PlanData, axes: Sequence[Axes]) -> None:
    """The smallest distance between the checked pairs of shapes at each sample (mm), with the
    task's clearance and the avoidance's influence distance; the closest approach over the plan
    (samples and between them) marked with its pair."""
    (ax,) = axes
    ax.set_ylabel("distance [mm]")
    if data.clearance is None:
        ax.text(0.5, 0.5, "no collision geometry (no shapes on the robot)", transform=ax.transAxes, ha="center")
        return
    _line(ax, data.t, data.clearance * 1e3, label="smallest distance of any pair", color="C0")
    task = data.request.get("task") or {}
    clearance = float(task.get("clearance_m") or 0.0)
    influence = float((task.get("scene") or {}).get("influence_distance_m") or 0.1)
    ax.axhline(clearance * 1e3, color="C3", linewidth=1.0, label=f"clearance {clearance * 1e3:.3g} mm")
    ax.axhline(influence * 1e3, color="0.5", linewidth=0.8, linestyle=":", label=f"influence distance {influence * 1e3:.3g} mm")
    t_min, d_min = data.metrics.get("t_min_clearance_s"), data.metrics.get("min_clearance_m")
    pair = data.metrics.get("min_clearance_pair")
    if t_min is not None and d_min is not None:
        names = " and ".join(pair) if pair else "?"
        ax.plot([t_min], [d_min * 1e3], marker="v", color="C3", linestyle="none", label=f"closest: {names}, {d_min * 1e3:.3g} mm")
    _legend(ax)


def draw_robustness(data: PlanData, axes: Sequence[Axes]) -> None:
    """The nominal plan's position and attitude errors with the band of the sampled robots
    (smallest to largest over the samples, median dashed), open loop and closed loop."""
    position, attitude = axes
    position.set_ylabel("position error [mm]")
    attitude.set_ylabel("attitude error [deg]")
    if not data.robust_bands:
        position.text(0.5, 0.5, "planned without uncertainty (no sampled robots)", transform=position.transAxes, ha="center")
        return
    for ax, nominal, index, scale in (
        (position, data.position_error, 0, 1e3),
        (attitude, data.attitude_error, 1, np.degrees(1.0)),
    ):
        for (loop, bands), color in zip(data.robust_bands.items(), ("C1", "C2"), strict=False):
            band = np.where(np.isfinite(bands[index]), bands[index], np.nan) * scale
            ax.fill_between(data.t, band[:, 0], band[:, 2], color=color, alpha=0.25, linewidth=0, label=f"{loop} loop: samples")
            _line(ax, data.t, band[:, 1], color=color, linestyle="--", label=f"{loop} loop: median")
        _line(ax, data.t, nominal * scale, color="C0", label="nominal plan")
        _legend(ax)


SCENE_INSTANTS = 5
#: The carrier's drift is drawn magnified to this fraction of the scene's size (and labelled so).
DRIFT_SCENE_FRACTION = 0.15
#: The scene's ticks: at most this many intervals on its longest axis, fewer on shorter ones.
SCENE_TICKS = 6


def _stride(n: int, max_points: int = MAX_POINTS) -> np.ndarray:
    """Indices of at most ``max_points`` evenly strided samples of ``n`` (first and last kept)."""
    if n <= max_points:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(int))


def arm_frames(data: PlanData, count: int = SCENE_INSTANTS) -> tuple[np.ndarray, list[np.ndarray]]:
    """Sample indices ``(K,)`` and the arm at ``K`` (at most ``count``) evenly spread finite
    samples: each ``(n + 2, 3)`` points base CoM, joints 1..n, end effector (m, world), from the
    plan's joint angles and base pose and the robot's forward kinematics
    (:func:`engine.kinematics.kinematics_batch`, one batch). Empty without the robot."""
    empty: tuple[np.ndarray, list[np.ndarray]] = (np.zeros(0, dtype=int), [])
    if not data.robot or data.q.size == 0:
        return empty
    try:
        model = RobotModel.from_dict(data.robot)
    except (ParameterError, KeyError, TypeError, ValueError):
        return empty
    R = _rotations(data.base_quat)
    finite = np.flatnonzero(
        np.all(np.isfinite(data.q), axis=1)
        & np.all(np.isfinite(data.base_position), axis=1)
        & np.all(np.isfinite(R), axis=(1, 2))
    )
    if finite.size == 0 or data.q.shape[1] != model.n_joints:
        return empty
    index = finite[np.unique(np.linspace(0, finite.size - 1, min(count, finite.size)).round().astype(int))]
    kin = kinematics_batch(model, data.q[index], R[index], data.base_position[index])
    lines = [
        np.concatenate([data.base_position[k][None], kin.joint_positions[i], kin.ee_position[i][None]])
        for i, k in enumerate(index)
    ]
    return index, lines


def arm_polylines(data: PlanData, count: int = SCENE_INSTANTS) -> tuple[np.ndarray, list[np.ndarray]]:
    """Times ``(K,)`` and the arm's polylines at them (:func:`arm_frames`)."""
    index, lines = arm_frames(data, count)
    return data.t[index], lines


#: Draw order of the scene (fixed, not by depth): the arm under the paths it is meant to show.
SCENE_ZORDER = {"arm": 2, "carrier": 3, "desired": 5, "achieved": 6}


def draw_scene(ax: Any, data: PlanData) -> None:
    """The counterpart of the paper's Fig. 10 on a 3D axes: the desired and achieved
    end-effector paths drawn over the arm (links through base CoM, joints and end effector at a
    few instants), and the carrier's CoM drift, magnified (the factor is in the legend) since it
    is millimetres. Metres are metres on every axis; shorter axes get fewer ticks."""
    ax.computed_zorder = False  # mplot3d's depth sort would bury the paths under the links
    idx = _stride(len(data.t))
    desired, achieved = data.ee_position_desired[idx], data.ee_position[idx]
    times, arms = arm_polylines(data)
    for k, (t, arm) in enumerate(zip(times, arms, strict=True)):
        shade = 0.3 + 0.5 * k / max(1, len(arms) - 1)
        ax.plot(
            *arm.T,
            color=(0.25, 0.25, 0.3, shade),
            linewidth=1.6,
            marker="o",
            markersize=2.5,
            label=f"arm at t = {t:.3g} s",
            zorder=SCENE_ZORDER["arm"],
        )
    ax.plot(*desired.T, color="C0", linewidth=4.0, alpha=0.5, label="desired end-effector path", zorder=SCENE_ZORDER["desired"])
    ax.plot(*achieved.T, color="C1", linewidth=1.3, label="achieved end-effector path", zorder=SCENE_ZORDER["achieved"])
    drawn = [shape for shape in data.obstacles if shape is not None]
    for i, shape in enumerate(drawn):
        for k, segment in enumerate(shape_outline(shape)):
            ax.plot(*segment.T, color="C4", linewidth=0.7, alpha=0.8, label="obstacles" if i == 0 and k == 0 else None, zorder=1)
    missing = [f"obstacle{i}" for i, shape in enumerate(data.obstacles) if shape is None]
    if missing:  # an empty line whose legend entry says what is not drawn (at most three named)
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        ax.plot([], [], [], color="none", label=f"not drawn (mesh deleted since): {', '.join(missing[:3])}{more}")
    closest = closest_pair(data)
    if closest is not None:
        points_ab, label = closest
        ax.plot(*points_ab.T, color="C3", linewidth=2.0, marker="x", label=label, zorder=SCENE_ZORDER["achieved"] + 1)
    outlines = [seg for shape in drawn for seg in shape_outline(shape)]
    points = [p for p in (desired, achieved, *arms, *outlines) if p.size]
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
            zorder=SCENE_ZORDER["carrier"],
        )
        ax.scatter(*base[0], color="C2", marker="s", s=30, label="carrier CoM at t = 0", zorder=SCENE_ZORDER["carrier"])
        cloud = np.concatenate([cloud, path]) if cloud.shape[0] else path
    if cloud.shape[0]:
        low, high = cloud.min(axis=0), cloud.max(axis=0)
        span = np.maximum(high - low, 1e-3 * max(1.0, float((high - low).max())))
        pad = 0.04 * span.max()
        low, span = low - pad, span + 2 * pad
        for axis, extent in zip((ax.xaxis, ax.yaxis, ax.zaxis), span, strict=True):
            axis.set_major_locator(
                mpl().ticker.MaxNLocator(nbins=max(2, round(SCENE_TICKS * extent / span.max())), steps=[1, 2, 2.5, 5, 10])
            )
        ax.set_xlim(low[0], low[0] + span[0])
        ax.set_ylim(low[1], low[1] + span[1])
        ax.set_zlim(low[2], low[2] + span[2])
        # true proportions, drawn a little smaller than the axes so the labels stay inside the figure
        ax.set_box_aspect(tuple(span), zoom=0.85)
    ax.tick_params(labelsize=7, pad=1)
    ax.set_xlabel("x [m]", labelpad=4)
    ax.set_ylabel("y [m]", labelpad=4)
    ax.set_zlabel("z [m]", labelpad=4)


def _body_shapes(model: RobotModel) -> list[tuple[str, int, Shape]]:
    out = [("carrier", 0, shape) for shape in model.base.shapes]
    for i, link in enumerate(model.links):
        out += [(link.name, i + 1, shape) for shape in link.shapes]
    return out


def closest_pair(data: PlanData) -> tuple[np.ndarray, str] | None:
    """The closest points ``(2, 3)`` m of the plan's closest pair at the sample nearest its
    time, and a label; None without geometry or robot. Placed by the engine's forward
    kinematics (bodies' CoMs and attitudes) and distances (:func:`engine.geometry.distance`)."""
    pair, t_min = data.metrics.get("min_clearance_pair"), data.metrics.get("t_min_clearance_s")
    if not pair or t_min is None or not data.robot or data.q.size == 0:
        return None
    try:
        model = RobotModel.from_dict(data.robot)
    except (ParameterError, KeyError, TypeError, ValueError):
        return None
    k = int(np.argmin(np.abs(data.t - float(t_min))))
    R = _rotations(data.base_quat[k : k + 1])
    if not (np.all(np.isfinite(data.q[k])) and np.all(np.isfinite(R))) or data.q.shape[1] != model.n_joints:
        return None
    kin = kinematics_batch(model, data.q[k : k + 1], R, data.base_position[k : k + 1])
    poses = {body: (kin.body_attitudes[0, body], kin.body_com[0, body]) for body in range(model.n_joints + 1)}
    owners: dict[str, list[tuple[Shape, tuple[np.ndarray, np.ndarray] | None]]] = {}
    for name, body, shape in _body_shapes(model):
        owners.setdefault(name, []).append((shape, poses[body]))
    for i, obstacle in enumerate(data.obstacles):
        if obstacle is not None:
            owners.setdefault(f"obstacle{i}", []).append((obstacle, None))
    if pair[0] not in owners or pair[1] not in owners:
        return None
    best = min(
        (distance(a, b, pose_a, pose_b) for a, pose_a in owners[pair[0]] for b, pose_b in owners[pair[1]]),
        key=lambda d: d.distance,
    )
    return best.points, f"closest pair at t = {data.t[k]:.3g} s: {pair[0]} and {pair[1]}, {best.distance * 1e3:.3g} mm"


def fig_scene_3d(data: PlanData) -> Figure:
    """:func:`draw_scene` of one plan, its legend on the right."""
    fig = mpl().figure.Figure(figsize=(9.0, 6.4), dpi=DPI, layout="constrained")
    ax = fig.add_subplot(projection="3d")
    fig.suptitle(_title(data, "3D view: end-effector path, arm and carrier"), fontsize=10)
    draw_scene(ax, data)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside right center", fontsize=7, framealpha=0.9)
    return fig


@dataclass(frozen=True)
class PlanFigure:
    """A plan figure: its heading, its caption on the plan page (with the paper's figure), its
    rows of time axes and how one plan is drawn into them (``rows == 0``: the 3D scene)."""

    heading: str
    caption: str
    rows: int
    draw: Callable[[PlanData, Sequence[Axes]], None]


PLAN_FIGURE_SPECS: dict[str, PlanFigure] = {
    "ee-velocity": PlanFigure("Desired end-effector velocity", "Desired end-effector velocity (Fig. 4)", 2, draw_ee_velocity),
    "gjm-determinant": PlanFigure(
        "Generalized Jacobian: determinant and smallest singular value",
        "det J_g and smallest singular value (Fig. 5)",
        2,
        draw_gjm_determinant,
    ),
    "joint-velocities": PlanFigure("Joint velocities", "Joint velocities (Figs. 6, 9)", 1, draw_joint_velocities),
    "joint-angles": PlanFigure("Joint angles", "Joint angles (Fig. 8)", 1, draw_joint_angles),
    "tracking-errors": PlanFigure("End-effector tracking errors", "Tracking errors (Fig. 11)", 2, draw_tracking_errors),
    "base-motion": PlanFigure("Base motion (drift from the initial pose)", "Base motion", 2, draw_base_motion),
    "damping": PlanFigure("Damping applied per step", "Damping", 2, draw_damping),
    "joint-torques": PlanFigure("Joint torques (executed trajectory)", "Joint torques and their limits", 2, draw_joint_torques),
    "carrier-wrench": PlanFigure(
        "Wrench on the carrier at joint 1 (carrier frame)", "Wrench on the carrier", 2, draw_carrier_wrench
    ),
    "clearance": PlanFigure("Clearance: smallest distance between shapes", "Clearance over time", 1, draw_clearance),
    "robustness": PlanFigure(
        "Tracking errors on the sampled robots (uncertainty)", "Robustness: errors of the sampled robots", 2, draw_robustness
    ),
    "scene-3d": PlanFigure(
        "3D view: end-effector path, arm and carrier", "3D view: path, arm and carrier (Fig. 10)", 0, lambda d, a: None
    ),
}


def _time_figure(name: str) -> Callable[[PlanData], Figure]:
    spec = PLAN_FIGURE_SPECS[name]

    def make(data: PlanData) -> Figure:
        fig, axes = _new(spec.rows, _title(data, spec.heading))
        spec.draw(data, axes)
        return fig

    make.__doc__ = spec.draw.__doc__
    return make


PLAN_FIGURES: dict[str, Callable[[PlanData], Figure]] = {
    name: fig_scene_3d if spec.rows == 0 else _time_figure(name) for name, spec in PLAN_FIGURE_SPECS.items()
}
FIGURE_TITLES = {name: spec.caption for name, spec in PLAN_FIGURE_SPECS.items()}
JOB_FIGURES = ("convergence",)
#: Every plan figure compares plans: side by side, one column per plan with shared y axes, but
#: tracking errors and joint torques overlay the plans on one set of axes.
COMPARE_FIGURES = tuple(PLAN_FIGURES)


def _column_title(data: PlanData) -> str:
    return f"{data.label} [{data.id[:8]}]"


def fig_compare_tracking(plans: Sequence[PlanData]) -> Figure:
    """Position and attitude error norms of several plans on one figure (DLS versus GA-tuned)."""
    fig, (ax_p, ax_a) = _new(2, "Tracking errors compared")
    for k, data in enumerate(plans):
        label = _column_title(data)
        _line(ax_p, data.t, data.position_error * 1e3, label=label, color=f"C{k % 10}")
        _line(ax_a, data.t, np.degrees(data.attitude_error), label=label, color=f"C{k % 10}")
    ax_p.set_ylabel("position error |e_p| [mm]")
    ax_a.set_ylabel("attitude error |δφ| [deg]")
    _legend(ax_p)
    _legend(ax_a)
    return fig


def fig_compare(plans: Sequence[PlanData], name: str) -> Figure:
    """The figure ``name`` of several plans side by side (one column each, titled by the plan's
    method and id), y axes shared along each row so the plans read on one scale, one legend on
    the right of the last column; ``tracking-errors`` overlays the error norms instead."""
    if name in COMPARE_OVERLAYS:
        return COMPARE_OVERLAYS[name](plans)
    spec = PLAN_FIGURE_SPECS[name]
    k = len(plans)
    if spec.rows == 0:
        fig = mpl().figure.Figure(figsize=(4.6 * k, 6.4), dpi=DPI, layout="constrained")
        fig.suptitle(f"{spec.heading} compared", fontsize=10)
        scenes = [fig.add_subplot(1, k, c + 1, projection="3d") for c in range(k)]
        for ax, data in zip(scenes, plans, strict=True):
            draw_scene(ax, data)
            ax.set_title(_column_title(data), fontsize=8)
            # a legend under each scene: the instants and the drift's magnification are the plan's own
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=2, fontsize=6.5, framealpha=0.9)
        return fig
    fig = mpl().figure.Figure(figsize=(3.6 * k + 2.8, 2.5 * spec.rows + 1.0), dpi=DPI, layout="constrained")
    fig.suptitle(f"{spec.heading} compared", fontsize=10)
    grid = fig.subplots(spec.rows, k, sharex="col", sharey="row", squeeze=False)
    for c, data in enumerate(plans):
        column = grid[:, c].tolist()
        spec.draw(data, column)
        threshold, source = data.threshold
        column[0].set_title(f"{_column_title(data)}\nshaded: σ_min < {source} = {threshold:.3g}", fontsize=8)
        column[-1].set_xlabel("time t [s]")
    for row in grid:
        # a row shares its y axis: the longest label says the most (e.g. that the axis is symmetric-log)
        label = max((ax.get_ylabel() for ax in row), key=len)
        for c, ax in enumerate(row):
            ax.set_ylabel(label if c == 0 else "")
            legend = ax.get_legend()
            if legend is None:
                continue
            if c < k - 1:
                legend.remove()
                continue
            for text in legend.get_texts():
                if text.get_text().startswith("singular region"):
                    text.set_text("singular region\n(threshold in each title)")
    return fig


def _objective_unit(objective: dict[str, Any] | None) -> str:
    """What B is made of, for an axis label: the position term in m plus the attitude term, m*rad
    for eq. 18 as printed (the default) or rad for the rotation angle."""
    term = (objective or {}).get("attitude_term")
    if term == "eq18":
        return "objective B [w1·m + w2·m·rad (eq. 18)]"
    if term == "angle":
        return "objective B [w1·m + w2·rad (angle)]"
    return "objective B [w1·m + w2·attitude term]"


def fig_compare_torques(plans: Sequence[PlanData]) -> Figure:
    """Several plans' joint torques (forces) overlaid, one panel per joint, with its limit. A
    panel whose joint is revolute in some plans and prismatic in others draws the forces (N) on
    a second y axis, dashed, beside the torques (N m)."""
    count = max((data.q.shape[1] for data in plans), default=1)
    fig = mpl().figure.Figure(figsize=(FIGSIZE[0], max(FIGSIZE[1], 1.25 * count + 1.0)), dpi=DPI, layout="constrained")
    axes = fig.subplots(count, 1, sharex=True, squeeze=False)[:, 0].tolist()
    fig.suptitle("Joint torques compared (executed trajectories)", fontsize=10)
    axes[-1].set_xlabel("time t [s]")
    for j, ax in enumerate(axes):
        at = [(k, d) for k, d in enumerate(plans) if j < d.q.shape[1]]
        kinds = sorted({bool(d.prismatic[j]) for _, d in at})
        # one y axis per unit: the first kind's on the panel, the other's (forces) on a second one
        axis_of = {kind: ax if kind == kinds[0] else ax.twinx() for kind in kinds}
        for kind, on in axis_of.items():
            unit = "N" if kind else "N m"
            mixed = on is not ax
            for k, data in at:
                if bool(data.prismatic[j]) == kind:
                    style = {"linestyle": "--"} if mixed else {}
                    _line(on, data.t, data.dynamics.tau[:, j], color=f"C{k % 10}", **style)
            limits = {
                float(d.dynamics.limit[j]) for _, d in at if bool(d.prismatic[j]) == kind and np.isfinite(d.dynamics.limit[j])
            }
            for value in sorted(limits):
                on.axhline(value, color="C3", linestyle="--", linewidth=1)
                on.axhline(-value, color="C3", linestyle="--", linewidth=1)
            if mixed:
                on.grid(False)
                on.set_ylabel(f"prismatic, dashed [{unit}]")
            else:
                ax.set_ylabel(f"joint {j + 1} [{unit}]")
    for k, data in enumerate(plans):  # the legend's entries on the first panel, whichever axis a plan's lines are on
        axes[0].plot([], [], color=f"C{k % 10}", label=f"{data.label} [{data.id[:8]}]")
    if limits_drawn := any(np.isfinite(d.dynamics.limit).any() for d in plans):
        axes[0].plot([], [], color="C3", linestyle="--", linewidth=1, label="the joint's limit")
    _legend(axes[0], 2 if limits_drawn else 1)
    return fig


#: The compared figures drawn as one overlay of the plans rather than side by side.
COMPARE_OVERLAYS: dict[str, Callable[[Sequence[PlanData]], Figure]] = {
    "tracking-errors": fig_compare_tracking,
    "joint-torques": fig_compare_torques,
}


def fig_convergence(job: dict[str, Any]) -> Figure:
    """Best-so-far and mean objective B per generation (paper Fig. 7), one pair of curves per GA
    phase (the tuned method and the DLS baseline), from the job's generation rows (``history``:
    ``phase``, ``role``, ``generation``, ``best``, ``mean`` each), written as each generation ends;
    a finished job without them falls back to its result's history. The y label names the job's
    attitude term (``objective``: its request's objective settings)."""
    history = _job_history(job)
    fig = mpl().figure.Figure(figsize=(9.0, 4.4), dpi=DPI, layout="constrained")
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
    ax.xaxis.set_major_locator(mpl().ticker.MaxNLocator(integer=True))
    ax.set_xlabel("generation")
    ax.set_ylabel(_objective_unit(job.get("objective")))
    _legend(ax)
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
        label = {"dls_baseline": "DLS baseline", "bounded_baseline": "bounded inverse"}.get(str(r.get("role")), name)
        out.setdefault(label, []).append(r)
    if not out and job.get("result"):
        method = str(job.get("method") or "GA")
        out[method] = list((job.get("result") or {}).get("history") or [])
    return out


# --- rendering and the cache ----------------------------------------------------------------


def render(fig: Figure, fmt: str, dpi: float | None = None) -> bytes:
    """``fig`` as ``fmt`` (:data:`RENDER_FORMATS`) at ``dpi`` (default :data:`DPI`: the PNG's
    pixels per inch, and the resolution of a vector figure's raster parts). Reproducible: no
    dates in SVG or PDF."""
    if fmt not in RENDER_FORMATS:
        raise ValueError(f"unknown format {fmt!r}")
    metadata = {"svg": {"Date": None}, "pdf": {"CreationDate": None, "ModDate": None}}.get(fmt)
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi or DPI, metadata=metadata)
    return buf.getvalue()


def render_plan_figure(data: PlanData, name: str, fmt: str = "svg", dpi: float | None = None) -> bytes:
    return render(PLAN_FIGURES[name](data), fmt, dpi)


def render_compare_figure(
    data: Sequence[PlanData], fmt: str = "svg", dpi: float | None = None, *, name: str = "tracking-errors"
) -> bytes:
    """The plan figure ``name`` of several plans on one figure (:func:`fig_compare`)."""
    return render(fig_compare(data, name), fmt, dpi)


def render_job_figure(job: dict[str, Any], fmt: str = "svg", dpi: float | None = None) -> bytes:
    return render(fig_convergence(job), fmt, dpi)


def _cell_edges(values: np.ndarray, log: bool) -> np.ndarray:
    """Edges of the cells centred on ``values`` (midpoints, in log space on a log axis)."""
    v = np.log10(values) if log else values
    mid = (v[1:] + v[:-1]) / 2.0
    edges = np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])
    out: np.ndarray = 10.0**edges if log else edges
    return out


def cells_path(xe: np.ndarray, ye: np.ndarray, mask: np.ndarray) -> matplotlib.path.Path:
    """One path of the cells where ``mask (len(xe) - 1, len(ye) - 1)`` is true: a rectangle per
    run of neighbouring cells along x, all in one path, so a hatch over it is one continuous
    pattern (a hatch per cell shows stripes where the cells meet, and seams in SVG)."""
    vertices: list[tuple[float, float]] = []
    codes: list[int] = []
    P = mpl().path.Path
    move, line, close = int(P.MOVETO), int(P.LINETO), int(P.CLOSEPOLY)
    for j in range(mask.shape[1]):
        column = np.concatenate([[False], mask[:, j], [False]]).astype(np.int8)
        starts = np.flatnonzero(np.diff(column) == 1)
        stops = np.flatnonzero(np.diff(column) == -1)
        for a, b in zip(starts, stops, strict=True):
            x0, x1, y0, y1 = xe[a], xe[b], ye[j], ye[j + 1]
            vertices += [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
            codes += [move, line, line, line, close]
    if not vertices:
        return P(np.zeros((0, 2)))
    return P(np.array(vertices), codes)


def fig_landscape(data: dict[str, Any]) -> Figure:
    """log10 B over two parameters (x along the horizontal axis), the infeasible region hatched
    grey, the grid's best cell, and from a tuning job its GA optimum and the contour
    ``B = B(tuned DLS)`` (inside it the method beats the tuned DLS). The heatmap is one raster
    image even in SVG and PDF (no seams between cells; it follows the ``dpi``) and the
    infeasible cells one hatched path (:func:`cells_path`). ``objective``: the request's
    objective settings, for the colour bar's units."""
    grids = data["grids"]
    x, y = np.asarray(grids["x"], dtype=float), np.asarray(grids["y"], dtype=float)
    b = np.asarray(grids["objective_b"], dtype=float)
    feasible = np.asarray(grids["feasible"], dtype=float) > 0.5
    x_log, y_log = data.get("x_scale") == "log", data.get("y_scale") == "log"
    fig = mpl().figure.Figure(figsize=(8.0, 6.0), dpi=DPI, layout="constrained")
    ax = fig.subplots()
    xe, ye = _cell_edges(x, x_log), _cell_edges(y, y_log)
    shown = np.where(feasible & (b > 0), np.log10(np.where(b > 0, b, 1.0)), np.nan)
    mesh = ax.pcolormesh(xe, ye, shown.T, cmap="viridis", shading="flat", rasterized=True, antialiased=False)
    colorbar = fig.colorbar(mesh, ax=ax, label="log10 " + _objective_unit(data.get("objective")).removeprefix("objective "))
    if colorbar.solids is not None:
        colorbar.solids.set_rasterized(True)
    infeasible = mpl().patches.PathPatch(
        cells_path(xe, ye, ~feasible), facecolor="0.82", edgecolor="0.45", linewidth=0.0, hatch="///"
    )
    infeasible.set_label("infeasible (speed limit or diverged)")
    ax.add_patch(infeasible)
    handles: list[Any] = [infeasible]
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
            handles.append(mpl().lines.Line2D([], [], color="white", linestyle="--", label=f"B of the tuned DLS ({_fmt(dls_b)})"))
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
    ax.set_xlim(xe[0], xe[-1])
    ax.set_ylim(ye[0], ye[-1])
    ax.set_xlabel(xn)
    ax.set_ylabel(yn)
    ax.grid(False)
    fixed = ", ".join(f"{k} = {_fmt(v)}" for k, v in (data.get("fixed") or {}).items())
    fig.suptitle(
        f"Objective landscape — {data.get('method')} ({x.size} x {y.size} cells{'; ' + fixed if fixed else ''})", fontsize=10
    )
    # below the axes: the marks are white (for the dark map), so the legend keeps a dark face
    fig.legend(
        handles=handles, loc="outside lower center", ncol=2, fontsize=8, facecolor="0.3", labelcolor="white", framealpha=0.9
    )
    return fig


def render_landscape_figure(data: dict[str, Any], fmt: str = "svg", dpi: float | None = None) -> bytes:
    return render(fig_landscape(data), fmt, dpi)


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

    def discard_where(self, drop: Callable[[tuple[Any, ...]], bool]) -> None:
        """Forget the figures whose key ``drop`` says."""
        with self._lock:
            for key in [key for key in self._data if drop(key)]:
                self._bytes -= len(self._data.pop(key))

    def __len__(self) -> int:
        return len(self._data)


CACHE = LRUCache()

DATA_CACHE_PLANS = 4  # decoded plans kept for rendering their other figures (a 20,000-step plan is ~8 MB)
_DATA: Lru[str, PlanData] = Lru(DATA_CACHE_PLANS)


def plan_data(plan_id: str, load: Callable[[], PlanData]) -> PlanData:
    """The decoded arrays of a plan, from a small LRU (decoding a long plan's JSON costs more
    than drawing one figure, and a plan page asks for all of them at once)."""
    return _DATA.get(plan_id, load)


def forget_obstacles() -> None:
    """A stored mesh was deleted: forget this process's decoded plans (their obstacles are read
    with them) and its rendered scene figures, the one kind that draws obstacles, so that they
    are drawn again without it (and say so). Other API processes keep theirs until they drop
    them (a few plans; figures as the LRU turns over)."""
    _DATA.clear()
    CACHE.discard_where(lambda key: "scene-3d" in key)


def cached(key: tuple[Any, ...], make: Callable[[], bytes]) -> tuple[bytes, bool]:
    """``(bytes, hit)``; renders with ``make`` on a miss."""
    value = CACHE.get(key)
    if value is not None:
        return value, True
    value = make()
    CACHE.put(key, value)
    return value, False
