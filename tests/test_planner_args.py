"""A run keeps each planner's arguments, and everything that rebuilds a planner from a
stored run builds the one that ran (experiments, reports, the command line's flags)."""

from __future__ import annotations

import json

import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj.config import CDFConfig, RiskConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.planners.registry import make_planner, stored_planner_arguments
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

CDF = CDFConfig(n_particles=200, tau=0.6, risk=RiskConfig(brake=0.3, release=0.15))
OWN = {"imm": {"params": {"threshold": 0.6, "p_left": 0.9}}}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("args")
    result = run_experiment(out, range(3), ["imm-risk", "cdf-threshold", "imm"], cdf=CDF, planner_args=OWN,
                            progress=False, workers=1)
    return out, result


def test_settings_keep_each_planners_arguments_and_they_rebuild_it(run):
    out, result = run
    settings = json.loads((out / "settings.json").read_text())
    args = settings["planner_args"]
    assert args["imm-risk"] == {"risk": CDF.risk.to_dict()}
    assert args["cdf-threshold"]["cdf"]["n_particles"] == 200 and args["cdf-threshold"]["cdf"]["tau"] == 0.6
    assert args["imm"] == OWN["imm"]
    scene = Scene.load()
    for rec in result:
        planner = make_planner(rec["planner"], **stored_planner_arguments(settings)[rec["planner"]])
        again = run_episode(None, rec["seed"], planner, scene, label=False).to_dict()
        assert {k: again[k] for k in ("brake_time", "min_gap", "planner_info")} == \
            {k: rec[k] for k in ("brake_time", "min_gap", "planner_info")}


def test_a_run_stored_before_planner_arguments_were_kept_reads_back_and_resumes(tmp_path):
    run_experiment(tmp_path, range(2), ["cdf-threshold", "imm-risk"], cdf=CDF, progress=False, workers=1)
    path = tmp_path / "settings.json"
    settings = json.loads(path.read_text())
    stored = settings.pop("planner_args")
    path.write_text(json.dumps(settings))
    assert stored_planner_arguments(settings) == stored
    resumed = run_experiment(tmp_path, range(2), ["cdf-threshold", "imm-risk"], cdf=CDF, progress=False,
                             workers=1, resume=True)
    assert resumed.ran == 0 and resumed.resumed == 4


def test_arguments_a_planner_does_not_take_are_refused_before_any_work(tmp_path):
    with pytest.raises(TypeError, match="planner 'reactive'"):
        run_experiment(tmp_path, range(2), ["reactive"], planner_args={"reactive": {"horizon": 2}},
                       progress=False, workers=1)
    with pytest.raises(ValueError, match="planners that do not run"):
        run_experiment(tmp_path, range(2), ["reactive"], planner_args={"cdf": {}}, progress=False, workers=1)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(("planners", "flag", "readers"), [
    ("reactive,imm", "--tau", "cdf-threshold"),
    ("reactive,cdf-threshold", "--brake-risk",
     "caution-moving, caution-phantom, caution-waiting, cdf, cdf-option, cdf-risk, cv-layered, cv-risk, "
     "imm-layered, imm-risk"),
])
def test_a_cdf_flag_that_no_planner_reads_is_refused(tmp_path, capsys, planners, flag, readers):
    """Which planner reads which flag comes from the registry (its shared settings and its rule)."""
    out = tmp_path / "x"
    status, stdout, stderr = run_cli(capsys, "experiment", "--episodes", "1", "--planner", planners, flag, "0.4",
                                     "--out", str(out))
    assert_one_line_error(status, stdout, stderr, f"{flag} ", readers)
    assert not out.exists()
