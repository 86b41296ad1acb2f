"""Plots of a diagnosis: residual maps before/after, per-cable bars, error vs distance, time.

Read at a glance: the two panels of the residual map share one arrow scale (a key
arrow says how long 1 mm is) and one colour scale; exit points whose fit rests on
a single measurement (their residual is zero by construction) are marked apart
from those checked at several poses; the residuals over time are the length
residuals per cable, before and after the correction, with steps marked.
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

    # 2. per-cable bars
    before = dg.rm.blocks(model).length
    after = dg.rm.blocks(dg.fitted_robot).length
    if np.isfinite(before).any():
        fig, ax = plt.subplots(figsize=(9, 4.5))
        x = np.arange(model.n_cables)
        rb = np.sqrt(np.nanmean(before ** 2, axis=0)) * 1e3
        ra = np.sqrt(np.nanmean(after ** 2, axis=0)) * 1e3
        ax.bar(x - 0.2, rb, 0.4, label="recording's model")
        ax.bar(x + 0.2, ra, 0.4, label="corrected model")
        ax.axhline(dg.rm.noise_summary()["length"] * 1e3, color="k", ls="--", lw=1,
                   label="noise level")
        ax.set_xticks(x, model.cable_ids)
        ax.set_yscale("log")
        ax.set_xlabel("cable")
        ax.set_ylabel("length residual RMS [mm]")
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3, frameon=False)
        ax.set_title("per-cable length residuals")
        written.append(_save(fig, d / "cables.png", plt))

    # 2b. exit points measured by the tracker: those seen at a single pose are fitted to
    # their one measurement (zero by construction), not validated
    if dg.rm.has_exit.any():
        e0 = np.linalg.norm(dg.rm.blocks(model).exit, axis=2) * 1e3
        e1 = np.linalg.norm(dg.rm.blocks(dg.fitted_robot).exit, axis=2) * 1e3
        seen = dg.rm.has_exit.sum(axis=0)
        fig, ax = plt.subplots(figsize=(9, 4.5))
        x = np.arange(model.n_cables)
        with np.errstate(invalid="ignore"):
            rb = np.sqrt(np.nanmean(e0 ** 2, axis=0))
            ra = np.sqrt(np.nanmean(e1 ** 2, axis=0))
        ax.bar(x - 0.2, rb, 0.4, label="recording's model")
        single = seen == 1
        ax.bar((x + 0.2)[~single], ra[~single], 0.4, label="corrected model (measured at "
                                                           "several poses)")
        ax.bar((x + 0.2)[single], np.nan_to_num(ra[single]), 0.4, color="none",
               edgecolor="grey", hatch="//",
               label="corrected model, one measurement only (zero by construction)")
        for k in np.flatnonzero(single):
            ax.text(x[k] + 0.2, max(float(np.nan_to_num(rb[k])) * 0.05, 0.1), "1 pose",
                    ha="center", va="bottom", fontsize=7, rotation=90, color="grey")
        ax.set_xticks(x, [f"{c}\n({n} pose{'' if n == 1 else 's'})"
                          for c, n in zip(model.cable_ids, seen, strict=True)])
        ax.set_xlabel("cable (poses where its exit point was measured)")
        ax.set_ylabel("exit point error RMS [mm]")
        ax.legend(fontsize=8)
        ax.set_title("measured minus predicted exit points")
        written.append(_save(fig, d / "exit_points.png", plt))

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
    if np.isfinite(before).any():
        n = model.n_cables
        cols = 2 if n > 4 else 1
        rows_ = int(np.ceil(n / cols))
        fig, axes = plt.subplots(rows_, cols, figsize=(12, 1.8 * rows_ + 1), sharex=True,
                                 squeeze=False)
        order = np.argsort(s.t)
        steps = dg.report["mismatch"].get("steps", [])
        noise = dg.rm.noise_summary()["length"] * 1e3
        for k, cid in enumerate(model.cable_ids):
            ax = axes[k % rows_][k // rows_]
            ax.plot(s.t[order], before[order, k] * 1e3, ".", ms=3, color="0.6",
                    label="recording's model")
            ax.plot(s.t[order], after[order, k] * 1e3, ".", ms=3, color="C1",
                    label="corrected model")
            ax.axhspan(-noise, noise, color="C2", alpha=0.15, lw=0)
            for st in steps:
                if st["cable"] == cid:
                    ax.axvline(st["t_s"], color="r", ls=":")
                    ax.text(st["t_s"], ax.get_ylim()[1], f" reading {-st['step_m'] * 1e3:+.1f} mm",
                            color="r", fontsize=7, va="top")
            ax.set_ylabel(f"{cid} [mm]", fontsize=8)
        axes[0][0].legend(fontsize=7, loc="upper left")
        for ax in axes[-1]:
            ax.set_xlabel("t [s]")
        fig.suptitle("length residual per cable over time (band: noise; dotted red: a step, "
                     "a slip or an encoder jump)")
        written.append(_save(fig, d / "lengths_over_time.png", plt))
    return written


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
