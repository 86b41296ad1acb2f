"""A logger's log of the paper's robot with its masts' stiffness concealed (the model's masts
are rigid: poses off by about 20 mm), shared by the tests of logs as benches write them."""

from __future__ import annotations

from pathlib import Path

from bench.logger_sim import LoggerSpec, simulate_truth, write_log
from firmware_sim.scenario import parse_scenario

#: four targets visited twice, 2 s dwells
POSES = {"kind": "grid", "n": [2, 2, 1], "x": [8.0, 12.0], "y": [6.0, 11.0], "rpy_deg": 2.0,
         "visits": 2, "dwell_s": 2.0, "init_s": 3.0}
#: the paper's mast stiffness [N/m] per axis and mast
STIFF = {f"k{a}_{m}": k for m in "1234" for a, k in zip("xyz", (2e5, 5e5, 3e5), strict=True)}
#: the plant's simulation rate [Hz] (the logger interpolates between its states)
PHYSICS_HZ = 10.0


def mast_log(directory: Path, seed: int, rates: dict) -> Path:
    """Write the campaign's log with the logger's ``rates`` (:class:`LoggerSpec` fields but
    ``physics_hz``) into ``directory``; returns the recording's directory."""
    sc = parse_scenario({"format": "cdpr-scenario/1", "robot": "rocaspect", "seed": seed,
                         "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0],
                         "nuisance": {"hysteresis_m": 1e-4, "drift_m_per_h": 5e-5},
                         "poses": POSES, "truth": {"mast_compliance": STIFF}})
    return write_log(directory, sc, LoggerSpec(physics_hz=PHYSICS_HZ, **rates),
                     simulate_truth(sc, PHYSICS_HZ))
