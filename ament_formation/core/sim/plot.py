"""The run figure, like the paper's Fig. 4 (matplotlib, Agg canvas; no pyplot global state).

(a) phase portrait x-y: each robot's path of p with orientation arrows at intervals, thick segments
    while it avoids, start (o) and end (s) markers, the leaders' references dashed; every
    obstacle's P (filled), L (dashed) and Q (dotted) ellipses (spec S6.1), drawn at a few instants
    for moving or rotating obstacles;
(b) wheel torques tau_1 (left) and tau_2 (right) vs time per robot, the limit +-tau_max dashed and
    the avoidance intervals shaded.
"""

from __future__ import annotations

import math
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse
import numpy as np

from ament_formation.core.sim.metrics import intervals
from ament_formation.core.sim.trajectory import SimResult

_COLORS = (
    'tab:blue',
    'tab:orange',
    'tab:green',
    'tab:red',
    'tab:purple',
    'tab:brown',
    'tab:pink',
    'tab:olive',
    'tab:cyan',
    'tab:gray',
)


def _obstacle_instants(result: SimResult, j: int, count: int) -> list[int]:
    """Sample indices at which obstacle j is drawn: one if it never moves, else ``count``
    spread.
    """
    c = result.obstacle_center_m[:, j]
    phi = result.obstacle_phi_rad[:, j]
    moving = np.ptp(c[:, 0]) + np.ptp(c[:, 1]) > 1e-6 or np.ptp(phi) > 1e-6
    n_t = len(result.t_s)
    if not moving or n_t < 2:
        return [0]
    return sorted(set(np.linspace(0, n_t - 1, count).round().astype(int).tolist()))


def _ellipse(center, phi, axes, scale, **kw) -> Ellipse:
    return Ellipse(
        tuple(center), 2 * axes[0] * scale, 2 * axes[1] * scale, angle=math.degrees(phi), **kw
    )


def _limits(result: SimResult, axes_by_name: dict, kappa: float):
    """X and y limits around every trajectory and every drawn Q ellipse, with a margin."""
    pts = [result.state[:, :, :2].reshape(-1, 2)]
    for j, name in enumerate(result.obstacle_names):
        reach = kappa * max(axes_by_name[name])
        c = result.obstacle_center_m[:, j]
        pts.append(np.concatenate([c - reach, c + reach]))
    allp = np.concatenate(pts)
    allp = allp[np.all(np.isfinite(allp), axis=1)]
    if len(allp) == 0:
        return (-1.0, 1.0), (-1.0, 1.0)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.04 * max(hi - lo) + 0.05
    return (lo[0] - pad, hi[0] + pad), (lo[1] - pad, hi[1] + pad)


def _figure_layout(n: int, xlim, ylim, dpi: int):
    """The figure: the phase portrait across the top, torque panels below in two columns.

    Returns (figure, portrait axes, torque grid, columns of the torque grid).
    """
    width_in = 14.0
    portrait_in = float(
        np.clip(0.78 * width_in * (ylim[1] - ylim[0]) / (xlim[1] - xlim[0]), 4.0, 9.0)
    )
    cols = 1 if n <= 1 else 2
    rows = max(1, math.ceil(n / cols))
    fig = Figure(figsize=(width_in, portrait_in + 1.9 * rows + 0.6), dpi=dpi)
    FigureCanvasAgg(fig)
    outer = fig.add_gridspec(2, 1, height_ratios=(portrait_in, 1.9 * rows), hspace=0.16)
    ax = fig.add_subplot(outer[0])
    tgrid = outer[1].subgridspec(rows, cols, hspace=0.45, wspace=0.15)
    return fig, ax, tgrid, cols


def _draw_obstacles(ax, result: SimResult, t, axes_by_name, rho_l, kappa, obstacle_instants):
    """Every obstacle's P filled, L dashed, Q dotted, at a few instants when it moves; its name."""
    for j, name in enumerate(result.obstacle_names):
        ax_m = axes_by_name[name]
        instants = _obstacle_instants(result, j, obstacle_instants)
        for rank, k in enumerate(instants):
            fade = 0.35 + 0.65 * (rank + 1) / len(instants)
            c = result.obstacle_center_m[k, j]
            phi = result.obstacle_phi_rad[k, j]
            ax.add_patch(
                _ellipse(
                    c, phi, ax_m, 1.0, facecolor='0.55', edgecolor='0.2', alpha=0.45 * fade, lw=1.0
                )
            )
            ax.add_patch(
                _ellipse(
                    c, phi, ax_m, rho_l, fill=False, edgecolor='0.25', ls='--', lw=0.9, alpha=fade
                )
            )
            ax.add_patch(
                _ellipse(
                    c, phi, ax_m, kappa, fill=False, edgecolor='0.4', ls=':', lw=0.9, alpha=fade
                )
            )
            if len(instants) > 1 and np.ptp(result.obstacle_center_m[:, j], axis=0).max() > 0.05:
                ax.annotate(f'{t[k]:.0f} s', c, fontsize=7, color='0.25', ha='center', va='center')
        c0 = result.obstacle_center_m[instants[0], j]
        phi0 = result.obstacle_phi_rad[instants[0], j]
        half_height = kappa * math.hypot(ax_m[0] * math.sin(phi0), ax_m[1] * math.cos(phi0))
        ax.annotate(
            name,
            c0 + np.array([0.0, half_height + 0.02]),
            fontsize=9,
            ha='center',
            va='bottom',
            weight='bold',
            color='0.15',
        )


def _arrow_samples(t, arrow_every_s, duration):
    """(stride, t[::stride], indices into it of the orientation arrows)."""
    every = arrow_every_s if arrow_every_s and arrow_every_s > 0 else max(duration / 14.0, 1e-9)
    stride = max(1, math.ceil(len(t) / 6000))
    ts = t[::stride]
    arrow_idx = (
        np.unique(np.searchsorted(ts, np.arange(t[0], t[-1] + 1e-9, every))) if len(t) else []
    )
    arrow_idx = [k for k in arrow_idx if k < len(ts)]
    return stride, ts, arrow_idx


def _draw_robot(ax, result: SimResult, i: int, rid, spec, t, stride, ts, arrow_idx):
    """Robot i's path (thick while avoiding), its leader reference, arrows, start and end."""
    color = _COLORS[i % len(_COLORS)]
    x, y, th = result.state[:, i, 0], result.state[:, i, 1], result.state[:, i, 2]
    x, y, th, avoid = (
        v[::stride] for v in (x, y, th, np.asarray(result.avoiding[:, i], dtype=bool))
    )
    if spec is not None and spec.leader and spec.path is not None and len(t):
        r, _, _ = spec.path.reference(ts)
        ax.plot(r[:, 0], r[:, 1], ls='--', lw=0.8, color=color, alpha=0.6)
    ax.plot(
        x,
        y,
        lw=1.2,
        color=color,
        label=f'R{rid}' + (' (leader)' if spec and spec.leader else ''),
    )
    if avoid.any():
        # extend each avoiding run by one sample so short runs still draw a segment
        thick = avoid | np.concatenate([[False], avoid[:-1]])
        ax.plot(
            np.where(thick, x, np.nan),
            np.where(thick, y, np.nan),
            lw=4.0,
            color=color,
            alpha=0.85,
            solid_capstyle='butt',
        )
    if len(arrow_idx):
        ax.quiver(
            x[arrow_idx],
            y[arrow_idx],
            np.cos(th[arrow_idx]),
            np.sin(th[arrow_idx]),
            color=color,
            angles='xy',
            scale_units='xy',
            scale=1 / 0.12,
            width=0.004,
            headwidth=3.5,
            zorder=4,
        )
    if len(t):
        ax.plot(x[0], y[0], 'o', mfc='white', mec=color, mew=1.6, ms=8, zorder=5)
        ax.plot(x[-1], y[-1], 's', color=color, ms=7, zorder=5)


def _finish_portrait(ax, result: SimResult, xlim, ylim, rho_l, kappa):
    """Legend entries, limits, grid, labels and title of the phase portrait."""
    ax.plot([], [], lw=4.0, color='0.3', label='avoidance mode')
    ax.plot([], [], 'o', mfc='white', mec='0.3', label='start')
    ax.plot([], [], 's', color='0.3', label='end')
    ax.plot([], [], ls='--', color='0.3', lw=0.8, label='leader reference')
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect('equal', adjustable='box')
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.set_title(
        f'(a) phase portrait: {result.scenario_name} '
        f'(P filled, L = {rho_l:g} P dashed, Q = {kappa:g} P dotted)',
        fontsize=10,
    )
    ax.legend(loc='upper left', bbox_to_anchor=(1.01, 1.0), fontsize=8, framealpha=0.8)


def _draw_torques(fig, tgrid, result: SimResult, t, ids, by_id, cols: int):
    """One panel per robot: tau_1 and tau_2 vs time, +-tau_max dashed, avoidance shaded."""
    n = len(ids)
    first = None
    for i, rid in enumerate(ids):
        tax = fig.add_subplot(tgrid[i // cols, i % cols], sharex=first)
        first = first or tax
        tau_max = by_id[rid].params.torque_limit_nm if rid in by_id else None
        for a, b in intervals(np.asarray(result.avoiding[:, i], dtype=bool), t):
            tax.axvspan(a, b, color=_COLORS[i % len(_COLORS)], alpha=0.18, lw=0)
        tax.plot(t, result.torque_nm[:, i, 0], lw=0.8, color='tab:blue', label=r'$\tau_1$ left')
        tax.plot(t, result.torque_nm[:, i, 1], lw=0.8, color='tab:red', label=r'$\tau_2$ right')
        if tau_max:
            for sign in (1, -1):
                tax.axhline(sign * tau_max, ls='--', lw=0.7, color='0.4')
            peak = float(np.abs(result.torque_nm[:, i, :]).max()) if len(t) else 0.0
            lim = min(tau_max * 1.1, max(peak * 1.3, 0.02))
            tax.set_ylim(-lim, lim)
        tax.set_ylabel(f'R{rid}\n[N m]', fontsize=8)
        tax.tick_params(labelsize=7)
        tax.grid(True, lw=0.4, alpha=0.5)
        if i == 0:
            tax.set_title(
                '(b) wheel torques vs time (avoidance shaded, dashed: limit)',
                fontsize=10,
                loc='left',
            )
            tax.legend(loc='upper right', fontsize=7, ncol=2)
        if i + cols < n:
            tax.tick_params(labelbottom=False)
        else:
            tax.set_xlabel('t [s]')


def render_figure(
    result: SimResult,
    scenario,
    path,
    *,
    arrow_every_s: float | None = None,
    obstacle_instants: int = 4,
    dpi: int = 110,
) -> Path:
    """Draw the figure of ``result`` and save it as PNG at ``path``. Returns the path.

    Parameters
    ----------
    result : the run (T samples, N robots, M obstacles)
    scenario : its Scenario (semi-axes, rho_L, kappa, torque limits, leader paths)
    arrow_every_s : spacing of orientation arrows [s] (default: duration / 14)
    obstacle_instants : how many instants to draw a moving/rotating obstacle at
    """
    t = np.asarray(result.t_s, dtype=float)
    ids = list(result.robot_ids)
    n = len(ids)
    by_id = {r.id: r for r in scenario.robots}
    axes_by_name = {o.name: o.semi_axes_m for o in scenario.obstacles}
    rho_l = scenario.avoidance.limit_cycle_scale
    kappa = scenario.avoidance.protected_scale
    duration = float(t[-1] - t[0]) if len(t) > 1 else 1.0

    xlim, ylim = _limits(result, axes_by_name, kappa)
    fig, ax, tgrid, cols = _figure_layout(n, xlim, ylim, dpi)
    _draw_obstacles(ax, result, t, axes_by_name, rho_l, kappa, obstacle_instants)
    stride, ts, arrow_idx = _arrow_samples(t, arrow_every_s, duration)
    for i, rid in enumerate(ids):
        _draw_robot(ax, result, i, rid, by_id.get(rid), t, stride, ts, arrow_idx)
    _finish_portrait(ax, result, xlim, ylim, rho_l, kappa)
    _draw_torques(fig, tgrid, result, t, ids, by_id, cols)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi, bbox_inches='tight')
    return out
