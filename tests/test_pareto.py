"""Planners set against one another (issue 35): the four criteria and the Pareto verdict of a
pair (cdf_mj.analysis.pareto), checked on records whose answer is known and against the
paired counts and metrics of real episodes; the tuning points; the page helpers; and the
Pareto figure (cdf_mj.viz.pareto)."""

from __future__ import annotations

import math

import pytest
from test_records import episode

from cdf_mj.analysis.metrics import Rate, paired_counts, planner_metrics
from cdf_mj.analysis.pareto import (
    CDF_LINE,
    CRITERIA,
    SIGNIFICANCE,
    ParetoPoint,
    compare,
    comparisons,
    cost_targets,
    intervention_lines,
    layered_label,
    pareto_lines,
    pareto_points,
    planner_item,
    planner_line,
    rule_label,
    tuning_points,
)
from cdf_mj.config import CDFConfig, LayeredConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.planners.registry import PLANNERS


def rec(seed: int, planner: str, label: str, *, hit: bool = False, hard: bool = False, slowed: bool = False,
        passed: float = 8.0) -> dict:
    """A stored record with its ``intervention``: collided, braked hard, intervened, and when
    it passed the fixed point [s]."""
    out = episode(seed, planner, label, brake=1.0 if hard else None, collision="obstacle" if hit else None)
    out["intervention"] = {"tolerance": 0.49, "first": 0.5 if slowed or hard else None,
                           "ticks": 5 if slowed or hard else 0, "time": 0.5 if slowed or hard else 0.0,
                           "peak_decel": 2.5 if slowed or hard else 0.0, "pass_time": passed, "passed": True}
    return out


def world(a: dict[int, dict], b: dict[int, dict], labels: dict[int, str]) -> list[dict]:
    """Records of planners ``a`` and ``b`` (seed -> keyword arguments of :func:`rec`) and of
    ``constant`` (passing at 8.0 s, never intervening) on the seeds of ``labels``."""
    return [*(rec(s, "constant", lab) for s, lab in labels.items()),
            *(rec(s, "a", lab, **a.get(s, {})) for s, lab in labels.items()),
            *(rec(s, "b", lab, **b.get(s, {})) for s, lab in labels.items())]


LABELS = {0: "Cutoff", 1: "Yield", 2: "Right", 3: "Yield", 4: "Right"}


def test_a_planner_that_is_no_worse_anywhere_and_better_once_dominates() -> None:
    # a slows on seeds 1-9 (0.5 s lost each), b on seed 1 only: eight discordant seeds, McNemar
    # and sign test p = 2 / 2**8, so b dominates a.
    labels = {0: "Cutoff"} | dict.fromkeys(range(1, 12), "Yield")
    records = world({s: {"slowed": True, "passed": 8.5} for s in range(1, 10)},
                    {1: {"slowed": True, "passed": 8.5}}, labels)
    v = compare(records, "a", "b")
    assert [c.name for c in v.criteria] == list(CRITERIA) and v.seeds == 12
    collisions, interventions, hard, lost = v.criteria
    assert (collisions.first, collisions.second, collisions.better) == (0, 0, "tie")
    assert (interventions.first, interventions.second, interventions.only_first, interventions.only_second) == (
        9, 1, 8, 0)
    assert hard.better == "tie" and lost.seeds == 11  # the non-Cutoff seeds
    assert lost.first == pytest.approx(4.5 / 11) and lost.second == pytest.approx(0.5 / 11)
    assert (lost.only_first, lost.only_second) == (8, 0)
    assert interventions.better == lost.better == "second"
    assert v.dominant == "b" and v.text().startswith("**b dominates a**")
    assert "non-Cutoff interventions (9 vs 1, McNemar p = 0.00781, significant at 0.05)" in v.text()
    assert "sign test p = 0.00781, significant at 0.05" in v.text()
    assert compare(records, "b", "a").dominant == "b"  # the same verdict either way round


def test_better_on_one_criterion_and_worse_on_another_is_no_dominance() -> None:
    # a never intervenes but collides on the Cutoff seeds 0-7; b slows on them and avoids them,
    # and slows on the Yield seeds 8-15 too (0.3 s lost each).
    labels = dict.fromkeys(range(8), "Cutoff") | dict.fromkeys(range(8, 16), "Yield")
    records = world({s: {"hit": True} for s in range(8)},
                    {s: {"slowed": True, "passed": 8.3 if s >= 8 else 8.0} for s in range(16)}, labels)
    v = compare(records, "a", "b")
    collisions, interventions, _, lost = v.criteria
    assert collisions.better == "second" and interventions.better == lost.better == "first"
    assert lost.seeds == 8 and lost.second == pytest.approx(0.3)  # the non-Cutoff seeds, none collided
    assert v.dominant is None
    text = v.text()
    assert text.startswith("no dominance: a better on non-Cutoff interventions") and "b better on collisions" in text
    # Means within 0.01 s tie even when every seed differs (sign test p = 2 / 2**8).
    tie = world({s: {"passed": 8.005} for s in range(8)}, {}, dict.fromkeys(range(8), "Yield"))
    lost = compare(tie, "a", "b").criteria[3]
    assert (lost.only_first, lost.only_second) == (8, 0) and lost.p < SIGNIFICANCE
    assert lost.better == "tie" and compare(tie, "a", "b").text().startswith("tied")


def test_a_difference_its_test_does_not_find_significant_is_a_tie() -> None:
    # Two discordant seeds (McNemar p = 2 / 2**2): chance, not a gain.
    records = world({1: {"slowed": True, "passed": 8.5}, 2: {"slowed": True, "passed": 8.5}}, {}, LABELS)
    v = compare(records, "a", "b")
    _, interventions, _, lost = v.criteria
    assert (interventions.first, interventions.second, interventions.p) == (2, 0, pytest.approx(0.5))
    assert interventions.better == lost.better == "tie" and v.dominant is None
    assert interventions.test_text() == "McNemar p = 0.5, not significant at 0.05"
    assert lost.test_text() == "sign test p = 0.5, not significant at 0.05"
    assert v.text() == "tied on all four: no dominance."
    row = next(line for line in pareto_lines(records, "a", ["b"]) if line.startswith("| a / b |"))
    assert "2 / 0 (2 / 0; p = 0.5)" in row and row.endswith("| none |")
    # The level: five discordant seeds (p = 2 / 2**5 = 0.0625) tie, six (p = 2 / 2**6) do not.
    labels = dict.fromkeys(range(6), "Yield")
    for seeds, better in ((5, "tie"), (6, "first")):
        hard = compare(world({}, {s: {"hard": True} for s in range(seeds)}, labels), "a", "b").criteria[2]
        assert hard.p == pytest.approx(2 / 2**seeds) and hard.better == better, (seeds, hard)


def test_many_discordant_seeds_are_significant_and_the_verdict_says_so() -> None:
    labels = dict.fromkeys(range(12), "Yield")
    records = world({s: {"hard": True} for s in range(8)}, {}, labels)
    hard = compare(records, "a", "b").criteria[2]
    assert (hard.only_first, hard.only_second) == (8, 0)
    assert hard.p == pytest.approx(2 / 2**8) and "significant at 0.05" in hard.test_text()
    assert "not significant" not in hard.test_text()


def test_without_the_reference_the_time_lost_is_not_judged() -> None:
    records = [r for r in world({1: {"slowed": True}}, {}, LABELS) if r["planner"] != "constant"]
    v = compare(records, "a", "b")
    assert v.criteria[3].better is None and v.dominant is None and v.text().startswith("not judged")
    lines = pareto_lines(records, "a", ["b", "nobody"])
    assert any(line.startswith("| a / b | 5 |") and line.endswith("| not judged |") for line in lines)
    assert pareto_lines(records, "nobody", ["a"]) == ["No pair to compare (`nobody` and another planner are needed)."]


def test_records_without_interventions_are_not_judged_on_them() -> None:
    """Records written before ``intervention`` was kept: the interventions are not measured
    (not a 0/0 tie), and the verdict says what is missing."""
    records = [{k: v for k, v in r.items() if k != "intervention"} for r in world({1: {"slowed": True}}, {}, LABELS)]
    v = compare(records, "a", "b")
    assert v.criteria[1].better is None and v.dominant is None
    assert v.text().startswith("not judged: non-Cutoff interventions") and "records with `intervention`" in v.text()


def test_compare_agrees_with_paired_counts_and_metrics_on_real_episodes(tmp_path) -> None:
    planners = ("cdf", "caution-moving", "reactive", "constant")
    records = list(run_experiment(tmp_path / "run", range(8), planners, workers=1, progress=False))
    metrics = planner_metrics(records)
    for other in ("caution-moving", "reactive"):
        v, c = compare(records, "cdf", other), paired_counts(records, "cdf", other)
        collisions, interventions, hard, lost = v.criteria
        assert (collisions.only_first, collisions.only_second) == (c.hit_only_first, c.hit_only_second)
        assert (interventions.only_first, interventions.only_second) == (c.intervene_only_first,
                                                                         c.intervene_only_second)
        assert (hard.only_first, hard.only_second) == (c.false_alarm_only_first, c.false_alarm_only_second)
        assert (collisions.first, collisions.second) == (metrics["cdf"].collisions, metrics[other].collisions)
        assert interventions.first == metrics["cdf"].false_interventions.k
        if not collisions.first and not collisions.second:  # then both means are over the same seeds
            assert lost.first == pytest.approx(metrics["cdf"].time_lost_fixed)
            assert lost.second == pytest.approx(metrics[other].time_lost_fixed)
    points = pareto_points(metrics)
    assert [p.name for p in points] == ["cdf", "caution-moving", "reactive"]  # the reference is the origin
    m = metrics["reactive"]
    assert points[2].hard_brakes == Rate(m.false_alarms.k, m.episodes - m.imminent)
    assert points[2].collisions == m.collisions
    table = intervention_lines(metrics)
    assert table[0].count("|") == 10 and "interventions, Yield (95 % CI)" in table[0]
    assert sum(line.startswith("| ") for line in table) == 1 + len(planners)
    assert any(line.startswith("Hard subset: ") for line in table)


def test_tuning_points_are_read_from_the_runs_settings(tmp_path) -> None:
    """Named by their rule as scripts/tune_option.py's folders hold them: ``T-THRESHOLD`` for
    the option rule, ``go-THRESHOLD`` for version 0.3's anticipation."""
    for name, layers in (("0.5-0.3", LayeredConfig(anticipation="option", option_time=0.5, anticipate=0.3,
                                                   anticipate_release=0.15)),
                         ("1-0.7", LayeredConfig(anticipation="option", option_time=1.0, anticipate=0.7,
                                                 anticipate_release=0.35)),
                         ("go-0.35", LayeredConfig(anticipation="go", anticipate=0.35, anticipate_release=0.175))):
        run_experiment(tmp_path / "default" / name, range(2), ("cdf", "constant"),
                       cdf=CDFConfig(layered=layers), workers=1, progress=False)
    points = tuning_points(tmp_path)
    assert [p.name for p in points] == ["option 0.5 s, 0.3", "option 1 s, 0.7", "go 0.35"]
    assert all(p.interventions.n + p.hard_brakes.n >= 0 and p.collisions >= 0 for p in points)
    with pytest.raises(ValueError, match="no folder 'stop-and-wait'"):
        tuning_points(tmp_path, scenario="stop-and-wait")
    with pytest.raises(ValueError, match="no run with 'imm-layered' records"):
        tuning_points(tmp_path, planner="imm-layered")


def test_a_rule_is_named_by_its_anticipation_and_each_planner_by_its_own() -> None:
    assert rule_label(LayeredConfig(anticipation="option", option_time=0.5, anticipate=0.9,
                                    anticipate_release=0.45)) == "option 0.5 s, 0.9"
    assert rule_label({"anticipate": 0.1, "option_time": 1.0}) == "go 0.1"  # stored before the option rule
    assert rule_label(LayeredConfig()) == f"{LayeredConfig().anticipation} {LayeredConfig().anticipate:g}"
    assert layered_label("cdf") == rule_label(LayeredConfig())  # the package's default rule
    assert layered_label("cdf-option").startswith("option ")
    for name in ("caution-moving", "cdf-risk", "reactive"):  # caution reads no anticipation; others no layers
        assert layered_label(name) is None
    assert planner_item("cdf-option").endswith(f" Layered rule: {layered_label('cdf-option')}.")
    assert planner_item("reactive") == f"- `reactive`: {planner_line('reactive')}"


def test_the_default_and_the_option_rule_are_each_compared_with_every_other_planner_once() -> None:
    planners = ["cdf", "cdf-option", "imm-layered", "caution-moving", "constant"]
    assert comparisons(planners) == [("cdf", ["imm-layered", "caution-moving"]),
                                     ("cdf-option", ["cdf", "imm-layered", "caution-moving"])]
    assert comparisons(["cdf-option", "reactive", "constant"]) == [("cdf-option", ["reactive"])]
    assert comparisons(["reactive", "constant"]) == []


def test_the_default_cdf_is_described_as_its_rule_behaves() -> None:
    """The page line of ``cdf`` follows the package's default rule: version 0.3's
    anticipation slows on the prior, and the line says so and points to ``cdf-option``."""
    if LayeredConfig().anticipation == "go":
        assert "version 0.3's anticipation" in CDF_LINE and "slows on the prior" in CDF_LINE
        assert f"probability {LayeredConfig().anticipate:g}" in CDF_LINE and "`cdf-option`" in CDF_LINE
    else:
        assert "slows on the prior" not in CDF_LINE


def test_every_registered_planner_has_one_plain_line() -> None:
    assert planner_line("cdf") == CDF_LINE
    for name in PLANNERS:
        line = planner_line(name)
        assert line and "``" not in line and ":class:" not in line and "\n" not in line, (name, line)
    assert planner_line("caution-moving").startswith("slow at the comfortable brake")  # its own name dropped
    with pytest.raises(ValueError, match="warp"):
        planner_line("warp")


def test_cost_targets_judge_the_issues_thresholds() -> None:
    good = world({}, {}, dict.fromkeys(range(20), "Yield") | {20: "Cutoff"})
    lines = cost_targets(planner_metrics(good)["a"])
    assert len(lines) == 5 and all(line.endswith(": met") for line in lines)
    slow = world({s: {"slowed": True, "passed": 8.5} for s in range(3)}, {}, dict.fromkeys(range(20), "Yield"))
    lines = cost_targets(planner_metrics(slow)["a"])
    assert lines[2].endswith("**missed**") and "15.0 %" in lines[2]  # 3 of 20 intervene
    assert lines[4].endswith("**missed**") and "0.075 s over 20 seeds" in lines[4]  # 1.5 s over 20 seeds
    assert lines[1].endswith("not measured")  # no Cutoff episode


def test_the_pareto_figure_marks_collisions_and_draws_the_tuning_points(tmp_path) -> None:
    pytest.importorskip("matplotlib")
    from cdf_mj.viz.pareto import pareto_figure

    points = [ParetoPoint("cdf", Rate(5, 60), 0.03, Rate(0, 60), 0),
              ParetoPoint("caution-moving", Rate(40, 60), 0.2, Rate(6, 60), 0),
              ParetoPoint("reactive", Rate(0, 60), 0.0, Rate(1, 60), 12),
              ParetoPoint("late", Rate(0, 0), math.nan, Rate(0, 0), 0)]
    tuning = [ParetoPoint("option 0.5 s, 0.3", Rate(20, 60), 0.08, Rate(0, 60), 0),
              ParetoPoint("go 0.1", Rate(2, 60), 0.01, Rate(1, 60), 1)]
    drawn = pareto_figure(points, tmp_path / "img" / "pareto.png", tuning, note="seeds 0-59 " * 40)  # wrapped
    assert drawn.path.stat().st_size > 10_000
    assert drawn.drawn == ["cdf", "caution-moving", "reactive"] and drawn.ringed == ["reactive"]
    assert drawn.skipped == ["late"] and drawn.tuning == 2
    with pytest.raises(ValueError, match="no planner has both"):
        pareto_figure(points[3:], tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()
