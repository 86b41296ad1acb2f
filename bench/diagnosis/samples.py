"""Samples of a recording: dwells averaged, quasi-static rows of moves, replicate groups.

A recording (``cdpr-recording/1``) may hold dwells (rows at one commanded pose,
replicate visits of a target), continuous moves (rows at 10-50 Hz along a path),
or both, with or without a ``state`` column. :func:`prepare` turns it into
the static samples the diagnosis fits:

- **dwell samples**: consecutive rows with one commanded pose (``state`` ``init``
  or ``dwell``, or, without a state column, runs of at least two rows whose
  encoder readings stand still) are averaged; rows of a dwell where the
  measured pose still moves (a transient) are left out.
- **path samples**: rows of moves (``state`` ``move``, or single rows between
  dwells) are quasi-static where the commanded motion does not accelerate
  (inertial forces below a few percent of the weight); they are kept as single
  rows, spread evenly in time, up to a budget.
- rows in a state of a supervisor's reaction (``hold``, ``quick_stop``:
  :func:`reaction_state`) count only while the platform stands still (encoders and pose
  do not move). The format leaves state names free: rows in ``end`` or in a state the
  format does not define (another controller's ``track``, ``measure``, ``approach``, a
  lab's ``stopped`` or ``estop_reset``) are read as rows without a state column, the
  data deciding whether they stand; the words are listed (``info["states_unknown"]``).

Replicate groups (``target``) gather visits of one commanded pose, and path
rows that pass within a few millimetres of each other on different moves:
model errors repeat there, noise does not. ``block`` numbers what held-out
splits keep together (a target with all its visits, or one move).

:func:`check_values` finds impossible values (tensions far beyond the robot's
limits, poses or lengths kilometres away) and excludes them by row and column,
or refuses a column group that is wholly implausible (wrong units).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bench.diagnosis.frame import pose_rates
from bench.recording import Recording, RecordingError
from bench.streams import (
    MOTION_WINDOW_S,
    jittered,
    length_acceleration,
    long_steps,
    measured_acceleration,
    signal_noise,
    still_rows,
)

#: states in which the platform stands by design
STILL_STATES = {"init", "dwell"}
#: states of the commanded motion
MOVE_STATES = {"move"}
#: states in which the platform is not following its commanded motion (a supervisor's
#: reaction: docs/formats/recording.md): such rows count only while the platform stands still
REACTION_STATES = {"hold", "quick_stop"}
#: the other state the format defines (the run has ended): its rows are read from the data
END_STATES = {"end"}


def reaction_state(name: str) -> bool:
    """Whether the state ``name`` is a supervisor's reaction (:data:`REACTION_STATES`, in any
    letter case). A lab's own words are no reaction, whatever they contain ("stopped",
    "estop_reset", "nonstop"): their rows are read from the data (:func:`known_state`)."""
    return name.strip().lower() in REACTION_STATES


def known_state(name: str) -> bool:
    """Whether the format defines the state ``name`` (docs/formats/recording.md)."""
    return name.strip().lower() in STILL_STATES | MOVE_STATES | REACTION_STATES | END_STATES


#: commanded acceleration [m/s^2] above which a moving row is not quasi-static
ACCEL_MAX = 0.2
#: angular acceleration [rad/s^2] above which a moving row is not quasi-static
ANG_ACCEL_MAX = 0.05
#: at most this many samples are fitted (dwell samples first, then path rows)
MAX_SAMPLES = 400
#: path rows closer than this [m, rad] on different moves are replicates of each other
NEAR_M = 1e-2
NEAR_RAD = 5e-3
#: a row whose commanded pose jumps from both neighbours faster than this [m/s] is a
#: standing measurement of its own (a table of poses), not a row of a motion
JUMP_M_S = 2.0
#: at most this many path rows are kept per move, evenly spread over it
PER_MOVE = 12
#: rows of one move share its slowly varying errors (the sign of hysteresis and friction,
#: drift): a move counts as this many independent samples, its rows weighted accordingly
MOVE_INDEPENDENT = 4
#: encoder change [m] below which a cable counts as standing still between two rows
STILL_M = 2e-5


@dataclass
class Samples:
    """N static samples of a recording (NaN = not measured).

    ``count`` rows averaged; ``target`` replicate groups (visits of one pose);
    ``block`` what held-out splits keep together; ``is_init`` the initialisation
    dwell; ``kind`` 0 dwell / 1 path row; ``direction`` (N,n) sign of each cable's
    last length change before the sample (+1 paid out, -1 reeled in, 0 unknown);
    ``row`` the recording.csv line of the sample's first row; ``tau_row_sd`` the
    load-cell noise of one row [N]; ``weight`` (N,) the share of an independent sample
    each counts for (1 for dwells; rows of a move share its slow errors).
    """

    t: np.ndarray
    pose_des: np.ndarray
    pose_meas: np.ndarray
    l_meas: np.ndarray
    tau: np.ndarray
    exit_meas: np.ndarray
    count: np.ndarray
    target: np.ndarray
    is_init: np.ndarray
    tau_row_sd: float | None = None
    kind: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    block: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    direction: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    row: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    info: dict = field(default_factory=dict)
    weight: np.ndarray = field(default_factory=lambda: np.zeros(0))
    triples: Samples | None = None  # raw rows in consecutive triples (white noise)
    cluster: np.ndarray | None = None  # samples that may share errors (standard errors)
    stream: Samples | None = None  # raw rows in time order, decimated (jumps in time)
    #: times [s] where moves start, meet and end, in order (:func:`_turns`)
    turns: np.ndarray | None = None
    #: (N,6) time derivative of the measured pose [m/s, rad/s] (0 for dwells; the tracker's
    #: latency is seen through it: :func:`bench.diagnosis.frame.pose_rates`)
    pose_rate: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))

    def __post_init__(self) -> None:
        N = len(self.t)
        n = self.l_meas.shape[1] if self.l_meas.ndim == 2 else 0
        if len(self.kind) != N:
            self.kind = np.zeros(N, dtype=int)
        if len(self.block) != N:
            self.block = np.asarray(self.target, dtype=int).copy()
        if self.direction.shape != (N, n):
            self.direction = np.zeros((N, n))
        if len(self.row) != N:
            self.row = np.arange(N) + 2
        if len(self.weight) != N:
            self.weight = np.ones(N)
        if self.pose_rate.shape != (N, 6):
            self.pose_rate = np.zeros((N, 6))

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def n_targets(self) -> int:
        return int(np.unique(self.target).size) if self.n else 0

    @property
    def replicated(self) -> bool:
        """Whether some replicate group holds more than one sample."""
        return bool(self.n > self.n_targets)

    def take(self, idx: np.ndarray) -> Samples:
        return Samples(self.t[idx], self.pose_des[idx], self.pose_meas[idx], self.l_meas[idx],
                       self.tau[idx], self.exit_meas[idx], self.count[idx], self.target[idx],
                       self.is_init[idx], self.tau_row_sd, self.kind[idx], self.block[idx],
                       self.direction[idx], self.row[idx], dict(self.info), self.weight[idx],
                       pose_rate=self.pose_rate[idx])


# ----- impossible values --------------------------------------------------------------

def check_values(rec: Recording, limit: int = 20) -> list[dict]:
    """Exclude impossible values of ``rec`` in place (set to NaN) and list them.

    Tensions beyond 10 times the robot's ``tension_max`` (or below minus that),
    positions farther than 10 times the robot's size from its exit points, angles
    beyond 2 pi, lengths negative or beyond 10 times the robot's size, or NaN in a row
    whose other lengths are numbers (a missing encoder value, not a row without an encoder
    sample). Returns ``[{"row", "column", "value", "why"}]`` (the first ``limit``; ``row``
    is the recording.csv line) plus a last entry ``{"more": k}`` when more were excluded.
    Raises :class:`RecordingError` when most values of a column group are impossible
    (e.g. tensions in the wrong unit): the recording cannot be trusted.
    """
    robot = rec.robot
    size = float(np.ptp(robot.exits, axis=0).max() + np.linalg.norm(robot.anchors, axis=1).max())
    size = max(size, 1.0)
    centre = robot.exits.mean(axis=0)
    out: list[dict] = []
    count = 0

    def flag(bad: np.ndarray, arr: np.ndarray, names: list[str], why: str, group: str) -> None:
        nonlocal count
        finite = np.isfinite(arr)
        if not bad.any():
            return
        share = bad.sum() / max(finite.sum(), 1)
        if share > 0.5:
            k = int(np.argwhere(bad)[0][0])
            k = int(rec.source_rows[k]) if rec.source_rows is not None else k
            raise RecordingError(
                f"{_samples_file(rec)}: {group}: {bad.sum()} of {finite.sum()} values "
                f"are impossible ({why}; e.g. line {k + 2}): wrong units or columns?")
        for idx in np.argwhere(bad):
            i = int(idx[0])
            col = names[int(idx[1])] if len(idx) > 1 else names[0]
            if count < limit:
                out.append({"row": i + 2, "column": col, "value": float(arr[tuple(idx)]),
                            "why": why})
            count += 1
        arr[bad] = np.nan

    cids = robot.cable_ids
    with np.errstate(invalid="ignore"):
        tmax = 10.0 * robot.tension_max
        flag(np.abs(rec.tau) > tmax, rec.tau, [f"tau_{c}" for c in cids],
             f"tension beyond 10 x tension_max = {tmax:g} N", "tensions")
        # NaN where a length is required: the row's encoders sampled (another length of
        # the row is a number) in a column that has numbers; a row without any length is
        # "no sample" (a stream at its own rate), a column without any is "not measured"
        have = np.isfinite(rec.l_meas)
        nan_len = (np.isnan(rec.l_meas) & have.any(axis=1, keepdims=True)
                   & have.any(axis=0, keepdims=True))
        flag((rec.l_meas < 0) | (rec.l_meas > 10 * size), rec.l_meas,
             [f"l_meas_{c}" for c in cids], f"length outside 0 .. {10 * size:.0f} m", "lengths")
        flag(nan_len, rec.l_meas, [f"l_meas_{c}" for c in cids],
             "length NaN where the row's other encoders sampled", "lengths")
        for name, arr in (("meas", rec.pose_meas), ("des", rec.pose_des)):
            axes = [f"{a}_{name}" for a in ("x", "y", "z", "roll", "pitch", "yaw")]
            far = np.linalg.norm(arr[:, :3] - centre, axis=1) > 10 * size
            # the coordinates that are themselves far named as such; the rest of such a
            # row's position goes with it, said so (not "more than ... m" of a sane value)
            own = np.zeros(arr.shape, dtype=bool)
            own[:, :3] = far[:, None] & (np.abs(arr[:, :3] - centre) > 10 * size / np.sqrt(3))
            own[:, 3:] = np.abs(arr[:, 3:]) > 2 * np.pi
            rest = np.zeros(arr.shape, dtype=bool)
            rest[:, :3] = far[:, None] & np.isfinite(arr[:, :3])
            rest &= ~own
            flag(own, arr, axes, f"pose more than {10 * size:.0f} m from the robot or angle "
                                 f"beyond 2 pi", f"{name} poses")
            flag(rest, arr, axes, "with the rest of its row's position, which is more than "
                                  f"{10 * size:.0f} m from the robot", f"{name} poses")
        e = rec.exit_meas.reshape(rec.n_samples, -1)
        far = np.zeros(rec.exit_meas.shape[:2], dtype=bool)
        seen = np.flatnonzero(np.isfinite(e).any(axis=1))  # (a max over NaN is slow)
        far[seen] = np.abs(rec.exit_meas[seen] - robot.exits[None]).max(axis=2) > size
        bad = np.repeat(far, 3, axis=1) & np.isfinite(e)
        flag(bad, e, [f"a{ax}_meas_{c}" for c in cids for ax in "xyz"],
             f"exit point more than {size:.0f} m from the model's", "exit points")
        rec.exit_meas[:] = e.reshape(rec.exit_meas.shape)
    if count > limit:
        out.append({"more": count - limit})
    return out


def _samples_file(rec: Recording) -> str:
    """The samples file(s) meta.toml names (a split recording's lines are its merged rows')."""
    files = rec.meta.get("samples", "recording.csv")
    if isinstance(files, list):
        return f"{rec.path / files[0]} (and the other files of the split recording)"
    return str(rec.path / str(files))


# ----- rows -> samples ------------------------------------------------------------------

def _keys(rec: Recording) -> np.ndarray:
    """A per-row key that stays constant during a dwell (what the controller aimed at)."""
    for arr, scale in ((rec.pose_des, 1e6), (rec.l_cmd, 1e6)):
        cols = np.isfinite(arr).any(axis=0)  # the columns the recording has
        if cols.any():
            k = np.round(np.nan_to_num(arr[:, cols], nan=1e9) * scale)
            return k.reshape(len(k), -1)
    cols = np.isfinite(rec.pose_meas).any(axis=0)
    key = np.arange(rec.n_samples)[:, None].astype(float)
    if cols.any():
        # no commanded values: rows whose measured pose stays within 2 mm / 2 mrad
        key = np.round(np.nan_to_num(rec.pose_meas[:, cols], nan=1e9) / 2e-3)
    judged = still_rows(rec)
    if judged is None:
        return key
    # where the measured motion can be judged (stretches of rows without gaps): a run of
    # standing rows is one key, a moving row its own (-(row + 1)), whatever the noise
    still, known = judged
    run = np.cumsum(np.r_[True, (still[1:] != still[:-1]) | _moved_across_gap(rec)]
                    ).astype(float)
    by_motion = np.where(still, run, -(np.arange(rec.n_samples) + 1.0))
    width = key.shape[1]
    return np.where(known[:, None], np.repeat(by_motion[:, None], width, axis=1) + 0.5, key)


def _moved_across_gap(rec: Recording) -> np.ndarray:
    """(N-1,) bool: between rows k and k+1 the log has a gap (longer than half the motion
    filter's window: the filter judges each side apart) across which the encoder readings
    (by more than STILL_M; else the measured position, by 1 mm) changed, or a reading is
    missing on one side: standing rows on either side are no one dwell."""
    N = rec.n_samples
    gap = np.diff(rec.t) > 0.5 * MOTION_WINDOW_S
    out = np.zeros(max(N - 1, 0), dtype=bool)
    if not gap.any():
        return out
    for arr, tol in ((rec.l_meas, STILL_M), (rec.pose_meas[:, :3], 1e-3)):
        cols = np.isfinite(arr).any(axis=0)
        if cols.any():  # (a reading missing on one side: an infinite change)
            d = np.nan_to_num(np.abs(np.diff(arr[:, cols], axis=0)), nan=np.inf)
            return gap & (d > tol).any(axis=1)
    return out


def _commanded(rec: Recording) -> bool:
    """Whether the recording holds what the controller aimed at (commanded pose or lengths)."""
    return bool(np.isfinite(rec.pose_des).any() or np.isfinite(rec.l_cmd).any())


def _moving(rec: Recording) -> np.ndarray:
    """(N,) bool: rows that measurements alone show moving, in a recording without the
    controller's columns (:func:`bench.streams.still_rows`); none otherwise."""
    judged = None if _commanded(rec) else still_rows(rec)
    if judged is None:
        return np.zeros(rec.n_samples, dtype=bool)
    still, known = judged
    return known & ~still


def _runs(keys: np.ndarray, states: list[str] | None, t: np.ndarray | None = None,
          source_rows: np.ndarray | None = None) -> list[tuple[int, int]]:
    """Runs ``[a, b)`` of rows with one key and state: a new run where either changes, and
    after a gap of the log (``t`` [s]: a step longer than :data:`bench.streams.GAP_PERIODS`
    median steps, the streams' own gap; a step over rows the reader left out, ``source_rows``
    the rows' indices in the log (a condensed recording keeps every k-th), counts per row
    of the log it spans). Across a gap the log saw nothing: the rows after it are another
    visit, even at the same commanded pose (the load changed while the platform stood
    there: one sample over both would hide the change's time)."""
    N = len(keys)
    change = np.ones(N, dtype=bool)
    change[1:] = np.any(keys[1:] != keys[:-1], axis=1)
    if states is not None:
        st = np.array(states)
        change[1:] |= st[1:] != st[:-1]
    if t is not None and N > 2:
        dt = np.diff(np.asarray(t, float))
        if source_rows is not None and len(source_rows) == N:
            dt = dt / np.maximum(np.diff(np.asarray(source_rows, float)), 1.0)
        change[1:] |= long_steps(dt)  # (steps of 0, a log split by sensor, not counted)
    starts = np.flatnonzero(change)
    return list(zip(starts.tolist(), list(starts[1:].tolist()) + [N], strict=True))


def _spread_limit(chunk: np.ndarray, floor: float) -> np.ndarray:
    """(d,) largest peak-to-peak spread [units of ``chunk``] of a standing signal's (K, d)
    samples: ``floor``, or the spread its own white noise reaches over K samples
    (2 sqrt(2 ln K) + 3 standard deviations), whichever is larger."""
    k = max(len(chunk), 2)
    return np.maximum(floor, (2.0 * np.sqrt(2.0 * np.log(k)) + 3.0)
                      * signal_noise(np.arange(len(chunk), dtype=float), chunk))


def _standing(rec: Recording, a: int, b: int) -> bool:
    """Whether the encoders (or, without them, the measured pose) stand still in rows a..b:
    every reading spreads by at most STILL_M (encoders; the pose: 1 mm, 1 mrad), or by what
    its own white noise gives over the rows (:func:`_spread_limit`)."""
    for arr, tol in ((rec.l_meas, STILL_M), (rec.pose_meas, 1e-3)):
        chunk = arr[a:b]
        ok = np.isfinite(chunk).all(axis=0)
        if ok.any() and b - a >= 2:
            x = chunk[:, ok]
            return bool(np.all(np.ptp(x, axis=0) <= _spread_limit(x, tol)))
    return True


def _settled(rec: Recording, a: int, b: int) -> np.ndarray:
    """Rows a..b of a dwell where the measured pose has settled (a transient at the start of a
    dwell is left out): within 5 robust standard deviations (at least 0.5 mm) of the median."""
    idx = np.arange(a, b)
    pos = rec.pose_meas[a:b, :3]
    ok = np.isfinite(pos).all(axis=1)
    if b - a < 5 or ok.sum() < 5:
        return idx
    med = np.median(pos[ok], axis=0)
    d = np.linalg.norm(pos - med, axis=1)
    mad = float(np.median(d[ok]))
    keep = ~ok | (d <= max(5.0 * 1.4826 * mad, 5e-4))
    return idx[keep]


def _quasi_static(rec: Recording, rows: np.ndarray) -> np.ndarray:
    """Which path ``rows`` are quasi-static: the commanded (or measured) motion does not
    accelerate around them. Measured poses only, or jittered time stamps: the acceleration
    of a filter that tracker noise and jitter cannot fool (of the commanded pose where
    there is one; :func:`bench.streams.measured_acceleration`); rows without a commanded
    or measured pose (no tracker, or between its fixes): the same filter's acceleration of
    the encoder readings (:func:`bench.streams.length_acceleration`); finite differences of
    consecutive rows only where the rows are too sparse for the filter."""
    if len(rows) < 3:
        return np.ones(len(rows), dtype=bool)
    ok = _quasi_static_rows(rec, rows)
    des = bool(np.isfinite(rec.pose_des[rows, :3]).all())
    if not des or jittered(rec.t):
        acc = measured_acceleration(rec, rows, rec.pose_des if des else None)
        judged = np.zeros(len(rows), dtype=bool)
        if acc is not None:
            judged = np.isfinite(acc[0]) & np.isfinite(acc[1])
            with np.errstate(invalid="ignore"):
                filt = (acc[0] <= ACCEL_MAX) & (acc[1] <= ANG_ACCEL_MAX)
            ok = np.where(judged, filt, ok)
        if not des and not judged.all():  # rows the pose's filter left: the encoders
            lacc = length_acceleration(rec, rows)
            if lacc is not None:
                by_len = ~judged & np.isfinite(lacc)
                ok = np.where(by_len, lacc <= ACCEL_MAX, ok)
    return ok


def _quasi_static_rows(rec: Recording, rows: np.ndarray) -> np.ndarray:
    """:func:`_quasi_static` by finite differences of consecutive ``rows``."""
    src = rec.pose_des if np.isfinite(rec.pose_des[rows, :3]).all() else rec.pose_meas
    p = src[rows]
    t = rec.t[rows]
    if not np.isfinite(p[:, :3]).all():
        return np.ones(len(rows), dtype=bool)
    p = np.nan_to_num(p)
    dt = np.diff(t)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.diff(p, axis=0) / dt[:, None]
        a = np.diff(v, axis=0) / (0.5 * (dt[1:] + dt[:-1]))[:, None]
    a = np.nan_to_num(a, nan=np.inf, posinf=np.inf, neginf=np.inf)
    lin = np.linalg.norm(a[:, :3], axis=1) <= ACCEL_MAX
    ang = np.abs(a[:, 3:]).max(axis=1) <= ANG_ACCEL_MAX
    ok_mid = lin & ang
    ok = np.zeros(len(rows), dtype=bool)
    # a row is quasi-static if the accelerations on both sides of it are small
    ok[1:-1] = ok_mid
    ok[0] = ok_mid[0]
    ok[-1] = ok_mid[-1]
    return ok


def _isolated(rec: Recording, rows: np.ndarray) -> np.ndarray:
    """Which path ``rows`` are standing measurements of their own: the commanded (or
    measured) pose jumps to them and away from them faster than any motion, or they are
    rows of a table of poses (:meth:`~bench.recording.Recording.table_rows`). A row without
    that pose (between a slow tracker's fixes, or refused by the alignment) is judged by
    nothing: it is no jump; a row with one is compared with the nearest rows that have one."""
    out = np.zeros(len(rows), dtype=bool)
    src = rec.pose_des if np.isfinite(rec.pose_des[:, :3]).any() else rec.pose_meas
    if not len(rows):
        return out
    out |= rec.table_rows()[rows]
    has = np.isfinite(src[:, :3]).all(axis=1)
    if not has.any():
        return out
    p = src[:, :3]
    t = rec.t
    known = np.flatnonzero(has)
    k = np.searchsorted(known, rows)  # rows with a pose: known[k] == row
    prev = np.where(k > 0, known[np.maximum(k - 1, 0)], -1)
    nxt_k = k + (has[rows] & (k < len(known))).astype(int)
    nxt = np.where(nxt_k < len(known), known[np.minimum(nxt_k, len(known) - 1)], -1)

    def speed(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        jj = np.maximum(j, 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            v = np.linalg.norm(p[i] - p[jj], axis=1) / np.abs(t[i] - t[jj])
        return np.where(j >= 0, np.nan_to_num(v, nan=np.inf, posinf=np.inf), np.inf)

    jump = (speed(rows, prev) > JUMP_M_S) & (speed(rows, nxt) > JUMP_M_S)
    return out | (has[rows] & jump)


#: with rows of moves, samples within this many consecutive moves may share errors
CLUSTER_MOVES = 3


def _clusters(s: Samples) -> np.ndarray:
    """Groups of samples whose errors may be correlated, for cluster-robust standard errors:
    a target with its visits when the recording has no rows of moves; otherwise stretches
    of time spanning CLUSTER_MOVES moves (the slow errors of a move carry into the next one
    and into the dwell between them)."""
    if not (s.kind == 1).any():
        return s.block.copy()
    order = np.argsort(s.t, kind="stable")
    out = np.zeros(s.n, dtype=int)
    moves_seen = 0
    cid = 0
    last_block = None
    for i in order:
        if s.kind[i] == 1 and s.block[i] != last_block:
            last_block = s.block[i]
            moves_seen += 1
            if moves_seen > CLUSTER_MOVES:
                cid += 1
                moves_seen = 1
        out[i] = cid
    return out


def _fresh(rec: Recording, rows: np.ndarray) -> np.ndarray:
    """Which ``rows`` (of moves) carry a fresh tracker pose and fresh tensions: the value
    differs from the previous row's (a sensor slower than the row rate repeats itself)."""
    ok = np.ones(len(rows), dtype=bool)
    if not len(rows):
        return ok
    prev = np.maximum(rows - 1, 0)
    for arr in (rec.pose_meas, rec.tau):
        if not np.isfinite(arr[rows]).any():
            continue
        a, b = arr[rows], arr[prev]
        same = np.all((a == b) | (np.isnan(a) & np.isnan(b)), axis=1) & (rows > 0)
        ok &= ~same
    return ok


def _segments(rec: Recording, rows: np.ndarray) -> np.ndarray:
    """Move ids of path ``rows``: a new move at a gap in rows or time, or where the commanded
    direction turns."""
    if not len(rows):
        return np.zeros(0, dtype=int)
    seg = np.zeros(len(rows), dtype=int)
    t = rec.t[rows]
    dt = np.diff(t)
    med = float(np.median(dt)) if len(dt) else 1.0
    new = np.zeros(len(rows), dtype=bool)
    new[1:] = (np.diff(rows) > 1) | (dt > 2.5 * med)
    p = rec.pose_des[rows, :3]
    if np.isfinite(p).all() and len(rows) > 2:
        d = np.diff(p, axis=0)
        nd = np.linalg.norm(d, axis=1)
        u = d / np.where(nd > 0, nd, 1.0)[:, None]
        turn = np.zeros(len(rows), dtype=bool)
        cosang = np.sum(u[1:] * u[:-1], axis=1)
        turn[2:] = (cosang < np.cos(np.radians(20))) & (nd[1:] > 0) & (nd[:-1] > 0)
        new |= turn
    seg = np.cumsum(new)
    return seg


def _turns(rec: Recording, rows: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Times [s] where the moves of path ``rows`` (move ids ``seg``) start, meet and end,
    sorted: a move's first and last rows, one time (the middle) where a move ends within
    2.5 row periods of the next one's start (no dwell between them)."""
    if not len(rows):
        return np.zeros(0)
    t = rec.t[rows]
    first = np.r_[True, seg[1:] != seg[:-1]]
    last = np.r_[seg[1:] != seg[:-1], True]
    starts, ends = t[first], t[last]
    dt = np.diff(t)
    med = float(np.median(dt)) if len(dt) else 0.0
    out = [starts[0]]
    for k in range(1, len(starts)):
        if starts[k] - ends[k - 1] <= 2.5 * med:
            out.append(0.5 * (starts[k] + ends[k - 1]))
        else:
            out += [ends[k - 1], starts[k]]
    out.append(ends[-1])
    return np.unique(np.asarray(out, dtype=float))


def prepare(rec: Recording, max_samples: int = MAX_SAMPLES) -> Samples:
    """The static samples of a recording (see the module docstring)."""
    init = np.zeros(rec.n_samples, dtype=bool)
    init[rec.init_rows] = True
    dwell_runs, path, dropped_states, unknown = _split_runs(rec, init)
    alone = _isolated(rec, path)
    dwell_runs += [np.array([i]) for i in path[alone]]
    path = path[~alone]
    qs = _quasi_static(rec, path)
    seg_all = _segments(rec, path)
    turns = _turns(rec, path, seg_all)
    # a sensor read slower than the rows holds its last value: while the platform moves,
    # only rows where the tracker (and the load cells) report a fresh value are measurements
    fresh = _fresh(rec, path)
    moving = path[fresh]
    moves_of = seg_all[fresh]  # (the moves of the fresh rows: their pose rates)
    path, seg_all = path[qs & fresh], seg_all[qs & fresh]
    # budget: dwell samples first (whole targets), path rows spread evenly in time
    dw = _dwell_samples(rec, dwell_runs, init)
    n_dwell = len(dwell_runs)
    keep_dwell = np.arange(n_dwell)
    if n_dwell > max_samples - min(100, len(path)):
        keep_dwell = _thin_targets(dw["target"], dw["is_init"],
                                   max(max_samples - min(100, len(path)), 1))
    path, seg_all = _thin_path(path, seg_all, max(max_samples - len(keep_dwell), 0))
    dwell_runs = [dwell_runs[k] for k in keep_dwell]
    dw = {k: v[keep_dwell] for k, v in dw.items()}
    s, order = _assemble(rec, dw, dwell_runs, path, seg_all, init)
    s.pose_rate = np.concatenate([np.zeros((len(dwell_runs), 6)),
                                  pose_rates(rec, path, moving, moves_of)])[order]
    s.triples = _triples(rec, dwell_runs, moving)
    s.cluster = _clusters(s)
    s.stream = _stream(rec)
    s.turns = turns
    s.info = {"rows": rec.n_samples, "dwell_samples": len(dwell_runs),
              "path_samples": len(path), "dwells_available": n_dwell,
              "path_rows_accelerating": int((~qs).sum()),
              "path_rows_stale": int((~fresh).sum()), "rows_in_other_states": dropped_states,
              "states_unknown": dict(sorted(unknown.items()))}
    return s


def _split_runs(rec: Recording, init: np.ndarray
                ) -> tuple[list[np.ndarray], np.ndarray, int, dict[str, int]]:
    """The recording's runs of rows (same commanded pose and state) split into dwells (the
    settled rows of each: a still state, a supervisor reaction where the platform stands,
    or rows that stand still where the state does not say) and rows of moves; the rows
    dropped (reactions while moving) and the state words the format does not define with
    their rows."""
    states = rec.state
    moving = _moving(rec)
    dwell_runs: list[np.ndarray] = []
    path_rows: list[int] = []
    dropped = 0
    unknown: dict[str, int] = {}  # a lab's own state words and their rows
    for a, b in _runs(_keys(rec), states, rec.t, rec.source_rows):
        st = states[a] if states is not None else None
        if st is not None and st.strip() and not known_state(st):
            unknown[st] = unknown.get(st, 0) + b - a
        st = None if st is None else st.strip().lower()  # the format's words in any case
        if st is not None and st not in STILL_STATES | MOVE_STATES and not reaction_state(st):
            st = None  # a state the format does not define, or "end": the data decide
        if st is not None and st not in STILL_STATES | MOVE_STATES:
            # supervisor reactions: only where the platform stands still
            if b - a >= 2 and _standing(rec, a, b):
                dwell_runs.append(_settled(rec, a, b))
            else:
                dropped += b - a
            continue
        still = (st in STILL_STATES) if st is not None else (b - a >= 2 and _standing(rec, a, b))
        if still or (st is None and init[a] and not moving[a]):
            dwell_runs.append(_settled(rec, a, b))
        else:
            path_rows.extend(range(a, b))
    return dwell_runs, np.array(path_rows, dtype=int), dropped, unknown


def _thin_path(path: np.ndarray, seg_all: np.ndarray, room: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """A few rows per move (:data:`PER_MOVE`, evenly spread over it), then at most ``room``
    rows evenly spread in time; with their moves."""
    if len(path):
        keep = np.zeros(len(path), dtype=bool)
        for g in np.unique(seg_all):
            idx = np.flatnonzero(seg_all == g)
            k = min(PER_MOVE, len(idx))
            keep[idx[np.unique(np.round(np.linspace(0, len(idx) - 1, k + 2)[1:-1]
                                        ).astype(int))]] = True
        path, seg_all = path[keep], seg_all[keep]
    if len(path) > room:
        pick = np.unique(np.round(np.linspace(0, len(path) - 1, room)).astype(int)) \
            if room else np.zeros(0, dtype=int)
        path, seg_all = path[pick], seg_all[pick]
    return path, seg_all


def _assemble(rec: Recording, dw: dict[str, np.ndarray], dwell_runs: list[np.ndarray],
              path: np.ndarray, seg_all: np.ndarray, init: np.ndarray
              ) -> tuple[Samples, np.ndarray]:
    """The samples in time order: the dwells' (``dw``) then the rows of moves (``path``,
    their moves ``seg_all``), their replicate groups (dwells by commanded pose, rows of
    moves by proximity on different moves), blocks, directions and weights (the rows of a
    move count as :data:`MOVE_INDEPENDENT` independent samples); and the sort into time
    order of the dwells then the rows."""
    n_dw = len(dwell_runs)

    def both(key: str, field_: str) -> np.ndarray:
        return np.concatenate([dw[key], getattr(rec, field_)[path]])

    t = np.concatenate([dw["t"], rec.t[path]])
    pose_des, pose_meas = both("pose_des", "pose_des"), both("pose_meas", "pose_meas")
    l_meas, tau, exit_meas = both("l_meas", "l_meas"), both("tau", "tau"), \
        both("exit_meas", "exit_meas")
    count = np.concatenate([dw["count"], np.ones(len(path), dtype=int)])
    is_init = np.concatenate([dw["is_init"], init[path]])
    kind = np.concatenate([np.zeros(n_dw, dtype=int), np.ones(len(path), dtype=int)])
    first = np.array([r[0] for r in dwell_runs] + path.tolist(), dtype=int)
    direction = _directions(rec, first)
    tg_d = _targets(pose_des[:n_dw], pose_meas[:n_dw], l_meas[:n_dw])
    tg_p = _near_groups(pose_meas[n_dw:], pose_des[n_dw:], seg_all)
    base = int(tg_d.max()) + 1 if len(tg_d) else 0
    target = np.concatenate([tg_d, tg_p + base])
    block = np.concatenate([tg_d, seg_all + base + (int(tg_p.max()) + 1 if len(tg_p) else 0)])
    order = np.argsort(t, kind="stable")
    s = Samples(t[order], pose_des[order], pose_meas[order], l_meas[order], tau[order],
                exit_meas[order], count[order], target[order], is_init[order],
                _tau_row_sd(rec, dwell_runs, path, seg_all), kind[order], block[order],
                direction[order], _lines(rec, first[order]))
    w = np.ones(len(t))
    for g in np.unique(seg_all):
        m = int(np.sum(seg_all == g))
        w[n_dw + np.flatnonzero(seg_all == g)] = min(1.0, MOVE_INDEPENDENT / m)
    s.weight = w[order]
    return s, order


def average_dwells(rec: Recording) -> Samples:
    """:func:`prepare` (kept for its callers)."""
    return prepare(rec)


def _triples(rec: Recording, runs: list[np.ndarray], path: np.ndarray,
             limit: int = 60) -> Samples | None:
    """Raw rows in consecutive triples, from dwells (three rows of one dwell) and moves (three
    consecutive rows), up to ``limit`` triples spread over the recording."""
    dwell: list[tuple[int, int, int]] = []
    moving: list[tuple[int, int, int]] = []
    for idx in runs:
        if len(idx) >= 3:
            dwell.append((int(idx[0]), int(idx[len(idx) // 2]), int(idx[-1])))
    if len(path) >= 3:
        # three fresh rows evenly spaced (the second difference cancels a steady motion)
        d1, d2 = path[1:-1] - path[:-2], path[2:] - path[1:-1]
        even = (d1 == d2) & (d1 <= 4)
        for k in np.flatnonzero(even):
            moving.append((int(path[k]), int(path[k + 1]), int(path[k + 2])))
    chosen: list[tuple[int, int, int]] = []
    kinds: list[int] = []
    for kind, cands in ((0, dwell), (1, moving)):
        if not cands:
            continue
        pick = np.unique(np.round(np.linspace(0, len(cands) - 1, min(limit, len(cands))))
                         .astype(int))
        chosen += [cands[k] for k in pick]
        kinds += [kind] * len(pick)
    if not chosen:
        return None
    rows = np.array(chosen).ravel()
    n = rec.robot.n_cables
    return Samples(rec.t[rows], rec.pose_des[rows], rec.pose_meas[rows], rec.l_meas[rows],
                   rec.tau[rows], rec.exit_meas[rows], np.ones(len(rows), dtype=int),
                   np.arange(len(rows)), np.isin(rows, rec.init_rows),
                   kind=np.repeat(kinds, 3), direction=np.zeros((len(rows), n)),
                   row=_lines(rec, rows))


#: at most this many raw rows are scanned for jumps in time
STREAM_ROWS = 4000


def _stream(rec: Recording) -> Samples | None:
    """Raw rows in time order (every k-th, at most STREAM_ROWS), for jumps between
    consecutive rows (a slip during a move). ``block`` numbers runs of rows close in time."""
    N = rec.n_samples
    if N < 20 or not np.isfinite(rec.l_meas).any():
        return None
    k = max(1, int(np.ceil(N / STREAM_ROWS)))
    rows = np.arange(0, N, k)
    t = rec.t[rows]
    dt = np.diff(t)
    med = float(np.median(dt)) if len(dt) else 1.0
    new = np.concatenate([[True], dt > 3.0 * max(med, 1e-9)])
    n = rec.robot.n_cables
    out = Samples(t, rec.pose_des[rows], rec.pose_meas[rows], rec.l_meas[rows], rec.tau[rows],
                  rec.exit_meas[rows], np.ones(len(rows), dtype=int), np.arange(len(rows)),
                  np.isin(rows, rec.init_rows), direction=np.zeros((len(rows), n)),
                  row=_lines(rec, rows))
    out.block = np.cumsum(new)
    return out


def _lines(rec: Recording, rows: np.ndarray) -> np.ndarray:
    """The recording.csv lines of ``rows`` (rows aligned or condensed by :mod:`bench.streams`
    keep the rows of the file they come from)."""
    src = rec.source_rows
    return (np.asarray(rows) if src is None else src[np.asarray(rows, dtype=int)]) + 2


def _mean(arr: np.ndarray, idx: np.ndarray) -> np.ndarray:
    chunk = arr[idx]
    ok = np.isfinite(chunk)
    with np.errstate(invalid="ignore"):
        return np.where(ok.any(axis=0), np.nansum(chunk, axis=0) / np.maximum(ok.sum(0), 1),
                        np.nan)


def _dwell_samples(rec: Recording, runs: list[np.ndarray], init: np.ndarray) -> dict:
    n = rec.robot.n_cables
    out = {k: [] for k in ("t", "pose_des", "pose_meas", "l_meas", "tau", "exit_meas")}
    for idx in runs:
        for k in out:
            out[k].append(_mean(getattr(rec, k), idx))
    shapes = {"t": (0,), "pose_des": (0, 6), "pose_meas": (0, 6), "l_meas": (0, n),
              "tau": (0, n), "exit_meas": (0, n, 3)}
    res = {k: (np.array(v) if v else np.zeros(shapes[k])) for k, v in out.items()}
    res["count"] = np.array([len(r) for r in runs], dtype=int)
    res["is_init"] = np.array([bool(init[r].any()) for r in runs], dtype=bool)
    res["target"] = _targets(res["pose_des"], res["pose_meas"], res["l_meas"])
    return res


def _thin_targets(target: np.ndarray, is_init: np.ndarray, room: int) -> np.ndarray:
    """Indices of dwell samples to keep within ``room``: the initialisation and whole targets
    (every visit of a kept target), spread over the target numbers."""
    keep = list(np.flatnonzero(is_init))
    tg = [g for g in np.unique(target) if not is_init[target == g].any()]
    per = max(np.mean([np.sum(target == g) for g in tg]) if tg else 1, 1)
    k = max(int((room - len(keep)) // per), 1)
    chosen = np.array(tg)[np.unique(np.round(np.linspace(0, len(tg) - 1, k)).astype(int))] \
        if tg else []
    keep += list(np.flatnonzero(np.isin(target, chosen)))
    return np.array(sorted(set(keep))[:room], dtype=int)


#: rows standing (every reading's change within the first noise estimate's reach) needed to
#: estimate the readings' noise from them alone
STANDING_ROWS_MIN = 20


def _standing_noise(t: np.ndarray, src: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(n,) white noise [m] of the readings ``src`` (N, n) from the rows where they stand:
    the second differences of :func:`signal_noise` also hold the motion's accelerations
    where rows are slow against the moves (15 Hz rows of a continuous recording read 60 um
    for 5 um of noise), so the rows whose change ``d`` (N, n) stays within 3 such standard
    deviations of a difference are taken again, their changes' robust spread / sqrt(2)
    kept, and the rows taken again with that (three times: the slow ends of the moves drop
    out); zeros (no noise known) with fewer than :data:`STANDING_ROWS_MIN` such rows."""
    sd = signal_noise(t, src)
    for _ in range(3):
        with np.errstate(invalid="ignore"):
            still = np.all(np.abs(d[1:]) <= 3.0 * np.sqrt(2.0) * sd, axis=1)
        if still.sum() < STANDING_ROWS_MIN:
            return np.zeros(src.shape[1])
        x = d[1:][still]
        sd = 1.4826 * np.median(np.abs(x - np.median(x, axis=0)), axis=0) / np.sqrt(2.0)
    return sd


def _directions(rec: Recording, rows: np.ndarray) -> np.ndarray:
    """Sign of each cable's last length change before each of ``rows`` (encoder readings, or
    commanded lengths)."""
    src = rec.l_meas if np.isfinite(rec.l_meas).any() else rec.l_cmd
    N, n = src.shape
    out = np.zeros((len(rows), n))
    if not np.isfinite(src).any():
        return out
    d = np.zeros((N, n))
    d[1:] = np.diff(src, axis=0)
    # a change counts beyond STILL_M / 2 and beyond 3 standard deviations of the
    # difference of two noisy readings (a reading's white noise must not set the sign)
    lim = np.maximum(STILL_M / 2, 3.0 * np.sqrt(2.0) * _standing_noise(rec.t, src, d))
    with np.errstate(invalid="ignore"):
        d = np.nan_to_num(np.where(np.abs(d) > lim, np.sign(d), 0.0))
    # carry the last nonzero sign forward: index of the last row with a move, per cable
    idx = np.where(d != 0, np.arange(N)[:, None], 0)
    np.maximum.accumulate(idx, axis=0, out=idx)
    carried = np.take_along_axis(d, idx, axis=0)
    return carried[np.asarray(rows, dtype=int)]


def _tau_row_sd(rec: Recording, runs: list[np.ndarray], path: np.ndarray,
                seg: np.ndarray) -> float | None:
    """Load-cell noise of one row [N]: spread within dwells, or second differences of
    consecutive path rows."""
    ss, dof = 0.0, 0
    for idx in runs:
        chunk = rec.tau[idx]
        if len(idx) >= 2 and np.isfinite(chunk).all():
            ss += float(((chunk - chunk.mean(axis=0)) ** 2).sum())
            dof += (len(idx) - 1) * chunk.shape[1]
    if dof:
        return float(np.sqrt(ss / dof))
    if len(path) >= 3 and np.isfinite(rec.tau).any():
        tau = rec.tau
        i = np.arange(1, rec.n_samples - 1)
        d2 = tau[i + 1] - 2 * tau[i] + tau[i - 1]
        d2 = d2[np.isfinite(d2)]
        if d2.size >= 10:
            return float(1.4826 * np.median(np.abs(d2)) / np.sqrt(6.0))
    return None


#: [m] dwells without a commanded or whole measured pose are one target where every
#: cable's encoder reading is within this of the target's first visit (the lengths fix the
#: pose; targets of a campaign are decimetres apart, a visit repeats within a millimetre)
SAME_LENGTHS_M = 5e-3


def _targets(pose_des: np.ndarray, pose_meas: np.ndarray,
             l_meas: np.ndarray | None = None) -> np.ndarray:
    """Number target poses: equal desired poses (0.1 mm) or, without them, measured poses
    within 5 mm / 5 mrad of each other, or, without a whole measured pose either (no
    tracker), encoder readings ``l_meas`` (N, n) within SAME_LENGTHS_M of each other."""
    N = len(pose_des)
    if N == 0:
        return np.zeros(0, dtype=int)
    cols = np.isfinite(pose_des).any(axis=0)
    have_des = np.isfinite(pose_des[:, cols]).all(axis=1) & cols.any()
    pose_des = np.where(cols, pose_des, 0.0)
    key = np.where(have_des[:, None], np.round(pose_des / 1e-4), np.nan)
    # a measured pose groups only when whole (every axis the recording measures): a row
    # between a slow tracker's fixes is nan there, and nan is near nothing
    meas_cols = np.isfinite(pose_meas).any(axis=0)
    whole = np.isfinite(pose_meas[:, meas_cols]).all(axis=1) & meas_cols[:3].all()
    lens = np.full((N, 1), np.nan) if l_meas is None else np.asarray(l_meas, dtype=float)
    by_len = ~have_des & ~whole & np.isfinite(lens).all(axis=1)
    ids = np.full(N, -1)
    reps: list[tuple[np.ndarray, str]] = []
    lookup: dict[bytes, int] = {}
    for i in range(N):
        if have_des[i]:
            kb = key[i].tobytes()
            if kb in lookup:
                ids[i] = lookup[kb]
                continue
        else:
            for j, (rep, how) in enumerate(reps):
                if (how == "meas" and whole[i]
                        and np.all(np.abs(pose_meas[i] - rep)[meas_cols] < 5e-3)) or \
                        (how == "len" and by_len[i]
                         and np.all(np.abs(lens[i] - rep) < SAME_LENGTHS_M)):
                    ids[i] = j
                    break
        if ids[i] < 0:
            ids[i] = len(reps)
            how = "des" if have_des[i] else "meas" if whole[i] else \
                "len" if by_len[i] else "none"
            reps.append((pose_meas[i] if how == "meas" else lens[i] if how == "len"
                         else key[i], how))
            if have_des[i]:
                lookup[key[i].tobytes()] = ids[i]
    return ids


def _near_groups(pose_meas: np.ndarray, pose_des: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Group path rows that lie within NEAR_M / NEAR_RAD of a group's first row, on moves
    that are not neighbours (no chains: every member is near the first); every other row is
    its own group. Neighbouring moves meet at the target between them: rows near it share
    that visit's errors (the lengths change from visit to visit), and their spread would
    miss them."""
    N = len(seg)
    ids = np.full(N, -1)
    if N == 0:
        return ids
    pos = np.where(np.isfinite(pose_meas), pose_meas, pose_des)
    ok = np.isfinite(pos).all(axis=1)
    cell = np.floor(np.nan_to_num(pos[:, :3]) / NEAR_M).astype(np.int64)
    seeds: dict[tuple, list[int]] = {}  # grid cell -> group seeds (row indices)
    members: dict[int, set] = {}
    n_groups = 0
    for i in range(N):
        if not ok[i]:
            ids[i] = n_groups
            n_groups += 1
            continue
        c = cell[i]
        best = -1
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    for j in seeds.get((c[0] + dx, c[1] + dy, c[2] + dz), ()):
                        if any(abs(int(seg[i]) - int(m)) < 2 for m in members[j]):
                            continue
                        if (np.linalg.norm(pos[i, :3] - pos[j, :3]) <= NEAR_M
                                and np.abs(pos[i, 3:] - pos[j, 3:]).max() <= NEAR_RAD):
                            best = j
                            break
        if best >= 0:
            ids[i] = ids[best]
            members[best].add(seg[i])
        else:
            ids[i] = n_groups
            n_groups += 1
            seeds.setdefault(tuple(c), []).append(i)
            members[i] = {seg[i]}
    return ids


def pooled_std(values: np.ndarray, target: np.ndarray) -> np.ndarray | None:
    """Pooled within-target standard deviation of ``values`` (N, d) per column, over targets
    visited more than once (model errors repeat at a target; noise does not). None if no
    target has replicates."""
    values = np.asarray(values, dtype=float)
    v2 = values.reshape(len(values), -1)
    ss = np.zeros(v2.shape[1])
    dof = np.zeros(v2.shape[1])
    for g in np.unique(target):
        sel = target == g
        if sel.sum() < 2:
            continue
        x = v2[sel]
        ok = np.isfinite(x)
        cnt = ok.sum(axis=0)
        m = np.where(cnt > 0, np.nansum(x, axis=0) / np.maximum(cnt, 1), 0.0)
        ss += np.nansum((x - m) ** 2, axis=0)
        dof += np.maximum(cnt - 1, 0)
    if not np.any(dof > 0):
        return None
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(dof > 0, np.sqrt(ss / np.maximum(dof, 1)), np.nan)
