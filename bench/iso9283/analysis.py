"""ISO 9283 figures of recordings: segment, group, compute; the JSON object and the table.

:func:`analyse` takes one or several recordings (analysed together: visits of the same
commanded pose and passes over the same commanded path are pooled) and returns an
:class:`Analysis`; :func:`to_json` and :func:`format_text` present analyses as
``cdpr iso9283`` prints them (JSON object documented in ``bench/commands/iso9283.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.iso9283.figures import (
    PathFigures,
    PoseFigures,
    path_figures,
    pose_figures,
    resample_path,
)
from bench.iso9283.segments import (
    SETTLE,
    Iso9283Error,
    Pass,
    Visit,
    group_passes,
    group_visits,
    segment,
)
from bench.recording import Recording

FORMAT = "cdpr-iso9283/1"
#: commanded points per path at which the figures are computed (evenly spaced by arc length)
PATH_POINTS = 500
#: the worst-case keys of a pose analysis (absolute maxima over its commanded poses)
WORST_KEYS = ("apx_m", "apy_m", "apz_m", "ap_m", "rp_m", "ap_a_rad", "ap_b_rad", "ap_c_rad",
              "rp_a_rad", "rp_b_rad", "rp_c_rad")


@dataclass
class PoseResult:
    figures: PoseFigures
    visits: list[Visit]


@dataclass
class PathResult:
    figures: PathFigures
    passes: list[Pass]


@dataclass
class Analysis:
    """The figures of one analysed unit (one recording, or several pooled)."""

    label: str
    sources: list[Path]
    kind: str  # "pose" | "path"
    kind_reason: str
    rule: str
    warnings: list[str] = field(default_factory=list)
    poses: list[PoseResult] = field(default_factory=list)
    paths: list[PathResult] = field(default_factory=list)

    def main_path(self) -> PathResult | None:
        """The path with the most commanded length in all (passes × length): the path
        test's own path rather than an approach to it (None for a pose analysis)."""
        if not self.paths:
            return None
        return max(self.paths, key=lambda r: r.figures.n * r.figures.length)

    def worst(self) -> dict[str, Any]:
        """Worst case over the commanded poses (as ISO 9283 and the paper report a pose
        set): the largest absolute value of each figure, and the pose (1-based) it is at."""
        out: dict[str, Any] = {}
        at: dict[str, int] = {}
        for k in WORST_KEYS:
            vals = [abs(r.figures.to_dict()[k]) for r in self.poses]
            ok = [i for i, v in enumerate(vals) if math.isfinite(v)]
            if ok:
                i = max(ok, key=lambda i: vals[i])
                out[k], at[k] = vals[i], i + 1
            else:
                out[k], at[k] = float("nan"), None
        out["pose_of"] = at
        return out


def _choose_kind(kind: str, visits: list[Visit], passes: list[Pass]) -> tuple[str, str]:
    n_targets = len(group_visits(list(visits)))
    if kind in ("pose", "path"):
        return kind, f"--kind {kind}"
    if passes and n_targets <= 2:
        return "path", (f"auto: {len(passes)} pass(es) and {n_targets} dwell pose(s) (a path "
                        f"test: at most 2 dwell poses, its ends)")
    if visits:
        return "pose", (f"auto: {n_targets} dwell pose(s)"
                        + (f" (3 or more: a pose test; {len(passes)} move(s) between them "
                           f"ignored)" if passes else ""))
    return "path" if passes else "none", "auto"


def analyse(recs: Sequence[Recording], kind: str = "auto", settle: float = SETTLE,
            path_points: int = PATH_POINTS, label: str | None = None) -> Analysis:
    """ISO 9283 figures of recordings analysed together (see :mod:`bench.iso9283.segments`
    for how visits and passes are found). ``kind`` "pose", "path" or "auto". Raises
    :class:`Iso9283Error` (naming the file) when the recordings hold no visit/pass."""
    if kind not in ("pose", "path", "auto"):
        raise ValueError(f"kind: {kind!r}: expected pose, path or auto")
    if not recs:
        raise ValueError("no recording")
    segs = [segment(r, settle) for r in recs]
    visits = [v for s in segs for v in s.visits]
    passes = [p for s in segs for p in s.passes]
    warnings = [w for s in segs for w in s.warnings]
    k, reason = _choose_kind(kind, visits, passes)
    names = ", ".join(str(r.path / str(r.meta.get("samples", "recording.csv"))) for r in recs)
    if k == "none":
        raise Iso9283Error(f"{names}: neither dwell nor move rows: "
                           + "; ".join(f"{s.no_visit_reason}, {s.no_pass_reason}" for s in segs))
    if k == "pose" and not visits:
        raise Iso9283Error(f"{names}: no dwell: "
                           + "; ".join(s.no_visit_reason for s in segs))
    if k == "path" and not passes:
        raise Iso9283Error(f"{names}: no move: " + "; ".join(s.no_pass_reason for s in segs))
    an = Analysis(label or (recs[0].path.name if len(recs) == 1
                            else f"{len(recs)} recordings pooled"),
                  [r.path for r in recs], k, reason,
                  segs[0].visit_rule if k == "pose" else segs[0].pass_rule, warnings)
    if k == "pose":
        for g in group_visits(visits):
            att = np.array([v.attained for v in g])
            an.poses.append(PoseResult(pose_figures(att, g[0].command), g))
        return an
    an.rule += (f"; attained points where each pass crosses the normal planes of the commanded "
                f"path at {path_points} points evenly spaced along it")
    for g in group_passes(passes):
        s, cmd, tan = resample_path(g[0].command, path_points, with_tangents=True)
        try:
            fig = path_figures(cmd, [p.attained for p in g], s=s, tangents=tan)
        except ValueError as e:
            a, b = g[0].lines
            raise Iso9283Error(f"{g[0].source}: lines {a}-{b}: path: {e}") from None
        incomplete = int((~fig.complete).sum())
        if incomplete:
            an.warnings.append(f"path {len(an.paths) + 1}: {incomplete} of {len(s)} points not "
                               f"crossed by every pass (left out of the figures)")
        an.paths.append(PathResult(fig, g))
    return an


# ---------------------------------------------------------------------------------------------
# presentation


def _num(v: Any) -> Any:
    """JSON-safe: NaN/inf -> None, numpy -> python."""
    if isinstance(v, dict):
        return {k: _num(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_num(x) for x in v]
    if isinstance(v, (np.integer, int)) and not isinstance(v, bool):
        return int(v)
    if isinstance(v, (np.floating, float)):
        return float(v) if math.isfinite(v) else None
    return v


def _r(a: np.ndarray, digits: int = 7) -> list:
    return np.round(np.asarray(a, dtype=float), digits).tolist()


def analysis_json(an: Analysis, along: bool = True) -> dict[str, Any]:
    """One analysis as the JSON object of ``cdpr iso9283 --json`` (m, rad)."""
    d: dict[str, Any] = {"label": an.label, "recordings": [str(p) for p in an.sources],
                         "kind": an.kind, "kind_reason": an.kind_reason, "rule": an.rule,
                         "warnings": list(an.warnings)}
    if an.kind == "pose":
        d["poses"] = []
        for i, r in enumerate(an.poses, start=1):
            f = r.figures
            e = {"pose": i, "command": _r(f.command), "barycentre": _r(f.barycentre)}
            e.update(f.to_dict())
            e["visits"] = [{"recording": str(v.source), "lines": list(v.lines),
                            "t_s": [v.t[0], v.t[1]], "attained": _r(v.attained)}
                           for v in r.visits]
            d["poses"].append(e)
        d["worst"] = an.worst()
    else:
        main = an.main_path()
        d["main_path"] = an.paths.index(main) + 1 if main is not None else None
        d["paths"] = []
        for i, r in enumerate(an.paths, start=1):
            f = r.figures
            e = {"path": i, "start": _r(f.command[0]), "end": _r(f.command[-1])}
            e.update(f.to_dict())
            e["pass_lines"] = [{"recording": str(p.source), "lines": list(p.lines)}
                               for p in r.passes]
            if along:
                e["along"] = {"s_m": _r(f.s), "command_m": _r(f.command[:, :3]),
                              "barycentre_m": _r(f.barycentre[:, :3]),
                              "at_x_m": _r(f.dev_xyz[:, 0]), "at_y_m": _r(f.dev_xyz[:, 1]),
                              "at_z_m": _r(f.dev_xyz[:, 2]), "at_m": _r(f.dev),
                              "rt_m": _r(f.rt_points), "count": f.count.tolist()}
            d["paths"].append(e)
    return _num(d)


def to_json(analyses: Sequence[Analysis], along: bool = True) -> dict[str, Any]:
    """The ``cdpr iso9283 --json`` object."""
    return {"format": FORMAT, "standard": "ISO 9283:1998",
            "analyses": [analysis_json(a, along) for a in analyses]}


def _fmt(v: float, scale: float, width: int, digits: int, sign: bool = False) -> str:
    if not math.isfinite(v):
        return f"{'n/a':>{width}}"
    return f"{v * scale:{'+' if sign else ''}{width}.{digits}f}"


def _table(head: list[tuple[str, int]], rows: list[list[str]]) -> list[str]:
    """Right-aligned columns (name, width); a row holds one string per column."""
    line = "  " + " ".join(f"{h:>{w}}" for h, w in head)
    return [line] + ["  " + " ".join(f"{c:>{w}}" for c, (_, w) in zip(r, head, strict=True))
                     for r in rows]


_MM, _DEG = 1e3, 180 / math.pi


def format_text(analyses: Sequence[Analysis]) -> str:
    """The tables ``cdpr iso9283`` prints (mm and degrees)."""
    out: list[str] = []
    for an in analyses:
        src = ", ".join(str(p) for p in an.sources)
        if an.kind == "pose":
            nv = sum(len(r.visits) for r in an.poses)
            out.append(f"{an.label} ({src}): ISO 9283 pose figures, {len(an.poses)} commanded "
                       f"poses, {nv} visits [{an.kind_reason}]")
            out.append(f"  {an.rule}")
            out.append("  mm and degrees; 'worst' is the largest absolute value over the poses")
            head = [("pose", 5), ("x [m]", 7), ("y [m]", 7), ("z [m]", 6), ("n", 4)] + \
                [(k, 7) for k in ("APx", "APy", "APz", "AP", "RP")] + \
                [(k, 6) for k in ("AP_a", "AP_b", "AP_c", "RP_a", "RP_b", "RP_c")]
            rows = []
            for i, r in enumerate(an.poses, start=1):
                f = r.figures
                c = f.command
                rows.append([f"P{i}", f"{c[0]:.3f}", f"{c[1]:.3f}", f"{c[2]:.3f}", str(f.n)]
                            + [_fmt(v, _MM, 7, 2, True) for v in f.ap_xyz]
                            + [_fmt(f.ap, _MM, 7, 2), _fmt(f.rp, _MM, 7, 2)]
                            + [_fmt(v, _DEG, 6, 3, True) for v in f.ap_abc]
                            + [_fmt(v, _DEG, 6, 3) for v in f.rp_abc])
            w = an.worst()
            rows.append(["worst", "", "", "", ""]
                        + [_fmt(w[k], _MM, 7, 2) for k in WORST_KEYS[:5]]
                        + [_fmt(w[k], _DEG, 6, 3) for k in WORST_KEYS[5:]])
            out += _table(head, rows)
        else:
            out.append(f"{an.label} ({src}): ISO 9283 path figures, {len(an.paths)} commanded "
                       f"path(s) [{an.kind_reason}]")
            out.append(f"  {an.rule}")
            out.append("  mm and degrees; AT max/mean over the points every pass crosses; "
                       "* the main path (most passes x length)")
            head = [("path", 5), ("start x, y, z [m]", 20), ("end x, y, z [m]", 20),
                    ("length [m]", 10), ("passes", 6), ("AT max", 7), ("AT mean", 7),
                    ("RT", 7)] + [(k, 6) for k in ("AT_a", "AT_b", "AT_c", "RT_a", "RT_b",
                                                    "RT_c")]
            rows = []
            for i, r in enumerate(an.paths, start=1):
                f = r.figures
                a, b = f.command[0], f.command[-1]
                mark = "*" if r is an.main_path() else ""
                rows.append([f"{i}{mark}", f"{a[0]:.2f}, {a[1]:.2f}, {a[2]:.2f}",
                             f"{b[0]:.2f}, {b[1]:.2f}, {b[2]:.2f}", f"{f.length:.3f}", str(f.n),
                             _fmt(f.at, _MM, 7, 2), _fmt(f.at_mean, _MM, 7, 2),
                             _fmt(f.rt, _MM, 7, 2)]
                            + [_fmt(v, _DEG, 6, 3) for v in f.at_abc]
                            + [_fmt(v, _DEG, 6, 3) for v in f.rt_abc])
            out += _table(head, rows)
        for wmsg in an.warnings:
            out.append(f"  warning: {wmsg}")
    return "\n".join(out)


def path_run(fig: PathFigures, executed: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """A path's figures as the run mapping the plot functions take (:mod:`.plots`):
    ``s_m``, ``at_xyz_m`` and ``executed_m`` (the barycentre unless given)."""
    return {"s_m": fig.s, "at_xyz_m": fig.dev_xyz,
            "executed_m": fig.barycentre[:, :3] if executed is None else executed}
