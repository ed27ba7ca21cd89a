"""The adaptive particle count (KLD-sampling, ``CDFConfig.adaptive``): its bound, its
resampling, and the filter's count in real MuJoCo episodes, where the measurement pins the
other car's pose and where an occluded ego's hypotheses spread along a hidden approach."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from cdf_mj.cli import main
from cdf_mj.config import AdaptiveConfig, CDFConfig
from cdf_mj.inference import kernels
from cdf_mj.planners import CDFPlanner
from cdf_mj.presets import load_preset
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

Z99 = 2.3263478740408408  # the standard normal's 0.99 quantile


class Counts:
    """An episode observer: the filter's particle count after every tick."""

    def __init__(self, planner: CDFPlanner) -> None:
        self.planner, self.n = planner, []

    def __call__(self, step) -> None:
        self.n.append(self.planner.filter.n)


def test_bound_grows_with_the_bins_and_tightness():
    """Fox's bound: none for one bin, more particles for more bins and for a smaller epsilon;
    with 2 bins at epsilon 0.05 and 99 % it asks for the chi-square(1) 0.99 quantile / 0.1
    (6.63 / 0.1 = 66; Wilson-Hilferty's approximation is within 1 % there)."""
    assert kernels.kld_bound(1, 0.05, Z99) == 0.0
    values = [kernels.kld_bound(k, 0.05, Z99) for k in range(2, 200)]
    assert all(b > a for a, b in itertools.pairwise(values))
    assert kernels.kld_bound(20, 0.02, Z99) > kernels.kld_bound(20, 0.05, Z99)
    assert kernels.kld_bound(2, 0.05, Z99) == pytest.approx(6.635 / 0.1, rel=0.01)


def test_few_bins_resample_n_min_draw_for_draw():
    """Where the particles fill few bins, KLD-resampling is stratified resampling of n_min
    particles with the same uniforms; where they spread over many, it keeps more, up to
    n_max, drawn from the same weights."""
    rng = np.random.default_rng(3)
    n = 800
    w = rng.random(n)
    w /= w.sum()
    mode, intent, has = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool)
    standing = np.tile([5.0, 2.0, 0.3, 0.0], (n, 1))
    keep = kernels.kld_resample(np.random.default_rng(9), w, standing, mode, intent, has, 0.5, 0.5, 0.05, Z99,
                                100, 4000)
    assert np.array_equal(keep, kernels.resample_to(np.random.default_rng(9), w, 100))
    spread = standing.copy()
    spread[:, 0] = np.linspace(0.0, 400.0, n)  # 800 bins of 0.5 m
    keep = kernels.kld_resample(np.random.default_rng(9), w, spread, mode, intent, has, 0.5, 0.5, 0.05, Z99,
                                100, 4000)
    assert 1000 < len(keep) <= 4000 and keep.min() >= 0 and keep.max() < n
    assert np.array_equal(kernels.resample_to(np.random.default_rng(1), w, n),
                          kernels.resample_indexes(w, np.random.default_rng(1).random(n)))


def test_config_checks_and_reads_back():
    cdf = CDFConfig(n_particles=2000, adaptive=AdaptiveConfig(n_min=300))
    assert CDFConfig(**{**cdf.__dict__, "adaptive": cdf.adaptive.to_dict()}) == cdf
    with pytest.raises(ValueError, match=r"adaptive\.n_min"):
        CDFConfig(n_particles=200, adaptive=AdaptiveConfig(n_min=300))
    with pytest.raises(ValueError, match=r"adaptive\.epsilon"):
        AdaptiveConfig(epsilon=0.0)
    with pytest.raises(ValueError, match=r"adaptive\.n_min"):
        AdaptiveConfig(n_min=0)
    with pytest.raises(ValueError, match="adaptive"):
        CDFConfig(adaptive="kld")


def test_count_follows_the_spread_of_the_hypotheses():
    """Default world: the prior starts at n_max; after the first resampling the measurement
    pins the waiting car's pose and the filter keeps n_min. An occluded ego that starts without the other car in sight:
    its hypotheses spread along the hidden approach and it keeps more, back to n_min once
    the car is measured. Both runs reproduce record for record."""
    cdf = CDFConfig(n_particles=3000, adaptive=AdaptiveConfig(n_min=400))
    planner = CDFPlanner(cdf)
    counts = Counts(planner)
    run_episode(None, 5, planner, label=False, observers=[counts])
    assert counts.n[0] == 3000 and counts.n[1] == 400 and min(counts.n) == 400
    config = load_preset("stress-occluded-rolling-stop")
    scene = Scene.load(names=config.names)
    seeds = []
    for seed in range(830000, 830012):
        planner = CDFPlanner(cdf)
        counts = Counts(planner)
        record = run_episode(config, seed, planner, scene, label=False, observers=[counts])
        if record.world.get("occluded", 0) > 0:
            seeds.append((seed, record, counts.n))
    assert seeds, "no episode started with the other car out of sight"
    seed, record, n = seeds[0]
    assert n[1] > 400 and n[-1] == 400
    again = run_episode(config, seed, CDFPlanner(cdf), scene, label=False)
    assert again.to_dict() == record.to_dict()


def test_the_command_line_sets_it_and_refuses_a_floor_above_the_most(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["experiment", "--episodes", "1", "--planner", "cdf", "--particles", "600", "--adaptive-particles",
                 "150", "--out", str(out), "--workers", "1", "--quiet"]) == 0
    settings = json.loads((out / "settings.json").read_text())
    assert settings["cdf"]["n_particles"] == 600 and settings["cdf"]["adaptive"]["n_min"] == 150
    capsys.readouterr()
    assert main(["experiment", "--episodes", "1", "--planner", "cdf", "--particles", "600", "--adaptive-particles",
                 "700", "--out", str(tmp_path / "bad"), "--workers", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["cdf-mj: error: --adaptive-particles 700 is more than --particles 600, the most the adaptive "
                   "count may reach"]
    assert not (tmp_path / "bad").exists()
    assert main(["sweep", "particles", "--values", "100,400", "--episodes", "1", "--planner", "cdf",
                 "--adaptive-particles", "200", "--out", str(tmp_path / "sweep"), "--workers", "1", "--quiet",
                 "--no-figure"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "cdf-mj: error: --adaptive-particles 200 is more than the particle count 100 the sweep of particles "
        "reaches (it sweeps the most the adaptive count may reach)"]


def test_bins_count_signed_positions_speeds_and_the_discrete_state():
    """Negative coordinates fall in their own bins (floor, not truncation); each of mode,
    intent and seen splits a bin; a spread of 32 000 bins along one axis is counted fast."""
    xs = np.array([-1.2, -0.6, -0.1, 0.1, 0.6, 1.2])
    pose = np.zeros((6, 4))
    pose[:, 0] = xs
    z6, f6 = np.zeros(6, dtype=np.int64), np.zeros(6, dtype=bool)
    keep = np.arange(6)
    assert kernels.kld_bins(keep, pose, z6, z6, f6, 0.5, 0.5) == 6  # -3, -2, -1, 0, 1, 2
    same = np.zeros((8, 4))
    combos = np.array([(m, i, h) for m in (0, 1) for i in (0, 1) for h in (0, 1)])
    assert kernels.kld_bins(np.arange(8), same, combos[:, 0].copy(), combos[:, 1].copy(), combos[:, 2].astype(bool),
                            0.5, 0.5) == 8
    n = 32000
    line = np.zeros((n, 4))
    line[:, 1] = np.arange(n) * 0.5 + 0.25
    zn = np.zeros(n, dtype=np.int64)
    assert kernels.kld_bins(np.arange(n), line, zn, zn, np.zeros(n, dtype=bool), 0.5, 0.5) == n


def test_the_fixed_count_draws_what_it_drew_before():
    """The fixed count's resampling is the stratified draw then the rejuvenation, the same
    numbers from the same stream as one call (what the records of every shipped page rest on)."""
    rng = np.random.default_rng(11)
    n = 300
    w = rng.random(n)
    theta = rng.random((n, 7))
    mode = rng.integers(0, 4, n)
    intent = rng.integers(0, 2, n)
    std, lo, hi = np.full(6, 0.05), np.zeros(6), np.ones(6)
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    keep, theta_a, intent_a = kernels.resample(a, w, theta, mode, intent, std, lo, hi, 0.3, 0.75)
    keep_b = kernels.resample_to(b, w, n)
    theta_b, intent_b = kernels.rejuvenate(b, keep_b, theta, mode, intent, std, lo, hi, 0.3, 0.75)
    assert np.array_equal(keep, keep_b) and np.array_equal(theta_a, theta_b) and np.array_equal(intent_a, intent_b)
    assert a.random() == b.random()  # the streams end in the same state


@pytest.mark.parametrize("redraw", [True, False])
def test_a_lost_track_reinitialises_at_the_right_count(redraw):
    """Every likelihood vanishes after the count fell to n_min: with the redraw the filter
    starts again from the prior at the most particles; without it the particles keep their
    hypotheses and their count. Either way the next tick runs."""
    from cdf_mj.inference.particle_filter import ParticleFilter
    from cdf_mj.scenario.episode import run_episode as run

    cdf = CDFConfig(n_particles=1200, adaptive=AdaptiveConfig(n_min=300), reinit_redraw=redraw)
    scene = Scene.load()
    poses = np.array(run(None, 1, "constant", scene, label=False, trace=True).trace["poses"])
    pf = ParticleFilter.from_layout(scene.layout(), cdf, np.random.default_rng(0), 0.1)
    pf.reset(poses[0])
    pf.predict(poses[0])
    pf.update(poses[1])
    assert pf.n == 300
    far = poses[2].copy()
    far[1, :2] += 50.0
    pf.predict(poses[1])
    pf.update(far)
    assert pf.reinits == 1 and pf.n == (1200 if redraw else 300)
    pf.predict(far)
    pf.update(far)
    assert len(pf.pose) == len(pf.theta) == pf.n


def test_a_scaled_config_keeps_the_count_and_scales_the_bins():
    from cdf_mj.config import scaled

    small = scaled(CDFConfig(n_particles=2000, adaptive=AdaptiveConfig()), 0.1)
    assert small.n_particles == 2000 and small.adaptive.n_min == 500
    assert small.adaptive.bin_pos == pytest.approx(0.05) and small.adaptive.bin_speed == pytest.approx(0.05)
