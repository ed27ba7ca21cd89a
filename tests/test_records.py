"""cdf_mj.records: the schema of a record, the records file, and the rules every metric counts by."""

from __future__ import annotations

import json
import math
import os

import pytest

from cdf_mj.analysis.metrics import mcnemar_exact, paired_counts, planner_metrics, scenario_summary, tau_curve
from cdf_mj.records import (
    FAILED,
    OK,
    EpisodeRecord,
    avoided,
    braked,
    check_record,
    hit_obstacle,
    is_false_alarm,
    is_imminent,
    lead_time,
    load_records,
    paper_avoided,
    prediction,
    read_records,
    read_settings,
)
from cdf_mj.scenario.episode import run_episode


def episode(seed: int, planner: str, label: str | None, *, brake: float | None = None,
            entered: float | None = None, collision: str | None = None, predicted: str | None = None,
            min_gap: float = 2.0, time_lost: float = 0.5) -> dict:
    """A complete stored record (``"status": "ok"``) with the outcomes given."""
    rec = EpisodeRecord(seed=seed, planner=planner, intent="right" if label == "Right" else "left", label=label,
                        ego_start_offset=0.0, first_seen_time=None, yielded=label == "Yield",
                        entered_lane_time=entered, collision=collision is not None, collision_with=collision,
                        collision_time=None if collision is None else 3.0,
                        min_gap=0.0 if collision else min_gap, brake_time=brake, time_lost=time_lost,
                        end_time=8.0, counterfactual_collision=label == "Cutoff",
                        planner_info={} if predicted is None else {"prediction": predicted})
    return {**rec.to_dict(), "status": OK}


# ----------------------------------------------------------------- schema
@pytest.mark.parametrize("planner", ["cdf", "reactive"])
def test_from_dict_round_trips_real_records(scene, planner):
    rec = run_episode(seed=1, planner=planner, scene=scene, trace=True)
    assert EpisodeRecord.from_dict(rec.to_dict()) == rec
    stored = json.loads(json.dumps({**rec.to_dict(), "status": OK}))  # a line of episodes.jsonl
    assert EpisodeRecord.from_dict(stored) == rec
    assert EpisodeRecord.from_dict(stored).to_dict() == rec.to_dict()


@pytest.mark.parametrize(("change", "message"), [
    ({"label": ...}, "field 'label' is missing"),
    ({"min_gap": "2.0"}, "field 'min_gap' must be a finite number, got str '2.0'"),
    ({"min_gap": None}, "field 'min_gap' must be a finite number, got null"),
    ({"seed": True}, "field 'seed' must be an integer, got bool True"),
    ({"seed": 1.7}, "field 'seed' must be an integer, got float 1.7"),
    ({"seed": "3"}, "field 'seed' must be an integer, got str '3'"),
    ({"seed": None}, "field 'seed' must be an integer, got null"),
    ({"seed": math.inf}, "field 'seed' must be an integer, got float inf"),
    ({"seed": -2}, "field 'seed' must be a non-negative integer, got -2"),
    ({"planner": ["cdf"]}, "field 'planner' must be a string, got list"),
    ({"brake_time": "0.9"}, "field 'brake_time' must be a finite number or null"),
    ({"brake_time": math.nan}, "field 'brake_time' must be a finite number or null, got float nan"),
    ({"time_lost": -math.inf}, "field 'time_lost' must be a finite number, got float -inf"),
    ({"planner_info": "{}"}, "field 'planner_info' must be an object"),
    ({"yielded": 1}, "field 'yielded' must be true or false"),
    ({"planner_info": []}, "field 'planner_info' must be an object"),
    ({"intent": "up"}, "field 'intent' must be one of 'left', 'right', got 'up'"),
    ({"label": "Maybe"}, "field 'label' must be one of 'Cutoff', 'Yield', 'Right'"),
    ({"collision_with": "tree"}, "field 'collision_with' must be one of"),
    ({"colour": "red"}, "unknown field 'colour'"),
    ({"status": FAILED}, "field 'status' is 'failed'"),
])
def test_from_dict_refuses_a_bad_record_naming_the_field(change, message):
    data = episode(0, "cdf", "Cutoff", brake=0.9, entered=2.0)
    for key, value in change.items():
        if value is ...:
            del data[key]
        else:
            data[key] = value
    with pytest.raises(ValueError, match="^" + message.replace("(", r"\(").replace(")", r"\)")):
        EpisodeRecord.from_dict(data)


def test_from_dict_takes_whole_numbers_for_numbers_and_leaves_defaults_out():
    data = {**episode(0, "reactive", "Right"), "min_gap": 2, "end_time": 8}
    del data["planner_info"], data["trace"]
    rec = EpisodeRecord.from_dict(data)
    assert (rec.min_gap, rec.planner_info, rec.trace) == (2, {}, None)


def test_failed_records_need_a_seed_and_a_planner():
    check_record({"seed": 3, "planner": "cdf", "status": FAILED, "error": "E: x", "traceback": "..."})
    with pytest.raises(ValueError, match="field 'seed' of a failed record must be an integer"):
        check_record({"planner": "cdf", "status": FAILED})
    with pytest.raises(ValueError, match="a JSON object, got list"):
        check_record([1, 2])


# ----------------------------------------------------------------- the records file
def test_the_reader_names_the_file_and_the_line(tmp_path):
    path = tmp_path / "episodes.jsonl"
    good = [episode(0, "cdf", "Right"), episode(1, "cdf", "Yield")]
    bad = {**episode(2, "cdf", "Yield"), "brake_time": "soon"}
    path.write_text(json.dumps(good[0]) + "\n\n" + json.dumps(good[1]) + "\n" + json.dumps(bad) + "\n")
    with pytest.raises(ValueError, match=rf"^{path}:4 is not an episode record: field 'brake_time' must be"):
        read_records(path)
    path.write_text(json.dumps(good[0]) + "\n{not json\n")
    with pytest.raises(ValueError, match=rf"^{path}:2 is not an episode record: not JSON \(Expecting"):
        read_records(path)


def test_the_reader_leaves_out_a_half_written_last_line_without_changing_the_file(tmp_path):
    path = tmp_path / "episodes.jsonl"
    lines = "".join(json.dumps(r) + "\n" for r in (episode(0, "cdf", "Right"), episode(1, "cdf", "Yield")))
    path.write_text(lines + '{"seed": 2, "plan')
    before = path.read_bytes()
    found = read_records(path)
    assert found.records == [episode(0, "cdf", "Right"), episode(1, "cdf", "Yield")]
    assert found.partial and found.complete_bytes == len(lines.encode()) and found.size == len(before)
    assert path.read_bytes() == before
    assert load_records(tmp_path) == found.records
    path.write_text(lines)
    assert not read_records(path).partial


@pytest.mark.parametrize(("line", "reason"), [
    ('{"seed": 1e400, "planner": "cdf", "status": "failed"}', "field 'seed' of a failed record must be an integer"),
    ('{"seed": -1, "planner": "cdf", "status": "failed"}', "field 'seed' must be a non-negative integer"),
    ("[" * 100_000 + "]" * 100_000, r"not JSON \(nested too deeply\)"),
    ('"\xff"', "not JSON"),
    ("7", "an episode record is a JSON object, got int"),
])
def test_the_reader_refuses_odd_json_naming_the_line(tmp_path, line, reason):
    path = tmp_path / "episodes.jsonl"
    path.write_bytes(json.dumps(episode(0, "cdf", "Right")).encode() + b"\n" + line.encode("latin-1") + b"\n")
    with pytest.raises(ValueError, match=rf"^{path}:2 is not an episode record: {reason}"):
        read_records(path)


def test_the_reader_refuses_records_of_another_run_and_duplicates(tmp_path):
    path = tmp_path / "episodes.jsonl"

    def lines(*recs: dict) -> None:
        path.write_text("".join(json.dumps(r) + "\n" for r in recs))

    lines(episode(3, "cdf", "Right"), episode(3, "reactive", "Right"), episode(3, "cdf", "Right"))
    with pytest.raises(ValueError, match=rf"^{path}:3 is not a record of this run: seed 3 of planner 'cdf' is "
                                         r"recorded twice \(first on line 1\)"):
        read_records(path)  # twice is wrong in any run
    lines(episode(3, "cdf", "Right"), {"seed": 3, "planner": "cdf", "status": FAILED})
    with pytest.raises(ValueError, match="recorded twice"):
        read_records(path)  # a failed and a completed record of one episode too
    lines(episode(3, "cdf", "Right"), episode(9, "cdf", "Right"))
    assert len(read_records(path).records) == 2
    with pytest.raises(ValueError, match=rf"^{path}:2 is not a record of this run: seed 9 is outside the run's "
                                         "seeds 0-4"):
        read_records(path, seeds=range(5))
    with pytest.raises(ValueError, match=r":1 is not a record of this run: planner 'cdf' is not one of the "
                                         r"run's planners \(reactive\)"):
        read_records(path, planners=["reactive"])
    assert len(read_records(path, seeds=range(10), planners=["cdf"]).records) == 2


def test_the_reader_refuses_what_is_not_a_regular_file(tmp_path):
    fifo = tmp_path / "episodes.jsonl"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="is not a regular file"):
        read_records(fifo)  # and does not block
    with pytest.raises(ValueError, match="is not a regular file"):
        read_records(tmp_path)


@pytest.mark.parametrize(("change", "key"), [
    ({"planners": 7}, "planners"), ({"planners": "cdf"}, "planners"), ({"planners": ["cdf", "cdf"]}, "planners"),
    ({"seeds": [0, 1.5]}, "seeds"), ({"seeds": [-1, 3]}, "seeds"), ({"seeds": None}, "seeds"),
    ({"seeds": [5, 2]}, "seeds"), ({"scenario": []}, "scenario"), ({"cdf": "x"}, "cdf"),
    ({"scenario": {"names": "abc"}}, "scenario.names"), ({"scene": 3}, "scene"),
    ({"scene_files": []}, "scene_files"), ({"version": 1}, "version"),
])
def test_settings_are_checked_naming_the_file_and_the_key(tmp_path, change, key):
    good = {"seeds": [0, 4], "planners": ["cdf", "reactive"], "scenario": {}, "cdf": {}, "scene": "s.xml"}
    path = tmp_path / "settings.json"
    path.write_text(json.dumps(good))
    assert read_settings(path) == good
    path.write_text(json.dumps({**good, **change}))
    with pytest.raises(ValueError, match=rf"^{path}: key '{key}' must be"):
        read_settings(path)
    for text, reason in (("[1, 2]", "settings are a JSON object, got list"), ("{", "not JSON")):
        path.write_text(text)
        with pytest.raises(ValueError, match=rf"^{path}: {reason}"):
            read_settings(path)


# ----------------------------------------------------------------- rules of one record
def test_the_rules_on_records_with_known_outcomes():
    cut_braked = episode(0, "cdf", "Cutoff", brake=0.9, entered=2.0, predicted="Cutoff")
    cut_hit = episode(1, "reactive", "Cutoff", brake=2.1, entered=2.0, collision="obstacle")
    yield_braked = episode(2, "reactive", "Yield", brake=0.9)
    yield_hit = episode(3, "cdf", "Yield", brake=0.9, collision="obstacle", predicted="Cutoff")
    right = episode(4, "reactive", "Right")
    unlabelled = episode(5, "reactive", None, brake=1.0)

    assert avoided(cut_braked) and is_imminent(cut_braked) and not is_false_alarm(cut_braked)
    assert lead_time(cut_braked) == pytest.approx(1.1)
    assert not avoided(cut_hit) and hit_obstacle(cut_hit)
    assert lead_time(cut_hit) == pytest.approx(-0.1)  # braked after the obstacle entered the lane
    # A Yield episode that braked is a false alarm, and has no imminent collision to avoid.
    assert is_false_alarm(yield_braked) and not avoided(yield_braked) and lead_time(yield_braked) is None
    assert hit_obstacle(yield_hit) and not is_imminent(yield_hit) and not avoided(yield_hit)
    assert not (braked(right) or is_false_alarm(right) or hit_obstacle(right))
    assert braked(unlabelled) and not is_false_alarm(unlabelled)  # no label, no verdict
    # The planner's own prediction, else braking means Cutoff.
    assert [prediction(r) for r in (cut_braked, cut_hit, yield_hit, right)] == ["Cutoff", "Cutoff", "Cutoff", None]
    # Dicts and EpisodeRecord objects alike.
    for rule in (avoided, braked, hit_obstacle, is_false_alarm, is_imminent, lead_time, prediction):
        for rec in (cut_braked, cut_hit, yield_braked, yield_hit, right, unlabelled):
            assert rule(EpisodeRecord.from_dict(rec)) == rule(rec)


def test_a_collision_in_a_yield_episode_counts_in_the_papers_formula_only():
    recs = [episode(0, "cdf", "Cutoff", brake=0.9, entered=2.0),
            episode(1, "cdf", "Cutoff", brake=1.0, entered=1.9),
            episode(2, "cdf", "Yield", brake=0.9, collision="obstacle"),
            episode(3, "cdf", "Right"),
            {"seed": 4, "planner": "cdf", "status": FAILED}]
    m = planner_metrics(recs)["cdf"]
    assert (m.episodes, m.imminent, m.collisions) == (4, 2, 1)
    assert (m.avoided.k, m.avoided.n) == (2, 2)  # ours: every Cutoff episode without a collision
    assert m.paper_avoided == pytest.approx(0.5)  # the paper's: (2 - 1) / 2
    assert (m.false_alarms.k, m.false_alarms.n) == (1, 4)
    assert m.lead_time == pytest.approx(1.0)  # median of 1.1 and 0.9
    assert m.min_gap == pytest.approx(2.0) and m.time_lost == pytest.approx(0.5)
    assert scenario_summary(recs)["avoided"] == m.avoided
    assert paper_avoided(417, 9) == pytest.approx(408 / 417) and math.isnan(paper_avoided(0, 0))


def test_paired_counts_and_the_tau_curve_use_the_same_rules():
    def with_history(rec: dict, p_cutoff: list[float]) -> dict:
        rec["planner_info"]["history"] = {"t": [0.1 * k for k in range(len(p_cutoff))], "p_cutoff": p_cutoff}
        return rec

    cdf = [with_history(episode(0, "cdf", "Cutoff", brake=0.2, entered=0.25), [0.1, 0.6, 0.95]),
           with_history(episode(1, "cdf", "Yield", brake=0.1), [0.2, 0.97, 0.1]),
           with_history(episode(2, "cdf", "Right"), [0.1, 0.1, 0.1])]
    reactive = [episode(0, "reactive", "Cutoff", brake=0.25, entered=0.25, collision="obstacle"),
                episode(1, "reactive", "Yield"), episode(2, "reactive", "Right", brake=0.5)]
    c = paired_counts(cdf + reactive, "cdf", "reactive")
    assert (c.seeds, c.collides_only_first, c.collides_only_second) == (3, 0, 1)
    assert (c.false_alarm_only_first, c.false_alarm_only_second, c.false_alarm_both) == (1, 1, 0)

    curve = {row["tau"]: row for row in tau_curve(cdf, tau_max=0.99)}
    assert curve[0.5]["false_alarms_k"] == 1 and curve[0.5]["detected_k"] == 1  # braked at 0.1 s, entry 0.25 s
    assert curve[0.96]["detected_k"] == 0 and curve[0.97]["false_alarms_k"] == 1
    assert curve[0.98]["false_alarms_k"] == 0 and curve[0.98]["episodes"] == 3


def test_mcnemar_exact_is_the_two_sided_binomial_test():
    assert mcnemar_exact(0, 0) == 1.0
    assert mcnemar_exact(3, 3) == 1.0
    assert mcnemar_exact(0, 5) == pytest.approx(2 / 32)  # 2 * P(X = 0), X ~ Bin(5, 1/2)
    assert mcnemar_exact(9, 1) == pytest.approx(2 * 11 / 1024) == mcnemar_exact(1, 9)  # 2 P(X <= 1), n = 10
    assert mcnemar_exact(0, 30) < 1e-8
    with pytest.raises(ValueError, match="counts must be >= 0"):
        mcnemar_exact(-1, 2)
