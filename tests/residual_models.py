"""Residual models of small generated campaigns on the paper's robot, for the diagnosis's
unit tests that need a real recording's samples but not a whole diagnosis."""

from __future__ import annotations

from pathlib import Path

from bench.campaign import run_campaign
from bench.diagnosis.residuals import ResidualModel
from bench.diagnosis.samples import prepare
from bench.recording import read_recording
from firmware_sim.scenario import parse_scenario


def campaign_residual_model(directory: Path, truth: dict, seed: int = 5) -> ResidualModel:
    """The residual model (noise estimated) of a 3 x 2 grid visited twice by ROCASPECT from
    the paper's start pose, with ``truth`` (scenario ``truth`` table) concealed; all sensors.
    The recording is written into ``directory``."""
    sc = parse_scenario({
        "format": "cdpr-scenario/1", "robot": "rocaspect", "seed": seed,
        "init_pose": [10.0, 8.56, 1.0, 0.0, 0.0, 0.0], "truth": truth,
        "poses": {"kind": "grid", "n": [3, 2, 1], "rpy_deg": 1.0, "visits": 2}})
    rec = read_recording(run_campaign(sc, directory))
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    return rm


def load_change_residual_model(seed: int, factor: float | None, directory: Path
                               ) -> tuple[ResidualModel, dict]:
    """The residual model (noise estimated) of ``cdpr evaluate --kind load_change`` case
    ``seed`` recorded into ``directory`` / "rec", its load changed by ``mass_factor`` =
    ``factor`` (None: the case's own; 1.0: no change), and the case (its truth:
    ``case["case"]["change"]["t_s"]``, the change's time [s])."""
    from bench.evaluate import make_case, record

    case = make_case(seed, kind="load_change")
    if factor is not None:
        case["case"]["change"]["mass_factor"] = factor
    record(case, directory / "rec")
    rec = read_recording(directory / "rec")
    s = prepare(rec)
    rm = ResidualModel(s, rec.robot, rec.init_pose, rec.init_tensions, rows=s.triples)
    rm.estimate_noise(rec.robot)
    return rm, case
