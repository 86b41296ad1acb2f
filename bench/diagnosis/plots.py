"""Plots of a diagnosis: residual maps before/after, per-cable bars, error vs distance, time."""

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

    # 1. residual map before / after
    if np.isfinite(dg.baseline_forward.pose_err).any():
        fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), sharex=True, sharey=True)
        for ax, fw, title in ((axes[0], dg.baseline_forward, "recording's model"),
                              (axes[1], dg.fitted_forward, "corrected model")):
            e = fw.pose_err
            ok = np.isfinite(e[:, :3]).all(axis=1)
            mag = np.linalg.norm(e[ok, :3], axis=1) * 1e3
            q = ax.quiver(pos[ok, 0], pos[ok, 1], e[ok, 0], e[ok, 1], mag, cmap="viridis",
                          angles="xy")
            fig.colorbar(q, ax=ax, label="3-D pose error [mm]")
            ax.plot(model.exits[:, 0], model.exits[:, 1], "r^")
            ax.plot(*dg.recording.init_pose[:2], "k*", ms=14, label="initialisation pose")
            ax.set_title(f"{title}: RMS {np.sqrt(np.mean(mag ** 2)):.2f} mm")
            ax.set_xlabel("x [m]")
            ax.set_aspect("equal")
        axes[0].set_ylabel("y [m]")
        axes[0].legend(loc="upper right")
        fig.suptitle("measured minus predicted platform position (arrows: xy, colour: 3-D)")
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
        ax.axhline(dg.rm.sigma["length"] * 1e3, color="k", ls="--", lw=1, label="noise level")
        ax.set_xticks(x, model.cable_ids)
        ax.set_yscale("log")
        ax.set_xlabel("cable")
        ax.set_ylabel("length residual RMS [mm]")
        ax.legend()
        ax.set_title("per-cable length residuals")
        written.append(_save(fig, d / "cables.png", plt))

    # 2b. exit points measured by the tracker
    if dg.rm.has_exit.any():
        e0 = np.linalg.norm(dg.rm.blocks(model).exit, axis=2) * 1e3
        e1 = np.linalg.norm(dg.rm.blocks(dg.fitted_robot).exit, axis=2) * 1e3
        fig, ax = plt.subplots(figsize=(9, 4.5))
        x = np.arange(model.n_cables)
        with np.errstate(invalid="ignore"):
            rb = np.sqrt(np.nanmean(e0 ** 2, axis=0))
            ra = np.sqrt(np.nanmean(e1 ** 2, axis=0))
        ax.bar(x - 0.2, rb, 0.4, label="recording's model")
        ax.bar(x + 0.2, ra, 0.4, label="corrected model")
        ax.set_xticks(x, model.cable_ids)
        ax.set_xlabel("cable")
        ax.set_ylabel("exit point error RMS [mm]")
        ax.legend()
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
            ax.semilogy(dist[ho], e1[ho] * 1e3, "kx", label="held out (corrected)")
        ax.set_xlabel("distance from the initialisation pose [m]")
        ax.set_ylabel("3-D pose error [mm]")
        ax.legend()
        ax.set_title("pose error grows away from the initialisation pose")
        written.append(_save(fig, d / "error_vs_distance.png", plt))

    # 4. length residuals over time
    if np.isfinite(before).any():
        fig, ax = plt.subplots(figsize=(10, 4.5))
        order = np.argsort(s.t)
        for k, cid in enumerate(model.cable_ids):
            ax.plot(s.t[order], before[order, k] * 1e3, ".-", lw=0.5, label=cid)
        for st in dg.report["mismatch"].get("steps", []):
            ax.axvline(st["t_s"], color="r", ls=":")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("length residual, recording's model [mm]")
        ax.legend(ncol=4, fontsize=8)
        ax.set_title("per-cable length residuals over time (a step is a slip)")
        written.append(_save(fig, d / "lengths_over_time.png", plt))
    return written


def _save(fig, path: Path, plt) -> Path:
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
