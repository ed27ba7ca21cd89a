"""The planner registry (names, ``"module:Class"`` targets, pickling, lazy imports) and
the base of deciding planners, on real episodes."""

from __future__ import annotations

import ast
import json
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cdf_mj.planners
from cdf_mj.config import CDFConfig, RiskConfig, ScenarioConfig
from cdf_mj.model.layout import Layout
from cdf_mj.planners import (
    PLANNERS,
    DecidingPlanner,
    LazyPlanner,
    Planner,
    PlannerInput,
    ReactivePlanner,
    base,
    make_planner,
    register,
    registry,
)
from cdf_mj.planners.base import PlannerContext
from cdf_mj.planners.imm import IMMConfig
from cdf_mj.planners.registry import PlannerSpec, bind_planner, planner_arguments, shared_arguments
from cdf_mj.scenario.episode import run_episode


def test_builtin_planners_are_registered_by_name():
    assert {"constant", "reactive", "cdf", "cv", "imm"} <= set(PLANNERS)
    for name in ("constant", "reactive", "cdf", "cv", "imm"):
        planner = make_planner(name)
        assert isinstance(planner, Planner) and planner.name == name
        assert make_planner(name) is not planner  # a fresh one every time
    planner = ReactivePlanner()
    assert make_planner(planner) is planner


def test_a_target_string_is_imported_on_first_use_and_pickles(monkeypatch):
    monkeypatch.setitem(PLANNERS, "twin", PLANNERS["reactive"])
    register("twin", "cdf_mj.planners.simple:ReactivePlanner")
    spec = PLANNERS["twin"]
    assert spec == PlannerSpec("twin", LazyPlanner("cdf_mj.planners.simple:ReactivePlanner"))
    assert isinstance(pickle.loads(pickle.dumps(spec))(), ReactivePlanner)
    assert isinstance(make_planner("twin"), ReactivePlanner)


def test_a_callable_target_is_kept_as_it_is(monkeypatch):
    monkeypatch.setitem(PLANNERS, "mine", PLANNERS["reactive"])
    register("mine", ReactivePlanner)
    assert PLANNERS["mine"].target is ReactivePlanner
    monkeypatch.setitem(PLANNERS, "by-hand", ReactivePlanner)  # version 0.1 let users do this
    assert isinstance(make_planner("by-hand"), ReactivePlanner)


def test_registered_arguments_are_updated_by_the_callers_and_stored_as_json(monkeypatch):
    """``register(name, target, **defaults)`` and ``make_planner(name, **kwargs)`` as
    ``gymnasium.make``; a run's stored arguments rebuild the same planner."""
    monkeypatch.setitem(PLANNERS, "imm-09", PLANNERS["imm"])
    register("imm-09", "cdf_mj.planners.imm:IMMPlanner", params=IMMConfig(threshold=0.9))
    assert make_planner("imm-09").params.threshold == 0.9
    register("imm-09", "cdf_mj.planners.baselines:IMMPlanner", params=IMMConfig(threshold=0.9))  # 0.3's home
    assert make_planner("imm-09").params.threshold == 0.9
    made = make_planner("imm-09", params=IMMConfig(threshold=0.5, p_left=0.4))
    assert (made.params.threshold, made.params.p_left) == (0.5, 0.4)
    stored = json.loads(json.dumps(planner_arguments("cdf", cdf=CDFConfig(n_particles=77, tau=0.7))))
    again = make_planner("cdf", **stored)
    assert again.cdf == CDFConfig(n_particles=77, tau=0.7)
    assert make_planner("cdf-threshold", **stored).cdf.decision == "threshold"
    with pytest.raises(TypeError, match=r"planner 'reactive': ReactivePlanner\(\) takes no arguments"):
        make_planner("reactive", horizon=2.0)
    with pytest.raises(ValueError, match="n_particles"):
        make_planner("cdf", cdf={"n_particles": 0})
    with pytest.raises(TypeError, match=r"cdf: .*unexpected keyword.*CDFConfig fields"):
        make_planner("cdf", cdf={"particles": 10})
    with pytest.raises(TypeError, match=r"arguments .* given with a planner object"):
        make_planner(ReactivePlanner(), horizon=2.0)


def test_the_shared_cdf_settings_go_where_the_registry_says():
    cdf = CDFConfig(n_particles=50, risk=RiskConfig(brake=0.3, release=0.1))
    assert shared_arguments("cdf", cdf) == {"cdf": cdf}
    assert shared_arguments("imm-risk", cdf) == {"risk": cdf.risk}
    assert shared_arguments("imm", cdf) == {} and shared_arguments("reactive", cdf) == {}
    assert bind_planner("cv-risk", cdf)().rule.config == cdf.risk
    assert bind_planner("cv", cdf)().rule.name == "threshold"
    own = {"n_particles": 20}  # a planner's own arguments win over the run's shared ones
    assert bind_planner("cdf", cdf, {"cdf": own})().cdf.n_particles == 20


class _OldStylePlanner(ReactivePlanner):
    def reset(self, layout, config, rng):  # the signature of version 0.1
        super().reset(layout, rng)


def test_a_planner_with_the_old_reset_is_refused_in_one_line(monkeypatch):
    monkeypatch.setitem(PLANNERS, "old", PLANNERS["reactive"])
    register("old", _OldStylePlanner)
    with pytest.raises(TypeError, match=r"reset\(self, layout, config, rng\) is the form of cdf_mj 0.1"):
        make_planner("old")


@pytest.mark.parametrize(("target", "error", "match"), [
    ("cdf_mj.planners.simple", ValueError, "must be 'package.module:ClassName'"),
    (":ReactivePlanner", ValueError, "must be 'package.module:ClassName'"),
    ("cdf_mj.planners.simple:Reactive Planner", ValueError, "must be 'package.module:ClassName'"),
    (42, TypeError, "target must be 'module:Class' or a callable"),
])
def test_bad_targets_are_refused_when_registered(target, error, match):
    before = dict(PLANNERS)
    with pytest.raises(error, match=match):
        register("bad", target)
    assert before == PLANNERS
    with pytest.raises(ValueError, match="non-empty string"):
        register("", "cdf_mj.planners.simple:ReactivePlanner")


def test_a_target_that_cannot_be_imported_says_so(monkeypatch):
    monkeypatch.setitem(PLANNERS, "ghost", PLANNERS["reactive"])
    register("ghost", "cdf_mj.planners.simple:NoSuchPlanner")
    with pytest.raises(ImportError, match=r"'cdf_mj\.planners\.simple:NoSuchPlanner' cannot be imported"):
        make_planner("ghost")
    with pytest.raises(ValueError, match=r"unknown planner 'psychic': choose one of .*reactive"):
        make_planner("psychic")


def _imported(module: object) -> set[str]:
    """The modules a module's source imports (absolute names)."""
    tree = ast.parse(Path(module.__file__).read_text())  # type: ignore[attr-defined]
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    return {m for m in imported | {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names} if m}


def test_the_registry_imports_no_planner_module():
    """registry.py names the planners by string: of the planners it imports only their base;
    base.py does not import the registry (no cycle) and no longer gives its names."""
    assert {m for m in _imported(registry) if m.startswith("cdf_mj.planners")} == {"cdf_mj.planners.base"}
    assert not {m for m in _imported(base) if m.startswith("cdf_mj.planners")}
    assert not hasattr(base, "make_planner")


def _fresh(code: str) -> list[str]:
    """What ``code`` prints in a fresh interpreter, split into words."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.split()


def test_each_baseline_loads_with_its_first_planner():
    """A predictor's module loads with the first planner made of it, not before; filterpy
    (about 1 s to import) only with the IMM's."""
    code = ("import sys, cdf_mj.planners as p\n"
            "def show(): print(*(m in sys.modules for m in ('cdf_mj.planners.cv', 'cdf_mj.planners.imm', "
            "'filterpy')))\n"
            "show(); p.make_planner('cv'); show(); p.make_planner('imm'); show()")
    assert _fresh(code) == ["False", "False", "False", "True", "False", "False", "True", "True", "True"]


def test_the_decision_rules_load_no_filter():
    """Importing the decision rules (or the planners' package) loads neither the particle
    filter and its kernels nor filterpy: their reference (``rollout_assessment``) lives
    apart, in ``cdf_mj.planners.rollout_reference``."""
    code = ("import sys, cdf_mj.planners.decision\n"
            "print(sorted(m for m in sys.modules if m.startswith(('cdf_mj.inference', 'filterpy'))))")
    assert _fresh(code) == ["[]"]


def test_the_package_gives_the_baselines_on_first_access():
    assert cdf_mj.planners.IMMPlanner().name == "imm"
    assert cdf_mj.planners.CVConfig().horizon > 0
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        _ = cdf_mj.planners.Nope


class _BrakesLate(DecidingPlanner):
    """Wants to brake from t = 0.5 s to t = 0.7 s only; records its measured obstacle speed."""

    name = "late"
    history_keys = ("p_left", "speed")

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        super().reset(context, rng)
        self.layout = context.layout

    def observe(self, obs: PlannerInput) -> None:
        self.record(obs.t, p_left=0.123456789, speed=obs.poses[1, 3])
        self._alarm = 1.0 if 0.45 < obs.t < 0.75 else 0.0

    def alarm(self) -> float:
        return self._alarm


def test_a_deciding_planner_latches_its_first_yes_and_keeps_a_history(scene):
    planner = _BrakesLate()
    rec = run_episode(ScenarioConfig(), seed=4, planner=planner, scene=scene, label=False, trace=True)
    assert isinstance(planner.layout, Layout) and planner.layout is scene.layout()
    assert rec.brake_time == 0.5 and all(rec.trace["brake"][5:]) and not any(rec.trace["brake"][:5])
    info = rec.planner_info
    assert info["decision_time"] == 0.5 and info["prediction"] == "Cutoff"
    history = info["history"]
    assert history["t"] == rec.trace["t"]
    assert set(history["p_left"]) == {0.12346}  # rounded to 5 decimals
    assert len(history["speed"]) == len(history["t"])
    planner.reset(PlannerContext.of(scene.layout(), ScenarioConfig()), np.random.default_rng(0))  # forgets the episode
    assert planner.decision_time is None and planner.history == {"t": [], "p_left": [], "speed": []}
