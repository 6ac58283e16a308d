"""The stratified lower bound (mcverify.estimate.strata): exact box probabilities, draws inside the box and
the prior elsewhere, the bound's arithmetic, and strata files refused in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from scipy.special import ndtr

from mcverify.campaign import executors
from mcverify.campaign.spec import load_campaign
from mcverify.errors import RunError
from mcverify.estimate import strata
from mcverify.estimate.input_vector import ClosedLoopProblem

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "tiny.toml"


@pytest.fixture(scope="module")
def problem():
    """The tiny cell with veh_f's burst drawn in (0.5, 2] m/s^2: x = [burst, then 10 steps x 3 channels]."""
    cell = load_campaign(FIXTURE, settings=["scenario.front_accel_range_mps2=[0.5, 2.0]"]).cells[0]
    p = ClosedLoopProblem(cell, 11, "ellipse", executors.solver_for(cell.params))
    assert [d.name for d in p.draws] == ["front_accel_mps2"] and p.dimension == 1 + 30
    return p


def box(**kw) -> strata.Stratum:
    fields = {"name": "s", "draws": (("front_accel_mps2", 0.5, 0.9),),
              "units": (strata.UnitBox(3, "front_y", -1.0, -0.6), strata.UnitBox(4, "front_y", 0.6, 1.0)),
              "episodes": 10, **kw}
    return strata.Stratum(**fields)


def test_the_box_probability_is_the_product_of_its_sides(problem):
    # burst 0.5-0.9 of a 1.5 wide range, and two units each on 0.4 of [-1, 1]
    assert box().probability(problem) == pytest.approx((0.4 / 1.5) * 0.2 * 0.2, rel=1e-12)


def test_draws_fall_in_the_box_and_keep_their_law_elsewhere(problem):
    x = box().inputs(problem, np.random.default_rng(0), 4000)
    burst = 2.0 - 1.5 * ndtr(x[:, 0])  # the rollout's transform: value = hi - (hi - lo) u
    assert burst.min() >= 0.5 and burst.max() <= 0.9
    y3, y4 = (2 * ndtr(x[:, 1 + 3 * k + 1]) - 1 for k in (3, 4))
    assert y3.max() <= -0.6 and y4.min() >= 0.6
    # inside the box, uniform: the unit's mean is the box's middle
    assert y3.mean() == pytest.approx(-0.8, abs=0.01)
    free = x[:, [1 + 3 * 3, 1 + 3 * 3 + 2, 1 + 3 * 5 + 1]]  # x and v of step 3, y of step 5: standard normals
    assert stats.kstest(free.ravel(), "norm").pvalue > 1e-3


def test_inputs_are_a_pure_function_of_the_generator(problem):
    a = box().inputs(problem, np.random.default_rng(7), 5)
    b = box().inputs(problem, np.random.default_rng(7), 5)
    assert np.array_equal(a, b)


def test_the_bound_is_bonferroni_over_clopper_pearson():
    counts = [strata.StratumCount("a", 0.01, 10, 300), strata.StratumCount("b", 0.002, 0, 100)]
    bound = strata.lower_bound(counts, 0.95)
    each = stats.beta.ppf(0.025, 10, 291)  # level 1 - 0.05 / 2 for each of the two strata
    assert bound.lower == pytest.approx(0.01 * each, rel=1e-12)
    assert bound.point == pytest.approx(0.01 * 10 / 300, rel=1e-12)
    assert bound.per_stratum[1] == (0.0, 0.0)


def test_the_bound_covers_at_its_level_on_a_known_rate():
    """Binomial draws with a known P(event | R): the bound lies below the true P(event and R) in at least 95 %
    of repetitions (exact Clopper-Pearson: the miss rate is at most 5 %)."""
    rng = np.random.default_rng(1)
    p_region, rate, n = 0.01, 0.03, 300
    truth = p_region * rate
    lows = [strata.lower_bound([strata.StratumCount("a", p_region, int(rng.binomial(n, rate)), n)]).lower
            for _ in range(2000)]
    assert np.mean(np.array(lows) <= truth) >= 0.95


@pytest.mark.parametrize("kw, message", [
    ({"draws": (("opp_speed_mps", 1.0, 2.0),)}, "is not a random draw of this cell"),
    ({"draws": (("front_accel_mps2", 0.2, 0.9),)}, "is not a sub-range of its range"),
    ({"units": (strata.UnitBox(10, "front_y", 0.0, 1.0),)}, "outside the episode's control steps 0 to 9"),
    ({"units": (strata.UnitBox(1, "opp_x", 0.0, 1.0),)}, "is not measured in this cell"),
    ({"units": (strata.UnitBox(1, "front_y", 0.0, 1.0), strata.UnitBox(1, "front_y", -1.0, 0.0))}, "twice"),
])
def test_a_box_the_cell_cannot_hold_is_one_line(problem, kw, message):
    with pytest.raises(RunError, match=message):
        box(**kw).probability(problem)


def test_strata_must_not_overlap(problem):
    other_burst = box(name="t", draws=(("front_accel_mps2", 0.9, 1.2),))
    strata.check_disjoint([box(), other_burst], problem)  # bursts meet at 0.9 only: disjoint
    other_unit = box(name="u", draws=(), units=(strata.UnitBox(3, "front_y", -0.6, 1.0),))
    strata.check_disjoint([box(), other_unit], problem)  # step 3's y ranges meet at -0.6 only
    with pytest.raises(RunError, match="strata 's' and 'v' overlap"):
        strata.check_disjoint([box(), box(name="v", units=(strata.UnitBox(5, "front_x", 0.0, 1.0),))], problem)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "strata.toml"
    path.write_text(text)
    return path


def test_a_strata_file_reads_as_its_boxes(tmp_path):
    path = write(tmp_path, """
[[stratum]]
name = "low then high"
episodes = 20
draws = { front_accel_mps2 = [0.5, 0.9] }
units = [{ step = 3, channel = "front_y", range = [-1.0, -0.6] }]
""")
    (s,) = strata.load_strata(path)
    assert s == strata.Stratum("low then high", (("front_accel_mps2", 0.5, 0.9),),
                               (strata.UnitBox(3, "front_y", -1.0, -0.6),), 20)


@pytest.mark.parametrize("text, message", [
    ("x = 1", "no \\[\\[stratum\\]\\] table"),
    ("[[stratum]]\nepisodes = 0\nunits = []", "episodes must be a positive integer"),
    ("[[stratum]]\nepisodes = 5", "boxes nothing"),
    ("[[stratum]]\nepisodes = 5\ncolour = 1", "unknown key"),
    ("[[stratum]]\nepisodes = 5\nunits = [{ step = 1, channel = 'front_z', range = [0, 1] }]",
     "channel must be one of"),
    ("[[stratum]]\nepisodes = 5\nunits = [{ step = 1, channel = 'front_y', range = [0, 2] }]",
     "must lie in \\[-1, 1\\]"),
    ("[[stratum]]\nepisodes = 5\nunits = [{ step = -1, channel = 'front_y', range = [0, 1] }]", "step must be"),
    ("[[stratum]]\nepisodes = 5\nunits = [{ step = 1, channel = 'front_y' }]", "exactly step, channel and range"),
    ("[[stratum]]\nepisodes = 5\ndraws = { front_accel_mps2 = [0.9, 0.5] }", "low < high"),
    ("[[stratum]\n", "cannot read the strata"),
])
def test_a_bad_strata_file_is_one_line(tmp_path, text, message):
    with pytest.raises(RunError, match=message) as err:
        strata.load_strata(write(tmp_path, text))
    assert "\n" not in str(err.value)
