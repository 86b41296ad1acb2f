"""Plots of ISO 9283 figures like the paper's Fig. 6 (pose) and Fig. 7 (path), PNG via Agg.

The functions take plain lists, dicts and arrays (SI units: m, rad; plotted in mm and
degrees), not recordings, so that any campaign can call them:

- :func:`plot_pose_bars`: grouped bars of AP/RP per run (pose set, velocity, model), one
  panel per family of figures (position accuracy, position repeatability, orientation
  accuracy, orientation repeatability). A run is a mapping with a ``label`` and the keys of
  ``cdpr iso9283 --json`` (``apx_m`` ... ``rp_c_rad``; an ``Analysis.worst()`` or a
  ``PoseFigures.to_dict()`` fits as it is).
- :func:`plot_path_cases`: one row per case (e.g. path and initialisation pose): the desired
  and executed paths in a plane (default YZ), then AT, AT_x, AT_y, AT_z along the path, one
  line per run (e.g. nominal, compliant, diagnosed model).
- :func:`plot_pose_scatter`: the attained positions of each commanded pose around it (the
  xy plane), with barycentre and RP circle.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: the figure families of :func:`plot_pose_bars`: (title, unit, scale, [(key, label)])
POSE_FAMILIES = (
    ("position accuracy", "mm", 1e3,
     [("apx_m", "AP$_x$"), ("apy_m", "AP$_y$"), ("apz_m", "AP$_z$"), ("ap_m", "AP")]),
    ("position repeatability", "mm", 1e3, [("rp_m", "RP")]),
    ("orientation accuracy", "deg", 180 / math.pi,
     [("ap_a_rad", "AP$_a$"), ("ap_b_rad", "AP$_b$"), ("ap_c_rad", "AP$_c$")]),
    ("orientation repeatability", "deg", 180 / math.pi,
     [("rp_a_rad", "RP$_a$"), ("rp_b_rad", "RP$_b$"), ("rp_c_rad", "RP$_c$")]),
)
#: colours of the runs of :func:`plot_path_cases`, in order of first appearance
RUN_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink",
               "tab:olive", "tab:cyan")
_AXES = {"x": 0, "y": 1, "z": 2}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out: str | Path, plt) -> Path:
    p = Path(out)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


def _value(run: Mapping[str, Any], key: str) -> float:
    v = run.get(key)
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else float("nan")


def _readable_limits(ax, at_zero: bool, min_span: float = 1.0) -> None:
    """Y limits spanning at least ``min_span`` (data units) without an offset text, from 0
    for a magnitude (``at_zero``)."""
    ax.ticklabel_format(axis="y", useOffset=False, style="plain")
    lo, hi = ax.get_ylim()
    if at_zero:
        lo = 0.0
    if hi - lo < min_span:
        mid = (lo + hi) / 2
        lo, hi = (0.0, min_span) if at_zero else (mid - min_span / 2, mid + min_span / 2)
    ax.set_ylim(lo, hi)


def safe_name(label: str) -> str:
    """A file-name-safe form of a label."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label).strip("_") or "run"


def plot_pose_bars(runs: Sequence[Mapping[str, Any]], out: str | Path,
                   title: str = "ISO 9283 pose accuracy AP and repeatability RP") -> Path:
    """Fig. 6-like grouped bars: one group per run, one bar per figure, one panel per family.

    ``runs``: mappings with ``label`` (str, e.g. "G N 10 %") and any of the keys ``apx_m``,
    ``apy_m``, ``apz_m``, ``ap_m``, ``rp_m`` [m] and ``ap_a_rad`` ... ``rp_c_rad`` [rad]
    (missing or None: no bar); optional ``color`` (a matplotlib colour) for the run's tick
    label. Families without any value are left out. Returns the PNG path ``out``.
    """
    plt = _plt()
    if not runs:
        raise ValueError("runs: nothing to plot")
    fams = [f for f in POSE_FAMILIES
            if any(math.isfinite(_value(r, k)) for r in runs for k, _ in f[3])]
    if not fams:
        raise ValueError("runs: no figure to plot (keys apx_m ... rp_c_rad)")
    ncol = 2 if len(fams) > 1 else 1
    nrow = math.ceil(len(fams) / ncol)
    width = max(7.0, 0.55 * len(runs) * 1.6 + 2)
    fig, axes = plt.subplots(nrow, ncol, figsize=(min(width * ncol, 26), 3.8 * nrow + 0.8),
                             squeeze=False)
    x = np.arange(len(runs))
    labels = [str(r.get("label", f"run {i + 1}")) for i, r in enumerate(runs)]
    for ax, (name, unit, scale, keys) in zip(axes.flat, fams, strict=False):
        w = 0.8 / len(keys)
        for j, (k, lab) in enumerate(keys):
            v = np.array([_value(r, k) for r in runs]) * scale
            ax.bar(x - 0.4 + w * (j + 0.5), np.nan_to_num(v), w, label=lab,
                   color=f"C{j}")
        ax.set_xticks(x, labels, rotation=45 if len(runs) > 4 else 0,
                      ha="right" if len(runs) > 4 else "center")
        for tick, r in zip(ax.get_xticklabels(), runs, strict=True):
            if r.get("color"):
                tick.set_color(r["color"])
        ax.axhline(0, color="k", lw=0.6)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.set_title(name)
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=8, ncol=len(keys))
    for ax in list(axes.flat)[len(fams):]:
        ax.set_visible(False)
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, out, plt)


def plot_path_cases(cases: Sequence[Mapping[str, Any]], out: str | Path,
                    title: str = "ISO 9283 path accuracy AT", plane: str = "yz") -> Path:
    """Fig. 7-like: per case, desired vs executed path in a plane and AT along the path.

    ``cases``: mappings with ``title`` (str), ``desired_m`` (k, 3) the desired path and
    ``runs``: {label: {``executed_m`` (k', 3) the executed path, ``s_m`` (m,) arc length
    along the desired path [m], ``at_xyz_m`` (m, 3) the deviation (barycentre minus desired
    point) at those points}}. One row per case, columns: the path in ``plane`` ("yz", "xz",
    "xy"), AT, AT_x, AT_y, AT_z [mm] against s. A run label keeps its colour in every case.
    Returns the PNG path ``out``.
    """
    plt = _plt()
    if not cases:
        raise ValueError("cases: nothing to plot")
    if len(plane) != 2 or any(c not in _AXES for c in plane) or plane[0] == plane[1]:
        raise ValueError(f"plane: {plane!r}: expected two of x, y, z, e.g. 'yz'")
    h, v = _AXES[plane[0]], _AXES[plane[1]]
    colours: dict[str, str] = {}
    for c in cases:
        for lab in c.get("runs", {}):
            colours.setdefault(lab, RUN_COLOURS[len(colours) % len(RUN_COLOURS)])
    fig, axes = plt.subplots(len(cases), 5, figsize=(22, 3.9 * len(cases) + 0.8), squeeze=False,
                             gridspec_kw={"width_ratios": [1.5, 1, 1, 1, 1]})
    comp = ("AT", "AT$_x$", "AT$_y$", "AT$_z$")
    for row, c in zip(axes, cases, strict=True):
        ax = row[0]
        d = np.asarray(c["desired_m"], dtype=float)
        ax.plot(d[:, h], d[:, v], color="red", lw=2.2, label="desired")
        for lab, r in c.get("runs", {}).items():
            e = np.asarray(r["executed_m"], dtype=float)
            ax.plot(e[:, h], e[:, v], color=colours[lab], lw=1.3, label=f"executed, {lab}")
        ax.set_xlabel(f"{plane[0]} [m]")
        ax.set_ylabel(f"{plane[1]} [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(str(c.get("title", "")))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        for k, (ax, name) in enumerate(zip(row[1:], comp, strict=True)):
            for lab, r in c.get("runs", {}).items():
                s = np.asarray(r["s_m"], dtype=float)
                dev = np.asarray(r["at_xyz_m"], dtype=float)
                y = np.linalg.norm(dev, axis=1) if k == 0 else dev[:, k - 1]
                ax.plot(s, y * 1e3, color=colours[lab], lw=1.3, label=lab)
            _readable_limits(ax, at_zero=k == 0)
            if k:
                ax.axhline(0, color="k", lw=0.6)
            ax.set_xlabel("distance along the desired path s [m]")
            ax.set_ylabel(f"{name} [mm]")
            ax.set_title(f"{name} along the path")
            ax.grid(alpha=0.3)
            if k == 0:
                ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, out, plt)


def plot_pose_scatter(poses: Sequence[Mapping[str, Any]], out: str | Path,
                      title: str = "attained positions around each commanded pose") -> Path:
    """Per commanded pose, the attained positions' deviations in the xy plane [mm].

    ``poses``: mappings with ``label``, ``command`` (3|6,) [m], ``attained`` (n, 3|6) [m] and
    optionally ``rp_m`` (drawn as a circle about the barycentre). Returns the PNG path.
    """
    plt = _plt()
    if not poses:
        raise ValueError("poses: nothing to plot")
    n = len(poses)
    ncol = min(n, 5)
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol + 0.6, 3.6 * nrow + 0.9),
                             squeeze=False)
    for ax, p in zip(axes.flat, poses, strict=False):
        c = np.asarray(p["command"], dtype=float)[:3]
        a = (np.asarray(p["attained"], dtype=float)[:, :3] - c) * 1e3
        b = a.mean(axis=0)
        ax.plot(a[:, 0], a[:, 1], ".", color="tab:blue", label="attained")
        ax.plot(0, 0, "r+", ms=14, mew=2, label="commanded")
        ax.plot(b[0], b[1], "kx", ms=10, mew=2, label="barycentre")
        rp = p.get("rp_m")
        if isinstance(rp, (int, float)) and math.isfinite(rp):
            th = np.linspace(0, 2 * np.pi, 100)
            ax.plot(b[0] + rp * 1e3 * np.cos(th), b[1] + rp * 1e3 * np.sin(th), "k--", lw=0.8,
                    label="RP about barycentre")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x deviation [mm]")
        ax.set_ylabel("y deviation [mm]")
        ax.set_title(f"{p.get('label', '')}  ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) m", fontsize=9)
        ax.grid(alpha=0.3)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8)
    return _save(fig, out, plt)
