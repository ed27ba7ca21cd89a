"""Every intervention counted (issue 35): the ego's own acceleration and the planner's command
on each tick, the episode's interventions and fixed-point pass time in its record, the rules
and metrics that read them, the tables that print them and the trace files that keep them."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cdf_mj.analysis.metrics import paired_counts, planner_metrics
from cdf_mj.analysis.tables import experiment_tables, intervention_table, planner_table
from cdf_mj.config import ScenarioConfig
from cdf_mj.model.driver import ego_control
from cdf_mj.presets import load_preset
from cdf_mj.records import (
    OK,
    Label,
    braked,
    check_record,
    hit_obstacle,
    intervened,
    is_false_intervention,
    is_imminent,
    load_records,
    pass_time,
)
from cdf_mj.scenario.ego_agent import INTERVENTION_SHARE, intervention_tolerance_of
from cdf_mj.scenario.episode import EpisodeTick, run_episode
from cdf_mj.scenario.monitor import CDFMonitor
from cdf_mj.scenario.trace_file import TraceError, read_trace, write_trace

PLANNERS = ("constant", "reactive", "cdf")
SEEDS = range(8)  # default world: Right, Cutoff, Right, Yield, Right, Cutoff, Right, Right


class _Applied:
    """An observer keeping per tick the acceleration the actuator applied [m/s^2] and the
    ego's speed hold's alone (its nominal controller, no following, no planner)."""

    def __init__(self) -> None:
        self.applied: list[float] = []
        self.speed_hold: list[float] = []

    def __call__(self, step: EpisodeTick) -> None:
        world = step.world
        self.applied.append(step.command)
        self.speed_hold.append(float(ego_control(world.driver, world.layout.ego, step.measurement.poses[0],
                                                 False)[0]))


def _run(scene, planner: str, seed: int, config: ScenarioConfig | None = None):
    seen = _Applied()
    rec = run_episode(config, seed=seed, planner=planner, scene=scene, trace=True, observers=[seen])
    return rec, seen


@pytest.fixture(scope="module")
def runs(scene):
    """(planner, seed) -> (record, its _Applied) in the default world."""
    return {(p, s): _run(scene, p, s) for p in PLANNERS for s in SEEDS}


def test_constant_never_intervenes_and_reactive_exactly_where_it_braked(runs, scene):
    tolerance = intervention_tolerance_of(scene.layout().ego.max_brake)
    assert tolerance == pytest.approx(INTERVENTION_SHARE * scene.layout().ego.max_brake)
    reactive_braked = 0
    for (planner, _seed), (rec, seen) in runs.items():
        check_record(json.loads(json.dumps({**rec.to_dict(), "status": OK})))
        info = rec.intervention
        assert info["tolerance"] == pytest.approx(tolerance)
        assert (info["first"] is None) == (info["ticks"] == 0)
        if planner == "constant":
            assert info["ticks"] == 0 and not intervened(rec)
            # Its ego is its own controller: what it applied is its own acceleration on every tick.
            np.testing.assert_allclose(seen.applied, rec.trace["own"], atol=1e-12)
        if planner == "reactive":
            assert intervened(rec) == braked(rec)
            if braked(rec):
                reactive_braked += 1
                assert info["first"] == pytest.approx(rec.brake_time)  # no brake latency by default
    assert reactive_braked >= 2  # the Cutoff seeds 1 and 5


def test_cdf_intervenes_from_its_first_ticks_as_its_trace_says(runs):
    for seed in SEEDS:
        rec, seen = runs[("cdf", seed)]
        info, trace = rec.intervention, rec.trace
        command, own = np.array(trace["command"]), np.array(trace["own"])
        flags = np.array(trace["intervening"])
        t = np.array(trace["t"])
        # Today's rule slows on the prior alone, from the first ticks, in every episode.
        assert info["first"] is not None and info["first"] <= 0.3
        assert np.all(np.isfinite(command))  # clipped to the car's limits in the trace
        np.testing.assert_array_equal(flags, command < own - info["tolerance"])
        assert info["ticks"] == flags.sum() and info["time"] == pytest.approx(0.1 * flags.sum())
        assert info["first"] == pytest.approx(t[flags][0])
        applied = np.array(seen.applied)
        assert info["peak_decel"] == pytest.approx(max(0.0, float(-applied[flags].min())))
        # What it applied is capped by its command and by its own controller.
        assert np.all(applied <= np.minimum(command, own) + 1e-9) or rec.collision
    assert sum(is_false_intervention(runs[("cdf", s)][0]) for s in SEEDS) == sum(
        runs[("cdf", s)][0].label != Label.CUTOFF for s in SEEDS)


def test_a_constant_ego_following_a_slower_car_does_not_intervene(scene):
    """stress-merge-slows, seed 22: a Cutoff the constant ego's ACC avoids by following the
    merged car, which slows to 30-60 % of its speed, to the 15 s limit."""
    rec, seen = _run(scene, "constant", 22, load_preset("stress-merge-slows"))
    own, hold = np.array(rec.trace["own"]), np.array(seen.speed_hold)
    following = own < hold - 1.0  # its own controller brakes behind the car ahead
    assert following.sum() >= 20 and not rec.collision
    assert rec.intervention["ticks"] == 0 and not any(rec.trace["intervening"])
    np.testing.assert_allclose(seen.applied, own, atol=1e-12)


def _arc_past_conflict(scene, poses: np.ndarray) -> np.ndarray:
    layout = scene.layout()
    s_conflict = layout.route_ego.project(layout.conflict)[0]
    return np.array([layout.route_ego.project_point(x, y)[0] for x, y in poses[:, 0, :2]]) - s_conflict


def test_pass_time_is_when_the_trace_passes_the_fixed_point_or_extrapolated(runs, scene):
    config = ScenarioConfig()
    label_distance, speed = config.timing.label_distance, config.ego.speed
    layout = scene.layout()
    s_start = layout.route_ego.project(layout.ego_start[:2])[0]
    s_conflict = layout.route_ego.project(layout.conflict)[0]
    passed = extrapolated = 0
    for rec, _seen in runs.values():
        info = rec.intervention
        past = _arc_past_conflict(scene, np.array(rec.trace["poses"]))
        beyond = np.flatnonzero(past > label_distance)
        if info["passed"]:
            passed += 1
            j, t = beyond[0], rec.trace["t"]  # the crossing lies in the tick before t[j]: interpolated
            share = (label_distance - past[j - 1]) / (past[j] - past[j - 1])
            assert info["pass_time"] == pytest.approx(t[j - 1] + share * (t[j] - t[j - 1]), abs=1e-5)
            assert t[j - 1] < info["pass_time"] <= t[j]
        else:
            extrapolated += 1
            assert beyond.size == 0
            # Where it stopped, from its progress deficit (World.time_lost), then at its nominal speed.
            s_end = s_start + rec.ego_start_offset + speed * (rec.end_time - rec.time_lost)
            remaining = label_distance - (s_end - s_conflict)
            assert remaining > 0
            assert info["pass_time"] == pytest.approx(rec.end_time + remaining / speed, abs=1e-5)
        assert pass_time(rec) == info["pass_time"]
    assert passed and extrapolated


def test_time_lost_at_the_fixed_point_and_the_hard_subset(runs, scene):
    records = [rec.to_dict() for rec, _ in runs.values()]
    metrics = planner_metrics(records)
    constant = {r["seed"]: r for r in records if r["planner"] == "constant"}
    assert metrics["constant"].time_lost_fixed == 0.0
    for name in ("reactive", "cdf"):
        mine = [r for r in records if r["planner"] == name and not is_imminent(r)]
        pairs = [pass_time(r) - pass_time(constant[r["seed"]]) for r in mine
                 if not (r["collision"] or constant[r["seed"]]["collision"])]
        assert metrics[name].time_lost_fixed == pytest.approx(sum(pairs) / len(pairs))
        assert metrics[name].time_lost_fixed_seeds == len(pairs)
    assert metrics["cdf"].time_lost_fixed > 0.05 and metrics["cdf"].false_interventions.value == 1.0
    assert metrics["cdf"].peak_decel > 0.0
    hard = {s for s, r in constant.items() if is_imminent(r) and hit_obstacle(r)}
    assert hard  # the constant ego hits the obstacle on Cutoff seeds 1 and 5
    for name, m in metrics.items():
        assert m.hard_cutoffs == len(hard)
        assert m.hard_avoided.k == sum(not hit_obstacle(r) for r in records
                                       if r["planner"] == name and r["seed"] in hard)
    assert metrics["constant"].hard_avoided.k == 0
    c = paired_counts(records, "cdf", "constant")
    assert (c.intervene_only_first, c.intervene_only_second) == (metrics["cdf"].false_interventions.k, 0)
    row = metrics["cdf"].to_row()
    assert row["false_interventions_k"] == metrics["cdf"].false_interventions.k
    assert row["interventions_Cutoff_n"] == 2 and row["hard_cutoffs"] == len(hard)


def test_following_a_slower_car_is_not_charged(scene):
    """On a seed where the constant ego follows the merged car (its pass time late), the
    time lost of another planner at the fixed point is measured against it, not the nominal."""
    config = load_preset("stress-merge-slows")
    records = [run_episode(config, seed=22, planner=p, scene=scene).to_dict() for p in ("constant", "cdf")]
    m = planner_metrics(records)
    assert records[0]["intervention"]["pass_time"] > 7.0  # about 5 s at the nominal speed
    lost = m["cdf"].time_lost_fixed_by_label["Cutoff"]
    assert lost == pytest.approx(records[1]["intervention"]["pass_time"] - records[0]["intervention"]["pass_time"])
    assert abs(lost) < 1.0


def test_records_without_the_field_load_and_the_tables_say_so(runs, tmp_path):
    path = tmp_path / "episodes.jsonl"
    old = [{**{k: v for k, v in rec.to_dict().items() if k not in ("intervention", "trace")}, "status": OK}
           for rec, _ in runs.values()]
    path.write_text("".join(json.dumps(r) + "\n" for r in old))
    records = load_records(tmp_path)
    assert all(intervened(r) is None and pass_time(r) is None for r in records)
    m = planner_metrics(records)["cdf"]
    assert m.false_interventions.n == 0 and math.isnan(m.time_lost_fixed) and math.isnan(m.peak_decel)
    assert m.without_intervention == len(SEEDS) and m.hard_cutoffs == 2  # the hard subset needs no field
    for text in (experiment_tables(records), experiment_tables(records, fmt="markdown"), planner_table(records)):
        assert "Records without `intervention`" in text and "cdf 8" in text
    assert "No `constant` episodes" in intervention_table(planner_metrics(
        [r for r in records if r["planner"] != "constant"]).values())


@pytest.mark.parametrize(("change", "message"), [
    ({"ticks": -1}, "field 'intervention.ticks' must be a non-negative integer"),
    ({"ticks": 2.0}, "field 'intervention.ticks' must be a non-negative integer"),
    ({"peak_decel": float("nan")}, "field 'intervention.peak_decel' must be a finite number >= 0"),
    ({"pass_time": None}, "field 'intervention.pass_time' must be a finite number >= 0"),
    ({"passed": 1}, "field 'intervention.passed' must be true or false"),
    ({"first": "0.1"}, "field 'intervention.first' must be a finite time >= 0 or null"),
    ({"first": None, "ticks": 3}, "field 'intervention.first' is None with 3 intervening ticks"),
    ({"tolerance": ...}, "field 'intervention.tolerance' is missing"),
])
def test_a_damaged_intervention_is_one_error_naming_the_field(runs, change, message):
    rec = {**runs[("cdf", 0)][0].to_dict(), "status": OK}
    info = {k: v for k, v in {**rec["intervention"], **change}.items() if v is not ...}
    with pytest.raises(ValueError, match=f"^{message}") as err:
        check_record({**rec, "intervention": info})
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="field 'intervention' must be an object or null"):
        check_record({**rec, "intervention": [1, 2]})


def _monitor_rows(scene) -> tuple[dict, list[dict]]:
    layout = scene.layout()
    monitor = CDFMonitor(layout, rng=0)
    ego, obstacle = [-40.8, -1.85, 0.0, 13.4], list(layout.obstacle_start)
    for k in range(3):
        ego[0] += 1.34
        monitor.observe(0.1 * k, ego, obstacle)
    # Observations as a trace written before interventions were counted holds them.
    return monitor.trace_header(), [{k: v for k, v in row.items() if k not in ("command", "own", "intervening")}
                                    for row in monitor.trace]


def test_trace_files_keep_command_own_and_intervening_and_read_old_ones(scene, tmp_path):
    header, rows = _monitor_rows(scene)
    old = read_trace(write_trace(tmp_path / "old.jsonl", header, rows))
    assert np.isnan(old.command).all() and np.isnan(old.own).all() and not old.intervening.any()
    new = [row | {"command": -2.5 * k, "own": 0.0, "intervening": k > 0} for k, row in enumerate(rows)]
    trace = read_trace(write_trace(tmp_path / "new.jsonl", header, new))
    np.testing.assert_array_equal(trace.command, [0.0, -2.5, -5.0])
    np.testing.assert_array_equal(trace.intervening, [False, True, True])
    with pytest.raises(TraceError, match=r"'intervening' must be true or false, got 1"):
        write_trace(tmp_path / "bad.jsonl", header, [*new[:2], new[2] | {"intervening": 1}])
    with pytest.raises(TraceError, match=r"'command' must be a finite acceleration"):
        write_trace(tmp_path / "bad.jsonl", header, [new[0] | {"command": "fast"}, *new[1:]])
    with pytest.raises(TraceError, match=r"observation 3: the observation lacks 'own'"):
        write_trace(tmp_path / "bad.jsonl", header, [*new[:2], {k: v for k, v in new[2].items() if k != "own"}])
    assert not (tmp_path / "bad.jsonl").exists()
