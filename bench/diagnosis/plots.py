"""Plots of a diagnosis: residual maps before/after, per-cable bars, error vs distance, time.

Read at a glance: the two panels of the residual map share one arrow scale (a key
arrow says how long 1 mm is) and one colour scale; the per-cable bars are linear from
zero with the noise level as a band; exit points moved by their own fitted offset onto
their only measurement (zero by construction) are hatched apart from those checked at
several poses; the residuals over time are the length residuals per cable, the
recording's model and the corrected one side by side on their own scales, the noise
band on each, steps marked. Each figure has a ``*_data`` function returning what it
draws (the tests check those numbers against the drawn artists).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.diagnosis.report import Diagnosis


def write_plots(dg: Diagnosis, out: str | Path) -> list[Path]:
    """Write the diagnosis plots as PNG files into ``out``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    s, model = dg.samples, dg.recording.robot
    written = []
    pos = np.where(np.isfinite(s.pose_meas[:, :3]), s.pose_meas[:, :3], s.pose_des[:, :3])

    # 1. residual map before / after: one arrow scale and one colour scale on both panels
    if np.isfinite(dg.baseline_forward.pose_err).any():
        errs = [dg.baseline_forward.pose_err[:, :3] * 1e3, dg.fitted_forward.pose_err[:, :3] * 1e3]
        fig = residual_map(errs, pos, model.exits, dg.recording.init_pose[:3], plt)
        written.append(_save(fig, d / "residual_map.png", plt))

    # 2. per-cable bars (linear, the noise level as a band)
    bars = cable_bars_data(dg)
    if np.isfinite(bars["before_mm"]).any():
        written.append(_save(cable_bars_figure(bars, plt), d / "cables.png", plt))

    # 2b. exit points measured by the tracker: those fitted to their only measurement are
    # zero by construction, drawn apart from the checked ones
    if dg.rm.has_exit.any():
        written.append(_save(exit_points_figure(exit_points_data(dg), plt),
                             d / "exit_points.png", plt))

    # 3. error against distance from the initialisation pose
    e0 = np.linalg.norm(dg.baseline_forward.pose_err[:, :3], axis=1)
    e1 = np.linalg.norm(dg.fitted_forward.pose_err[:, :3], axis=1)
    if np.isfinite(e0).any():
        dist = np.linalg.norm(pos - dg.recording.init_pose[:3], axis=1)
        fig, ax = plt.subplots(figsize=(8, 4.5))
        ax.semilogy(dist, e0 * 1e3, "o", alpha=0.6, label="recording's model")
        ax.semilogy(dist, e1 * 1e3, "s", alpha=0.6, label="corrected model")
        ho = dg.heldout
        if len(ho):
            ax.semilogy(dist[ho], e1[ho] * 1e3, "kx", label="test samples (corrected)")
        noise = dg.report["mismatch"].get("noise", {}).get("pose_m")
        if noise:
            ax.axhline(noise * 1e3, color="k", ls="--", lw=1, label="repeatability")
        ax.set_xlabel("distance from the initialisation pose [m]")
        ax.set_ylabel("3-D pose error [mm]")
        ax.legend()
        ax.set_title("pose error against the distance from the initialisation pose")
        written.append(_save(fig, d / "error_vs_distance.png", plt))

    # 4. length residuals per cable over time, before and after, steps marked
    lot = lengths_over_time_data(dg)
    if np.isfinite(lot["before_mm"]).any():
        written.append(_save(lengths_over_time_figure(lot, plt), d / "lengths_over_time.png",
                             plt))
    return written


def cable_bars_data(dg: Diagnosis) -> dict:
    """What ``cables.png`` draws: per cable the length residual RMS [mm] under the
    recording's model (``before_mm``) and the corrected one (``after_mm``), and the noise
    level of the lengths (``noise_mm``, the one sigma the diagnosis assumed)."""
    model = dg.recording.robot
    before = dg.rm.blocks(model).length
    after = dg.rm.blocks(dg.fitted_robot).length
    rb, ra = _rms_mm(before), _rms_mm(after)
    return {"cables": list(model.cable_ids), "before_mm": rb, "after_mm": ra,
            "noise_mm": float(dg.rm.noise_summary()["length"] * 1e3)}


def cable_bars_figure(data: dict, plt):
    """Bars on a linear axis from zero, each with its value written; the noise level as a
    shaded band from zero with a dashed line and its value (visible at any bar height)."""
    fig, ax = plt.subplots(figsize=(9, 4.8))
    x = np.arange(len(data["cables"]))
    noise = data["noise_mm"]
    ax.axhspan(0, noise, color="0.6", alpha=0.35, lw=0, gid="noise_band",
               label=f"noise level ({noise:.2f} mm)")
    ax.axhline(noise, color="k", ls="--", lw=1, gid="noise_line")
    for off, key, lab, c in ((-0.2, "before_mm", "recording's model", "C0"),
                             (0.2, "after_mm", "corrected model", "C1")):
        v = np.nan_to_num(data[key])
        bars = ax.bar(x + off, v, 0.4, label=lab, color=c, gid=f"bars_{key}")
        ax.bar_label(bars, fmt="%.2f", fontsize=7, padding=1)
    top = max(float(np.nanmax(np.concatenate([data["before_mm"], data["after_mm"],
                                              [noise]]))), 1e-6)
    ax.set_ylim(0, 1.12 * top)
    ax.annotate(f"noise {noise:.2f} mm", (1.0, noise), xycoords=("axes fraction", "data"),
                xytext=(3, 0), textcoords="offset points", va="center", fontsize=8)
    ax.set_xticks(x, data["cables"])
    ax.set_xlabel("cable")
    ax.set_ylabel("length residual RMS [mm]")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3, frameon=False)
    ax.set_title("per-cable length residuals (linear axis from zero)")
    return fig


def exit_points_data(dg: Diagnosis) -> dict:
    """What ``exit_points.png`` draws: per cable the exit-point error RMS [mm] under the
    recording's model and the corrected one, the poses where the exit point was
    measured, and ``constructed``: the corrected value is zero by construction, not a
    check (the exit point was measured at one pose only and the corrected model moved it
    with its own fitted offset, ``d[xyz]_CABLE`` of ``exit_point_offset``, onto that one
    measurement)."""
    model = dg.recording.robot
    rb = _rms_mm(np.linalg.norm(dg.rm.blocks(model).exit, axis=2))
    ra = _rms_mm(np.linalg.norm(dg.rm.blocks(dg.fitted_robot).exit, axis=2))
    seen = dg.rm.has_exit.sum(axis=0)
    fitted = {p for e in dg.report["effects"] if e["name"] == "exit_point_offset"
              for p in e["params"]}
    own = np.array([any(f"d{a}_{c}" in fitted for a in "xyz") for c in model.cable_ids])
    return {"cables": list(model.cable_ids), "before_mm": rb, "after_mm": ra,
            "poses": seen, "constructed": (seen == 1) & own}


def exit_points_figure(data: dict, plt):
    """Bars per cable: the recording's model, the corrected model where it was checked at
    several poses (solid), and hatched full-height slots where the corrected value is zero
    by construction (its value written, a cross at it): a fit to one measurement is no
    check of the model."""
    from matplotlib.transforms import blended_transform_factory

    fig, ax = plt.subplots(figsize=(9.5, 5))
    x = np.arange(len(data["cables"]))
    rb, ra, built = data["before_mm"], data["after_mm"], data["constructed"]
    ax.bar(x - 0.2, np.nan_to_num(rb), 0.4, label="recording's model", color="C0",
           gid="bars_before")
    ax.bar((x + 0.2)[~built], np.nan_to_num(ra[~built]), 0.4, color="C1", gid="bars_fitted",
           label="corrected model (checked: measured at more poses than it was fitted to)")
    slots = blended_transform_factory(ax.transData, ax.transAxes)
    for i, k in enumerate(np.flatnonzero(built)):
        ax.bar(x[k] + 0.2, 1.0, 0.4, bottom=0.0, transform=slots, color="none",
               edgecolor="0.45", hatch="///", lw=0.8, gid="bars_constructed",
               label=("corrected model, fitted to its only measurement: zero by "
                      "construction, not a check") if i == 0 else None)
        ax.plot(x[k] + 0.2, np.nan_to_num(ra[k]), "x", color="0.2", ms=7,
                gid="constructed_value")
        ax.text(x[k] + 0.2, 0.5, f"{np.nan_to_num(ra[k]):.2f} mm by construction",
                transform=slots, rotation=90, ha="center", va="center", fontsize=7,
                color="0.25", bbox={"fc": "white", "ec": "none", "pad": 1})
    ax.set_ylim(0, 1.1 * max(float(np.nanmax(np.concatenate([rb, ra, [1e-6]]))), 1e-6))
    ax.set_xticks(x, [f"{c}\n({n} pose{'' if n == 1 else 's'})"
                      for c, n in zip(data["cables"], data["poses"], strict=True)])
    ax.set_xlabel("cable (poses where its exit point was measured)")
    ax.set_ylabel("exit point error RMS [mm]")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.2), frameon=False)
    ax.set_title("measured minus predicted exit points")
    return fig


def lengths_over_time_data(dg: Diagnosis) -> dict:
    """What ``lengths_over_time.png`` draws: sample times [s] (sorted), per cable the
    length residuals [mm] under the recording's model and the corrected one, the noise
    level [mm] and the steps found (slips, encoder jumps)."""
    s, model = dg.samples, dg.recording.robot
    order = np.argsort(s.t)
    return {"cables": list(model.cable_ids), "t": s.t[order],
            "before_mm": dg.rm.blocks(model).length[order] * 1e3,
            "after_mm": dg.rm.blocks(dg.fitted_robot).length[order] * 1e3,
            "noise_mm": float(dg.rm.noise_summary()["length"] * 1e3),
            "steps": list(dg.report["mismatch"].get("steps", []))}


def lengths_over_time_figure(data: dict, plt):
    """One row per cable, the recording's model on the left and the corrected model on
    the right, each panel on its own linear scale (so the corrected residuals are read
    against the noise band, ±1 sigma, shaded with dashed edges); steps marked."""
    n = len(data["cables"])
    fig, axes = plt.subplots(n, 2, figsize=(13, 1.45 * n + 1.4), sharex=True, squeeze=False)
    noise, t = data["noise_mm"], data["t"]
    for k, cid in enumerate(data["cables"]):
        for col, (key, colour) in enumerate((("before_mm", "0.45"), ("after_mm", "C1"))):
            ax = axes[k][col]
            ax.axhspan(-noise, noise, color="C2", alpha=0.25, lw=0, gid="noise_band",
                       label=f"noise ±{noise:.2f} mm" if k == 0 else None)
            for sgn in (1, -1):
                ax.axhline(sgn * noise, color="C2", ls="--", lw=0.9, gid="noise_edge")
            ax.plot(t, data[key][:, k], ".", ms=3, color=colour, gid=f"residual_{key}",
                    label=("recording's model" if col == 0 else "corrected model")
                    if k == 0 else None)
            v = data[key][:, k]
            ok = np.isfinite(v)
            lo = min(float(v[ok].min()) if ok.any() else 0.0, -2 * noise)
            top = max(float(v[ok].max()) if ok.any() else 0.0, 2 * noise)
            ax.set_ylim(lo - 0.12 * (top - lo), top + 0.12 * (top - lo))
            for st in data["steps"]:
                if st["cable"] == cid:
                    ax.axvline(st["t_s"], color="r", ls=":", gid="step")
                    if col == 0:
                        ax.text(st["t_s"], top, f" reading {-st['step_m'] * 1e3:+.1f} mm",
                                color="r", fontsize=7, va="top")
            ax.tick_params(labelsize=7)
        axes[k][0].set_ylabel(f"{cid} [mm]", fontsize=8)
    axes[0][0].set_title("recording's model", fontsize=10, loc="left")
    axes[0][1].set_title("corrected model", fontsize=10, loc="left")
    for ax in axes[0]:  # above the panel, beside its title: never over the points
        ax.legend(fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=2,
                  frameon=False)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    fig.suptitle("length residual per cable over time (green band: noise ±1 sigma; dotted "
                 "red: a step, a slip or an encoder jump); each panel on its own scale")
    fig.tight_layout(rect=(0, 0, 1, 0.975))
    return fig


def _rms_mm(a: np.ndarray) -> np.ndarray:
    """RMS over axis 0 of ``a`` [m] in mm, ignoring NaN (NaN where a column has none)."""
    ok = np.isfinite(a)
    n = ok.sum(axis=0)
    sq = np.where(ok, a, 0.0) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(sq.sum(axis=0) / np.maximum(n, 1)), np.nan) * 1e3


def _key_length(top: float) -> float:
    """A round arrow-key length [mm] (1, 2 or 5 times a power of ten) near half of ``top``."""
    if not (np.isfinite(top) and top > 0):
        return 1.0
    p = 10 ** np.floor(np.log10(top / 2))
    return float(max(m * p for m in (1, 2, 5) if m * p <= max(top / 2, p)))


def residual_map(errs: list[np.ndarray], pos: np.ndarray, exits: np.ndarray,
                 init: np.ndarray, plt):
    """Measured minus predicted platform position, before and after, seen from above.

    ``errs``: two (n, 3) arrays [mm] in F_b; ``pos`` (n, 3) [m] where each was measured;
    ``exits`` (c, 3) [m]; ``init`` the initialisation position [m]. Arrows are the xy
    error on one scale for both panels (the largest drawn an eighth of the plot wide, a
    key arrow in mm below each panel); colour is the vertical error z, signed, on one
    colour scale for both panels; grey dots mark every measured position, so a panel whose
    errors are too small to draw still shows where it was measured.
    """
    xy = np.vstack([pos[:, :2], exits[:, :2], init[None, :2]])
    xy = xy[np.isfinite(xy).all(axis=1)]
    extent = float(np.max(np.ptp(xy, axis=0))) or 1.0
    top = max((float(np.nanmax(np.linalg.norm(e[:, :2], axis=1)))
               if np.isfinite(e).all(axis=1).any() else 0.0) for e in errs) or 1.0
    zmax = max((float(np.nanmax(np.abs(e[:, 2]))) if np.isfinite(e).all(axis=1).any()
                else 0.0) for e in errs) or 1.0
    scale = top / (extent / 8)  # mm of error per metre of plot
    key = _key_length(top)
    fig, axes = plt.subplots(1, 2, figsize=(13, 6.2), sharex=True, sharey=True)
    q = None
    for ax, e, title in zip(axes, errs, ("recording's model", "corrected model"), strict=True):
        ok = np.isfinite(e).all(axis=1) & np.isfinite(pos[:, :2]).all(axis=1)
        ax.plot(pos[ok, 0], pos[ok, 1], ".", color="0.55", ms=3, label="measured positions")
        q = ax.quiver(pos[ok, 0], pos[ok, 1], e[ok, 0], e[ok, 1], e[ok, 2], cmap="coolwarm",
                      angles="xy", scale_units="xy", scale=scale, clim=(-zmax, zmax),
                      width=0.005, headwidth=3.5, headlength=4, headaxislength=3.5,
                      minlength=0.0, edgecolor="k", linewidth=0.3)
        ax.quiverkey(q, 0.03, -0.2, key, f"arrow key: {key:g} mm (xy)", labelpos="E",
                     coordinates="axes", color="k")
        ax.plot(exits[:, 0], exits[:, 1], "r^", label="exit points")
        ax.plot(init[0], init[1], "k*", ms=14, label="initialisation pose")
        mag = np.linalg.norm(e[ok], axis=1)
        rms = np.sqrt(np.mean(mag ** 2)) if ok.any() else float("nan")
        big = float(mag.max()) if ok.any() else float("nan")
        ax.set_title(f"{title}\n3-D error RMS {rms:.2f} mm, largest {big:.2f} mm")
        ax.set_xlabel("x [m]")
        ax.set_aspect("equal")
    fig.colorbar(q, ax=list(axes), label="vertical error z [mm] (one scale on both panels)",
                 shrink=0.85)
    axes[0].set_ylabel("y [m]")
    axes[0].legend(loc="upper center", bbox_to_anchor=(1.1, -0.25), ncol=3, fontsize=8,
                   frameon=False)
    fig.suptitle("measured minus predicted platform position, seen from above\n"
                 "arrows: the xy error (one scale on both panels); colour: the z error")
    return fig


def _save(fig, path: Path, plt) -> Path:
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
