"""Falsification (``cdf_mj.falsify``, ``cdf-mj falsify``, ``cdf-mj estimate``): space files
that say one line of what is wrong; robustness and densities that mean what they say; a
journal that survives a kill; a search that is the same run given its seed, whether fresh,
resumed or on workers; counterexamples that fail again from their own preset files and
are one-minimal; two estimators that agree; and run directories that go on where they
stopped and refuse other settings.

Everything runs real MuJoCo episodes of the cheap planners (``reactive``, ``constant``) on
small spaces written here, over a world that ends sooner than the default (the ego stops
30 m past the junction and within 6 s: every collision of these spaces is over by 3 s).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from statistics import NormalDist

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj.config import ScenarioConfig
from cdf_mj.experiments.store import locked
from cdf_mj.falsify.counterexamples import cluster_failures, find_counterexamples, write_counterexamples
from cdf_mj.falsify.estimate import Estimate, Proposal, agree, cross_entropy, monte_carlo
from cdf_mj.falsify.evaluate import JOURNAL_FILE, Evaluator, Journal
from cdf_mj.falsify.run import estimate, falsify
from cdf_mj.falsify.search import run_search
from cdf_mj.falsify.space import (
    MARGIN_CAP,
    Choice,
    FailureSpec,
    Range,
    SpaceError,
    load_space,
    space_names,
    truncnorm_logpdf,
    truncnorm_sample,
)
from cdf_mj.presets import read_preset
from cdf_mj.scenario.episode import run_episode

REPO = Path(__file__).resolve().parent.parent

#: The default world, ended sooner (same collisions, half the cost of an episode).
FAST_PRESET = '''description = "The default world, ended 30 m past the junction or at 6 s."

[scenario.timing]
until_clear = false
end_distance = 30.0
duration = 6.0
'''

#: Four dimensions where reactive collides often: a model driver or an aggressive one,
#: always turning left across the ego, which starts anywhere; the merged car keeps going
#: or stops. Its search finds collisions in its first generation.
SMALL_SPACE = '''description = "Where reactive collides often: who turns left across the ego, and where it starts."
preset = "fast.toml"

[failure]
margin = "ttc"
threshold = 0.0

[dims."obstacle.p_left"]
choices = [1.0]

[dims."ego.start_spread"]
range = [-8.0, 8.0]

[dims."after_merge.behaviour"]
choices = ["keep", "stop"]

[dims."obstacle.family"]
choices = ["model", "aggressive"]
'''

#: One failure mode for the estimators: the model driver turning left fails reactive
#: about half the time once the ego starts 1 m or more ahead, never 1 m behind; the
#: nominal start (a normal about 2 m behind) puts P(collision) near 5 %.
ESTIMATE_SPACE = '''description = "The model driver turning left; the ego starts mostly well behind."
preset = "fast.toml"

[failure]
margin = "gap"
threshold = 0.0

[dims."obstacle.family"]
choices = ["model"]

[dims."obstacle.p_left"]
choices = [1.0]

[dims."ego.start_spread"]
range = [-8.0, 8.0]
mean = -2.0
std = 2.0
'''

#: The small space's search: budget and CMA-ES population (4 + 3 ln 4 = 8 per generation).
BUDGET = 48
POPSIZE = 8
#: The killed command's budget: killed after two generations, half way.
KILL_BUDGET = 32


def _write_spaces(directory: Path) -> dict[str, Path]:
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "fast.toml").write_text(FAST_PRESET)
    out = {}
    for name, text in (("small", SMALL_SPACE), ("estimate", ESTIMATE_SPACE)):
        out[name] = directory / f"{name}.toml"
        out[name].write_text(text)
    return out


@pytest.fixture(scope="module")
def spaces(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return _write_spaces(tmp_path_factory.mktemp("spaces"))


def _evaluator(space_path: Path, journal: Path, planners: tuple[str, ...] = ("reactive",),
               workers: int = 1) -> Evaluator:
    return Evaluator(load_space(space_path), list(planners), Journal(journal), workers=workers)


def _search(space_path: Path, journal: Path, budget: int = BUDGET, *, workers: int = 1, seed: int = 0):
    ev = _evaluator(space_path, journal, workers=workers)
    try:
        result = run_search(ev, "reactive", budget, seed=seed)
    finally:
        ev.close()
        ev.journal.close()
    return result, ev.episodes_run


def _robustness(space, record) -> float:
    return space.failure.robustness(record.to_dict())


# ============================================================================ space files
def test_the_shipped_space_loads_and_every_point_is_a_world():
    """The default space: 22 options, each point of the unit cube a valid world in which
    every option has the point's value (a range on a pair option pins it to (v, v))."""
    space = load_space("default")
    assert len(space.dims) == 22 and len(set(space.keys)) == 22
    assert space.failure == FailureSpec("ttc", 0.0)
    rng = np.random.default_rng(1)
    units = [np.zeros(22), np.ones(22), *rng.random((4, 22))]
    pairs = 0
    for u in units:
        point = space.from_unit(u)
        config = space.config(point)
        assert isinstance(config, ScenarioConfig)
        values = space.values(point)
        for dim, x in zip(space.dims, point, strict=True):
            got = config.get(dim.key)
            if isinstance(dim, Range):
                assert dim.low <= x <= dim.high
                if dim.pair:
                    pairs += 1
                    assert got == (x, x)  # pinned: the world draws nothing for it
                    assert values[dim.key] == x
                else:
                    assert got == pytest.approx(x) and values[dim.key] == got
                assert dim.from_unit(dim.to_unit(x)) == pytest.approx(x)
            else:
                assert float(x).is_integer() and 0 <= x < len(dim.values)
                assert got == dim.values[int(x)] == values[dim.key]
    assert pairs > 0
    # the ends of the cube reach every choice's first and last value
    first, last = space.config(space.from_unit(np.zeros(22))), space.config(space.from_unit(np.ones(22)))
    family = next(d for d in space.dims if d.key == "obstacle.family")
    assert (first.obstacle.family, last.obstacle.family) == (family.values[0], family.values[-1])
    # nothing chosen: the base world
    assert space.config(space.from_unit(rng.random(22)), keep=space.keys) == space.base


@pytest.mark.parametrize("name", space_names())
def test_every_shipped_space_loads_and_its_points_are_worlds(name):
    space = load_space(name)
    assert space.name == name and space.description and space.dims
    rng = np.random.default_rng(2)
    for u in rng.random((8, len(space.dims))):
        point = space.from_unit(u)
        assert isinstance(space.config(point), ScenarioConfig)
        assert set(space.values(point)) == set(space.keys)


def test_a_space_files_preset_path_is_read_beside_the_file(spaces, monkeypatch, tmp_path):
    """``preset = "fast.toml"`` is the file next to the space, wherever the command runs."""
    monkeypatch.chdir(tmp_path)
    space = load_space(spaces["small"])
    assert space.name == "small" and space.preset == "fast.toml"
    assert space.base.timing.duration == 6.0 and space.base.timing.until_clear is False
    assert space.keys == ("obstacle.p_left", "ego.start_spread", "after_merge.behaviour", "obstacle.family")
    assert space.text == SMALL_SPACE  # what a run stores and compares


_HEAD = 'description = "A space with a mistake."\n'
_BAD_SPACES = [
    ("unknown-option", _HEAD + '[dims."obstacle.nosuch"]\nrange = [0.0, 1.0]\n', "unknown field 'obstacle.nosuch'"),
    ("empty-range", _HEAD + '[dims."obstacle.accel"]\nrange = [1, 1]\n', "is empty"),
    ("inverted-range", _HEAD + '[dims."obstacle.accel"]\nrange = [2, 1]\n', "is inverted"),
    ("nan-in-range", _HEAD + '[dims."obstacle.accel"]\nrange = [nan, 2.0]\n', "two finite numbers"),
    ("inf-in-range", _HEAD + '[dims."obstacle.accel"]\nrange = [1.0, inf]\n', "two finite numbers"),
    ("weights-length", _HEAD + '[dims."obstacle.family"]\nchoices = ["model", "aggressive"]\nweights = [1.0]\n',
     "weights must be 2"),
    ("negative-weight",
     _HEAD + '[dims."obstacle.family"]\nchoices = ["model", "aggressive"]\nweights = [1.0, -0.5]\n',
     "weights must be 2 finite numbers >= 0"),
    ("mean-without-std", _HEAD + '[dims."obstacle.accel"]\nrange = [1.0, 3.0]\nmean = 2.0\n', "both mean and std"),
    ("choice-of-wrong-type", _HEAD + '[dims."obstacle.family"]\nchoices = ["model", 3]\n',
     "obstacle.family must be a string, got 3"),
    ("choice-of-a-pair", _HEAD + '[dims."ego.start_spread"]\nchoices = [1.0]\n', "give range = [low, high]"),
    ("choice-out-of-range", _HEAD + '[dims."ego.speed"]\nchoices = [nan]\n', "ego.speed=nan is out of range"),
    ("flat-and-dotted-key", _HEAD + '[dims."beta"]\nrange = [0.0, 0.5]\n[dims."obstacle.beta"]\nrange = [0.0, 0.5]\n',
     'is given twice'),
    ("unknown-top-key", _HEAD + 'budget = 10\n[dims."obstacle.accel"]\nrange = [1.0, 3.0]\n', "unknown key 'budget'"),
    ("not-toml", "this is [ not toml\n", "not valid TOML"),
    ("world-refuses", _HEAD + '[dims."obstacle.beta"]\nrange = [0.5, 2.0]\n', "obstacle.beta=2.0 is out of range"),
    ("world-refuses-a-choice", _HEAD + '[dims."obstacle.family"]\nchoices = ["model", "nosuch"]\n',
     "obstacle.family='nosuch'"),
    ("no-dimension", _HEAD, "at least one dimension"),
    ("no-description", '[dims."obstacle.accel"]\nrange = [1.0, 3.0]\n', "needs description"),
    ("bad-margin", _HEAD + '[failure]\nmargin = "speed"\n[dims."obstacle.accel"]\nrange = [1.0, 3.0]\n',
     "margin must be one of gap, ttc, headway"),
    ("fractional-ticks", _HEAD + '[dims."sensing.latency"]\nrange = [0, 2.5]\n', "whole ends"),
    ("unknown-preset", 'description = "x"\npreset = "nosuch"\n[dims."obstacle.accel"]\nrange = [1.0, 3.0]\n',
     "unknown preset 'nosuch'"),
]


@pytest.mark.parametrize(("text", "needle"), [case[1:] for case in _BAD_SPACES],
                         ids=[case[0] for case in _BAD_SPACES])
@pytest.mark.filterwarnings("ignore::cdf_mj.config.FlatKeyWarning")
def test_a_bad_space_file_is_one_line_naming_the_file_and_the_problem(tmp_path, text, needle):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SpaceError) as info:
        load_space(path)
    message = str(info.value)
    assert "\n" not in message
    assert str(path) in message and needle in message, message


@pytest.mark.parametrize("what", ["missing", "directory"])
def test_a_space_that_is_not_a_file_is_one_line(tmp_path, what):
    path = tmp_path / "space.toml"
    if what == "directory":
        path.mkdir()
    with pytest.raises(SpaceError) as info:
        load_space(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_an_unknown_space_name_lists_the_shipped_ones():
    assert "default" in space_names()
    with pytest.raises(SpaceError, match="unknown space 'nosuch': choose from ") as info:
        load_space("nosuch")
    assert f"choose from {', '.join(space_names())}, or give the path of a .toml file" in str(info.value)


@pytest.mark.parametrize("command", ["falsify", "estimate"])
def test_the_command_line_says_a_bad_space_in_one_line_before_any_work(tmp_path, capsys, command):
    bad = tmp_path / "bad.toml"
    bad.write_text(_HEAD + '[dims."obstacle.nosuch"]\nrange = [0.0, 1.0]\n')
    out = tmp_path / "out"
    result = run_cli(capsys, command, "--space", str(bad), "--planner", "reactive", "--episodes", "10",
                     "--workers", "1", "--out", str(out), "--quiet")
    assert_one_line_error(*result, str(bad), "unknown field 'obstacle.nosuch'")
    assert not out.exists()
    assert_one_line_error(*run_cli(capsys, command, "--space", "nosuch", "--out", str(out), "--quiet"),
                          "unknown space 'nosuch'")


# ============================================================================ robustness
def test_robustness_is_the_margin_less_the_threshold_and_a_collision_fails():
    gap, ttc, headway = FailureSpec("gap", 0.0), FailureSpec("ttc", 0.0), FailureSpec("headway", 0.0)
    passed = {"min_gap": 2.5, "collision": False, "safety": {"min_ttc": 1.5, "min_headway": 0.8}}
    assert gap.robustness(passed) == 2.5  # the least gap, from min_gap
    assert ttc.robustness(passed) == 1.5 and headway.robustness(passed) == 0.8
    assert FailureSpec("gap", 1.0).robustness(passed) == 1.5  # the threshold is subtracted
    assert FailureSpec("ttc", 2.0).robustness(passed) == pytest.approx(-0.5)  # fails: below the threshold
    never = {"min_gap": 9.0, "collision": False, "safety": {"min_ttc": None, "min_headway": None}}
    assert ttc.robustness(never) == MARGIN_CAP and headway.robustness(never) == MARGIN_CAP
    assert FailureSpec("ttc", 3.0).robustness(never) == MARGIN_CAP - 3.0
    assert ttc.robustness({"min_gap": 9.0, "collision": False}) == MARGIN_CAP  # no safety block at all
    assert ttc.robustness({**passed, "safety": {"min_ttc": 1e9}}) == MARGIN_CAP  # finite for the search
    # a collision fails whatever the margin read
    hit = {"min_gap": 0.4, "collision": True, "safety": {"min_ttc": 2.0, "min_headway": None}}
    assert all(spec.robustness(hit) <= 0 for spec in (gap, ttc, headway, FailureSpec("gap", 1.0)))


def test_robustness_of_real_episodes(spaces, scene):
    """A collision is a failure on every margin; an episode without one reads its margin."""
    space = load_space(spaces["small"])
    # the model driver pulling out in front of an ego 3 m ahead: reactive collides about half the time
    config = space.base.with_values({"obstacle.family": "model", "obstacle.p_left": 1.0,
                                     "ego.start_spread": (3.0, 3.0)})
    records = {}
    for seed in range(40):
        rec = run_episode(config, seed, "reactive", scene, label=False).to_dict()
        records.setdefault(rec["collision"], rec)
        if len(records) == 2:
            break
    assert set(records) == {True, False}
    for margin in ("gap", "ttc", "headway"):
        assert FailureSpec(margin).robustness(records[True]) <= 0
    assert FailureSpec("gap").robustness(records[False]) == records[False]["min_gap"] > 0
    assert FailureSpec("ttc").robustness(records[False]) > 0


# ============================================================================ densities
@pytest.mark.parametrize(("mean", "std", "low", "high"), [
    (0.0, 1.0, -1.0, 2.0), (13.4, 1.5, 9.0, 18.0), (0.0, 0.1, 0.0, 0.6), (5.0, 0.8, 0.0, 4.0),
    (2.0, math.inf, 1.0, 3.0)])
def test_truncnorm_logpdf_is_a_density_on_its_range(mean, std, low, high):
    n = 200_000
    x = low + (np.arange(n) + 0.5) * (high - low) / n  # midpoints
    density = np.exp(truncnorm_logpdf(x, mean, std, low, high))
    assert density.sum() * (high - low) / n == pytest.approx(1.0, abs=1e-6)
    if math.isinf(std):
        assert np.all(density == pytest.approx(1 / (high - low)))


@pytest.mark.parametrize(("mean", "std", "low", "high"), [
    (0.0, 1.0, -1.0, 2.0), (13.4, 1.5, 9.0, 18.0), (0.0, 0.1, 0.0, 0.6), (5.0, 0.8, 0.0, 4.0),
    (2.0, math.inf, 1.0, 3.0)])
def test_truncnorm_sample_stays_in_range_with_the_truncated_mean(mean, std, low, high):
    n = 20_000
    x = truncnorm_sample(np.random.default_rng(3), n, mean, std, low, high)
    assert x.shape == (n,) and x.min() >= low and x.max() <= high
    assert np.array_equal(x, truncnorm_sample(np.random.default_rng(3), n, mean, std, low, high))
    if math.isinf(std):
        expected, sd = (low + high) / 2, (high - low) / math.sqrt(12)
    else:
        z, a, b = NormalDist(), (low - mean) / std, (high - mean) / std
        mass = z.cdf(b) - z.cdf(a)
        expected = mean + std * (z.pdf(a) - z.pdf(b)) / mass
        sd = std * math.sqrt(1 + (a * z.pdf(a) - b * z.pdf(b)) / mass - ((z.pdf(a) - z.pdf(b)) / mass) ** 2)
    assert abs(x.mean() - expected) < 5 * sd / math.sqrt(n)
    assert x.std() == pytest.approx(sd, rel=0.05)


def test_the_nominal_proposal_is_the_spaces_declared_mix(tmp_path):
    """Choices: log of their weights (normalised) in the density, and their frequencies in
    draws; ranges: the truncated normal (or the uniform) each declares."""
    path = tmp_path / "mix.toml"
    path.write_text(_HEAD + '[dims."obstacle.family"]\nchoices = ["model", "aggressive", "rolling-stop"]\n'
                    'weights = [6, 3, 1]\n[dims."sensing.latency"]\nrange = [0, 2]\nweights = [0.5, 0.25, 0.25]\n'
                    '[dims."ego.speed"]\nrange = [9.0, 18.0]\nmean = 13.4\nstd = 1.5\n'
                    '[dims."ego.start_spread"]\nrange = [-8.0, 8.0]\n')
    space = load_space(path)
    family, latency, _, _ = space.dims
    assert isinstance(latency, Choice) and latency.values == (0, 1, 2)
    assert family.weights == pytest.approx((0.6, 0.3, 0.1))
    nominal = Proposal.nominal(space)
    n = 4000
    points = nominal.sample(space, np.random.default_rng(5), n)
    assert points.shape == (n, 4)
    expected = (np.log(np.array(family.weights))[points[:, 0].astype(int)]
                + np.log(np.array(latency.weights))[points[:, 1].astype(int)]
                + truncnorm_logpdf(points[:, 2], 13.4, 1.5, 9.0, 18.0) - math.log(16.0))
    assert nominal.logpdf(space, points) == pytest.approx(expected)
    for j, dim in ((0, family), (1, latency)):
        freq = np.bincount(points[:, j].astype(int), minlength=len(dim.values)) / n
        w = np.array(dim.weights)
        assert np.all(np.abs(freq - w) < 5 * np.sqrt(w * (1 - w) / n))
    assert points[:, 3].min() >= -8 and points[:, 3].max() <= 8
    for p in points[:20]:  # every draw is a world
        space.config(p)


# ============================================================================ journal
def _items(space, n: int, seed: int = 0) -> list[tuple[tuple[float, ...], int]]:
    rng = np.random.default_rng(seed)
    return [(tuple(space.from_unit(rng.random(len(space.dims)))), 1000 + i) for i in range(n)]


def test_the_journal_drops_a_half_written_last_line_and_keeps_the_rest(spaces, tmp_path):
    path = tmp_path / JOURNAL_FILE
    ev = _evaluator(spaces["small"], path)
    items = _items(ev.space, 3)
    first = ev.evaluate(items, ["reactive"])
    ev.journal.close()
    assert ev.episodes_run == 3
    whole = path.read_bytes()
    assert whole.count(b"\n") == 3
    with open(path, "ab") as fh:  # a kill in the middle of a write
        fh.write(whole.splitlines(keepends=True)[0][:57])
    again = _evaluator(spaces["small"], path)
    assert path.read_bytes() == whole  # the half line is gone from the file, not only skipped
    assert again.evaluate(items, ["reactive"]) == first and again.episodes_run == 0
    more = _items(again.space, 1, seed=9)
    again.evaluate([(more[0][0], 2000)], ["reactive"])  # appends after the whole lines
    again.journal.close()
    lines = path.read_text().splitlines()
    assert len(lines) == 4 and all(json.loads(line)["planner"] == "reactive" for line in lines)


@pytest.mark.parametrize("damage", ["garbage", "key"])
def test_a_damaged_line_in_the_middle_of_the_journal_is_one_line_naming_it(spaces, tmp_path, damage):
    path = tmp_path / JOURNAL_FILE
    ev = _evaluator(spaces["small"], path)
    ev.evaluate(_items(ev.space, 3), ["reactive"])
    ev.journal.close()
    lines = path.read_text().splitlines(keepends=True)
    if damage == "garbage":
        lines[1] = "this is not JSON\n"
    else:  # a line whose key does not say what it holds (another seed)
        data = json.loads(lines[1])
        data["seed"] += 1
        lines[1] = json.dumps(data) + "\n"
    path.write_text("".join(lines))
    before = path.read_bytes()
    with pytest.raises(ValueError, match="line 2 is not an evaluation") as info:
        Journal(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)
    assert path.read_bytes() == before  # nothing is truncated or rewritten


# ============================================================================ search
@pytest.fixture(scope="module")
def reference_run(spaces, tmp_path_factory):
    """The small space's search of reactive, seed 0, serial, into a fresh journal: the
    result and the journal."""
    journal = tmp_path_factory.mktemp("reference") / JOURNAL_FILE
    result, run = _search(spaces["small"], journal)
    assert run == BUDGET
    return result, journal


@pytest.fixture(scope="module")
def reference(reference_run):
    return reference_run[0]


def test_the_search_is_consistent_and_finds_failures(spaces, reference):
    space = load_space(spaces["small"])
    evs = reference.evaluations
    assert len(evs) == BUDGET and reference.failures  # reactive fails often here
    assert reference.first_failure == 1 + next(i for i, e in enumerate(evs) if e.failed)
    assert all(e.error is None for e in evs)
    assert len({e.seed for e in evs}) == BUDGET  # each candidate its own episode seed
    for e in evs:
        space.config(e.point)  # every candidate is a world of the space
        assert e.summary["collision"] == e.failed  # ttc threshold 0: the failures are the collisions
    gens = reference.generations
    assert [g.episodes for g in gens] == list(range(POPSIZE, BUDGET + 1, POPSIZE))
    assert gens[-1].failures_so_far == len(reference.failures)
    assert gens[-1].best_so_far == min(e.robustness for e in evs)
    summary = reference.to_dict()
    assert summary["episodes"] == BUDGET and summary["failures"] == len(reference.failures)


def test_the_search_is_the_same_run_given_its_seed(spaces, reference, tmp_path):
    """A second fresh run: the same candidates, episode seeds and results; another seed
    searches elsewhere."""
    again, run = _search(spaces["small"], tmp_path / "a.jsonl")
    assert run == BUDGET
    assert again.evaluations == reference.evaluations
    assert again.generations == reference.generations and again.first_failure == reference.first_failure
    other, _ = _search(spaces["small"], tmp_path / "b.jsonl", budget=POPSIZE, seed=1)
    assert [e.point for e in other.evaluations] != [e.point for e in reference.evaluations[:POPSIZE]]
    assert not {e.seed for e in other.evaluations} & {e.seed for e in reference.evaluations}


def test_a_larger_budget_goes_on_from_the_journal(spaces, reference, tmp_path):
    """A search stopped within a generation (28 of 48) and run again with the larger
    budget runs only the new episodes and is the fresh larger run; once more, nothing."""
    journal = tmp_path / JOURNAL_FILE
    short, run = _search(spaces["small"], journal, budget=28)
    assert run == 28 and short.evaluations == reference.evaluations[:28]
    longer, run = _search(spaces["small"], journal)
    assert run == BUDGET - 28
    assert longer.evaluations == reference.evaluations and longer.generations == reference.generations
    same, run = _search(spaces["small"], journal)
    assert run == 0 and same.evaluations == reference.evaluations
    assert len(journal.read_text().splitlines()) == BUDGET


def test_a_process_pool_runs_the_serial_search(spaces, reference, tmp_path):
    pooled, run = _search(spaces["small"], tmp_path / JOURNAL_FILE, workers=2)
    assert run == BUDGET
    assert pooled.evaluations == reference.evaluations and pooled.generations == reference.generations


# ============================================================================ counterexamples
@pytest.fixture(scope="module")
def found(spaces, reference_run, tmp_path_factory):
    """The reference search's failures, clustered, minimised, replayed on constant and
    written as presets (the search replayed from a copy of its journal)."""
    out = tmp_path_factory.mktemp("counterexamples")
    shutil.copyfile(reference_run[1], out / JOURNAL_FILE)
    ev = _evaluator(spaces["small"], out / JOURNAL_FILE, planners=("reactive", "constant"))
    search = run_search(ev, "reactive", BUDGET, seed=0)
    assert ev.episodes_run == 0 and search.evaluations == reference_run[0].evaluations
    cxs = find_counterexamples(ev, "reactive", search.failures, ["constant"])
    write_counterexamples(ev.space, cxs, out / "files")
    ev.journal.close()
    return ev.space, search, cxs


def test_failures_cluster_by_their_choices(found):
    space, search, _ = found
    clusters = cluster_failures(space, search.failures)
    assert sorted(e.seed for c in clusters for e in c) == sorted(e.seed for e in search.failures)
    assert [len(c) for c in clusters] == sorted((len(c) for c in clusters), reverse=True)
    choices = [j for j, d in enumerate(space.dims) if d.discrete]
    for cluster in clusters:
        assert len({tuple(space.dims[j].value(e.point[j]) for j in choices) for e in cluster}) == 1
        assert cluster[0].robustness == min(e.robustness for e in cluster)
    assert len({tuple(space.dims[j].value(c[0].point[j]) for j in choices) for c in clusters}) == len(clusters)


def test_counterexamples_fail_again_from_their_preset_files(found):
    """Each file is a preset whose world is the minimised point's; its episode with the
    counterexample's seed is the same collision."""
    space, search, cxs = found
    assert cxs and sum(len(c.members) for c in cxs) == len(search.failures)
    paths = [Path(c.path) for c in cxs]
    assert [p.name for p in paths] == [f"{i:02d}-seed-{c.seed}.toml" for i, c in enumerate(cxs, 1)]
    for c, path in zip(cxs, paths, strict=True):
        assert set(c.changed) == set(space.keys) - set(c.keep) and set(c.keep) <= set(space.keys)
        assert all(m.failed for m in c.members) and c.robustness <= 0
        preset = read_preset(path)
        assert preset.config() == space.config(c.point, c.keep)
        assert f"--seed {c.seed} --planner reactive" in " ".join(preset.description.split())
        record = run_episode(preset.config(), c.seed, "reactive")
        assert record.collision and record.min_gap == c.summary["min_gap"]


def test_a_minimised_counterexample_is_one_minimal(found, scene):
    """Putting back any one more of its changed options to the base world's value: the
    same seed no longer fails."""
    space, _, cxs = found
    checked = [c for c in cxs if c.changed]
    assert checked
    for c in checked:
        for key in c.changed:
            record = run_episode(space.config(c.point, [*c.keep, key]), c.seed, "reactive", scene, label=False)
            assert _robustness(space, record) > 0, (c.changed, key)


def test_counterexamples_are_replayed_on_the_other_planners(found, scene):
    space, _, cxs = found
    for c in cxs:
        record = run_episode(space.config(c.point, c.keep), c.seed, "constant", scene, label=False)
        assert c.others["constant"] == (_robustness(space, record) <= 0)
        failed, replayed = c.others_members["constant"]
        assert replayed == min(len(c.members), 20)  # members replayed, at most 20
        # as many of them as fail when replayed here
        assert failed == sum(_robustness(space, run_episode(space.config(m.point), m.seed, "constant", scene,
                                                            label=False)) <= 0 for m in c.members[:20])


def test_the_episode_command_replays_a_counterexample_file(found, capsys):
    _, _, cxs = found
    c = cxs[0]
    status, out, err = run_cli(capsys, "episode", "--preset", c.path, "--seed", str(c.seed), "--planner", "reactive")
    assert status == 0, err
    record = json.loads(out)
    assert record["collision"] is True and record["seed"] == c.seed


# ============================================================================ estimators
def test_monte_carlo_and_cross_entropy_agree_and_replay_from_the_journal(spaces, tmp_path):
    """On one failure mode near 5 %: the two 95 % intervals overlap; importance sampling
    draws more failures than the nominal, with weights at most 1 / defensive and an
    effective sample size of at most its failures; the same seed on the same journal is
    the same estimate without an episode."""
    journal = tmp_path / JOURNAL_FILE
    ev = _evaluator(spaces["estimate"], journal)
    mc = monte_carlo(ev, "reactive", 200, seed=0)
    ce = cross_entropy(ev, "reactive", 160, seed=0, stage=40)
    ev.journal.close()
    assert ev.episodes_run == 360
    assert mc.n == mc.episodes == 200 and 0 < mc.failures < 50
    assert ce.episodes == 160 and sum(s["episodes"] for s in ce.stages) == 160 and ce.stages[-1]["final"]
    assert ce.failures > 0 and not ce.upper_only
    assert agree(mc, ce), (mc.text(), ce.text())
    assert ce.failures / ce.n > mc.failures / mc.n  # the proposal moved towards the failures
    assert ce.ess > 0
    assert ce.p <= ce.failures / ce.n / 0.1 + 1e-12  # each weight is at most 1 / defensive (0.1)
    again = _evaluator(spaces["estimate"], journal)
    assert monte_carlo(again, "reactive", 200, seed=0).to_dict() == mc.to_dict()
    assert cross_entropy(again, "reactive", 160, seed=0, stage=40).to_dict() == ce.to_dict()
    assert again.episodes_run == 0
    again.journal.close()


# ============================================================================ run directories
def _files(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def test_falsify_writes_its_directory_and_a_second_call_runs_nothing(spaces, tmp_path):
    space = load_space(spaces["small"])
    out = tmp_path / "run"
    result = falsify(space, "reactive", 24, out, workers=1)
    settings = json.loads((out / "settings.json").read_text())
    assert settings["kind"] == "falsify" and settings["planner"] == "reactive" and settings["seed"] == 0
    assert settings["space_text"] == SMALL_SPACE
    summary = json.loads((out / "summary.json").read_text())
    assert summary == json.loads(json.dumps(result.to_dict()))
    assert summary["search"]["episodes"] == 24 and summary["search"]["failures"] == len(result.search.failures) > 0
    journal = (out / JOURNAL_FILE).read_text().splitlines()
    assert len(journal) == result.episodes_run >= 24  # the search, then the minimisation
    assert len({json.loads(line)["key"] for line in journal}) == len(journal)
    written = sorted(p.name for p in (out / "counterexamples").iterdir())
    assert written == sorted(Path(c.path).name for c in result.counterexamples) and written
    report = (out / "report.md").read_text()
    assert "# Falsification of `reactive` on space `small`" in report and "![progress](progress.png)" in report
    assert all(f"`{name}`" in report for name in written)
    assert (out / "progress.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    before = _files(out)
    again = falsify(space, "reactive", 24, out, workers=1)
    assert again.episodes_run == 0 and again.to_dict() == result.to_dict()
    assert _files(out)[JOURNAL_FILE] == before[JOURNAL_FILE]
    assert (out / "summary.json").read_bytes() == before["summary.json"]


def test_a_directory_refuses_other_settings_and_a_second_run(spaces, tmp_path, capsys):
    space = load_space(spaces["small"])
    out = tmp_path / "run"
    falsify(space, "reactive", 8, out, workers=1, figure=False)
    before = _files(out)
    for kwargs, needle in (({"planner": "constant"}, "another planner"), ({"seed": 1}, "another seed")):
        args = {"planner": "reactive", "seed": 0, **kwargs}
        with pytest.raises(ValueError, match=needle) as info:
            falsify(space, args["planner"], 8, out, seed=args["seed"], workers=1, figure=False)
        assert "\n" not in str(info.value)
    edited = tmp_path / "small.toml"
    edited.write_text(SMALL_SPACE.replace('["keep", "stop"]', '["keep", "brake"]'))
    (tmp_path / "fast.toml").write_text(FAST_PRESET)
    with pytest.raises(ValueError, match="another space") as info:
        falsify(load_space(edited), "reactive", 8, out, workers=1, figure=False)
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="another kind of run"):
        estimate(space, "reactive", 8, out, workers=1)
    with locked(out), pytest.raises(ValueError, match="in use by another run"):
        falsify(space, "reactive", 8, out, workers=1, figure=False)
    assert_one_line_error(*run_cli(capsys, "falsify", "--space", str(spaces["small"]), "--planner", "constant",
                                   "--episodes", "8", "--workers", "1", "--out", str(out), "--quiet", "--no-figure"),
                          str(out), "another planner")
    assert _files(out) == before  # nothing refused wrote anything
    reworded = tmp_path / "reworded.toml"  # another name, description and comments: the same space, the same run
    reworded.write_text(SMALL_SPACE.replace("Where reactive collides often", "Reworded") + "# a comment\n")
    assert falsify(load_space(reworded), "reactive", 8, out, workers=1, figure=False).episodes_run == 0


def test_a_damaged_journal_is_one_line_on_the_command_line(spaces, tmp_path, capsys):
    out = tmp_path / "run"
    argv = ("falsify", "--space", str(spaces["small"]), "--planner", "reactive", "--episodes", "8", "--workers", "1",
            "--out", str(out), "--quiet", "--no-figure")
    status, _, err = run_cli(capsys, *argv)
    assert status == 0, err
    lines = (out / JOURNAL_FILE).read_text().splitlines(keepends=True)
    (out / JOURNAL_FILE).write_text(lines[0] + "{broken\n" + "".join(lines[1:]))
    assert_one_line_error(*run_cli(capsys, *argv), JOURNAL_FILE, "line 2")


def test_the_estimate_command_prints_its_estimate_and_writes_it(spaces, tmp_path, capsys):
    out = tmp_path / "est"
    argv = ("estimate", "--space", str(spaces["estimate"]), "--planner", "reactive", "--method", "mc",
            "--episodes", "60", "--seed", "2", "--workers", "1", "--out", str(out), "--quiet")
    status, text, err = run_cli(capsys, *argv)
    assert status == 0 and err == "", err
    saved = json.loads((out / "estimate.json").read_text())
    assert saved["method"] == "mc" and saved["n"] == saved["episodes"] == 60 and saved["planner"] == "reactive"
    assert saved["space"] == "estimate" and saved["failure"] == "a collision"
    lo, hi = saved["ci95"]
    assert lo <= saved["p"] <= hi and saved["p"] == saved["failures"] / 60
    lines = text.splitlines()
    assert lines[0].startswith("P(a collision) per encounter of reactive on space estimate: ")
    shown = f"< {hi:.2g}" if saved["upper_only"] else f"{saved['p']:.3g} [{lo:.2g}, {hi:.2g}]"
    assert shown in lines[0] and "Monte Carlo, 60 episodes" in lines[0]
    if saved["p"] > 0:  # the first failure Monte Carlo expects at the rate, for the search to be set against
        expected = 60 / saved["failures"]
        assert lines.pop(1) == f"at this rate plain Monte Carlo expects its first failure after {expected:.0f} episodes"
    assert lines[1] == f"wrote {out}/estimate.json"
    journal = (out / JOURNAL_FILE).read_bytes()
    assert journal.count(b"\n") == 60
    assert run_cli(capsys, *argv) == (0, text, "")  # resumed: the same, from the journal
    assert (out / JOURNAL_FILE).read_bytes() == journal


# ============================================================================ a killed run
def test_a_killed_falsify_goes_on_to_the_uninterrupted_result(spaces, tmp_path):
    """SIGKILL to the command and its workers mid-search, then the same command: exit 0,
    no episode twice in the journal, and the result of a run never interrupted."""
    out = tmp_path / "killed"
    command = [sys.executable, "-m", "cdf_mj", "falsify", "--planner", "reactive", "--space", str(spaces["small"]),
               "--episodes", str(KILL_BUDGET), "--workers", "2", "--out", str(out), "--quiet", "--no-figure"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    journal = out / JOURNAL_FILE
    with open(tmp_path / "stderr", "wb") as err:
        proc = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=err,
                                start_new_session=True)
        try:
            deadline = time.monotonic() + 120
            while not (journal.exists() and journal.read_bytes().count(b"\n") >= 2 * POPSIZE):
                assert proc.poll() is None, (tmp_path / "stderr").read_text()[-2000:]
                assert time.monotonic() < deadline, "no episode journalled in 120 s"
                time.sleep(0.02)
            os.killpg(proc.pid, signal.SIGKILL)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "summary.json").exists()
    killed = journal.read_bytes().count(b"\n")
    resumed = subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert f"failures of reactive (a collision) in {KILL_BUDGET} episodes" in resumed.stdout.splitlines()[0]
    lines = journal.read_text().splitlines()
    keys = [json.loads(line)["key"] for line in lines]
    assert len(keys) == len(set(keys)) and killed < len(keys)
    reference = tmp_path / "whole"
    falsify(load_space(spaces["small"]), "reactive", KILL_BUDGET, reference, workers=1, figure=False)
    whole = [json.loads(line)["key"] for line in (reference / JOURNAL_FILE).read_text().splitlines()]
    assert keys and set(keys) == set(whole)

    def summary(directory: Path) -> dict:
        data = json.loads((directory / "summary.json").read_text())
        for c in data["counterexamples"]:
            c["path"] = Path(c["path"]).name
        return data

    got, want = summary(out), summary(reference)
    assert got["search"]["failures"] == want["search"]["failures"] > 0
    assert got["search"]["first_failure"] == want["search"]["first_failure"]
    assert got == want
    files = {name: text.replace(bytes(str(out), "utf-8"), bytes(str(reference), "utf-8"))
             for name, text in _files(out / "counterexamples").items()}
    assert files == _files(reference / "counterexamples")


# ============================================================================ found by review
class _KnownFailures:
    """An evaluator of a known function of the point (no episodes): the estimator alone,
    against a probability computed exactly. Fails iff the driver is aggressive (nominal
    0.1), the measurement 3 ticks late (0.03) and the ego faster than 16.5 m/s."""

    def __init__(self, space) -> None:
        self.space = space
        keys = space.keys
        self.fam, self.lat, self.speed = (keys.index(k) for k in ("obstacle.family", "sensing.latency", "ego.speed"))

    class _Result:
        def __init__(self, robustness: float) -> None:
            self.robustness, self.error = robustness, None

    def evaluate(self, items, planners, keep=None):
        out = []
        for point, _ in items:
            p = np.asarray(point)
            r = (p[self.fam] != 3) * 1.0 + (3 - p[self.lat]) * 0.3 + (16.5 - p[self.speed]) / 3
            out.append({planners[0]: self._Result(float(r))})
        return out


def test_cross_entropy_finds_a_known_rare_probability_in_many_dimensions():
    """Three of the default space's 22 dimensions make the failure (7.4e-5); the others
    must not spread the weights: each estimate within a factor 1.5 of the truth, and the
    intervals cover it in most runs (the refit leaves dimensions that do not matter at the
    nominal, and fits the rest by the truncated family's moments)."""
    space = load_space("default")
    n = NormalDist()

    def tail(t: float) -> float:  # P(speed > t) under the truncated normal (13.4, 1.5) on [9, 18]
        a, b = n.cdf((9 - 13.4) / 1.5), n.cdf((18 - 13.4) / 1.5)
        return (b - n.cdf((t - 13.4) / 1.5)) / (b - a)

    truth = 0.1 * (0.03 * tail(16.5) + 0.07 * tail(17.4))  # latency 3 at 16.5 m/s; below it, speed makes up
    assert 5e-5 < truth < 1e-4
    runs = [cross_entropy(_KnownFailures(space), "x", 2000, seed=s) for s in range(4)]
    assert all(abs(math.log(e.p / truth)) < math.log(1.5) for e in runs), [e.p / truth for e in runs]
    assert sum(e.ci[0] <= truth <= e.ci[1] for e in runs) >= 3
    assert sum(e.reliable for e in runs) >= 3  # one of these four rests on a few heavy weights, and says so


def test_a_mean_outside_its_range_is_refused(tmp_path):
    path = tmp_path / "far.toml"
    path.write_text('description = "x"\n[dims."ego.speed"]\nrange = [9.0, 19.0]\nmean = 100.0\nstd = 1.0\n')
    with pytest.raises(SpaceError, match=r"within the range \[9, 19\]") as info:
        load_space(path)
    assert "\n" not in str(info.value)


def test_a_counterexample_file_survives_backslashes_and_quotes_in_its_description(tmp_path):
    from cdf_mj.falsify.counterexamples import preset_text

    config = ScenarioConfig().with_values({"obstacle.family": "aggressive", "sensing.latency": 2})
    text = 'Replay: C:\\runs\\01-seed-7.toml with "quotes", a """ and a tab\there.'
    path = tmp_path / "cx.toml"
    path.write_text(preset_text(config, text))
    preset = read_preset(path)
    assert preset.config() == config
    assert preset.description == " ".join(text.split())


def test_writing_counterexamples_replaces_an_earlier_runs_files(found, tmp_path):
    space, _, cxs = found
    stale = tmp_path / "99-seed-1.toml"
    stale.write_text("left by another run")
    mine = tmp_path / "notes.toml"
    mine.write_text("not a counterexample")
    write_counterexamples(space, cxs[:1], tmp_path)
    assert not stale.exists() and mine.exists()
    assert sorted(p.name for p in tmp_path.glob("*-seed-*.toml")) == [f"01-seed-{cxs[0].seed}.toml"]


class _RaisingPlanner:
    """A planner whose every tick raises (a bug in a planner under comparison)."""

    name = "raising"
    graded = False

    def reset(self, *args, **kwargs) -> None:
        raise RuntimeError("a planner bug")


def test_an_episode_that_raises_in_a_replay_is_counted_not_read_as_a_pass(spaces, reference_run, tmp_path,
                                                                            monkeypatch, capsys):
    """A compared planner that raises is 'raised', not 'passes', and the command exits 1."""
    from cdf_mj.planners.registry import PLANNERS, register

    monkeypatch.setitem(PLANNERS, "raising", PLANNERS["reactive"])
    register("raising", _RaisingPlanner)
    out = tmp_path / "run"
    out.mkdir()
    shutil.copyfile(reference_run[1], out / JOURNAL_FILE)
    result = falsify(load_space(spaces["small"]), "reactive", BUDGET, out, compare=["raising"], workers=1,
                     figure=False)
    assert result.counterexamples and result.errors
    assert all(c.others["raising"] is None for c in result.counterexamples)
    assert "raised" in (out / "report.md").read_text() and "passes" not in (out / "report.md").read_text()
    status, _, err = run_cli(capsys, "falsify", "--space", str(spaces["small"]), "--planner", "reactive",
                             "--episodes", str(BUDGET), "--compare", "raising", "--workers", "1", "--quiet",
                             "--no-figure", "--out", str(out))
    assert status == 1 and "raised" in err


def test_the_shipped_counterexamples_of_the_page_still_fail(scene):
    """docs/falsify/cdf (written by scripts/falsify.py with docs/FALSIFY.md): each file is
    a preset whose seed, in its name, makes ``cdf`` collide. A change that moves them is
    a change that must remake the page."""
    files = sorted((Path(__file__).resolve().parents[1] / "docs" / "falsify" / "cdf").glob("*-seed-*.toml"))
    assert files
    for path in files:
        seed = int(path.stem.rsplit("-", 1)[1])
        record = run_episode(read_preset(path).config(), seed, "cdf", scene, label=False)
        assert record.collision, f"{path.name} no longer collides: remake docs/FALSIFY.md (python scripts/falsify.py)"


def test_a_counterexample_of_a_scene_of_your_own_says_how_to_replay_it(found, tmp_path):
    """A preset cannot hold a scene or its names: the replay commands in its description do."""
    space, _, cxs = found
    write_counterexamples(space, cxs[:1], tmp_path, "--scene my/junction.xml --names my/names.toml")
    description = " ".join(read_preset(next(tmp_path.glob("01-seed-*.toml"))).description.split())
    assert "--planner reactive --scene my/junction.xml --names my/names.toml; watch: cdf-mj render" in description


def test_ctrl_c_is_one_line_and_a_missing_scene_is_refused_before_anything_is_written(spaces, tmp_path, capsys):
    """Ctrl-C (SIGINT to the command and its workers, as a terminal sends it) is one line,
    exit 130, and the journal so far kept; a scene that cannot be loaded is one error line
    before the run directory is made (once, not per worker), so the right command then
    starts there."""
    out = tmp_path / "interrupted"
    command = [sys.executable, "-m", "cdf_mj", "estimate", "--method", "mc", "--planner", "reactive", "--space",
               str(spaces["small"]), "--episodes", "100000", "--workers", "2", "--out", str(out), "--quiet"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    journal = out / JOURNAL_FILE
    proc = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        while not (journal.exists() and journal.read_bytes().count(b"\n") >= 4):
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130
    assert err.strip().splitlines() == [f"cdf-mj: interrupted; what finished is saved in {out}: run the same "
                                        "command again to continue"]
    assert journal.read_bytes().count(b"\n") >= 4

    missing = tmp_path / "missing"
    status, stdout, stderr = run_cli(capsys, "falsify", "--planner", "reactive", "--space", str(spaces["small"]),
                                     "--episodes", "3", "--workers", "2", "--scene", str(tmp_path / "nope.xml"),
                                     "--out", str(missing), "--quiet", "--no-figure")
    assert_one_line_error(status, stdout, stderr, "nope.xml")
    assert not missing.exists()


def test_an_estimate_that_is_not_reliable_says_why_on_its_line():
    """What `cdf-mj estimate` prints and the page shows: a reliable estimate bare, else the
    reason (too few failures to weigh, or one carrying more than a quarter of it)."""
    def ce(ess: float, top: float) -> Estimate:
        return Estimate("ce", "cdf", 2000, 400, 12, 0.01, (0.005, 0.015), ess=ess, top_share=top)

    assert ce(12.0, 0.2).text() == "0.01 [0.005, 0.015]"
    assert ce(9.5, 0.2).text() == "0.01 [0.005, 0.015] (not reliable: effective sample size 9.5 < 10)"
    assert ce(12.0, 0.4).text() == "0.01 [0.005, 0.015] (not reliable: one failure carries 40% of it)"
    assert Estimate("mc", "cdf", 400, 400, 4, 0.01, (0.004, 0.025)).text() == "0.01 [0.004, 0.025]"


@pytest.mark.parametrize(("extra", "needle"), [
    (["--method", "mc", "--stage", "20"], "--stage is for --method ce"),
    (["--method", "ce", "--episodes", "100", "--stage", "90"], "leaves no adaptive stage"),
])
def test_an_estimate_refuses_a_stage_it_would_not_use(spaces, tmp_path, capsys, extra, needle):
    out = tmp_path / "e"
    argv = ["estimate", "--planner", "reactive", "--space", str(spaces["small"]), "--episodes", "100", "--out",
            str(out), "--quiet", *extra]
    assert_one_line_error(*run_cli(capsys, *argv), needle)
    assert not out.exists()
