"""``cdpr commission tare|calibrate SENSOR``: zero a load cell, fit its gain from known loads.

SENSOR is a cable id (``21``) or ``unit:N`` (Modbus unit id). Both read the cell's raw value
(``measured``, before any calibration) as the mean of ``--samples`` fresh samples (the
cell's counter must advance; a cell that is not OK is an error naming the unit), and write
the calibration file the HAL reads (``--loadcell-calibration``, default
``loadcell_calibration.toml`` in the current directory; the old file is kept as a
timestamped backup). The model is the HAL's: ``measured = gain * true + offset``.

- ``tare``: the cell carries ``--load`` newtons (default 0: unloaded): ``offset = measured -
  gain * load``, the gain kept.
- ``calibrate``: known loads one after another: on a terminal each is asked for
  (``12.5`` = kg, ``122.6N`` = newtons; an empty line ends); with ``--weights 0,10,20kg,196N``
  each is announced and measured after Enter (``--no-wait``: at once). Two or more distinct
  loads: least-squares fit of gain and offset, with the residual of every point; one load:
  the gain through it with the offset kept (tare first). Masses become forces with ``--g``
  (default 9.81 m/s^2).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.commission.common import (
    DEFAULT_CALIBRATION,
    CommissionError,
    Ui,
    register_map_of,
    resolve_sensor,
)
from bench.commission.report import Section


@dataclass(frozen=True)
class RawMean:
    """Mean of ``n`` fresh raw samples [N] with their standard deviation."""

    mean_N: float
    std_N: float
    n: int


def measure_raw(client, k: int, samples: int, timeout_s: float = 10.0,
                period_s: float = 0.02) -> RawMean:
    """Mean of ``samples`` fresh raw readings of cell ``k`` (``client`` with the identity
    calibration, not started: polled here). A poll without an answer (a frame lost on the
    line, a unit slow to answer) is polled again until ``timeout_s``; CommissionError when the
    cell reports a fault (sensor fault, out of range, a Modbus exception, not a number), when
    no valid reading came within ``timeout_s`` (naming the last problem), or when its counter
    does not advance within ``timeout_s``."""
    from hal.loadcell_client import CableStatus

    transient = {CableStatus.NO_DATA, CableStatus.STALE, CableStatus.TIMEOUT,
                 CableStatus.COMM_ERROR}
    values: list[float] = []
    last_counter = None
    deadline = time.monotonic() + timeout_s
    while len(values) < samples:
        client.poll_once()
        r = client.read()
        st = CableStatus(int(r.status[k]))
        if st is not CableStatus.OK:
            what = r.messages[k] or client.map.describe(k)
            if st not in transient:
                raise CommissionError(f"{what}: no valid reading")
            if time.monotonic() > deadline:
                raise CommissionError(f"{what}: no valid reading within {timeout_s:g} s")
            time.sleep(period_s)
            continue
        counter = int(r.counter[k])
        if counter != last_counter:
            if last_counter is not None:  # the first value may predate the load
                values.append(float(r.values_N[k]))
            last_counter = counter
        if time.monotonic() > deadline:
            raise CommissionError(f"{client.map.describe(k)}: only {len(values)} fresh samples "
                                  f"of {samples} in {timeout_s:g} s (counter stuck at "
                                  f"{counter}?)")
        if len(values) < samples:
            time.sleep(period_s)
    a = np.asarray(values)
    return RawMean(float(a.mean()), float(a.std(ddof=1)) if len(a) > 1 else 0.0, len(a))


def parse_load(text: str, g: float) -> float:
    """A load [N] from ``12.5`` / ``12.5kg`` (mass) or ``122.6N`` (force)."""
    t = text.strip().replace(" ", "")
    try:
        if t.lower().endswith("kg"):
            return float(t[:-2]) * g
        if t.lower().endswith("n"):
            return float(t[:-1])
        return float(t) * g
    except ValueError:
        raise CommissionError(f"load {text!r}: expected a mass in kg (12.5, 12.5kg) or a "
                              "force in N (122.6N)", 2) from None


@dataclass(frozen=True)
class Fit:
    gain: float
    offset_N: float
    residuals_N: np.ndarray  #: measured - (gain * load + offset), per point
    rms_N: float
    method: str


def fit_gain(loads_N: np.ndarray, raw_N: np.ndarray, offset_N: float) -> Fit:
    """``raw = gain * load + offset``: least squares over two or more distinct loads, or the
    gain through one loaded point with ``offset_N`` kept."""
    F = np.asarray(loads_N, float)
    m = np.asarray(raw_N, float)
    if len(F) == 0 or not np.any(F != 0):
        raise CommissionError("calibrate needs at least one non-zero known load")
    if len(np.unique(F)) >= 2:
        A = np.column_stack([F, np.ones_like(F)])
        (gain, offset), *_ = np.linalg.lstsq(A, m, rcond=None)
        method = f"least squares over {len(F)} points"
    else:
        nz = F != 0
        gain = float(np.mean((m[nz] - offset_N) / F[nz]))
        offset = offset_N
        method = "one load: gain through it, offset kept"
    if not gain > 0:
        raise CommissionError(f"fitted gain {gain:.6g} is not positive: loads entered in the "
                              "wrong order or the cell is wired backwards?")
    res = m - (gain * F + offset)
    return Fit(float(gain), float(offset), res, float(np.sqrt(np.mean(res ** 2))), method)


def _client(args: argparse.Namespace):
    from hal.loadcell_client import LoadCellClient

    if args.modbus is None:
        raise CommissionError("no load cells: give --modbus HOST:PORT or rtu:DEVICE:BAUD", 2)
    rmap = register_map_of(args)
    return rmap, LoadCellClient(args.modbus, register_map=rmap, calibration=None,
                                timeout_s=args.loadcell_timeout, stale_s=args.loadcell_stale)


def _calibration_file(args: argparse.Namespace, rmap):
    from hal.loadcell_calibration import LoadCellCalibration, load_calibration

    path = Path(args.loadcell_calibration or DEFAULT_CALIBRATION)
    cal = load_calibration(path, rmap.cables) if path.exists() else \
        LoadCellCalibration.identity(rmap.cables)
    return path, cal


def _replace(cal, k: int, gain: float, offset: float, source: str):
    from hal.loadcell_calibration import LoadCellCalibration

    g = cal.gain.copy()
    o = cal.offset_N.copy()
    g[k], o[k] = gain, offset
    return LoadCellCalibration(g, o, cal.cables, source)


def run_tare(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    from bench.commission.files import write_calibration

    if args.samples < 1:
        raise CommissionError(f"--samples {args.samples}: must be >= 1", 2)
    rmap, client = _client(args)
    k = resolve_sensor(rmap, args.sensor)
    path, cal = _calibration_file(args, rmap)
    who = rmap.describe(k)
    section.fact("load cell", who)
    try:
        ui.progress(f"{who}: averaging {args.samples} samples with {args.load:g} N on it ...")
        raw = measure_raw(client, k, args.samples)
    finally:
        client.stop()
    gain = float(cal.gain[k])
    old = float(cal.offset_N[k])
    offset = raw.mean_N - gain * args.load
    new = _replace(cal, k, gain, offset, str(path))
    saved = write_calibration(path, new, f"tare of cable {rmap.cables[k]} "
                              f"(offset {old:.4f} -> {offset:.4f} N)")
    msg = (f"{who}: raw {raw.mean_N:.4f} N (std {raw.std_N:.4f} N, {raw.n} samples) with "
           f"{args.load:g} N: offset_{rmap.cables[k]} {old:.4f} -> {offset:.4f} N, gain "
           f"{gain:.6f} kept; written to {path}" + (f" (old file kept as {saved})" if saved
                                                    else ""))
    ui.say(msg)
    section.fact("result", msg)
    ui.emit({"sensor": rmap.cables[k], "device_id": int(rmap.unit_ids[k]), "raw_N": raw.mean_N,
             "std_N": raw.std_N, "samples": raw.n, "load_N": args.load, "offset_old_N": old,
             "offset_N": offset, "gain": gain, "file": str(path),
             "backup": str(saved) if saved else None})
    return 0


def collect_points(measure: Callable[[], RawMean], loads: list[float] | None, ui: Ui,
                   ask: Callable[[str], str | None], wait: bool, g: float
                   ) -> list[tuple[float, RawMean]]:
    """Known loads one after another: (load [N], raw mean) pairs. ``ask(prompt)`` returns
    the operator's line (None at the end of the input)."""
    points: list[tuple[float, RawMean]] = []
    if loads is not None:
        for i, F in enumerate(loads):
            if wait:
                line = ask(f"load {i + 1}/{len(loads)}: put {F:.3f} N ({F / g:.3f} kg) on the "
                           "cell, then press Enter: ")
                if line is None:
                    raise CommissionError("input ended before all loads were measured")
            points.append((F, measure()))
            ui.progress(f"  {F:10.3f} N: raw {points[-1][1].mean_N:10.4f} N "
                        f"(std {points[-1][1].std_N:.4f})")
        return points
    while True:
        line = ask(f"load {len(points) + 1} on the cell (kg, or N with suffix N; empty line "
                   "ends): ")
        if line is None or not line.strip():
            return points
        F = parse_load(line, g)
        points.append((F, measure()))
        ui.progress(f"  {F:10.3f} N: raw {points[-1][1].mean_N:10.4f} N "
                    f"(std {points[-1][1].std_N:.4f})")


def _ask_stdin(prompt: str) -> str | None:
    print(prompt, end="", file=sys.stderr, flush=True)
    line = sys.stdin.readline()
    return None if line == "" else line


def run_calibrate(args: argparse.Namespace, ui: Ui, section: Section) -> int:
    from bench.commission.files import write_calibration

    if args.samples < 1:
        raise CommissionError(f"--samples {args.samples}: must be >= 1", 2)
    if not args.g > 0:
        raise CommissionError(f"--g {args.g}: must be > 0", 2)
    loads = [parse_load(x, args.g) for x in args.weights.split(",")] if args.weights else None
    if loads is None and not sys.stdin.isatty() and not args.stdin_loads:
        raise CommissionError("no terminal to ask for the loads: give --weights W1,W2,... "
                              "(or --stdin-loads to read them as lines from stdin)", 2)
    rmap, client = _client(args)
    k = resolve_sensor(rmap, args.sensor)
    path, cal = _calibration_file(args, rmap)
    who = rmap.describe(k)
    section.fact("load cell", who)
    try:
        points = collect_points(lambda: measure_raw(client, k, args.samples), loads, ui,
                                _ask_stdin, not args.no_wait, args.g)
    finally:
        client.stop()
    F = np.array([p[0] for p in points])
    m = np.array([p[1].mean_N for p in points])
    fit = fit_gain(F, m, float(cal.offset_N[k]))
    c = rmap.cables[k]
    from bench.tables import col, render

    rows = [[f"{Fi:.3f}", f"{mi:.4f}", f"{p[1].std_N:.4f}", f"{r:+.4f}"]
            for Fi, mi, p, r in zip(F, m, points, fit.residuals_N, strict=True)]
    ui.say(f"{who}: {fit.method}")
    ui.say(render([col("load", "N"), col("raw", "N"), col("std", "N"), col("residual", "N")],
                  rows, stream=ui.out))
    old_g, old_o = float(cal.gain[k]), float(cal.offset_N[k])
    new = _replace(cal, k, fit.gain, fit.offset_N, str(path))
    saved = write_calibration(path, new, f"calibration of cable {c} from {len(points)} "
                              f"load(s), residual RMS {fit.rms_N:.4f} N")
    msg = (f"gain_{c} {old_g:.6f} -> {fit.gain:.6f}, offset_{c} {old_o:.4f} -> "
           f"{fit.offset_N:.4f} N, residual RMS {fit.rms_N:.4f} N; written to {path}"
           + (f" (old file kept as {saved})" if saved else ""))
    ui.say(msg)
    section.fact("result", msg)
    section.table(["load [N]", "raw [N]", "std [N]", "residual [N]"], rows)
    ui.emit({"sensor": c, "device_id": int(rmap.unit_ids[k]),
             "points": [{"load_N": float(Fi), "raw_N": float(p[1].mean_N),
                         "std_N": p[1].std_N, "samples": p[1].n, "residual_N": float(r)}
                        for Fi, p, r in zip(F, points, fit.residuals_N, strict=True)],
             "gain": fit.gain, "offset_N": fit.offset_N, "residual_rms_N": fit.rms_N,
             "gain_old": old_g, "offset_old_N": old_o, "method": fit.method,
             "file": str(path), "backup": str(saved) if saved else None})
    return 0
