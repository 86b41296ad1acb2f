"""``cdpr dry-run ... --site FILE``: the dry run on buses it is given.

``cdpr sim --write-site`` runs as a separate process (as another machine would); the dry
run reaches it only through the site file, runs the path in lock-step (the sim follows
the master's SYNC) in a process of its own that never imports ``firmware_sim``, and its
pose error is the one of ``--rig process``. Refusals: no ``--yes`` without a terminal, a
bad site file, a preflight that finds a problem (nothing moves).
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import queue
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

from bench.cli import main
from bench.recording import read_recording
from hal.site import load_site, write_site

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
           PYTHONUNBUFFERED="1")


class SimWithSite:
    """``cdpr sim SCENARIO --write-site DIR/sim.toml`` in another process (ends with stdin)."""

    def __init__(self, folder: Path, *args: str) -> None:
        self.site = folder / "sim.toml"
        self.err = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bench.cli", "sim", *args, "--json", "--exit-on-stdin-eof",
             "--write-site", str(self.site)], cwd=folder, env=ENV, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=self.err, text=True)
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(self.proc.stdout.readline()),
                         daemon=True).start()
        try:
            self.info = json.loads(lines.get(timeout=60))
        except (queue.Empty, json.JSONDecodeError):
            self.close()
            raise AssertionError(f"cdpr sim gave no endpoints: {self._stderr()}") from None

    def _stderr(self) -> str:
        self.err.seek(0)
        return self.err.read()[-2000:]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.err.close()

    def __enter__(self) -> SimWithSite:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: the dry run on the site in a fresh interpreter; prints its JSON, then the firmware_sim
#: modules it imported (none allowed on the hardware path)
DRY_RUN = """
import json, sys
from bench.cli import main
code = main(sys.argv[1:])
print(json.dumps({"exit": code, "firmware_sim": sorted(m for m in sys.modules
                                                        if m.split('.')[0] == 'firmware_sim')}))
"""


def _dry_run_apart(*argv: str, cwd: Path) -> tuple[dict, dict]:
    out = subprocess.run([sys.executable, "-c", DRY_RUN, "dry-run", *argv], cwd=cwd, env=ENV,
                         stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=240)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    assert len(lines) == 2, out.stdout + out.stderr[-3000:]
    return json.loads(lines[0]), json.loads(lines[1])


def test_dry_run_on_a_site_written_by_a_separate_sim(tmp_path, capsys):
    latches = tmp_path / "latches.csv"
    with SimWithSite(tmp_path, "paper-centre", "--latch-log", str(latches)) as sim:
        assert sim.info["site"] == str(sim.site) and sim.info["clock"] == "sync"
        res, tail = _dry_run_apart("paper-centre", "--site", str(sim.site), "--yes",
                                   "--duration", "2", "--json", "--quiet", "--record",
                                   str(tmp_path / "rec"), cwd=tmp_path)
        # the latches are written as they come (flushed each second), not at the sim's exit
        assert len(latches.read_text().splitlines()) > 100
        # the master in real time, the sim still following its SYNC: whether the host keeps
        # real time under load is issue 30's real-time item (a loaded 2-core host may end
        # it with the supervisor's quick stop); here: it runs in real time, ends as the
        # supervisor says, never in an error
        code = main(["dry-run", "paper-centre", "--site", str(sim.site), "--yes", "--realtime",
                     "--duration", "1", "--json", "--quiet"])
        rt = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert rt["realtime"] and rt["cycles"] > 0 and rt["wall_s"] >= rt["trajectory_s"], rt
        assert rt["ended"] in ("completed", "quick_stop", "hold_timeout"), rt
        assert code == (0 if rt["ended"] == "completed" else 1)
        # the commissioning commands take the same site
        assert main(["commission", "scan", "--site", str(sim.site), "--json",
                     "--no-report"]) == 0
        scan = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert [d["status"] for d in scan["drives"]] == ["ok"] * 8
        assert [c["status"] for c in scan["load_cells"]] == ["ok"] * 8
    assert tail == {"exit": 0, "firmware_sim": []}, tail
    assert res["ended"] == "completed" and res["rig"] == "site" and not res["realtime"], res
    _stamps_are_the_latches(tmp_path / "rec", latches)
    assert res["site"] == str(sim.site) and res["speed_pct"] == 100.0
    pf = res["preflight"]
    assert pf["ok"] and not pf["problems"] and pf["tracker"]["locked"]
    assert [d["status"] for d in pf["drives"]] == ["ok"] * 8
    assert [c["status"] for c in pf["load_cells"]] == ["ok"] * 8
    # the simulated drives ship with their EDS values: stored safety objects differ (not
    # required by the sim's site), reported as warnings naming node and object
    assert any("0x6007" in w and "node 1 (cable 11)" in w for w in pf["warnings"])
    # the same path with --rig process: the same pose error (noise apart)
    code = main(["dry-run", "paper-centre", "--rig", "process", "--duration", "2", "--json",
                 "--quiet"])
    ref = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 0 and ref["ended"] == "completed" and ref["preflight"]["ok"]
    assert ref["cycles"] == res["cycles"]
    # the tracker serves fixes on the wall clock while lock-step runs at the host's pace:
    # under load the measured error varies (0.9 .. 1.6 mm rms seen on a loaded 2-core host)
    for key in ("pose_error_rms_m", "pose_error_max_m"):
        assert 0.5 < res[key] / ref[key] < 2.0, (key, res[key], ref[key])
    assert res["pose_error_rms_m"] < 3e-3


def _stamps_are_the_latches(rec: Path, latch_log: Path) -> None:
    """Each encoder sample of the recording ``rec`` is stamped at the SYNC its drive latched
    it at (tests/test_stamp46_encoder_stamps.py): on the SYNC clock, whose time the drives
    count as the master does, exactly. The later runs on the same sim (their SYNCs come
    after this run's on the drives' clock) are left out."""
    from test_stamp46_encoder_stamps import WINCHES, read_latch_log, stamp_errors

    end = float(read_recording(rec).t[-1]) + 1e-6  # clock_origin_s is 0: the first master
    logged = {node: a[a[:, 0] <= end] for node, a in read_latch_log(latch_log).items()}
    err, unclear = stamp_errors(rec, logged, WINCHES)
    assert err.size > 100, (err.size, unclear)
    assert np.all(np.abs(err) < 1e-6), np.unique(np.round(err / WINCHES.bus.sync_period_s))


def test_refused_without_yes_and_without_a_terminal(tmp_path, capsys):
    site = ROOT / "examples" / "site" / "rocaspect-site.toml"
    code = main(["dry-run", "paper-centre", "--site", str(site), "--json", "--quiet"])
    out = json.loads(capsys.readouterr().out)
    assert code == 2 and "give --yes" in out["error"] and "nothing was opened" in out["error"]


def test_bad_site_and_bad_combinations_open_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('format = "cdpr-site/1"\n[robot]\ndescription = "rocaspect"\n')
    assert main(["dry-run", "paper-centre", "--site", str(bad), "--yes", "--json"]) == 2
    err = json.loads(capsys.readouterr().out)["error"]
    assert str(bad.resolve()) in err and "[drives]" in err
    site = ROOT / "examples" / "site" / "rocaspect-site.toml"
    assert main(["dry-run", "paper-centre", "--site", str(site), "--rig", "process",
                 "--yes", "--json"]) == 2
    assert "one or the other" in json.loads(capsys.readouterr().out)["error"]
    assert main(["dry-run", "paper-centre", "--modbus", "127.0.0.1:5020", "--json"]) == 2
    assert "--site FILE or --can" in json.loads(capsys.readouterr().out)["error"]
    assert main(["dry-run", "paper-centre", "--site", str(site), "--tracker", "none",
                 "--yes", "--json"]) == 2
    assert "no tracker" in json.loads(capsys.readouterr().out)["error"]


class _Tty(io.StringIO):
    """stdin as a terminal that answers ``text``."""

    def isatty(self) -> bool:
        return True


def test_preflight_refuses_before_anything_moves(tmp_path, capsys, monkeypatch):
    """A site whose tension window the hanging platform is not in: refused after the
    read-only checks, the drives never enabled; a site requiring the safety parameters
    stored refuses the simulated drives (their EDS values at power-on) before the HAL opens
    the bus; a path leaving the site's workspace box is refused before anything moves."""
    with SimWithSite(tmp_path, "paper-centre") as sim:
        text = sim.site.read_text()
        # first, while no master has configured the drives yet
        strict = tmp_path / "strict.toml"
        strict.write_text(text.replace("require_stored_safety = false",
                                       "require_stored_safety = true"))
        code = main(["dry-run", "paper-centre", "--site", str(strict), "--yes", "--json",
                     "--quiet", "--duration", "1"])
        res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert code == 1 and res["ended"] == "refused" and not res["preflight"]["ok"]
        assert any("0x1016" in p and "commission check --apply" in p
                   for p in res["preflight"]["problems"])
        narrow = tmp_path / "narrow.toml"
        narrow.write_text(text.replace("tension_max_N = 3000.0", "tension_max_N = 100.0"))
        code = main(["dry-run", "paper-centre", "--site", str(narrow), "--yes", "--json",
                     "--quiet", "--duration", "1"])
        res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert code == 1 and res["ended"] == "refused" and res["cycles"] == 0, res
        assert "outside the site's window [1, 100] N (overload)" in res["message"]
        assert all(s in ("SWITCH_ON_DISABLED", "READY_TO_SWITCH_ON", "SWITCHED_ON")
                   for s in res["drive_states"]), res["drive_states"]
        # on a terminal: asked after the checks, before the drives are enabled
        for answer, ended in (("no\n", "refused"), ("yes\n", "completed")):
            monkeypatch.setattr(sys, "stdin", _Tty(answer))
            code = main(["dry-run", "paper-centre", "--site", str(sim.site), "--json",
                         "--quiet", "--duration", "0.5"])
            out = capsys.readouterr()
            res = json.loads(out.out.strip().splitlines()[-1])
            assert res["ended"] == ended and code == (ended != "completed"), res
            assert "Type 'yes' to go on" in out.err
            if ended == "refused":
                assert res["message"] == "not confirmed: nothing moved" and res["cycles"] == 0
        # the path leaves the site's workspace box: refused at the path check
        site = load_site(sim.site)
        lim = dataclasses.replace(site.limits, workspace_max_m=(10.05, 8.65, 1.5))
        box = write_site(dataclasses.replace(site, limits=lim), tmp_path / "box.toml")
        code = main(["dry-run", "paper-centre", "--site", str(box), "--yes", "--json",
                     "--quiet", "--duration", "1"])
        res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert code == 1 and res["ended"] == "refused" and res["cycles"] == 0, res
        assert "outside the site's workspace box" in res["message"], res["message"]


def test_a_wall_clock_site_runs_in_real_time(tmp_path, capsys):
    """Drives on the wall clock take each SYNC as one period: the dry run runs in real time
    on such a site even without --realtime (never faster than planned)."""
    with SimWithSite(tmp_path, "paper-centre", "--clock", "wall") as sim:
        assert load_site(sim.site).clock == "wall"
        code = main(["dry-run", "paper-centre", "--site", str(sim.site), "--yes", "--json",
                     "--duration", "1"])
        out = capsys.readouterr()
        res = json.loads(out.out.strip().splitlines()[-1])
    # whether a wall-clock sim keeps up on a loaded host is issue 30's real-time item, not
    # this test's: here, that the dry run ran in real time (never ahead of the wall clock)
    assert res["realtime"] and "runs in real time" in out.err, res
    assert code == (0 if res["ended"] == "completed" else 1)
    # never ahead of the wall clock, also when the run stopped before its path began
    assert res["cycles"] > 0 and res["wall_s"] >= res["trajectory_s"] >= 0, res
    assert res["wall_s"] >= 0.95 * res["cycles"] / res["rate_hz"], res
