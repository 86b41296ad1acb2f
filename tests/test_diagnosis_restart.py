"""The selection's restart: when a wide effect (the most free parameters) was chosen, the
search runs again from the model as it is without it, and the set it ends in
replaces the first when its BIC is lower; a single wide effect too. And the swaps that
follow from what a fit held: an effect displaced by another (`Selector._displaced`)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from bench.diagnosis.select import Selection, Selector
from tests.robots import rocaspect


class _Space:
    def __init__(self, sizes: dict[str, int]) -> None:
        self.effects = tuple(sizes)
        self._ix, k = {}, 0
        for e, n in sizes.items():
            self._ix[e] = np.arange(k, k + n)
            k += n

    def indices(self, e: str) -> np.ndarray:
        return self._ix[e]

    def robot(self, phi: np.ndarray):
        return rocaspect()  # (every load cell at the model's gain)


def _fit(sizes: dict[str, int], bic: float, undetermined: int = 0) -> SimpleNamespace:
    space = _Space(sizes)
    stderr = np.ones(sum(sizes.values()))
    stderr[:undetermined] = np.inf  # the first effect's first parameters: undetermined
    return SimpleNamespace(space=space, stderr=stderr, bic=bic, reduced_chi2=1.0,
                           phi=np.zeros(len(stderr)))


def _selector(found: tuple[list[str], SimpleNamespace]) -> tuple[Selector, list]:
    sel = object.__new__(Selector)
    sel.rm = None  # no residual model (stands_out without the tracker latency floor)
    sel.model = rocaspect()  # 24 exit-point offsets, 8 pulley radii, 8 length offsets, ...
    sel.progress = lambda msg: None
    sel.stalled = False
    sel.budget = None
    sel.max_effects = 5
    sel.restarted = set()
    sel.cache = {("exit_point_offset",): None, (): None}
    calls: list = []

    def search(chosen, current, candidates, selection):
        calls.append((list(chosen), current, list(candidates)))
        return found

    sel._search = search
    return sel, calls


CANDIDATES = ["exit_point_offset", "cable_elasticity", "cable_length_offset",
              "pulley_kinematics"]
BASE = _fit({}, 1e5)


def test_the_search_without_the_widest_effect_replaces_a_worse_set():
    chosen = ["exit_point_offset", "cable_elasticity"]
    current = _fit({"exit_point_offset": 24, "cable_elasticity": 1}, 340.0, undetermined=7)
    other = (["cable_elasticity", "cable_length_offset", "pulley_kinematics"],
             _fit({"cable_elasticity": 1, "cable_length_offset": 1, "pulley_kinematics": 8},
                  215.0))
    sel, calls = _selector(other)
    got = sel._restart(chosen, current, CANDIDATES, BASE)
    assert got == other
    assert calls == [([], BASE, ["cable_elasticity", "cable_length_offset",
                                 "pulley_kinematics"])]
    assert not sel.stalled  # the new path's own state


def test_a_selection_again_skips_the_restart_the_one_before_ran():
    """A selection again (a nuisance fitted, slip times) gets the effects the selection
    before ran its restart without: that second opinion was taken (12883: 8 of 77 s for the
    same search without the exit points, which lost again); another one still runs."""
    chosen = ["exit_point_offset", "cable_elasticity"]
    current = _fit({"exit_point_offset": 24, "cable_elasticity": 1}, 340.0)
    other = (["cable_elasticity", "pulley_kinematics"],
             _fit({"cable_elasticity": 1, "pulley_kinematics": 8}, 215.0))
    first, calls = _selector(other)
    assert first._restart(chosen, current, CANDIDATES, BASE) == other
    assert first.restarted == {"exit_point_offset"} and len(calls) == 1
    again, calls = _selector(other)
    again.restarted = set(first.restarted)
    assert again._restart(chosen, current, CANDIDATES, BASE) is None
    assert calls == []
    # the restart without another wide effect is not skipped
    wide = _fit({"pulley_kinematics": 30, "cable_elasticity": 1}, 340.0)
    assert again._restart(["pulley_kinematics", "cable_elasticity"], wide,
                          ["pulley_kinematics", "cable_elasticity", "drum_scale"],
                          BASE) == other
    assert len(calls) == 1 and again.restarted == {"exit_point_offset", "pulley_kinematics"}


def test_an_effect_no_wider_than_another_candidate_runs_no_restart():
    # the pulleys (8 radii) are the widest chosen, but the exit points have more: the
    # pulleys cannot carry the shares of two effects
    chosen = ["pulley_kinematics", "cable_elasticity"]
    current = _fit({"pulley_kinematics": 8, "cable_elasticity": 1}, 300.0)
    sel, calls = _selector((["exit_point_offset"], _fit({"exit_point_offset": 24}, 100.0)))
    assert sel._restart(chosen, current, CANDIDATES, BASE) is None
    assert calls == []


def test_the_width_counts_the_parameters_the_data_fix():
    # 24 exit parameters of which 20 undetermined: 4, fewer than the pulleys' 8
    chosen = ["exit_point_offset", "cable_elasticity"]
    current = _fit({"exit_point_offset": 24, "cable_elasticity": 1}, 300.0, undetermined=20)
    sel, calls = _selector((["pulley_kinematics"], _fit({"pulley_kinematics": 8}, 100.0)))
    assert sel._restart(chosen, current, CANDIDATES, BASE) is None
    assert calls == []


def test_a_restart_that_ends_higher_keeps_the_set_and_its_state():
    chosen = ["exit_point_offset", "cable_elasticity"]
    current = _fit({"exit_point_offset": 24, "cable_elasticity": 1}, 200.0)
    sel, calls = _selector((["pulley_kinematics"], _fit({"pulley_kinematics": 8}, 900.0)))
    sel.stalled = True  # the first search's state (the restart searches unstalled)
    assert sel._restart(chosen, current, CANDIDATES, BASE) is None
    assert len(calls) == 1 and sel.stalled


def test_a_single_wide_effect_runs_the_restart_too():
    # exit points took in one step what pulley radii and two cables' stretch did: no effect
    # was left for a second step, and only a search without them finds the other path
    found = (["cable_elasticity", "pulley_kinematics"],
             _fit({"cable_elasticity": 2, "pulley_kinematics": 8}, 300.0))
    sel, calls = _selector(found)
    current = _fit({"exit_point_offset": 24}, 360.0)
    assert sel._restart(["exit_point_offset"], current, CANDIDATES, BASE) == found
    assert calls[0][0] == [] and "exit_point_offset" not in calls[0][2]
    # ... and keeps the exit points when the other path fits worse
    sel, calls = _selector((found[0], _fit({"cable_elasticity": 2, "pulley_kinematics": 8},
                                           400.0)))
    assert sel._restart(["exit_point_offset"], current, CANDIDATES, BASE) is None
    assert len(calls) == 1


def test_the_selection_record_is_untouched_by_the_restart():
    # the restart records its screens in a selection of its own
    chosen = ["exit_point_offset", "cable_elasticity"]
    current = _fit({"exit_point_offset": 24, "cable_elasticity": 1}, 340.0)
    seen: list = []
    sel, _ = _selector((chosen, current))

    def search(chosen_, current_, candidates, selection):
        seen.append(selection)
        return chosen, current

    sel._search = search
    sel._restart(chosen, current, CANDIDATES, BASE)
    assert isinstance(seen[0], Selection) and seen[0].effects == []


def test_no_restart_without_an_effect_of_the_load_cells_gauge():
    # the cells' gains trade with the mass along the gauge: the gauge moves search that
    sel, calls = _selector((["platform_mass"], _fit({"platform_mass": 4}, 1.0)))
    current = _fit({"load_cell_calibration": 16, "platform_mass": 4}, 500.0)
    assert sel._restart(["load_cell_calibration", "platform_mass"], current,
                        ["load_cell_calibration", "platform_mass", "cable_elasticity"],
                        BASE) is None
    assert calls == []


def test_the_restart_may_fit_as_many_new_sets_as_the_first_search_and_one_effect_more():
    chosen = ["exit_point_offset", "cable_elasticity"]
    current = _fit({"exit_point_offset": 24, "cable_elasticity": 1}, 340.0)
    seen: list = []
    sel, _ = _selector((chosen, current))

    def search(chosen_, current_, candidates, selection):
        seen.append((sel.budget, sel.max_effects))
        return chosen, current

    sel._search = search
    sel._restart(chosen, current, CANDIDATES, BASE)
    # as many new sets as the first search, and one effect more than it chose at most
    assert seen == [(2 * len(sel.cache), 3)]
    assert sel.budget is None and sel.max_effects == 5


def test_a_stalled_search_restarts_far_from_the_data_with_two_effects_more():
    chosen = ["exit_point_offset", "load_cell_calibration"]
    current = _fit({"exit_point_offset": 24, "load_cell_calibration": 16}, 39198.0)
    current.reduced_chi2 = 33.0  # the stall rule ended the first search there
    better = (["cable_sag", "drum_scale", "platform_mass"], _fit({"cable_sag": 1}, 685.0))
    sel, calls = _selector(better)
    sel.stalled = True
    seen: list = []
    search = sel._search

    def spy(*a):
        seen.append((sel.max_effects, sel.stalled))
        return search(*a)

    sel._search = spy
    assert sel._restart(chosen, current, CANDIDATES, BASE) == better
    # the restart searches afresh (not stalled) and may name one effect more than the
    # first search would have been allowed
    assert seen == [(len(chosen) + 2, False)]
    assert [c for c in calls[0][2]] == [c for c in CANDIDATES if c != "exit_point_offset"]
    # a worse set leaves the first one and the stall in place
    sel2, _ = _selector((["drum_scale"], _fit({"drum_scale": 8}, 5e4)))
    sel2.stalled = True
    assert sel2._restart(chosen, current, CANDIDATES, BASE) is None
    assert sel2.stalled


def test_a_search_whose_budget_is_spent_stops():
    sel, _ = _selector(([], BASE))
    del sel._search  # the real search
    sel.budget = len(sel.cache)
    sel._forward = lambda *a: (_ for _ in ()).throw(AssertionError("no step"))
    assert sel._search(["pulley_kinematics"], BASE, CANDIDATES, None) == (
        ["pulley_kinematics"], BASE)


def test_a_restart_far_from_the_data_with_as_many_effects_as_the_first_set_stops():
    sel, _ = _selector(([], BASE))
    del sel._search
    sel.max_effects, sel.budget = 3, 100  # in a restart from a set of two
    far = SimpleNamespace(reduced_chi2=6.7)
    sel._forward = lambda *a: (["drum_scale", "mast_compliance"], far)
    sel._pairs = lambda *a: None
    sel._backward = lambda *a: (_ for _ in ()).throw(AssertionError("stopped before"))
    assert sel._search(["drum_scale"], BASE, CANDIDATES, None) == (
        ["drum_scale", "mast_compliance"], far)


def test_a_restart_far_from_the_data_is_not_run():
    sel, calls = _selector((["pulley_kinematics"], _fit({"pulley_kinematics": 8}, 1.0)))
    current = _fit({"exit_point_offset": 24, "cable_elasticity": 1}, 500.0)
    current.reduced_chi2 = 5.0  # the first search's set leaves far more than the noise
    assert sel._restart(["exit_point_offset", "cable_elasticity"], current, CANDIDATES,
                        BASE) is None
    assert calls == []


def test_with_the_cells_gain_shared_both_restarts_run_and_the_better_is_kept():
    """Exit points and the load cells stalled at 33 x the noise, every cell 30 % high: the
    search runs again without the exit points (two effects more, the stall) and without
    the cells (three in their place); the lower BIC of the two is kept."""
    chosen = ["exit_point_offset", "load_cell_calibration"]
    current = _fit({"exit_point_offset": 24, "load_cell_calibration": 16}, 39198.0)
    current.reduced_chi2 = 33.0
    current.space.robot = lambda phi: rocaspect().replace(load_cell_gain=np.full(8, 1.3))
    sel, _ = _selector(([], BASE))
    sel.stalled = True
    no_exit = (["cable_sag", "drum_scale", "platform_mass"], _fit({"cable_sag": 1}, 685.0))
    no_cells = (["platform_mass"], _fit({"platform_mass": 4}, 5000.0))
    seen: list = []

    def search(chosen_, current_, candidates, selection):
        seen.append((sel.max_effects, "exit_point_offset" in candidates))
        return no_cells if "exit_point_offset" in candidates else no_exit

    sel._search = search
    assert sel._restart(chosen, current, CANDIDATES + ["load_cell_calibration"],
                        BASE) == no_exit
    assert seen == [(len(chosen) + 2, False), (len(chosen) + 3, True)]
    # the cells right (no gain shared), only the first restart runs
    current.space.robot = lambda phi: rocaspect()
    seen.clear()
    sel.stalled = True
    sel.restarted.clear()  # (another selection: none of its restarts ran)
    sel._restart(chosen, current, CANDIDATES + ["load_cell_calibration"], BASE)
    assert seen == [(len(chosen) + 2, False)]


def test_an_effect_held_at_the_model_beside_another_is_displaced_by_it():
    """The mass chosen, then the sag fitted beside it with the mass held at the model's
    values: the sag took its place, a swap to try; where the mass kept a value, or the set
    was never fitted, none."""
    sel, _ = _selector(([], BASE))
    held = _fit({"cable_sag": 1, "platform_mass": 4}, 571.2)
    held.space.neutral = np.zeros(5)
    held.phi = np.array([0.0357, 0.0, 0.0, 0.0, 0.0])
    sel.cache = {("cable_sag", "platform_mass"): held}
    cands = ["cable_sag", "platform_mass", "exit_point_offset"]
    assert sel._displaced(["platform_mass"], cands) == [("platform_mass", "cable_sag")]
    held.phi[1] = 29.3 - 35.0  # the mass keeps a change: both effects act
    assert sel._displaced(["platform_mass"], cands) == []
    sel.cache = {}
    assert sel._displaced(["platform_mass"], cands) == []


def test_a_swap_at_equal_cost_needs_a_tie_a_wider_one_the_entry_bar():
    chosen = ["platform_mass"]
    current = _fit({"platform_mass": 4}, 583.2)
    current.n_free = 1
    sel, _ = _selector(([], BASE))
    sel.swap_screen = lambda *a: {("platform_mass", "cable_sag"): -12.0}
    sag = _fit({"cable_sag": 1}, 571.2)
    sag.n_free = 1
    sel.fit_many = lambda sets, start: [sag]
    assert sel._swap(chosen, current, ["cable_sag"]) == (["cable_sag"], sag)
    sag.n_free = 2  # one parameter more: the entry bar
    assert sel._swap(chosen, current, ["cable_sag"]) is None


def test_a_lookalike_that_beats_the_chosen_effect_is_swapped_in():
    """Pulley radii refitted as a look-alike of exit offsets (case 12079: the linearised
    swap screen predicted +228, the refit -11.4 at fewer free parameters): the swap the
    screen missed; at a BIC lower within the tie too (the report prefers what the data
    favour); at an equal or higher BIC, or at more parameters short of the entry bar,
    none."""
    sel, _ = _selector(([], BASE))
    cur = _fit({"mast_compliance": 12, "exit_point_offset": 24}, 213.0)
    cur.n_free = 17
    pulleys = _fit({"mast_compliance": 12, "pulley_kinematics": 8}, 213.0 - 11.4)
    pulleys.n_free = 16
    sel.fit = lambda effects, start: pulleys
    record = Selection(["mast_compliance", "exit_point_offset"], cur, BASE)
    record.alternatives = {"exit_point_offset": [("pulley_kinematics", -11.4)],
                           "mast_compliance": []}
    e, a, chosen, fit = sel._missed_swap(record)
    assert (e, a, fit) == ("exit_point_offset", "pulley_kinematics", pulleys)
    assert chosen == ["mast_compliance", "pulley_kinematics"]
    pulleys.bic = 213.0 - 2.5  # within the tie, lower: preferred
    assert sel._missed_swap(record)[1] == "pulley_kinematics"
    pulleys.bic = 213.0  # equal: the chosen one stays
    assert sel._missed_swap(record) is None
    pulleys.bic = 213.0 + 3.0
    assert sel._missed_swap(record) is None
    pulleys.bic, pulleys.n_free = 213.0 - 20.0, 18  # more parameters: the entry bar
    assert sel._missed_swap(record) is None
    pulleys.bic = 213.0 - 30.0
    assert sel._missed_swap(record) is not None
    record.alternatives = {}
    assert sel._missed_swap(record) is None


def test_lookalikes_within_the_screens_error_on_a_large_signal_are_refitted():
    """The linearised swap screen's error grows with the signal it replaces: on exit
    offsets that remove a chi-square of 82,000 a prediction of +400 is refitted (the best
    LOOKALIKE_REFITS of them), on a signal of 2,000 it is not (beyond the margin)."""
    chosen = ["exit_point_offset"]
    cands = ["exit_point_offset", "pulley_kinematics", "drum_scale", "cable_length_offset"]
    pred = {("exit_point_offset", "pulley_kinematics"): 400.0,
            ("exit_point_offset", "drum_scale"): 700.0,
            ("exit_point_offset", "cable_length_offset"): 1642.0}
    for signal, want in ((82000.0, [("pulley_kinematics",), ("drum_scale",)]),
                         (2000.0, [])):
        sel, _ = _selector(([], BASE))
        cur = _fit({"exit_point_offset": 24}, 213.0)
        cur.chi2 = 180.0
        sel._signal = {}

        def screen(c, ch, ca, signal=signal, sel=sel):
            sel._signal[(id(c), tuple(ch), tuple(ca), "exit_point_offset")] = signal
            return pred

        refitted: list = []

        def many(sets, start, refitted=refitted):
            refitted.extend(sets)
            return [SimpleNamespace(bic=start.bic + 5.0, chi2=start.chi2) for _ in sets]

        sel.swap_screen, sel.fit_many = screen, many
        sel.imitation = lambda *a: {}
        record = Selection(chosen, cur, BASE)
        sel._lookalikes(record, cands)
        assert refitted == want
        assert record.alternatives["exit_point_offset"] == \
            [(s[0], 5.0) for s in want]


def test_an_imitation_the_refit_does_not_bear_out_is_no_alternative():
    """Exit offsets imitate 99 % of the masts' signature, linearised; refitted in their
    place they leave a chi-square 19,000 higher: no alternative. Where the refit fits as
    well and only its parameters cost BIC, it is one."""
    for rise, listed in ((19000.0, False), (3.0, True)):
        sel, _ = _selector(([], BASE))
        cur = _fit({"mast_compliance": 12}, 213.0)
        cur.chi2 = 180.0
        sel._signal = {}
        sel.swap_screen = lambda *a: {}
        sel.fit_many = lambda sets, start: []
        sel.imitation = lambda *a: {"exit_point_offset": 0.99}
        sel.fit = lambda effects, start, rise=rise: SimpleNamespace(
            chi2=start.chi2 + rise, bic=start.bic + rise + 60.0)
        record = Selection(["mast_compliance"], cur, BASE)
        sel._lookalikes(record, ["mast_compliance", "exit_point_offset"])
        assert bool(record.alternatives["mast_compliance"]) == listed


def test_a_swap_the_search_fitted_already_is_an_alternative_and_the_better_one_preferred():
    """The mass chosen by the greedy order, a sag fitted in its place on the way (a
    displaced effect) 2.5 lower in BIC, which the screen did not predict as a look-alike
    (case 12435): listed as the alternative, and then preferred at no more free
    parameters; a cached swap beyond the tie is not listed."""
    for sag_bic, listed in ((890.7, True), (893.2 + 30.0, False)):
        sel, _ = _selector(([], BASE))
        cur = _fit({"platform_mass": 4}, 893.2)
        cur.chi2, cur.n_free = 886.7, 1
        sag = _fit({"cable_sag": 1}, sag_bic)
        sag.n_free = 1
        sel.cache = {("platform_mass",): cur, ("cable_sag",): sag, (): BASE}
        sel._signal = {}
        sel.swap_screen = lambda *a: {("platform_mass", "cable_sag"): 400.0}
        sel.fit_many = lambda sets, start: [SimpleNamespace(bic=start.bic + 500.0)
                                            for _ in sets]
        sel.imitation = lambda *a: {}
        sel.fit = lambda effects, start, sag=sag: sag
        record = Selection(["platform_mass"], cur, BASE)
        sel._lookalikes(record, ["platform_mass", "cable_sag"])
        alts = record.alternatives["platform_mass"]
        assert [a for a, _ in alts] == (["cable_sag"] if listed else [])
        if listed:
            assert alts[0][1] == sag_bic - 893.2
            assert sel._missed_swap(record)[1] == "cable_sag"


def _far(sizes: dict[str, int], bic: float, red: float, z: float) -> SimpleNamespace:
    """A fit whose last effect's parameters sit ``z`` of their errors from the model's."""
    f = _fit(sizes, bic)
    k = len(f.stderr)
    f.space.neutral = np.zeros(k)
    f.phi = np.full(k, z)
    f.cov = np.eye(k)
    f.reduced_chi2, f.n_eff, f.n_res = red, 128.0, 128
    return f


def test_far_from_the_data_the_bic_lets_an_effect_in_that_its_errors_would_not():
    """Exit offsets leave 286 x the noise (a CoGiRo dwell without tensions, case 12204): a
    drum scale lowers the BIC by 19,223, and its errors, which measure the misfit of the
    effects still missing, make it stand out by a chi-square of 26 on 8 only. It enters;
    where the set with it comes within ten times the noise of the data (an effect outside
    the vocabulary may leave that much), or where it takes less than half of the excess (a
    tenth of a misfit outside the vocabulary: friction at 1,380 x the noise), the errors
    decide and it does not."""
    current = _far({"exit_point_offset": 24}, 22442.0, 286.0, 0.0)
    for red, enters in ((40.0, True), (250.0, False), (4.0, False), (1.2, False)):
        sel, _ = _selector(([], BASE))
        sel.measured_noise = False
        drum = _far({"exit_point_offset": 24, "drum_scale": 8}, 22442.0 - 19223.0, red, 0.6)
        sel.screen = lambda cur, rest: {"drum_scale": -19000.0}
        sel.fit_many = lambda sets, start, multistart=False, drum=drum: [drum]
        sel._whole_gauge = lambda *a: None
        got = sel._forward(current, ["exit_point_offset"], ["exit_point_offset", "drum_scale"],
                           Selection([], BASE, BASE))
        assert (got is not None and got[0] == ["exit_point_offset", "drum_scale"]) == enters


def test_far_from_the_data_the_backward_step_keeps_what_the_bic_needs():
    sel, _ = _selector(([], BASE))
    for red, kept in ((40.0, True), (250.0, False), (4.0, False), (1.2, False)):
        current = _far({"exit_point_offset": 24, "drum_scale": 8}, 3219.0, red, 0.6)
        without = _far({"exit_point_offset": 24}, 22442.0, 286.0, 0.0)
        sel.fit = lambda effects, start, without=without: without
        chosen, fit, dropped = sel._backward(["exit_point_offset", "drum_scale"], current)
        assert (not dropped) == kept


def test_a_search_that_comes_back_to_a_set_it_left_stops_there():
    """A swap the backward step undoes and the forward step brings back cycles (case
    12554: the load cells swapped for a cable's E*A and E*A dropped, fourteen times over):
    the search stops when it comes back to a set it left."""
    sel = object.__new__(Selector)
    sel.rm = None  # no residual model (stands_out without the tracker latency floor)
    sel.progress = lambda msg: None
    sel.budget = None
    sel.max_effects = 5
    sel.cache = {}
    fit = _fit({"platform_mass": 1}, 100.0)
    calls = {"swap": 0}

    def forward(current, chosen, candidates, selection):
        if "load_cell_calibration" in chosen or "cable_elasticity" in chosen:
            return None
        return chosen + ["load_cell_calibration"], current

    def backward(chosen, current):
        if "cable_elasticity" in chosen:
            return [c for c in chosen if c != "cable_elasticity"], current, True
        return chosen, current, False

    def swap(chosen, current, candidates):
        if "load_cell_calibration" not in chosen:
            return None
        calls["swap"] += 1
        return [c for c in chosen if c != "load_cell_calibration"] + ["cable_elasticity"], \
            current

    sel._forward, sel._backward, sel._swap = forward, backward, swap
    chosen, _ = sel._search(["platform_mass"], fit, CANDIDATES + ["load_cell_calibration"],
                            Selection([], BASE, BASE))
    assert calls["swap"] <= 2
    assert "platform_mass" in chosen


def test_prefetch_makes_the_fits_fit_would_make_and_keeps_none_of_them(monkeypatch):
    """``prefetch(..., refits=True)``: the fits :meth:`Selector.fit` would make from the
    start are made on the pool all at once: the new sets', and the refits of the sets fitted
    before that are subsets of the start; not those of unrelated sets. What the selection
    keeps (its cache, the refits it made) is left as :meth:`fit` leaves it: the pool
    changes when a fit is made, not which fit the selection holds."""
    import bench.diagnosis.select as select

    asked = []

    def side_by_side(pool, rm, jobs):
        asked.extend(space.effects for space, _, _, _ in jobs)
        return [SimpleNamespace(space=space, bic=5.0, chi2=5.0, phi=np.zeros(0))
                for space, _, _, _ in jobs]

    monkeypatch.setattr(select, "fits_side_by_side", side_by_side)
    sel = object.__new__(Selector)
    sel.model = rocaspect()
    sel.progress = lambda msg: None
    sel.rm, sel.train, sel.pool = None, None, object()
    sel._refit_from = set()
    sel._starts = lambda key, start: [None]
    sel._pinned_many = lambda fits: [[] for _ in fits]
    old = SimpleNamespace(space=SimpleNamespace(effects=("drum_scale",)), bic=10.0, chi2=10.0)
    unrelated = SimpleNamespace(space=SimpleNamespace(effects=("pulley_kinematics",)),
                                bic=1.0, chi2=1.0)
    sel.cache = {("drum_scale",): old, ("pulley_kinematics",): unrelated}
    start = SimpleNamespace(space=SimpleNamespace(effects=("drum_scale", "exit_point_offset")),
                            chi2=3.0)
    sel.prefetch([("drum_scale",), ("exit_point_offset",), ("pulley_kinematics",)], start,
                 refits=True)
    assert sorted(asked) == [("drum_scale",), ("exit_point_offset",)]
    assert sel.cache == {("drum_scale",): old, ("pulley_kinematics",): unrelated}
    assert not sel._refit_from
    # without refits, a set fitted before is not asked for again
    asked.clear()
    sel.prefetch([("drum_scale",), ("cable_length_offset",), ("exit_point_offset",)], start)
    assert sorted(asked) == [("cable_length_offset",), ("exit_point_offset",)]
    assert sel.cache[("drum_scale",)] is old


def test_the_backward_step_asks_the_pool_for_every_set_without_one_and_its_refits():
    """The backward step's sets (each chosen effect left out) go to the pool together,
    with the refits from the current fit of those fitted before: ``fit`` would refit
    each in turn (12883: five in a row)."""
    sel, _ = _selector(([], BASE))
    current = _far({"exit_point_offset": 24, "drum_scale": 8, "cable_elasticity": 1},
                   100.0, 1.0, 5.0)
    asked = []
    sel.prefetch = lambda sets, start, refits=False: asked.append((sets, start, refits))
    sel.fit = lambda effects, start: current
    sel._backward(["exit_point_offset", "drum_scale", "cable_elasticity"], current)
    assert asked == [([("drum_scale", "cable_elasticity"),
                       ("exit_point_offset", "cable_elasticity"),
                       ("exit_point_offset", "drum_scale")], current, True)]
