"""Resampling (cdf_mj.inference.resampling): identical to filterpy's given the same uniforms."""

from __future__ import annotations

import statistics
import time

import numpy as np
import pytest
from filterpy.monte_carlo import resampling as fp_resampling
from filterpy.monte_carlo import stratified_resample as fp_stratified
from filterpy.monte_carlo import systematic_resample as fp_systematic

from cdf_mj.inference.resampling import (
    effective_sample_size,
    stratified_indexes_from_uniforms,
    stratified_resample,
    systematic_indexes_from_uniform,
    systematic_resample,
)


def _weight_sets(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    sets = {"uniform": np.full(n, 1.0 / n)}
    for at in {0, n // 2, n - 1}:
        sets[f"one-hot at {at}"] = np.eye(n)[at]
    w = rng.random(n)
    sets["random"] = w / w.sum()
    if n > 1:
        w = rng.random(n) * (rng.random(n) < 0.4)
        w[0] = w[-1] = 0.0  # zeros at both ends too
        w[n // 2] = 1.0
        sets["random with zeros"] = w / w.sum()
    return sets


@pytest.mark.parametrize("n", [1, 7, 1000])
def test_stratified_matches_filterpy(n):
    """filterpy draws ``(random(N) + range(N)) / N`` from NumPy's global state: re-seed,
    draw the same uniforms and the indexes agree exactly; so do the systematic ones."""
    rng = np.random.default_rng(n)
    state = np.random.get_state()  # noqa: NPY002
    try:
        for name, w in _weight_sets(n, rng).items():
            for seed in range(5):
                np.random.seed(seed)  # noqa: NPY002
                expected = fp_stratified(w)
                np.random.seed(seed)  # noqa: NPY002
                ours = stratified_indexes_from_uniforms(w, np.random.random(n))  # noqa: NPY002
                assert np.array_equal(ours, expected), (name, seed)
                assert np.all(w[ours] > 0)  # zero-weight particles are never kept
                np.random.seed(seed)  # noqa: NPY002
                expected = fp_systematic(w)
                np.random.seed(seed)  # noqa: NPY002
                assert np.array_equal(systematic_indexes_from_uniform(w, np.random.random()),  # noqa: NPY002
                                      expected), (name, seed)
    finally:
        np.random.set_state(state)  # noqa: NPY002


def test_ties_on_slice_boundaries_skip_zero_weights(monkeypatch):
    """A position exactly on a cumulative sum belongs to the next slice (filterpy's
    ``u < C_j``), so zero-weight particles are skipped even then."""
    monkeypatch.setattr(fp_resampling, "random", lambda n: np.zeros(n))
    for w in (np.array([0.5, 0.0, 0.5]), np.array([0.0, 0.25, 0.0, 0.75]),
              np.array([0.0, 0.0, 1.0, 0.0])):
        ours = stratified_indexes_from_uniforms(w, np.zeros(len(w)))
        assert np.array_equal(ours, fp_stratified(w))
        assert np.all(w[ours] > 0)
        assert np.array_equal(systematic_indexes_from_uniform(w, 0.0), ours)
    idx = stratified_indexes_from_uniforms(np.array([0.5, 0.0, 0.5]), np.zeros(3))
    assert list(idx) == [0, 0, 2]


def test_unnormalised_weights_are_normalised(monkeypatch):
    w = np.array([0.0, 3.0, 1.0, 0.0, 4.0])
    u = np.random.default_rng(0).random(5)
    assert np.array_equal(stratified_indexes_from_uniforms(w, u),
                          stratified_indexes_from_uniforms(w / 8.0, u))
    # The largest uniform: (4 + (1 - 2**-53)) / 5 rounds to 1.0, yet the index stays on
    # the last particle with weight (filterpy's loop runs off the end there).
    top = np.nextafter(1.0, 0.0)
    assert (4 + top) / 5 == 1.0
    assert stratified_indexes_from_uniforms(w, np.full(5, top))[-1] == 4
    assert systematic_indexes_from_uniform(w, top)[-1] == 4
    w[-1] = 0.0
    assert stratified_indexes_from_uniforms(w, np.full(5, top))[-1] == 2
    # filterpy's loop, fed the same uniforms (its module-level `random`), runs off the end.
    monkeypatch.setattr(fp_resampling, "random", lambda n: np.full(n, top))
    with pytest.raises(IndexError):
        fp_stratified(np.full(5, 0.2))


def test_counts_stay_near_n_w():
    """Systematic: each count is floor or ceil of N w_i. Stratified: within 2 (not 1:
    see the next test), and N w_i on average."""
    rng = np.random.default_rng(11)
    n = 50
    mean_counts = np.zeros(n)
    draws = 400
    for trial in range(draws):
        w = rng.random(n) ** 3
        w /= w.sum()
        if trial == 0:
            w_fixed = w
        counts = np.bincount(stratified_resample(w, rng), minlength=n)
        assert np.all(np.abs(counts - n * w) < 2)
        sys_counts = np.bincount(systematic_resample(w, rng), minlength=n)
        assert np.all(sys_counts >= np.floor(n * w - 1e-9))
        assert np.all(sys_counts <= np.ceil(n * w + 1e-9))
        mean_counts += np.bincount(stratified_resample(w_fixed, rng), minlength=n)
    mean_counts /= draws
    # Unbiased: sd of a stratified count is <= ~0.8, so of the mean <= 0.04.
    np.testing.assert_allclose(mean_counts, n * w_fixed, atol=0.2)


def test_stratified_count_can_differ_from_n_w_by_more_than_one():
    """N w = 0.75 but the particle is drawn twice: both neighbouring strata land in it."""
    w = np.array([0.5, 0.25, 0.25])
    idx = stratified_indexes_from_uniforms(w, np.array([0.5, 0.9, 0.1]))
    assert list(idx) == [0, 1, 1]


def test_generator_seed_reproduces():
    w = np.random.default_rng(5).random(1000)
    a = stratified_resample(w, np.random.default_rng(42))
    b = stratified_resample(w, np.random.default_rng(42))
    c = stratified_resample(w, np.random.default_rng(43))
    assert a.shape == (1000,) and np.issubdtype(a.dtype, np.integer)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert np.all(np.diff(a) >= 0)  # positions increase, so do the indexes
    assert np.array_equal(systematic_resample(w, np.random.default_rng(1)),
                          systematic_resample(w, np.random.default_rng(1)))


def test_effective_sample_size():
    rng = np.random.default_rng(2)
    for n in (1, 7, 1000):
        assert effective_sample_size(np.full(n, 1.0 / n)) == pytest.approx(n)
        assert effective_sample_size(np.full(n, 3.0)) == pytest.approx(n)  # unnormalised
        assert effective_sample_size(np.eye(n)[n - 1]) == 1.0
        ess = effective_sample_size(rng.random(n))
        assert 1.0 <= ess <= n
    assert effective_sample_size(np.array([0.5, 0.5, 0.0, 0.0])) == pytest.approx(2.0)


@pytest.mark.parametrize(("weights", "match"), [
    (np.ones((2, 2)), "1-D"),
    (np.array([]), "non-empty"),
    (np.array([0.5, np.nan]), "finite"),
    (np.array([0.5, np.inf]), "finite"),
    (np.array([0.5, -0.1, 0.6]), "non-negative"),
    (np.zeros(4), "positive finite sum"),
    (np.array([1e308, 1e308]), "positive finite sum"),
])
def test_bad_weights_are_rejected(weights, match):
    rng = np.random.default_rng(0)
    for call in (lambda: stratified_resample(weights, rng),
                 lambda: systematic_resample(weights, rng),
                 lambda: stratified_indexes_from_uniforms(weights, np.zeros(weights.shape[:1]))):
        with pytest.raises(ValueError, match=match):
            call()
    with pytest.raises(ValueError, match=match):
        effective_sample_size(weights)


def test_bad_uniforms_are_rejected():
    w = np.full(3, 1 / 3)
    with pytest.raises(ValueError, match="3 uniforms"):
        stratified_indexes_from_uniforms(w, np.zeros(2))
    with pytest.raises(ValueError, match=r"\[0, 1\)"):
        stratified_indexes_from_uniforms(w, np.array([0.0, 1.0, 0.5]))
    with pytest.raises(ValueError, match=r"\[0, 1\)"):
        systematic_indexes_from_uniform(w, -0.1)


def _median_time(fn, repeats=50):
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def test_faster_than_filterpy():
    """N = 1000: vectorised searchsorted vs filterpy's Python loop (~20 vs ~300 us)."""
    w = np.random.default_rng(3).random(1000)
    w /= w.sum()
    rng = np.random.default_rng(0)
    ours = _median_time(lambda: stratified_resample(w, rng))
    theirs = _median_time(lambda: fp_stratified(w), repeats=10)
    assert ours < theirs
