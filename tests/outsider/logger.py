"""A lab logger's habits, each allowed by docs/formats/recording*.md.

Streams at their own rates with jittered clocks, rows at the encoder cycle (other streams in
the nearest row) or one row per sample, columns in any order, unknown extra columns, `nan`,
`NaN` or empty for "no sample", a clock not starting at 0, CRLF line ends, one run split
across files in time or by sensor.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tests.outsider.campaign import Campaign, readings
from tests.outsider.physics import Robot

POSE = ("x_meas", "y_meas", "z_meas", "roll_meas", "pitch_meas", "yaw_meas")


@dataclass(frozen=True)
class Habits:
    """How this logger writes. Rates [Hz], times [s], noise in SI units."""

    encoders_hz: float = 200.0
    load_cells_hz: float = 50.0
    tracker_hz: float = 20.0
    layout: str = "cycle"            # "cycle": rows at the encoder cycle; "sample": a row
    #                                  per sample
    jitter_s: float = 3e-4
    t0_s: float = 1234.5678          # the logger's clock at the campaign's start
    empty: tuple = ("",)             # tokens for "no sample", drawn per field
    crlf: bool = False
    shuffle: bool = False            # a column order of its own (per file)
    extra: bool = False              # unknown columns: temperatures, drive speeds
    controller_hz: float | None = None  # commanded pose (x_des ...) at this rate, else none
    drop: tuple = ()                 # streams this bench does not have ("tracker", ...)
    tracker_gaps: tuple = ()         # (start, duration) [s of the campaign]: line of sight lost
    state_words: tuple | None = None  # a `state` column: (word standing, word moving)
    split: str | None = None         # None, "time" (consecutive parts) or "sensor"
    parts: int = 3
    noise_l_m: float = 5e-6
    noise_tau_n: float = 1.5
    noise_pos_m: float = 5e-5
    noise_ang_rad: float = 3e-5


def _clock(hz: float, duration: float, jitter: float, phase: float,
           rng: np.random.Generator) -> np.ndarray:
    """A sensor's sample instants [s]: nominal period plus jitter, strictly increasing."""
    t = np.arange(phase, duration, 1.0 / hz)
    return np.sort(t + rng.normal(0.0, jitter, len(t)))


def _streams(model: Robot, true: Robot, camp: Campaign, habits: Habits, pretension: float,
             offset: np.ndarray, rng: np.random.Generator, slip_at_s: float | None) -> dict:
    """{stream: (times, {column: values})} with noise, times from the campaign's start."""
    dur = camp.duration_s
    te = _clock(habits.encoders_hz, dur, habits.jitter_s, 0.0, rng)
    if habits.layout == "cycle":
        tl = te[:: round(habits.encoders_hz / habits.load_cells_hz)]
        tt = te[1:: round(habits.encoders_hz / habits.tracker_hz)]
    else:
        tl = _clock(habits.load_cells_hz, dur, habits.jitter_s, 0.0031, rng)
        tt = _clock(habits.tracker_hz, dur, habits.jitter_s, 0.0173, rng)
    ids = model.ids
    enc = readings(model, true, camp, te, pretension, offset, slip_at_s).lengths_read
    enc = enc + rng.normal(0, habits.noise_l_m, enc.shape)
    tau = readings(model, true, camp, tl, pretension, offset, slip_at_s).tensions
    tau = tau + rng.normal(0, habits.noise_tau_n, tau.shape)
    for start, dur in habits.tracker_gaps:
        tt = tt[(tt < start) | (tt > start + dur)]
    pose = readings(model, true, camp, tt, pretension, offset, slip_at_s).poses
    sd = np.array([habits.noise_pos_m] * 3 + [habits.noise_ang_rad] * 3)
    pose = pose + rng.normal(0, 1, pose.shape) * sd
    out = {}
    if habits.controller_hz:  # the pose the controller aimed at: the true pose
        tc = te[:: round(habits.encoders_hz / habits.controller_hz)]
        des = readings(model, true, camp, tc, pretension, offset, slip_at_s).poses
        out["controller"] = (tc, {POSE[i].replace("_meas", "_des"): des[:, i] for i in range(6)})
    return out | {
        "encoders": (te, {f"l_meas_{c}": enc[:, i] for i, c in enumerate(ids)}),
        "load_cells": (tl, {f"tau_{c}": tau[:, i] for i, c in enumerate(ids)}),
        "tracker": (tt, {POSE[i]: pose[:, i] for i in range(6)}),
    }


def _extra(times: np.ndarray, rng: np.random.Generator) -> dict:
    """Unknown columns a lab logs: a temperature and a drive speed, sometimes missing."""
    temp = 21.0 + 0.01 * np.linspace(0, 1, len(times)) + rng.normal(0, 0.05, len(times))
    vel = rng.normal(0, 1e-3, len(times))
    vel[rng.random(len(times)) < 0.1] = np.nan
    return {"temp_c": temp, "vel_11": vel}


def _table(streams: dict, names: list, habits: Habits, rng: np.random.Generator):
    """Rows (times, {column: values with nan for no sample}) of the named streams merged."""
    if habits.layout == "cycle" and "encoders" in names:
        times = streams["encoders"][0]
        cols = {}
        for name in names:
            ts, values = streams[name]
            at = np.searchsorted(times, ts)          # the same instants: exact rows
            for col, v in values.items():
                full = np.full(len(times), np.nan)
                full[at] = v
                cols[col] = full
    else:
        times = np.concatenate([streams[n][0] for n in names])
        order = np.argsort(times, kind="stable")
        times = times[order]
        cols, start = {}, 0
        total = len(times)
        for name in names:
            ts, values = streams[name]
            for col, v in values.items():
                full = np.full(total, np.nan)
                full[start:start + len(ts)] = v
                cols[col] = full
            start += len(ts)
        cols = {c: v[order] for c, v in cols.items()}
    if habits.extra:
        cols.update(_extra(times, rng))
    return times, cols


def _states(camp: Campaign, times: np.ndarray, words: tuple) -> np.ndarray:
    """The lab's own state word per row: standing (init, dwells) or moving."""
    moving = np.zeros(len(times), dtype=bool)
    for t0, t1, a, b in camp.segments:
        if np.any(a != b):
            moving |= (times >= t0) & (times < t1)
    return np.where(moving, words[1], words[0]).astype(object)


def _write_csv(path: Path, times: np.ndarray, cols: dict, habits: Habits,
               rng: np.random.Generator) -> None:
    """One CSV file: header, then a row per time; empty tokens drawn per field."""
    names = ["t", *cols]
    if habits.shuffle:
        names = list(rng.permutation(names))
    data = {"t": times + habits.t0_s, **cols}
    text = {}
    if "state" in cols:
        text["state"] = cols["state"]
    for name in (n for n in names if n != "state"):
        fmt = ("%.4f" if name == "t" else "%.7g" if name.startswith(("tau", "temp", "vel"))
               else "%.9f")
        s = np.char.mod(fmt, data[name]).astype(object)
        gone = np.isnan(data[name])
        s[gone] = rng.choice(habits.empty, int(gone.sum()))
        text[name] = s
    eol = "\r\n" if habits.crlf else "\n"
    rows = zip(*(text[n] for n in names), strict=True)
    lines = [",".join(names)] + [",".join(row) for row in rows]
    path.write_bytes((eol.join(lines) + eol).encode())


def write_recording(out: Path, model_toml: Path, model: Robot, true: Robot, camp: Campaign,
                    habits: Habits, *, pretension_n: float, length_offset_m: np.ndarray,
                    seed: int, slip_at_s: float | None = None) -> Path:
    """Write a cdpr-recording/1 directory `out` and return it."""
    rng = np.random.default_rng(seed)
    out.mkdir(parents=True, exist_ok=True)
    (out / "robot.toml").write_text(Path(model_toml).read_text())
    streams = _streams(model, true, camp, habits, pretension_n, length_offset_m, rng,
                       slip_at_s)
    streams = {k: v for k, v in streams.items() if k not in habits.drop}
    files: list[str] = []
    if habits.split == "sensor":
        for name in streams:
            times, cols = _table(streams, [name], habits, rng)
            files.append(f"{name}.csv")
            _write_csv(out / files[-1], times, cols, habits, rng)
    else:
        times, cols = _table(streams, list(streams), habits, rng)
        if habits.state_words:
            cols["state"] = _states(camp, times, habits.state_words)
        parts = habits.parts if habits.split == "time" else 1
        bounds = np.linspace(0, len(times), parts + 1).astype(int)
        for k in range(parts):
            files.append("samples.csv" if parts == 1 else f"run-part{k + 1:03d}.csv")
            sl = slice(bounds[k], bounds[k + 1])
            _write_csv(out / files[-1], times[sl], {c: v[sl] for c, v in cols.items()}, habits, rng)
    p0 = camp.init_pose + rng.normal(0, 1e-5, 6)
    samples = f'"{files[0]}"' if len(files) == 1 else "[" + ", ".join(f'"{f}"' for f in files) + "]"
    (out / "meta.toml").write_text(
        'format = "cdpr-recording/1"\nrobot = "robot.toml"\n'
        f"samples = {samples}\ninit_pose = [{', '.join(repr(float(v)) for v in p0)}]\n"
        'pose_source = "tracker (outsider)"\nlab_operator = "someone else"\n')
    return out
