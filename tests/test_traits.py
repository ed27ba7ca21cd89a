"""The obstacle driver's traits (cdf_mj.traits): one schema, and everything derived from it
lands where the code reads it.

Distinct sentinel values are packed by name and read back at the index constants that the
compiled kernels use (the driver's and the filter's float vectors, the per-car parameter
columns, the particles' theta), the world's driver and the filter's prior are built from
the schema's names, and the clear rule, run compiled, reads the traits it is given by
name. The kernel files' LAYOUT stamps (Numba's cache key) must be current.
"""

from __future__ import annotations

import dataclasses
import math
import re
import subprocess
import sys

import numpy as np
import pytest

from cdf_mj.config import CDFConfig, DriverPrior, Observation, ObstacleDriver, ProcessNoise, Pursuit, ScenarioConfig
from cdf_mj.inference import kernels as filter_kernels
from cdf_mj.inference.particle_filter import ParticleFilter, draw_parameters
from cdf_mj.model import kernels as model_kernels
from cdf_mj.model.driver import DriverModel, DriverParams, road_clear
from cdf_mj.traits import PER_CAR, PRIOR_RANGES, SHARED, THETA, TRAITS, with_traits

# The index constants of the kernels and the names they must read.
DRIVER_INDEXES = {"C_DT": "dt", "C_WHEELBASE": "wheelbase", "C_MAX_STEER": "max_steer", "C_MAX_BRAKE": "max_brake",
                  "C_LOOKAHEAD": "lookahead", "C_GAIN": "lookahead_gain", "C_PASSED": "passed_margin",
                  "C_CX": "conflict_x", "C_CY": "conflict_y", "C_COMMIT": "s_commit_left"}
EGO_INDEXES = {"E_LOOKAHEAD": "lookahead", "E_GAIN": "lookahead_gain", "E_WHEELBASE": "wheelbase",
               "E_MAX_STEER": "max_steer", "E_SPEED": "speed", "E_SPEED_GAIN": "speed_gain",
               "E_MAX_BRAKE": "max_brake", "E_MAX_ACCEL": "max_accel"}
FILTER_INDEXES = {"F_JUMP": "mode_jump", "F_ACC_LO": "accel_lo", "F_ACC_HI": "accel_hi", "F_STEER_LO": "steer_lo",
                  "F_STEER_HI": "steer_hi", "F_NU_A": "nu_accel", "F_NU_S": "nu_steer", "F_OBS_POS": "obs_pos",
                  "F_OBS_HEAD": "obs_heading", "F_OBS_SPEED": "obs_speed", "F_EYE_X": "eye_x", "F_EYE_Y": "eye_y",
                  "F_S_ENTER": "s_enter", "F_STOP_MARGIN": "stop_margin", "F_CLEAR_MARGIN": "clear_margin",
                  "F_EGO_BRAKE": "ego_brake", "F_EGO_LATENCY": "ego_latency", "F_T_SLOWEST": "t_slowest",
                  "F_PAPER": "paper_rule", "F_REINIT": "reinit_maha2"}
PARAM_INDEXES = {"P_ACCEL": "accel", "P_TURN": "turn_speed", "P_YIELD": "yield_brake", "P_GAP": "critical_gap",
                 "P_CLEAR": "clear_distance"}
THETA_INDEXES = {"T_ACCEL": "accel", "T_TURN": "turn_speed", "T_YIELD": "yield_brake", "T_GAP": "critical_gap",
                 "T_CLEAR": "clear_distance", "T_BETA": "beta", "T_PGO": "p_go"}


def _sentinels(fields: tuple[str, ...]) -> dict[str, float]:
    """A distinct value per name."""
    return {name: 1000.0 + 7.0 * i for i, name in enumerate(fields)}


# ------------------------------------------------------------------ one schema, everywhere
def test_the_world_the_prior_and_the_columns_are_the_schemas():
    names = [t.name for t in TRAITS]
    world = ObstacleDriver()
    # The traits, then the choice of driver (family: not a trait of any one driver).
    assert [f.name for f in dataclasses.fields(ObstacleDriver)] == [*names, "family"]
    assert [getattr(world, t.name) for t in TRAITS] == [t.default for t in TRAITS]
    assert [f.name for f in dataclasses.fields(ScenarioConfig().obstacle)] == [*names, "family"]
    modelled = [t.name for t in TRAITS if t.prior is not None]
    prior = DriverPrior()
    assert [f.name for f in dataclasses.fields(DriverPrior)][:len(modelled)] == modelled
    assert [getattr(prior, n) for n in modelled] == [t.prior for t in TRAITS if t.prior is not None]
    assert [f.name for f in dataclasses.fields(DriverParams)] == list(PER_CAR)
    # the orders agree: theta starts with the per-car columns, then the other ranges, then p_go
    assert THETA[:len(PER_CAR)] == PER_CAR and THETA[-1] == "p_go"
    assert set(THETA[:-1]) == set(PRIOR_RANGES)
    assert all(name in model_kernels.DRIVER_FIELDS for name in SHARED)


def test_sentinels_packed_by_name_are_read_back_at_the_kernels_indexes():
    driver = _sentinels(model_kernels.DRIVER_FIELDS)
    cfg = model_kernels.pack_driver(driver)
    for const, name in DRIVER_INDEXES.items():
        assert cfg[getattr(model_kernels, const)] == driver[name], const
    assert cfg[model_kernels.C_COMMIT + 1] == driver["s_commit_right"]  # C_COMMIT + intent
    ego = _sentinels(model_kernels.EGO_FIELDS)
    car = model_kernels.pack_ego(ego)
    for const, name in EGO_INDEXES.items():
        assert car[getattr(model_kernels, const)] == ego[name], const
    every = _sentinels(model_kernels.DRIVER_FIELDS + filter_kernels.FILTER_FIELDS)
    full = filter_kernels.pack_filter(every)
    for const, name in {**DRIVER_INDEXES, **FILTER_INDEXES}.items():
        module = filter_kernels if const.startswith("F_") else model_kernels
        assert full[getattr(module, const)] == every[name], const
    params = DriverParams(**_sentinels(PER_CAR)).rows(3)
    for const, name in PARAM_INDEXES.items():
        assert (params[:, getattr(model_kernels, const)] == _sentinels(PER_CAR)[name]).all(), const
    for const, name in THETA_INDEXES.items():
        assert getattr(filter_kernels, const) == THETA.index(name), const


def test_every_index_constant_is_checked_here():
    """A new constant in a kernel module must be added to the tables above."""
    seen = {n for n in dir(model_kernels) if n[:2] in ("C_", "E_", "P_") and n[2:].isupper()}
    seen |= {n for n in dir(filter_kernels) if n[:2] in ("F_", "T_") and n[2:].isupper()}
    assert seen == set(DRIVER_INDEXES) | set(EGO_INDEXES) | set(PARAM_INDEXES) | set(FILTER_INDEXES) | set(
        THETA_INDEXES)


def test_pack_refuses_a_missing_or_unknown_name():
    values = _sentinels(model_kernels.DRIVER_FIELDS)
    with pytest.raises(ValueError, match=r"missing \['dt'\]"):
        model_kernels.pack_driver({k: v for k, v in values.items() if k != "dt"})
    with pytest.raises(ValueError, match=r"unknown \['reaction_time'\]"):
        model_kernels.pack_driver({**values, "reaction_time": 1.0})


def test_the_world_and_the_filter_pack_their_own_values_by_name(scene):
    """The world's driver model packs the world's traits; the filter's packs its prior's,
    its own noise and the planner's tick, never the world's."""
    layout = scene.layout()
    world = ObstacleDriver(**{n: 1.0 + 0.25 * i for i, n in enumerate(PER_CAR)}, passed_margin=4.5)
    model = DriverModel.from_layout(layout, world, Pursuit(lookahead=2.5, lookahead_gain=0.2), 0.05)
    assert model.cfg[model_kernels.C_PASSED] == 4.5 and model.cfg[model_kernels.C_DT] == 0.05
    assert model.cfg[model_kernels.C_LOOKAHEAD] == 2.5 and model.cfg[model_kernels.C_GAIN] == 0.2
    row = model.param_rows(1)[0]
    for const, name in PARAM_INDEXES.items():
        assert row[getattr(model_kernels, const)] == getattr(world, name)

    prior = DriverPrior(passed_margin=2.25, departure_hazard=(2.0, 2.0),
                        observation=Observation(pos=0.7, heading=0.03, speed=0.9),
                        pursuit=Pursuit(lookahead=3.5, lookahead_gain=0.4),
                        **{n: (0.5 + 0.01 * j, 0.5 + 0.01 * j) for j, n in enumerate(THETA[:-1])})
    cdf = CDFConfig(n_particles=5, prior=prior, process_noise=ProcessNoise(accel=0.2, steer=0.02))
    pf = ParticleFilter.from_layout(layout, cdf, np.random.default_rng(0), 0.2)
    cfg = pf._cfg
    assert (cfg[model_kernels.C_PASSED], cfg[model_kernels.C_DT]) == (2.25, 0.2)
    assert (cfg[model_kernels.C_LOOKAHEAD], cfg[model_kernels.C_GAIN]) == (3.5, 0.4)
    assert (cfg[filter_kernels.F_OBS_POS], cfg[filter_kernels.F_OBS_HEAD], cfg[filter_kernels.F_OBS_SPEED]) == (
        0.7, 0.03, 0.9)
    assert cfg[filter_kernels.F_NU_A] == 1.5 * 0.2 and cfg[filter_kernels.F_NU_S] == 1.5 * 0.02
    theta = draw_parameters(prior, 4, 0.2, np.random.default_rng(1))
    for j, name in enumerate(THETA[:-1]):
        assert (theta[:, j] == 0.5 + 0.01 * j).all(), name
    assert theta[:, filter_kernels.T_PGO] == pytest.approx(-math.expm1(-2.0 * 0.2))


def test_the_compiled_clear_rule_reads_each_trait_by_name(scene):
    """The clear rule (compiled) with a passed margin, a clear distance and a critical gap
    of distinct values: each decides where only it should."""
    layout = scene.layout()
    world = ObstacleDriver(passed_margin=2.0, clear_distance=12.0, critical_gap=3.0)
    model = DriverModel.from_layout(layout, world, Pursuit(), 0.1)
    route = layout.route_ego
    s_conflict = route.project(layout.conflict)[0]
    before, after = route.point_at(np.array([s_conflict - 0.5, s_conflict + 0.5]))
    theta = math.atan2(after[1] - before[1], after[0] - before[0])  # the ego's heading there (a straight road)

    def clear(distance_before: float, speed: float) -> bool:
        xy = route.point_at(np.array([s_conflict - distance_before]))[0]
        belief = np.array([[xy[0], xy[1], theta, speed]])
        return bool(road_clear(model, belief, np.array([True]), np.array([0]))[0])

    assert clear(-2.5, 10.0) and not clear(-1.5, 10.0)  # past by more / less than passed_margin 2 m
    assert not clear(11.0, 0.1) and clear(13.0, 0.1)  # nearer / further than clear_distance 12 m
    assert not clear(13.0, 5.0) and clear(16.0, 5.0)  # 2.6 s / 3.2 s away: gap 3 s


# ------------------------------------------------------------------ the schema's rules
@pytest.mark.parametrize("t", TRAITS, ids=[t.name for t in TRAITS])
def test_every_trait_is_checked_against_its_range_in_the_world_and_the_prior(t):
    bad = t.range.high * 2 + 1.0
    value = (bad, bad) if t.range.pair else bad
    with pytest.raises(ValueError, match=rf"obstacle\.{t.name}=.*" + re.escape(t.range.allowed())):
        ObstacleDriver(**{t.name: value})
    if t.prior is not None:
        with pytest.raises(ValueError, match=rf"DriverPrior\.{t.name}="):
            DriverPrior(**{t.name: (bad, bad) if isinstance(t.prior, tuple) else bad})


def test_a_class_may_not_declare_a_trait_itself():
    with pytest.raises(TypeError, match="'accel' is a trait"):
        @dataclasses.dataclass(frozen=True)
        @with_traits("world")
        class Driver:
            accel: float = 1.0


def test_the_kernel_layout_stamps_are_current():
    """Numba's cache keys a kernel on its file's text: each kernel file carries the digest
    of the names its index constants come from, so that a new layout recompiles."""
    for module in (model_kernels, filter_kernels):
        digest = model_kernels.layout_digest(*module.LAYOUTS)
        assert digest == module.LAYOUT, (f"the layout of {module.__name__} changed: set LAYOUT = {digest!r} in "
                                         f"{module.__file__} so that Numba recompiles its kernels")
        assert module.CACHE, f"{module.__name__} compiles without Numba's cache"


_CHANGED_LAYOUT = """
import warnings
import cdf_mj.traits as traits
traits.THETA = (*traits.THETA, "a_new_column")  # a schema change the stamp does not know
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    from cdf_mj.inference import kernels
print(kernels.CACHE, any("compiling without Numba's cache" in str(w.message) for w in caught))
"""


def test_a_layout_the_stamp_does_not_know_never_reads_a_stale_kernel():
    """A schema change whose stamp was not updated compiles without the cache (and warns),
    so no kernel compiled for the old offsets is loaded."""
    out = subprocess.run([sys.executable, "-c", _CHANGED_LAYOUT], capture_output=True, text=True, timeout=120,
                         check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "True"]
