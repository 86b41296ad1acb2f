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


#: loop events that are no supervisor reaction (not marked on the plots)
_NOT_SUPERVISOR = {"initialised", "reaction_override", "init_tensions"}
#: colours of the supervisor's reactions on the plots
_REACTION_COLOURS = {"log": "tab:gray", "substitute": "tab:purple", "hold": "tab:orange",
                     "quick_stop": "tab:red", "disable": "black"}


def path_errors(rec) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The pose errors a dry run counted: ``(t [s], error [m], state)`` per tracker fix.

    The numbers are the ones the run's summary (``pose_error_rms_m``,
    ``pose_error_max_m``) is made of: the distance from each new tracker fix (one per
    fix, by the tracker's time stamp; a fix held over several rows counts once) to the
    commanded path, as the loop measured it (:class:`bench.dryrun.loop.CrossTrack`),
    read from the recording's ``pose_err`` column. A recording without that column gets
    them replayed with the same :class:`~bench.dryrun.loop.CrossTrack` over its rows (a
    new fix: a row whose measured pose differs from the row before; the path at the
    recording's rate, not the loop's, so close to the summary but not equal).
    """
    states = list(rec.state) if rec.state is not None else [""] * rec.n_samples
    col = rec.extra.get("pose_err")
    if col is not None:
        k = np.flatnonzero(np.isfinite(col))
        return rec.t[k], col[k], [states[i] for i in k]
    from bench.dryrun.loop import CrossTrack

    dt = float(np.median(np.diff(rec.t))) if rec.n_samples > 1 else 1.0
    xt = CrossTrack(dt)
    t, e, st = [], [], []
    last = np.full(3, np.nan)
    for i in range(rec.n_samples):
        if np.isfinite(rec.pose_des[i, :3]).all():
            xt.command(rec.pose_des[i])
        p = rec.pose_meas[i, :3]
        fresh = np.isfinite(p).all() and not np.array_equal(p, last)
        if fresh and states[i] not in ("init", "quick_stop") and xt._n:
            t.append(rec.t[i])
            e.append(xt.error(p))
            st.append(states[i])
        if np.isfinite(p).all():
            last = p.copy()
    return np.array(t), np.array(e), st


def error_figures(err_m: np.ndarray) -> tuple[float | None, float | None]:
    """RMS and largest of pose errors [m], as the summary computes them (None if none)."""
    if not len(err_m):
        return None, None
    return float(np.sqrt(np.sum(err_m * err_m) / len(err_m))), float(np.max(err_m))


def data_limits(*values: np.ndarray, pad_frac: float = 0.08,
                pad_min: float = 0.02) -> tuple[float, float]:
    """Axis limits around the finite ``values`` [m]: their range grown by ``pad_frac`` of
    it on each side, at least ``pad_min`` [m] (a flat coordinate still gets a readable
    axis, centred on the data)."""
    v = np.concatenate([np.ravel(a) for a in values])
    v = v[np.isfinite(v)]
    if not len(v):
        return (0.0, 1.0)
    lo, hi = float(v.min()), float(v.max())
    pad = max(pad_frac * (hi - lo), pad_min)
    return lo - pad, hi + pad


def supervisor_events(recording: str | Path) -> list[dict]:
    """The supervisor's events of a dry run (``events.csv`` beside the recording): those
    with a reaction (log, substitute, hold, quick_stop, disable), as dicts with ``t`` [s],
    ``kind``, ``reaction``, ``active`` (bool), ``device``, ``address``, ``text``."""
    import csv

    f = Path(recording) / "events.csv"
    if not f.exists():
        return []
    out = []
    with f.open(newline="") as fh:
        for row in csv.DictReader(fh):
            if row["reaction"] in ("event", "none") or row["kind"] in _NOT_SUPERVISOR:
                continue
            out.append({"t": float(row["t"]), "kind": row["kind"], "reaction": row["reaction"],
                        "active": row["active"] == "1", "device": row["device"],
                        "address": row["address"], "text": row["text"]})
    return out


def following_error_window(rec, winches=None) -> tuple[np.ndarray, str]:
    """The drives' following-error window (0x6065) per cable [m] in the recording's cable
    order, and where it came from: ``winches`` (a :class:`controller.winch.WinchSet`),
    else the winch file the recording's ``meta.toml`` names (``winches``), else the
    shipped winch file."""
    from controller.winch import load_winches

    if winches is None:
        named = rec.meta.get("winches")
        winches = load_winches(Path(rec.path) / named if named else None)
    by_cable = dict(zip(winches.cables, winches.following_error_m, strict=True))
    window = np.array([by_cable.get(c, np.nan) for c in rec.robot.cable_ids], float)
    return window, Path(winches.source).name


def path_figure(rec, plt, max_points: int = 20000):
    """The path.png figure: top and side views of the commanded path and the tracker's
    fixes (axes around the data), and the pose error per fix as the summary counts it
    (:func:`path_errors`) with its RMS and largest drawn as lines."""
    step = max(1, rec.n_samples // max_points)
    des = rec.pose_des[::step, :3]
    meas = rec.pose_meas[:, :3]
    fresh = np.isfinite(meas).all(axis=1)
    fresh[1:] &= np.any(meas[1:] != meas[:-1], axis=1)  # each fix once
    fix = meas[fresh]
    fig, ax = plt.subplots(1, 3, figsize=(17, 5.2), width_ratios=(1, 1, 1.3))
    for a, (i, j, name) in zip(ax[:2], ((0, 1, "top view (x, y), to scale"),
                                        (1, 2, "side view (y, z), z axis around the data")),
                               strict=True):
        a.plot(des[:, i], des[:, j], "r-", lw=1.5, label="commanded path", gid="commanded")
        a.plot(fix[:, i], fix[:, j], "b.", ms=2.5, label="tracker fixes", gid="measured")
        xl = data_limits(des[:, i], fix[:, i])
        yl = data_limits(des[:, j], fix[:, j])
        if i == 0:  # to scale: both axes span the larger range, centred on the data
            half = max(xl[1] - xl[0], yl[1] - yl[0]) / 2
            xl, yl = ((sum(v) / 2 - half, sum(v) / 2 + half) for v in (xl, yl))
            a.set_aspect("equal", adjustable="box")
        a.set_xlim(*xl)
        a.set_ylim(*yl)
        a.set_xlabel(f"{'xyz'[i]} [m]")
        a.set_ylabel(f"{'xyz'[j]} [m]")
        a.set_title(name)
        a.grid(True, alpha=0.3)
        a.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=8,
                 frameon=False)  # below the view: never over the path
    t, err, st = path_errors(rec)
    rms, big = error_figures(err)
    e = ax[2]
    st_arr = np.array(st)
    for name, c in (("move", "k"), ("approach", "tab:blue"), ("dwell", "tab:green"),
                    ("hold", "tab:orange"), ("end", "tab:olive")):
        sel = st_arr == name
        if sel.any():
            e.plot(t[sel], 1e3 * err[sel], ".", ms=3, color=c, label=f"{name}",
                   gid=f"error_{name}")
    other = ~np.isin(st_arr, ["move", "approach", "dwell", "hold", "end"])
    if other.any():
        e.plot(t[other], 1e3 * err[other], ".", ms=3, color="0.5", label="other states",
               gid="error_other")
    if rms is not None:
        e.axhline(1e3 * rms, color="tab:blue", ls="--", lw=1, gid="error_rms",
                  label=f"RMS {1e3 * rms:.2f} mm (the summary's)")
        e.axhline(1e3 * big, color="tab:red", ls=":", lw=1, gid="error_max",
                  label=f"largest {1e3 * big:.2f} mm")
    e.set_ylim(0, 1.3e3 * big if big else 1.0)  # room for the legend above the data
    e.set_xlabel("t [s]")
    e.set_ylabel("distance from the tracker's fix to the commanded path [mm]")
    e.set_title("pose error per tracker fix, as the summary counts it")
    e.grid(True, alpha=0.3)
    e.legend(loc="upper left", fontsize=8, ncol=2)
    fig.suptitle(f"dry run {rec.path.name}: model {rec.robot.name}")
    fig.tight_layout()
    return fig


def _mark_events(ax, events: list[dict], label: bool) -> None:
    """Vertical lines at supervisor events (solid: start, dashed: end), coloured by
    reaction; one legend entry per reaction when ``label``."""
    seen = set()
    for ev in events:
        c = _REACTION_COLOURS.get(ev["reaction"], "tab:brown")
        lab = None
        if label and ev["active"] and ev["reaction"] not in seen:
            seen.add(ev["reaction"])
            lab = f"supervisor: {ev['reaction']}"
        ax.axvline(ev["t"], color=c, ls="-" if ev["active"] else "--", lw=1.2, alpha=0.8,
                   label=lab, gid=f"event_{ev['reaction']}_{'start' if ev['active'] else 'end'}")


def cables_figure(rec, events: list[dict], window_m: np.ndarray, window_src: str, plt,
                  max_points: int = 20000):
    """The cables.png figure: tensions measured and planned; commanded minus measured
    length per cable with the drives' following-error window (0x6065) drawn; the
    supervisor's events marked on both panels (their kinds named on the upper one) and
    quick-stop rows shaded."""
    from matplotlib.lines import Line2D

    step = max(1, rec.n_samples // max_points)
    t = rec.t[::step]
    fig, ax = plt.subplots(2, 1, figsize=(13, 9), sharex=True)
    plan = np.column_stack([rec.extra.get(f"plan_tau_{c}", np.full(rec.n_samples, np.nan))
                            for c in rec.robot.cable_ids])[::step]
    colours = plt.cm.tab10(np.arange(rec.robot.n_cables) % 10)
    for k, c in enumerate(rec.robot.cable_ids):
        ax[0].plot(t, rec.tau[::step, k], "-", color=colours[k], lw=0.8, label=f"{c}")
        ax[0].plot(t, plan[:, k], ":", color=colours[k], lw=1.0)
        ax[1].plot(t, 1e3 * (rec.l_cmd[::step, k] - rec.l_meas[::step, k]), "-",
                   color=colours[k], lw=0.8, label=f"cable {c}", gid=f"following_{c}")
    for w in np.unique(window_m[np.isfinite(window_m)]):
        for sign in (1, -1):
            ax[1].axhline(sign * 1e3 * w, color="tab:red", ls="--", lw=1.2,
                          gid="following_error_window",
                          label=(f"following-error window 0x6065 ±{1e3 * w:g} mm "
                                 f"({window_src})") if sign > 0 else None)
    if rec.state is not None:
        qs = np.array(rec.state) == "quick_stop"
        if qs.any():
            for a in ax:
                a.fill_between(rec.t, 0, 1, where=qs, transform=a.get_xaxis_transform(),
                               color="tab:red", alpha=0.08, lw=0, gid="quick_stop_rows",
                               label="quick stop (drives stopping)" if a is ax[1] else None)
    for a in ax:
        _mark_events(a, events, label=a is ax[1])
    for ev in events:
        if ev["active"]:
            who = {"drive": f" node {ev['address']}", "loadcell": f" unit {ev['address']}"}
            ax[0].annotate(ev["kind"] + who.get(ev["device"], ""), (ev["t"], 1.0),
                           xycoords=("data", "axes fraction"), rotation=90, fontsize=7,
                           va="top", ha="right",
                           color=_REACTION_COLOURS.get(ev["reaction"], "tab:brown"))
    handles, _ = ax[0].get_legend_handles_labels()
    handles += [Line2D([], [], color="k", ls="-", label="measured"),
                Line2D([], [], color="k", ls=":", label="planned")]
    ax[0].legend(handles=handles, ncol=5, fontsize=8, loc="upper left",
                 bbox_to_anchor=(1.01, 1.0))
    ax[0].set_ylabel("tension [N]")
    ax[0].grid(True, alpha=0.3)
    ax[1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax[1].set_ylabel("commanded - measured length [mm]")
    ax[1].set_xlabel("t [s]")
    ax[1].grid(True, alpha=0.3)
    ax[0].set_title(f"dry run {rec.path.name}: cable tensions (measured, planned) and "
                    f"following errors; supervisor events marked")
    fig.tight_layout()
    return fig


def plot_run(recording: str | Path, out_dir: str | Path, max_points: int = 20000,
             winches=None) -> list[Path]:
    """PNG plots of a dry-run recording into ``out_dir``: ``path.png`` (:func:`path_figure`)
    and ``cables.png`` (:func:`cables_figure`; the following-error window from ``winches``,
    see :func:`following_error_window`). Returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bench.recording import read_recording

    rec = read_recording(recording)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    window, src = following_error_window(rec, winches)
    files = []
    for name, fig in (("path.png", path_figure(rec, plt, max_points)),
                      ("cables.png", cables_figure(rec, supervisor_events(recording), window,
                                                   src, plt, max_points))):
        files.append(out / name)
        fig.savefig(files[-1], dpi=110, bbox_inches="tight")
        plt.close(fig)
    return files
