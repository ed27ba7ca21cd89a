"""ScenarioConfig by owner (timing, ego, obstacle, observation, pursuit, noise, names) and
the flat keys of version 0.1 (cdf_mj.config.FLAT_KEYS).

Old input keeps working: flat keywords, ``replace`` and attribute reads (each with a
DeprecationWarning naming the dotted key), a flat settings.json (read silently, and a run
stored with it is continued, not refused); the package's own code reads only the nested
names (an episode of every kind and the CDF run with DeprecationWarnings as errors).
"""

from __future__ import annotations

import dataclasses
import json
import warnings

import pytest
from cli_helpers import run_cli

from cdf_mj.config import (
    FLAT_KEYS,
    GROUPS,
    SCENARIO_KEYS,
    CDFConfig,
    DriverPrior,
    FlatKeyWarning,
    ScenarioConfig,
    normalise_settings,
    scenario_key,
)
from cdf_mj.config.scenario import VERSION_0_1_WORLD
from cdf_mj.planners import CDFPlanner
from cdf_mj.presets import load_preset, preset_names
from cdf_mj.scenario.episode import run_episode

#: The "scenario" and "cdf" of a settings.json written by version 0.1 (all defaults).
OLD_SCENARIO = json.loads("""{"dt": 0.1, "duration": 8.0, "beta": 0.05, "obs_noise_pos": 0.5,
  "obs_noise_heading": 0.02, "obs_noise_speed": 0.5, "p_left": 0.75, "ego_speed": 13.4,
  "ego_start_spread": [-8.0, 8.0], "ego_speed_gain": 1.0, "obstacle_accel": 2.5, "obstacle_turn_speed": 8.0,
  "obstacle_yield_brake": 4.0, "critical_gap": 5.0, "passed_margin": 3.0, "clear_distance": 10.0,
  "stop_dwell": [0.0, 0.0], "departure_look": 0.0, "hesitation": 0.0, "hesitation_creep": 0.7,
  "hesitation_pause": [0.5, 1.5], "lookahead": 3.0, "lookahead_gain": 0.3, "noise_accel": 0.3,
  "noise_steer": 0.01, "names": {"ego_prefix": "ego_", "route_ego": "route_ego"}}""")
OLD_CDF = json.loads("""{"n_particles": 1000, "likelihood_std": [0.3, 0.3, 0.05, 0.3], "likelihood_cov": null,
  "tau": 0.85, "cutoff_rule": "predictive", "resample_ess_fraction": 1.0, "reinit_mahalanobis": 12.0,
  "process_noise_scale": 1.5, "prior": {"p_left": 0.75, "beta": [0.03, 0.07], "critical_gap": [4.0, 7.0],
  "accel": [1.5, 3.0], "turn_speed": [6.0, 10.0], "yield_brake": [3.0, 5.0], "clear_distance": [7.0, 13.0],
  "departure_hazard": [0.4, 4.0]}, "mode_jump": 0.005, "intent_floor": 0.02, "reinit_redraw": true,
  "param_jitter": 0.02, "ego_brake": null, "ego_latency": 0.0, "decision": "risk",
  "risk": {"brake": 0.5, "release": 0.25, "latency": 0.1, "horizon": 5.0, "margin": 0.3}}""")


# ------------------------------------------------------------------ the groups
def test_the_groups_and_their_fields():
    config = ScenarioConfig()
    assert [f.name for f in dataclasses.fields(config)] == [*GROUPS, "names"]
    assert {k.partition(".")[0] for k in SCENARIO_KEYS} == set(GROUPS)
    assert (config.timing.dt, config.ego.speed, config.obstacle.accel, config.observation.pos,
            config.pursuit.lookahead, config.noise.steer) == (0.1, 13.4, 2.5, 0.5, 3.0, 0.01)
    assert config.to_dict()["obstacle"]["critical_gap"] == 5.0  # nested
    assert ScenarioConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config


def test_dotted_keys_group_mappings_and_group_objects_build_the_same_config():
    by_key = ScenarioConfig().with_values({"obstacle.beta": 0.1, "ego.start_spread": (-4.0, 4.0)})
    by_mapping = ScenarioConfig(obstacle={"beta": 0.1}, ego={"start_spread": [-4, 4]})
    by_object = ScenarioConfig().replace(obstacle=ScenarioConfig().obstacle.replace(beta=0.1),
                                         ego=ScenarioConfig().ego.replace(start_spread=(-4.0, 4.0)))
    assert by_key == by_mapping == by_object
    assert by_key.get("obstacle.beta") == 0.1 and by_key.obstacle.accel == 2.5  # the rest kept
    with pytest.raises(ValueError, match=r"unknown scenario key 'obstacle\.bta'.*obstacle\.beta"):
        ScenarioConfig().with_values({"obstacle.bta": 0.1})
    with pytest.raises(ValueError, match=r"obstacle: unknown key among \['bta'\]"):
        ScenarioConfig(obstacle={"bta": 0.1})


@pytest.mark.parametrize(("key", "value", "message"), [
    ("timing.dt", 0.0, "timing.dt=0.0 is out of range: must be > 0 and <= 1 [s] (the paper's tick is 0.1 s)"),
    ("timing.duration", 0.05, "timing.duration=0.05 is out of range: must be in [dt = 0.1, 600] [s]"),
    ("ego.speed", -1.0, "ego.speed=-1.0 is out of range: must be > 0 and <= 100 [m/s]"),
    ("obstacle.accel", 0.0, "obstacle.accel=0.0 is out of range: must be > 0 and <= 100 [m/s^2]"),
    ("obstacle.p_left", 1.5, "obstacle.p_left=1.5 is out of range: must be in [0, 1] (a probability)"),
    ("observation.heading", 4.0, "observation.heading=4.0 is out of range: must be in [0, 3.14159] [rad]"),
    ("pursuit.lookahead", 0.0, "pursuit.lookahead=0.0 is out of range: must be > 0 and <= 1000 [m]"),
    ("noise.accel", -0.1, "noise.accel=-0.1 is out of range: must be in [0, 100] [m/s^2]"),
])
def test_errors_name_the_dotted_field_and_its_bounds(key, value, message):
    with pytest.raises(ValueError, match=r"is out of range") as err:
        ScenarioConfig().with_values({key: value})
    assert str(err.value) == message


# ------------------------------------------------------------------ version 0.1's flat keys
def test_every_flat_key_names_one_dotted_key():
    assert set(FLAT_KEYS.values()) <= set(SCENARIO_KEYS)
    assert len(set(FLAT_KEYS.values())) == len(FLAT_KEYS)
    assert set(FLAT_KEYS) == set(OLD_SCENARIO) - {"names"}  # every field of version 0.1
    assert scenario_key("obstacle_accel") == scenario_key("obstacle.accel") == "obstacle.accel"


def test_flat_keywords_replace_and_reads_still_work_with_a_warning_naming_the_dotted_key():
    nested = ScenarioConfig(obstacle={"beta": 0.1, "accel": 1.2}, timing={"duration": 4.0})
    for build in (ScenarioConfig, ScenarioConfig().replace):
        with pytest.warns(FlatKeyWarning, match="is deprecated") as got:  # a DeprecationWarning, as for input files
            assert build(beta=0.1, obstacle_accel=1.2, duration=4.0) == nested
        assert [str(w.message) for w in got] == [
            f"ScenarioConfig: the flat key {old!r} is deprecated; use {new!r}"
            for old, new in (("beta", "obstacle.beta"), ("obstacle_accel", "obstacle.accel"),
                             ("duration", "timing.duration"))]
    with pytest.warns(FlatKeyWarning, match=r"ScenarioConfig\.ego_speed is deprecated; read config\.ego\.speed"):
        assert nested.ego_speed == 13.4
    with pytest.warns(DeprecationWarning, match="'beta'"):
        assert dataclasses.replace(ScenarioConfig(), beta=0.1).obstacle.beta == 0.1
    with pytest.raises(AttributeError, match="no attribute 'bta'"):
        _ = nested.bta
    with pytest.raises(TypeError, match="unknown scenario key 'bta'"):
        ScenarioConfig(bta=0.1)


def test_a_flat_settings_file_of_version_0_1_reads_as_today_s_settings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # stored results read without a word
        old = ScenarioConfig.from_dict(OLD_SCENARIO)
        # Its rule was the risk rule, stored by name: it stays the run's rule.
        assert CDFConfig.from_dict(OLD_CDF) == CDFConfig(likelihood_std=[0.3, 0.3, 0.05, 0.3], decision="risk")
    # Read in version 0.1's world: its 8 s, and what it did not have as it was then.
    then = ScenarioConfig().with_values({**VERSION_0_1_WORLD, "timing.duration": 8.0})
    assert old == then
    settings = {"scenario": OLD_SCENARIO, "cdf": OLD_CDF, "seeds": [0, 2]}
    now = json.loads(json.dumps({"scenario": then.to_dict(), "cdf": CDFConfig(decision="risk").to_dict(),
                                 "seeds": [0, 2]}))
    assert normalise_settings(settings) == now
    assert normalise_settings({"scenario": {"beta": 7.0}})["scenario"] == {"beta": 7.0}  # kept, to be refused


def test_a_run_stored_with_flat_settings_is_continued_not_refused(tmp_path, capsys):
    """A flat settings.json reads in version 0.1's world (VERSION_0_1_WORLD): a run of that
    world, stored flat, continues; today's defaults would be other settings."""
    out = tmp_path / "run"
    world = [w for key, value in VERSION_0_1_WORLD.items() for w in ("--set", f"{key}={json.dumps(value)}")]
    argv = ["experiment", "--episodes", "2", "--planner", "reactive", "--workers", "1", "--quiet", "--out", str(out),
            *world, "--set", "timing.duration=8"]
    assert run_cli(capsys, *argv)[0] == 0
    path = out / "settings.json"
    settings = json.loads(path.read_text())
    flat = {k: ScenarioConfig.from_dict(settings["scenario"]).get(v) for k, v in FLAT_KEYS.items()}
    settings["scenario"] = json.loads(json.dumps({**flat, "names": settings["scenario"]["names"]}))
    for key in ("process_noise",):  # the fields version 0.1 did not have
        settings["cdf"].pop(key)
    for key in ("passed_margin", "observation", "pursuit"):
        settings["cdf"]["prior"].pop(key)
    path.write_text(json.dumps(settings))
    lines = (out / "episodes.jsonl").read_text().splitlines()
    (out / "episodes.jsonl").write_text(lines[0] + "\n")  # as if cut after the first episode
    status, text, err = run_cli(capsys, *argv)
    assert status == 0, err
    assert "1 run in" in text and "1 already on disk" in text
    settings["scenario"]["beta"] = 0.1  # other settings are still refused, by their dotted name
    path.write_text(json.dumps(settings))
    status, _, err = run_cli(capsys, *argv)
    assert status == 2 and "scenario.obstacle.beta" in err


# ------------------------------------------------------------------ the package's own reads
def test_the_package_reads_only_nested_names(scene):
    """An episode of every kind of planner, the CDF with its filter, the presets and the
    world's checks, with DeprecationWarnings as errors."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        config = ScenarioConfig(timing={"duration": 3.0})
        for planner in ("constant", "reactive", "cv", "imm", "imm-risk", "cdf-threshold"):
            run_episode(config, 4, planner, scene)
        run_episode(config, 4, CDFPlanner(CDFConfig(n_particles=200)), scene, trace=True)
        for name in preset_names():
            load_preset(name)


def test_the_prior_reads_back_nested_groups_from_json():
    prior = DriverPrior(observation={"pos": 0.7}, pursuit={"lookahead": 2.0})
    assert prior.observation.pos == 0.7 and prior.pursuit.lookahead == 2.0
    assert DriverPrior(**json.loads(json.dumps(prior.to_dict()))) == prior
    with pytest.raises(ValueError, match=r"observation\.pos="):
        DriverPrior(observation={"pos": -1.0})
