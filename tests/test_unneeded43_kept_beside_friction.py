"""A true effect is not lost to the rule that does not name an effect a probe stands for
(:func:`bench.diagnosis.probes.unneeded`, ``report._without_unneeded``,
:func:`bench.diagnosis.probes.lost_with`).

A CoGiRo-class dwell campaign with friction at the load cells (30 N by direction of
travel) and a true calibration of the cells (cell 41 reads 8 % high, 21 5 % low, 32 has an
offset of -27 N): the selection names the cells' calibration and length offsets; the
cells' friction probe stands for the offsets and, beside it, they are not needed. Left
out, the refit holds nothing of the friction they took: the cells' gains fall below the
noise and the calibration went with them (nothing was named). Such a drop is not made:
the calibration stays named, the offsets stay, in question, marked ``others_need_it``.
The same campaign with nothing concealed still names nothing (the offsets and the
elasticity that soak the friction go)."""

from __future__ import annotations

import copy

import pytest

from bench.campaign import run_campaign
from bench.diagnosis import probes
from bench.diagnosis.report import diagnose
from bench.evaluate import one_blas_thread
from firmware_sim.scenario import parse_scenario

#: the scenario of evaluation case 13302 (a perturbed CoGiRo-class robot, 11 poses)
SCENARIO = {"format": "cdpr-scenario/1",
 "robot": {"name": "cogiro-variant",
           "gravity": 9.81,
           "platform": {"mass": 103.645889222, "com": [-0.034, -0.013, -0.236]},
           "cables": {"tension_min": 100.0, "tension_max": 5000.0, "ea": 724767.502771},
           "mast": [{"id": "1", "pivot": [-7.67742752493, -5.27556710307, 0.0]},
                    {"id": "2", "pivot": [-7.74896771635, 5.0438971962, 0.0]},
                    {"id": "3", "pivot": [7.36691611525, 5.17072551066, 0.0]},
                    {"id": "4", "pivot": [7.33641775684, -5.40102853711, 0.0]}],
           "cable": [{"id": "11",
                      "mast": "1",
                      "exit": [-7.52064679098, -5.4038750788, 5.46385688688],
                      "anchor": [0.539387471819, -0.506686315917, -0.458317850489]},
                     {"id": "12",
                      "mast": "1",
                      "exit": [-7.854130686, -5.1197947441, 5.4566985049],
                      "anchor": [-0.546354917301, 0.360684983003, 0.456117924807]},
                     {"id": "21",
                      "mast": "2",
                      "exit": [-7.89565814108, 4.89272521811, 5.7057928044],
                      "anchor": [-0.539387471819, -0.277608168217, -0.458317850489]},
                     {"id": "22",
                      "mast": "2",
                      "exit": [-7.58434056002, 5.19035002489, 5.67827945555],
                      "anchor": [0.531669686053, 0.366134328527, 0.457951196209]},
                     {"id": "31",
                      "mast": "3",
                      "exit": [7.2055186721, 5.2862176095, 5.84718904475],
                      "anchor": [-0.539387471819, 0.506686315917, -0.458317850489]},
                     {"id": "32",
                      "mast": "3",
                      "exit": [7.53220738365, 5.05105560483, 5.88487621848],
                      "anchor": [0.535742961874, -0.349991927634, 0.457492878358]},
                     {"id": "41",
                      "mast": "4",
                      "exit": [7.48983597397, -5.26775231949, 5.25234721264],
                      "anchor": [0.53820836566, 0.282749060221, -0.45895949548]},
                     {"id": "42",
                      "mast": "4",
                      "exit": [7.17521614745, -5.56142327975, 5.27533708249],
                      "anchor": [-0.540780960915, -0.356058180199, 0.456117924807]}]},
 "seed": 13302,
 "init_pose": [3.4620315703, -2.79277764204, 2.61235864096, 0.0, 0.0, -0.0],
 "truth": {"load_cell_calibration": {"gain_41": 1.07957181904,
                                     "offset_32": -26.5218233686,
                                     "gain_21": 0.949556561764}},
 "noise": {"tracker_m": 1.5e-05,
           "tracker_rad": 1e-05,
           "load_cell_n": 0.25,
           "encoder_m": 1e-06,
           "process_m": 0.0001,
           "exit_m": 2.5e-05},
 "nuisance": {"hysteresis_m": 2.36739874336e-05,
              "drift_m_per_h": 1.00519810746e-05,
              "init_pretension_n": 22.1505945257,
              "friction_n": 29.844309805},
 "poses": {"kind": "list",
           "list": [[-5.58147831237,
                     -3.93427714636,
                     1.91258477101,
                     0.00409046352987,
                     -0.0149992576139,
                     0.0249407226434],
                    [-1.98164302326,
                     -3.93427714636,
                     1.91258477101,
                     -0.000850424688691,
                     -0.0104802839377,
                     0.0316639485016],
                    [1.61819226584,
                     -3.93427714636,
                     1.91258477101,
                     -0.0251061850021,
                     -0.00640681983807,
                     -0.00462898729447],
                    [5.21802755494,
                     -3.93427714636,
                     1.91258477101,
                     0.0124037034283,
                     -0.0346189643317,
                     0.0254314020638],
                    [-5.58147831237,
                     -0.137602835123,
                     1.91258477101,
                     0.0268634517668,
                     -0.0186782240139,
                     -0.0301996893958],
                    [-1.98164302326,
                     -0.137602835123,
                     1.91258477101,
                     -0.0179303904372,
                     0.026691750351,
                     -0.0289121373933],
                    [1.61819226584,
                     -0.137602835123,
                     1.91258477101,
                     0.016877939446,
                     -0.0116515397504,
                     -0.03116406353],
                    [5.21802755494,
                     -0.137602835123,
                     1.91258477101,
                     -0.0221119110779,
                     -0.0294613033498,
                     -0.0144722657088],
                    [-5.58147831237,
                     3.65907147611,
                     1.91258477101,
                     0.0343125045945,
                     0.0200524756827,
                     -0.00165263153311],
                    [1.61819226584,
                     3.65907147611,
                     1.91258477101,
                     0.0149854214727,
                     0.009782255309,
                     0.00957291382822],
                    [5.21802755494,
                     3.65907147611,
                     1.91258477101,
                     0.0254714000102,
                     -0.0160867749648,
                     -0.0241706252305]],
           "visits": 3,
           "dwell_s": 3.0,
           "rate_hz": 2.0,
           "init_s": 4.0},
 "recording": {"kind": "dwell",
               "dwell_at_targets": False,
               "state_column": False,
               "tracker": True,
               "load_cells": True}}


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    """{name: report} of the campaign with the cells' calibration concealed ("true") and
    with nothing concealed ("none")."""
    one_blas_thread()
    out = {}
    for name in ("true", "none"):
        sc = copy.deepcopy(SCENARIO)
        if name == "none":
            sc["truth"] = {}
        rec = run_campaign(parse_scenario(sc), tmp_path_factory.mktemp(name) / "rec")
        out[name] = diagnose(rec).report
    return out


def test_a_true_cell_calibration_beside_the_cells_friction_stays_named(reports):
    rep = reports["true"]
    named = [e["name"] for e in rep["effects"]]
    assert "load_cell_calibration" in named, named
    un = rep["unexplained"]
    assert un is not None and un.get("load_cell_direction_cables")
    assert not un.get("effects_not_named")
    kept = [q for q in un["effects_in_question"] if q.get("others_need_it")]
    assert kept and all(q["effect"] in named for q in kept)
    assert all(q["others_need_it"] == ["load_cell_calibration"] for q in kept)


def test_with_nothing_concealed_the_effects_that_soak_the_friction_still_go(reports):
    rep = reports["none"]
    assert rep["effects"] == [], [e["name"] for e in rep["effects"]]
    gone = {q["effect"] for q in rep["unexplained"]["effects_not_named"]}
    assert "cable_length_offset" in gone
    assert not any(q.get("others_need_it")
                   for q in rep["unexplained"].get("effects_in_question", []))


def _stand(effect: str, beyond: float = 3.0) -> dict:
    return {"effect": effect, "delta_bic": -100.0, "needed_beyond_bic": beyond,
            "probe_finding": True, "probe": "cell_friction", "cable": None}


def test_lost_with_only_the_named_effects_that_went_besides_the_dropped():
    before = ["load_cell_calibration", "cable_length_offset", "cable_elasticity"]
    gone = ["cable_length_offset", "cable_elasticity"]
    assert probes.lost_with(before, gone, []) == ["load_cell_calibration"]
    assert probes.lost_with(before, gone, ["load_cell_calibration"]) == []
    # an effect the selection found anew does not count; one dropped alone is no loss
    assert probes.lost_with(before, gone, ["load_cell_calibration", "platform_mass"]) == []
    assert probes.lost_with(["cable_length_offset"], ["cable_length_offset"], []) == []
    # an effect a probe stands for went with what it soaked (12986: an elasticity that went
    # with the offsets, both soaking the cells' friction)
    assert probes.lost_with(before, gone, [], {"load_cell_calibration"}) == []
    assert probes.lost_with(before, ["cable_length_offset"], [],
                            {"cable_length_offset", "cable_elasticity"}) == \
        ["load_cell_calibration"]


def test_a_stand_the_others_need_is_not_unneeded_the_rest_still_are():
    keep, drop = _stand("cable_length_offset"), _stand("cable_elasticity")
    marked = probes.needed_by_others([keep, drop], [keep], ["load_cell_calibration"])
    assert marked[0]["others_need_it"] == ["load_cell_calibration"]
    assert "others_need_it" not in marked[1]
    assert probes.unneeded(marked) == [drop]
    assert probes.unneeded([keep, drop]) == [keep, drop]
