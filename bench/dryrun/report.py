"""A dry run's summary as text, and its plots (from the recording it wrote)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _mm(v: float | None) -> str:
    return "-" if v is None else f"{1e3 * v:.2f} mm"


def summary_text(out: dict) -> str:
    """The human summary of a ``cdpr dry-run`` result object."""
    lines = [
        f"dry run {out['scenario']} (model {out['robot']}): {out['ended']}"
        + (f": {out['message']}" if out.get("message") else ""),
        f"  {out['cycles']} cycles at {out['rate_hz']:.1f} Hz: {out['simulated_s']:.2f} s "
        f"simulated in {out['wall_s']:.2f} s wall "
        f"(x{out['simulated_s'] / max(out['wall_s'], 1e-9):.1f}), {out['overruns']} overruns",
        f"  path {out['trajectory_s']:.2f} of {out['path_s']:.2f} s; pose error (tracker to "
        f"the commanded path): {_mm(out['pose_error_rms_m'])} RMS, "
        f"{_mm(out['pose_error_max_m'])} max",
    ]
    if out.get("drive_states"):
        names, counts = np.unique(out["drive_states"], return_counts=True)
        lines.append("  drives at the end: " + ", ".join(
            f"{c} x {n}" for n, c in zip(names, counts, strict=True)))
    sup = [e for e in out["events"] if e["reaction"] != "event"]
    if sup:
        lines.append(f"  supervisor events ({len(sup)}):")
        for e in sup[:20]:
            who = {"drive": f"node {e['address']}", "loadcell": f"unit {e['address']}"}.get(
                e["device"], e["device"])
            lines.append(f"    t={e['t']:8.3f} s  {'start' if e['active'] else 'end  '}  "
                         f"{e['kind']:16} {who:10} {e['reaction']:10} {e.get('text', '')}")
        if len(sup) > 20:
            lines.append(f"    ... {len(sup) - 20} more (events.csv)")
    if out.get("recording"):
        lines.append(f"  recording: {out['recording']}")
    if out.get("plots"):
        lines.append(f"  plots: {', '.join(out['plots'])}")
    return "\n".join(lines)


def plot_run(recording: str | Path, out_dir: str | Path, max_points: int = 20000) -> list[Path]:
    """PNG plots of a dry-run recording into ``out_dir``: the path (commanded and
    measured, top and side views) with the pose error along time; tensions measured and
    planned; cable following errors. Returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bench.recording import read_recording

    rec = read_recording(recording)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    step = max(1, rec.n_samples // max_points)
    t = rec.t[::step]
    des = rec.pose_des[::step]
    meas = rec.pose_meas[::step]
    states = np.array(rec.state[::step]) if rec.state is not None else None
    files = []

    fig, ax = plt.subplots(1, 3, figsize=(16, 5))
    for a, (i, j, name) in zip(ax[:2], ((0, 1, "top view (x, y)"), (1, 2, "side view (y, z)")),
                               strict=True):
        a.plot(des[:, i], des[:, j], "r-", lw=1.5, label="commanded")
        a.plot(meas[:, i], meas[:, j], "b.", ms=1.5, label="measured (tracker)")
        a.set_xlabel(f"{'xyz'[i]} [m]")
        a.set_ylabel(f"{'xyz'[j]} [m]")
        a.set_title(name)
        a.axis("equal")
        a.grid(True, alpha=0.3)
        a.legend(loc="best")
    err = np.linalg.norm(meas[:, :3] - des[:, :3], axis=1) * 1e3
    ax[2].plot(t, err, "k-", lw=0.8, label="|measured - commanded| (same time)")
    if states is not None:
        for st, c in (("dwell", "tab:green"), ("hold", "tab:orange"),
                      ("quick_stop", "tab:red")):
            sel = states == st
            if sel.any():
                ax[2].plot(t[sel], err[sel], ".", ms=2, color=c, label=f"state {st}")
    ax[2].set_xlabel("t [s]")
    ax[2].set_ylabel("position error [mm]")
    ax[2].set_title("pose error along the run")
    ax[2].grid(True, alpha=0.3)
    ax[2].legend(loc="best")
    fig.suptitle(f"dry run {rec.path.name}: model {rec.robot.name}")
    fig.tight_layout()
    files.append(out / "path.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(2, 1, figsize=(12, 8), sharex=True)
    plan = np.column_stack([rec.extra.get(f"plan_tau_{c}", np.full(rec.n_samples, np.nan))
                            for c in rec.robot.cable_ids])[::step]
    colours = plt.cm.tab10(np.arange(rec.robot.n_cables) % 10)
    for k, c in enumerate(rec.robot.cable_ids):
        ax[0].plot(t, rec.tau[::step, k], "-", color=colours[k], lw=0.8, label=f"{c}")
        ax[0].plot(t, plan[:, k], ":", color=colours[k], lw=1.0)
        ax[1].plot(t, 1e3 * (rec.l_cmd[::step, k] - rec.l_meas[::step, k]), "-",
                   color=colours[k], lw=0.8, label=f"{c}")
    ax[0].set_ylabel("tension [N] (solid measured, dotted planned)")
    ax[0].legend(ncol=8, fontsize=8, loc="upper right")
    ax[0].grid(True, alpha=0.3)
    ax[1].set_ylabel("commanded - measured length [mm]")
    ax[1].set_xlabel("t [s]")
    ax[1].grid(True, alpha=0.3)
    ax[0].set_title("cable tensions and following errors")
    fig.tight_layout()
    files.append(out / "cables.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    return files
