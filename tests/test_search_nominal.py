"""The falsifier's search starts from the space's nominal and beats sampling (issue 37).

The search algorithm is checked on functions of the point whose failure probability is
known exactly (no episodes: an evaluator of a formula, as the estimator's own check in
tests/test_falsify.py), and on real episodes for what a run writes (likelihoods, the
order of the counterexamples, the settings that refuse another search)."""

from __future__ import annotations

import math
from statistics import NormalDist, median

import numpy as np
import pytest
from cli_helpers import run_cli

from cdf_mj.falsify.counterexamples import choice_mass
from cdf_mj.falsify.estimate import Proposal
from cdf_mj.falsify.evaluate import Evaluation
from cdf_mj.falsify.run import falsify
from cdf_mj.falsify.search import run_search
from cdf_mj.falsify.space import load_space


class _Formula:
    """An evaluator of ``robustness(point)`` (<= 0 fails): the search alone, on a known function."""

    def __init__(self, space, robustness) -> None:
        self.space, self.robustness, self.asked = space, robustness, []

    def evaluate(self, items, planners, keep=None):
        out = []
        for point, seed in items:
            self.asked.append(np.asarray(point, dtype=float))
            r = float(self.robustness(np.asarray(point, dtype=float)))
            out.append({planners[0]: Evaluation(planners[0], seed, tuple(point), (), r, r <= 0.0, {})})
        return out


@pytest.fixture(scope="module")
def space():
    return load_space("default")


def _speed_tail(t: float) -> float:
    """P(ego.speed > t) under the default space's nominal (normal 13.4, 1.5 truncated to [9, 18])."""
    n = NormalDist()
    a, b = n.cdf((9 - 13.4) / 1.5), n.cdf((18 - 13.4) / 1.5)
    return (b - n.cdf((t - 13.4) / 1.5)) / (b - a)


def test_the_first_generation_is_a_nominal_sample(space):
    """Started at the latent origin with a step of 1, the search's first generation is
    drawn from the space's nominal: over 60 runs, each choice's share and each range's mean
    match the nominal's (a search from the unit cube's centre would draw every driver
    family alike, half of them aggressive or off-route)."""
    firsts = []
    for seed in range(60):
        ev = _Formula(space, lambda p: 1.0)
        run_search(ev, "x", 13, seed=seed, popsize=13)
        firsts.extend(ev.asked)
    points = np.array(firsts)
    sample = Proposal.nominal(space).sample(space, np.random.default_rng(0), 20000)
    for j, d in enumerate(space.dims):
        got, want = points[:, j], sample[:, j]
        if d.discrete:
            for k in range(len(d.values)):
                p = float(np.mean(want == k))
                assert abs(float(np.mean(got == k)) - p) <= 4 * math.sqrt(p * (1 - p) / len(got)) + 1e-3, d.key
        else:
            assert abs(got.mean() - want.mean()) <= 4 * want.std() / math.sqrt(len(got)), d.key


def test_the_search_beats_sampling_ten_times_on_a_rare_smooth_failure(space):
    """Fails when the ego is faster than 17.6 m/s (nominal probability 1.5e-3: plain Monte
    Carlo expects its first failure after about 670 episodes); the robustness falls with
    the speed. The search's median first failure over 5 run seeds is within a tenth of that."""
    j = space.keys.index("ego.speed")
    p = _speed_tail(17.6)
    assert 1e-3 < p < 2e-3
    firsts = []
    for seed in range(5):
        result = run_search(_Formula(space, lambda x: 17.6 - x[j]), "x", 400, seed=seed)
        firsts.append(result.first_failure or math.inf)
    assert median(firsts) <= 0.1 / p, firsts


def test_every_evaluation_carries_its_nominal_log_likelihood(space):
    ev = _Formula(space, lambda x: 1.0)
    result = run_search(ev, "x", 30, seed=3)
    assert len(result.log_likelihood) == len(result.evaluations) == 30
    want = Proposal.nominal(space).logpdf(space, np.array([e.point for e in result.evaluations]))
    assert np.allclose(result.log_likelihood, want)
    assert result.to_dict()["likeliest_failure"] is None  # nothing failed


def test_the_likely_objective_finds_likelier_failures(space):
    """Two ways to fail: an aggressive driver (nominal 0.1) and anything at all once the ego
    is faster than 17 m/s. The robustness reads only the speed, so the plain search goes to
    fast egos; asked for likely failures it keeps failing and moves towards the nominal's
    likelier worlds: its likeliest failure is likelier than the plain search's (median of 5 run seeds)."""
    fam, speed = space.keys.index("obstacle.family"), space.keys.index("ego.speed")

    def robustness(x):
        return -1.0 if round(x[fam]) == 3 else 17.0 - x[speed]

    plain, likely = [], []
    for seed in range(5):
        plain.append(run_search(_Formula(space, robustness), "x", 300, seed=seed).to_dict()["likeliest_failure"])
        likely.append(run_search(_Formula(space, robustness), "x", 300, seed=seed,
                                 objective="likely").to_dict()["likeliest_failure"])
    assert None not in likely and None not in plain
    assert median(likely) > median(plain) + 0.3, (plain, likely)
    with pytest.raises(ValueError, match="objective"):
        run_search(_Formula(space, robustness), "x", 10, objective="fast")


def test_choice_mass_is_the_product_of_the_choices_nominal_weights(space):
    point = Proposal.nominal(space).sample(space, np.random.default_rng(1), 1)[0]
    want = 1.0
    for d, x in zip(space.dims, point, strict=True):
        if d.discrete:
            want *= d.weights[round(x)] / sum(d.weights)
    assert math.isclose(choice_mass(space, point), want, rel_tol=1e-12)


def test_a_run_lists_its_counterexamples_likeliest_first_and_refuses_another_search(tmp_path, capsys):
    """Real episodes: reactive on the small test space; the counterexamples carry their
    likelihoods and come likeliest first, in summary.json, report.md and the command's
    output; a directory made by another search is refused in one line."""
    from test_falsify import FAST_PRESET, SMALL_SPACE  # the suite's small space and its preset

    path = tmp_path / "small.toml"
    path.write_text(SMALL_SPACE)
    (tmp_path / "fast.toml").write_text(FAST_PRESET)
    space = load_space(path)
    result = falsify(space, "reactive", 60, tmp_path / "run", workers=1, figure=False)
    found = result.counterexamples
    assert found, "reactive fails on the small space within 60 episodes"
    keys = [(c.likeliest, c.choice_mass) for c in found]
    assert keys == sorted(keys, reverse=True)
    for c in found:
        assert math.isfinite(c.log_likelihood) and c.likeliest >= c.log_likelihood
        assert 0.0 < c.choice_mass <= 1.0
    report = (tmp_path / "run" / "report.md").read_text()
    assert "log-likelihood (likeliest of the cluster)" in report
    settings = (tmp_path / "run" / "settings.json")
    settings.write_text(settings.read_text().replace('"latent-cma-1"', '"unit-cube-cma"'))
    status, _, err = run_cli(capsys, "falsify", "--space", str(path), "--planner", "reactive", "--episodes", "60",
                             "--workers", "1", "--out", str(tmp_path / "run"), "--quiet", "--no-figure")
    assert status == 2 and err.count("\n") == 1 and "another search" in err


def test_the_first_failure_is_printed_beside_monte_carlos_expectation(tmp_path, capsys):
    """``--estimate`` reads an estimate run's rate: the first failure and the episodes Monte
    Carlo expects at that rate on one line; a file without a rate is one line, exit 2."""
    from test_falsify import FAST_PRESET, SMALL_SPACE

    path = tmp_path / "small.toml"
    path.write_text(SMALL_SPACE)
    (tmp_path / "fast.toml").write_text(FAST_PRESET)
    (tmp_path / "est").mkdir()
    (tmp_path / "est" / "estimate.json").write_text(
        '{"p": 0.05, "space": "small", "planner": "reactive", "failure": "a collision"}')
    argv = ["falsify", "--space", str(path), "--planner", "reactive", "--episodes", "20", "--workers", "1",
            "--quiet", "--no-figure", "--max-clusters", "1"]
    status, out, err = run_cli(capsys, *argv, "--out", str(tmp_path / "run"), "--estimate", str(tmp_path / "est"))
    assert status == 0, err
    assert "(Monte Carlo expects one in 20 at the estimated rate 0.05)" in out.splitlines()[0]
    (tmp_path / "bad.json").write_text('{"p": 1.5, "space": "small", "planner": "reactive", "failure": "a collision"}')
    status, _, err = run_cli(capsys, *argv, "--out", str(tmp_path / "run2"), "--estimate", str(tmp_path / "bad.json"))
    assert status == 2 and err.count("\n") == 1 and "--estimate" in err and "[1e-12, 1]" in err
    (tmp_path / "other.json").write_text(
        '{"p": 0.05, "space": "default", "planner": "reactive", "failure": "a collision"}')
    status, _, err = run_cli(capsys, *argv, "--out", str(tmp_path / "run3"), "--estimate", str(tmp_path / "other.json"))
    assert status == 2 and err.count("\n") == 1 and "same space, planner and failure" in err


def test_the_post_encroachment_margin_reads_only_crossing_traffic():
    """``pet``: the time between the cars' crossings of the conflict area; a car that never
    crosses (a right-turner in its own lane) reads the cap, not a near miss; two cars in the
    area together read their least gap as time; only a collision fails at threshold 0."""
    from cdf_mj.falsify.space import MARGIN_CAP, PET_GAP_SPEED, FailureSpec

    spec = FailureSpec("pet", 0.0)
    assert spec.robustness({"min_gap": 0.5, "collision": False, "safety": {"pet": 1.25}}) == 1.25
    assert spec.robustness({"min_gap": 0.5, "collision": False, "safety": {"pet": None}}) == MARGIN_CAP
    assert spec.robustness({"min_gap": 0.5, "collision": False, "safety": {"pet": 0.0}}) == 0.5 / PET_GAP_SPEED
    assert spec.robustness({"min_gap": 0.0, "collision": True, "safety": {"pet": 0.0}}) <= 0.0
    assert spec.text == "a collision"


def test_a_search_can_stop_at_its_first_failure(space):
    j = space.keys.index("ego.speed")
    result = run_search(_Formula(space, lambda x: 16.0 - x[j]), "x", 1000, seed=0, until_failure=True)
    gens = result.generations
    assert result.first_failure is not None and len(gens) >= 2
    assert gens[-2].episodes < result.first_failure <= gens[-1].episodes  # it stopped in that generation


def test_the_mixture_estimator_weighs_several_failure_modes(space):
    """Three failure modes of known total probability (an aggressive driver with a fast
    ego, an off-route driver measured 3 ticks late, a right-turner with a very fast ego):
    the mixture estimator's estimates are within a factor 1.5 of the truth, reliable, and
    its modes name the three; Monte Carlo's relative s.e. at the same budget is larger."""
    from cdf_mj.falsify.estimate import cross_entropy

    keys = space.keys
    fam, lat, spd, left = (keys.index(k) for k in ("obstacle.family", "sensing.latency", "ego.speed",
                                                   "obstacle.p_left"))

    class _Modes:
        def __init__(self) -> None:
            self.space = space

        def evaluate(self, items, planners, keep=None):
            out = []
            for point, seed in items:
                p = np.asarray(point)
                r = min((p[fam] != 3) + (16.5 - p[spd]) / 3, (p[fam] != 4) + (3 - p[lat]) * 0.3,
                        (p[left] != 0) + (17.0 - p[spd]) / 3)
                out.append({planners[0]: Evaluation(planners[0], seed, tuple(point), (), float(r), r <= 0, {})})
            return out

    sample = Proposal.nominal(space).sample(space, np.random.default_rng(11), 100000)
    truth = float(np.mean([r[ "x"].failed for r in _Modes().evaluate([(p, 0) for p in sample], ["x"])]))
    assert 0.004 < truth < 0.012
    runs = [cross_entropy(_Modes(), "x", 4000, seed=s, components=8) for s in range(3)]
    assert all(abs(math.log(e.p / truth)) < math.log(1.5) and e.reliable and e.method == "mixture" for e in runs), \
        [(e.p / truth, e.ess) for e in runs]
    mc_rel = math.sqrt((1 - truth) / (4000 * truth))
    assert median([e.rel_error for e in runs]) < mc_rel
    families = {m["choices"]["obstacle.family"] for e in runs for m in e.stages[-1]["cells"][:6]}
    assert {"aggressive", "off-route"} <= families


def test_the_mixture_estimator_takes_a_choice_the_nominal_never_draws():
    """near-default gives a latency of 3 ticks weight 0: failures there alone (the
    proposal's floor draws it) weigh nothing, and the estimate is 0, not an error."""
    from cdf_mj.falsify.estimate import cross_entropy

    near = load_space("near-default")
    lat = near.keys.index("sensing.latency")
    est = cross_entropy(_Formula(near, lambda x: 3 - x[lat]), "x", 1000, seed=0, components=8)
    assert est.method == "mixture" and est.p == 0.0
    assert est.failures > 0 and est.upper_only and "none the nominal can draw" in est.text()  # they were found


def test_on_a_narrow_junction_the_pet_guided_search_finds_a_left_turner_collision(tmp_path):
    """The narrow (3.2 m), rotated, mirrored junction on which the TTC-guided search spent
    most of its budget on right-turners passing half a metre away: with the PET the
    default space's search (the route not pinned) collides with a left-turner within 500
    episodes of cdf, run seed 0."""
    from junctions import build_junction

    from cdf_mj.falsify.evaluate import Evaluator, Journal

    scene = tmp_path / "narrow.xml"
    scene.write_text(build_junction(rotation=0.7, lane_width=3.2, center=(25.0, -40.0), mirror=True).to_xml())
    text = load_space("default").text.replace('margin = "ttc"', 'margin = "pet"')
    (tmp_path / "narrow_pet.toml").write_text(text)
    narrow = load_space(tmp_path / "narrow_pet.toml")
    assert narrow.failure.margin == "pet"
    journal = Journal(tmp_path / "j.jsonl")
    evaluator = Evaluator(narrow, ["cdf"], journal, scene=scene, workers=1)
    try:
        result = run_search(evaluator, "cdf", 500, seed=0, until_failure=True)
    finally:
        evaluator.close()
        journal.close()
    assert result.first_failure is not None
    hit = result.evaluations[result.first_failure - 1]
    assert hit.summary["collision"] and hit.summary["intent"] == "left"


def test_a_choice_of_weight_zero_is_never_drawn_from_the_latent_coordinates():
    from cdf_mj.falsify.space import LATENT_CAP, Choice

    last_zero = Choice("sensing.latency", (0, 1, 2, 3), (0.98, 0.01, 0.01, 0.0))
    middle_zero = Choice("sensing.latency", (0, 1, 2), (0.5, 0.0, 0.5))
    for z in np.linspace(-LATENT_CAP - 1, LATENT_CAP + 1, 2001):
        assert last_zero.from_latent(float(z)) != 3.0 and middle_zero.from_latent(float(z)) != 1.0
