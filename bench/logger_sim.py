"""Recordings written the way a bench's logger writes them: each sensor at its own rate.

The physics is the campaign's (:func:`bench.campaign.run_campaign` with a ``sink``: the
controller, the plant with the scenario's concealed effects and nuisances), settled at
``physics_hz``; this module only *samples* that truth the way a logger does:

- rows at the controller cycle (``rows_hz``) with jittered time stamps (``jitter_s``, the
  standard deviation of each stamp about its nominal instant);
- every sensor stream (encoders, load cells, tracker) at its own rate with its own phase:
  a sample lands in the row nearest its instant; the other rows leave the stream's fields
  ``nan`` (``empty="nan"``) or empty (``empty=""``): "no sample";
- optionally without the controller's columns (``*_des``, ``l_cmd_*``, ``state``);
- optionally split across several files (``split="time"``: consecutive parts with the same
  header; ``split="sensor"``: one file per stream holding only its own rows), listed in
  ``meta.toml``'s ``samples`` (docs/formats/recording-streams.md);
- optionally with sensor dropouts (``dropouts``): a stream silent for a while, as a
  tracker that loses its line of sight, a load cell's bus unit that times out, an encoder
  stream that stalls; the rows go on, the stream's fields hold "no sample".

The truth between two settled physics steps is linear in time (steps of 1 cm at 0.25 m/s;
the curvature of a cable length over one step is a micrometre). Sensor noise is the
scenario's (:class:`firmware_sim.scenario.Noise`), encoders quantised as in a campaign.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bench.campaign import campaign_plant, run_campaign
from bench.recording import FORMAT, POSE_AXES, write_header_files
from firmware_sim.scenario import RecordingSpec, Scenario

#: what each stream measures (column group names of :class:`bench.recording.Recording`)
STREAMS = ("encoders", "load_cells", "tracker")


@dataclass(frozen=True)
class LoggerSpec:
    """How the logger writes: rates [Hz] of the rows and of each stream, time-stamp jitter
    [s] (standard deviation), the fields of a stream without a sample (``"nan"`` or ``""``),
    the controller's columns or not, and the files (``split`` None, ``"time"`` into
    ``files`` parts, or ``"sensor"``: one file per stream)."""

    rows_hz: float = 200.0
    encoders_hz: float = 200.0
    load_cells_hz: float = 200.0
    tracker_hz: float = 10.0
    jitter_s: float = 2e-4
    empty: str = "nan"
    controller_columns: bool = True
    split: str | None = None
    files: int = 1
    physics_hz: float = 25.0
    seed: int = 0
    dropouts: tuple[tuple[str, float, float, float], ...] = ()

    def __post_init__(self) -> None:
        drops = tuple((str(s), float(r), float(a), float(b)) for s, r, a, b in self.dropouts)
        for s, r, a, b in drops:
            if s not in STREAMS or r < 0 or not 0 <= a <= b:
                raise ValueError(f"dropouts: {(s, r, a, b)!r} is not (stream, per_minute >= 0, "
                                 f"0 <= shortest_s <= longest_s)")
        object.__setattr__(self, "dropouts", drops)  # lists from a case's JSON -> tuples

    def rate(self, stream: str) -> float:
        return {"encoders": self.encoders_hz, "load_cells": self.load_cells_hz,
                "tracker": self.tracker_hz}[stream]


@dataclass
class Truth:
    """The campaign's truth at its physics steps: times (K,) [s], commanded pose (K,6) and
    lengths (K,n), encoder readings (K,n) [m], pose (K,6), load-cell readings without
    noise (K,n) [N], exit points (K,n,3) [m], controller state names (K,)."""

    t: np.ndarray
    pose_des: np.ndarray
    l_cmd: np.ndarray
    l_meas: np.ndarray
    pose: np.ndarray
    tau: np.ndarray
    exits: np.ndarray
    label: np.ndarray


class _Horizon(Exception):
    """The campaign reached the horizon of :func:`simulate_truth`."""


def simulate_truth(sc: Scenario, physics_hz: float, until_s: float | None = None,
                   predict: bool = True) -> Truth:
    """Run the scenario's campaign as a continuous log at ``physics_hz`` (its dwells kept)
    and collect the truth of every step, up to ``until_s`` [s] when given. A run of equal
    steps (a dwell) is kept as its first and last step: the truth is linear between steps.
    ``predict``: the plant starts each rest search along a move from the rest extrapolated
    from the last two (:attr:`firmware_sim.plant.Plant.predict`: the same rests within its
    force tolerance, several times faster); False searches from the last rest."""
    rows: list[tuple] = []

    def same(a: tuple, b: tuple) -> bool:
        return a[7] == b[7] and all(np.array_equal(x, y) for x, y in zip(a[1:7], b[1:7],
                                                                          strict=True))

    def sink(t, p_des, l_cmd, l_meas, state, tau_read, label) -> None:
        if until_s is not None and t > until_s:
            raise _Horizon
        row = (t, np.array(p_des, float), np.array(l_cmd, float), np.array(l_meas, float),
               state.pose.copy(), np.array(tau_read, float), state.exits.copy(), label)
        if len(rows) >= 2 and same(row, rows[-1]) and same(row, rows[-2]):
            rows[-1] = row  # the run's last step moves on
        else:
            rows.append(row)

    sc2 = replace(sc, recording=RecordingSpec(kind="continuous", dwell_at_targets=True,
                                              rate_hz=physics_hz))
    try:
        run_campaign(sc2, None, sink=sink, plant=campaign_plant(sc2, predict=predict))
    except _Horizon:
        pass
    cols = list(zip(*rows, strict=True))
    return Truth(*(np.array(c) for c in cols[:7]), label=np.array(cols[7]))


def _at(t_truth: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``values`` (K, ...) linear in time between the steps ``t_truth``, at times ``t``."""
    k = np.clip(np.searchsorted(t_truth, t) - 1, 0, len(t_truth) - 2)
    w = np.clip((t - t_truth[k]) / (t_truth[k + 1] - t_truth[k]), 0.0, 1.0)
    w = w.reshape((-1,) + (1,) * (values.ndim - 1))
    return (1.0 - w) * values[k] + w * values[k + 1]


def _instants(t0: float, t1: float, rate: float, jitter: float,
              rng: np.random.Generator) -> np.ndarray:
    """Time stamps of a clock at ``rate`` [Hz] with a random phase and jitter, in [t0, t1]."""
    period = 1.0 / rate
    nominal = t0 + rng.uniform(0, period) + np.arange(int((t1 - t0) * rate) + 1) * period
    t = nominal + rng.normal(0.0, jitter, len(nominal))
    t = np.sort(t[(t >= t0) & (t <= t1)])
    return t


def dropout_intervals(spec: LoggerSpec, sc_seed: int, t0: float, t1: float
                      ) -> dict[str, np.ndarray]:
    """Each stream's dropouts in [``t0``, ``t1``] [s] as (D, 2) [start, end] intervals [s]:
    starts a Poisson process at the stream's ``per_minute``, durations uniform in its
    [``shortest_s``, ``longest_s``]. Drawn from a generator of their own (``spec.seed``, the
    scenario's seed): a logger without dropouts samples as it always did."""
    rng = np.random.default_rng([spec.seed, sc_seed, 46])
    out: dict[str, np.ndarray] = {}
    for stream, per_min, shortest, longest in spec.dropouts:
        n = rng.poisson(per_min * (t1 - t0) / 60.0)
        start = np.sort(rng.uniform(t0, t1, n))
        end = start + rng.uniform(shortest, longest, n)
        iv = np.column_stack([start, end])
        out[stream] = iv if stream not in out else np.vstack([out[stream], iv])
    return out


def _kept(t: np.ndarray, rows: np.ndarray, intervals: np.ndarray | None) -> np.ndarray:
    """The ``rows`` whose times ``t[rows]`` [s] lie outside every interval (D, 2) [s]."""
    if intervals is None or not len(intervals):
        return rows
    tr = t[rows]
    inside = np.zeros(len(rows), dtype=bool)
    for a, b in intervals:
        inside[np.searchsorted(tr, a):np.searchsorted(tr, b, side="right")] = True
    return rows[~inside]


def sample_log(sc: Scenario, truth: Truth, spec: LoggerSpec) -> dict[str, np.ndarray]:
    """The logger's columns (name -> (R,) values, NaN = no sample; ``state`` as strings)."""
    rng = np.random.default_rng(spec.seed + 7919 * sc.seed + 1)
    nz, model = sc.noise, sc.model
    ids = model.cable_ids
    t = _instants(truth.t[0], truth.t[-1], spec.rows_hz, spec.jitter_s, rng)
    R = len(t)
    t[0] = truth.t[0]  # the log starts with the first cycle at the initialisation
    cols: dict[str, np.ndarray] = {"t": t}
    drops = dropout_intervals(spec, sc.seed, t[0], t[-1])
    if spec.controller_columns:
        p_des, l_cmd = _at(truth.t, truth.pose_des, t), _at(truth.t, truth.l_cmd, t)
        for a, ax in enumerate(POSE_AXES):
            cols[f"{ax}_des"] = p_des[:, a]
        for j, c in enumerate(ids):
            cols[f"l_cmd_{c}"] = l_cmd[:, j]
    exit_idx = [ids.index(c) for c in sc.poses.exit_points] if sc.recording.tracker else []
    for stream in STREAMS:
        if stream == "tracker" and not sc.recording.tracker:
            continue
        if stream == "load_cells" and not sc.recording.load_cells:
            continue
        own = _instants(t[0], t[-1], spec.rate(stream), spec.jitter_s, rng)
        if spec.rate(stream) >= spec.rows_hz:  # read every cycle
            rows = np.arange(R)
        else:  # the row nearest each of the stream's own instants
            k = np.clip(np.searchsorted(t, own), 1, R - 1)
            k -= (own - t[k - 1]) < (t[k] - own)
            rows = np.unique(k)
        rows = _kept(t, rows, drops.get(stream))
        tr = t[rows]
        for name, vals in _stream_values(stream, truth, tr, nz, exit_idx, ids, rng).items():
            col = np.full(R, np.nan)
            col[rows] = vals
            cols[name] = col
    if spec.controller_columns and sc.recording.state_column:
        k = np.clip(np.searchsorted(truth.t, t, side="right") - 1, 0, len(truth.t) - 1)
        cols["state"] = truth.label[k]
    return cols


def _stream_values(stream: str, truth: Truth, t: np.ndarray, nz, exit_idx: list[int],
                   ids: list[str], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One stream's readings at its instants ``t``: truth plus the sensor's noise."""
    out: dict[str, np.ndarray] = {}
    if stream == "encoders":
        lm = _at(truth.t, truth.l_meas, t)
        if nz.encoder_m > 0:
            lm = np.round(lm / nz.encoder_m) * nz.encoder_m
        for j, c in enumerate(ids):
            out[f"l_meas_{c}"] = lm[:, j]
    elif stream == "load_cells":
        tau = _at(truth.t, truth.tau, t) + rng.normal(0, nz.load_cell_n, (len(t), len(ids)))
        for j, c in enumerate(ids):
            out[f"tau_{c}"] = tau[:, j]
    else:
        pose = _at(truth.t, truth.pose, t)
        pose[:, :3] += rng.normal(0, nz.tracker_m, (len(t), 3))
        pose[:, 3:] += rng.normal(0, nz.tracker_rad, (len(t), 3))
        for a, ax in enumerate(POSE_AXES):
            out[f"{ax}_meas"] = pose[:, a]
        if exit_idx:
            ex = _at(truth.t, truth.exits[:, exit_idx], t)
            ex = ex + rng.normal(0, nz.exit_m, ex.shape)
            for q, k in enumerate(exit_idx):
                for c, ax in enumerate("xyz"):
                    out[f"a{ax}_meas_{ids[k]}"] = ex[:, q, c]
    return out


def _group(name: str) -> str:
    """The stream a column belongs to (``controller`` for commands and ``state``)."""
    if name.startswith("l_meas_"):
        return "encoders"
    if name.startswith("tau_"):
        return "load_cells"
    if name.endswith("_meas") or name.startswith(("ax_meas_", "ay_meas_", "az_meas_")):
        return "tracker"
    return "controller"


def write_log(out: str | Path, sc: Scenario, spec: LoggerSpec,
              truth: Truth | None = None) -> Path:
    """Write the recording directory ``out`` of the scenario's campaign as the logger
    ``spec`` writes it; returns ``out``."""
    truth = truth if truth is not None else simulate_truth(sc, spec.physics_hz)
    cols = sample_log(sc, truth, spec)
    d = Path(out)
    names = list(cols)
    if spec.split == "sensor":
        parts = []
        for g in ("encoders", "load_cells", "tracker"):
            own = [c for c in names if c != "t" and _group(c) in
                   ((g, "controller") if g == "encoders" else (g,))]
            if not own:
                continue
            num = [c for c in own if c != "state"]
            rows = np.isfinite(np.column_stack([cols[c] for c in num])).any(axis=1)
            parts.append((f"{g}.csv", ["t"] + own, rows))
    elif spec.split == "time" and spec.files > 1:
        edges = np.linspace(0, len(cols["t"]), spec.files + 1).astype(int)
        parts = []
        for k in range(spec.files):
            rows = np.zeros(len(cols["t"]), dtype=bool)
            rows[edges[k]:edges[k + 1]] = True
            parts.append((f"recording-{k + 1:03d}.csv", names, rows))
    elif spec.split is None or spec.files == 1:
        parts = [("recording.csv", names, np.ones(len(cols["t"]), dtype=bool))]
    else:
        raise ValueError(f"split: {spec.split!r} is not None, 'time' or 'sensor'")
    samples = [p[0] for p in parts]
    rates = ", ".join(f"{s} {spec.rate(s):g} Hz" for s in STREAMS)
    meta = {"format": FORMAT, "samples": samples[0] if len(samples) == 1 else samples,
            "notes": f"logger: rows at {spec.rows_hz:g} Hz, {rates}; jitter "
                     f"{spec.jitter_s * 1e3:g} ms"}
    write_header_files(d, sc.model, sc.init_pose, meta,
                       robot_header=f"model the controller ran with ({sc.model.name})")
    for fname, header, rows in parts:
        _write_csv(d / fname, {c: cols[c][rows] for c in header}, spec.empty)
    return d


def _write_csv(path, cols: dict[str, np.ndarray], empty: str, header: bool = True) -> None:
    """Write columns as CSV (floats in full precision; NaN written as ``empty``) to the file
    ``path`` (atomically), or append them to an open binary file (``header`` or not)."""
    from bench.streams import _polars_usable

    _polars_usable()  # this process starts polars' thread pool: its forked children read
    import polars as pl

    series = [pl.Series(name, v.astype(str)) if v.dtype.kind in "USO"
              else pl.Series(name, v, nan_to_null=True) for name, v in cols.items()]
    if not isinstance(path, Path):
        pl.DataFrame(series).write_csv(path, null_value=empty, include_header=header)
        return
    tmp = path.with_name(f".{path.name}.tmp")
    pl.DataFrame(series).write_csv(tmp, null_value=empty)
    tmp.replace(path)


def write_long_log(out: str | Path, sc: Scenario, spec: LoggerSpec, truth: Truth,
                   window_rows: int = 500_000) -> Path:
    """Write the recording directory ``out`` like :func:`write_log` (one file, or
    ``split="time"`` into ``spec.files`` parts), ``window_rows`` rows at a time: an hours-long
    log is never held whole (the instants of every row and sample are; 8 bytes each).
    The noise is drawn window by window (another draw than :func:`write_log`'s)."""
    if spec.split not in (None, "time"):
        raise ValueError(f"split: {spec.split!r}: a long log is written whole or split in time")
    rng = np.random.default_rng(spec.seed + 7919 * sc.seed + 1)
    t = _instants(truth.t[0], truth.t[-1], spec.rows_hz, spec.jitter_s, rng)
    t[0] = truth.t[0]
    R = len(t)
    own: dict[str, np.ndarray | None] = {}
    drops = dropout_intervals(spec, sc.seed, t[0], t[-1])
    for stream in STREAMS:
        if (stream == "tracker" and not sc.recording.tracker) or \
                (stream == "load_cells" and not sc.recording.load_cells):
            continue
        if spec.rate(stream) >= spec.rows_hz:
            own[stream] = None if stream not in drops else _kept(t, np.arange(R),
                                                                 drops[stream])
            continue
        inst = _instants(t[0], t[-1], spec.rate(stream), spec.jitter_s, rng)
        k = np.clip(np.searchsorted(t, inst), 1, R - 1)
        k -= (inst - t[k - 1]) < (t[k] - inst)
        own[stream] = _kept(t, np.unique(k), drops.get(stream))
    files = spec.files if spec.split == "time" else 1
    edges = np.linspace(0, R, files + 1).astype(int)
    names = [f"recording-{k + 1:03d}.csv" for k in range(files)] if files > 1 \
        else ["recording.csv"]
    d = Path(out)
    rates = ", ".join(f"{s} {spec.rate(s):g} Hz" for s in STREAMS)
    meta = {"format": FORMAT, "samples": names[0] if files == 1 else names,
            "notes": f"logger: rows at {spec.rows_hz:g} Hz, {rates}; jitter "
                     f"{spec.jitter_s * 1e3:g} ms"}
    write_header_files(d, sc.model, sc.init_pose, meta,
                       robot_header=f"model the controller ran with ({sc.model.name})")
    exit_idx = [sc.model.cable_ids.index(c) for c in sc.poses.exit_points] \
        if sc.recording.tracker else []
    for k, name in enumerate(names):
        tmp = d / f".{name}.tmp"
        with tmp.open("wb") as f:
            for r0 in range(edges[k], edges[k + 1], window_rows):
                r1 = min(r0 + window_rows, edges[k + 1])
                cols = _window(sc, truth, t, own, r0, r1, exit_idx, rng)
                _write_csv(f, cols, spec.empty, header=r0 == edges[k])
        tmp.replace(d / name)
    return d


def _window(sc: Scenario, truth: Truth, t: np.ndarray, own: dict, r0: int, r1: int,
            exit_idx: list[int], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The sensor columns of rows ``r0:r1`` (no controller columns)."""
    cols: dict[str, np.ndarray] = {"t": t[r0:r1]}
    for stream, rows in own.items():
        rows = np.arange(r0, r1) if rows is None else \
            rows[np.searchsorted(rows, r0):np.searchsorted(rows, r1)]
        vals = _stream_values(stream, truth, t[rows], sc.noise, exit_idx, sc.model.cable_ids,
                              rng)
        for name, v in vals.items():
            col = np.full(r1 - r0, np.nan)
            col[rows - r0] = v
            cols[name] = col
    return cols
