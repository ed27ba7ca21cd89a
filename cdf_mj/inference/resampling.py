"""Resampling for the particle filter: stratified (low-variance) and systematic.

Given normalised weights ``w_i`` (i = 0..N-1) with cumulative sums ``C_j = w_0 + ... +
w_j`` (``C_{N-1} = 1``), a resampler draws N positions ``u_i`` in [0, 1) and picks, for
each, the particle whose slice of the cumulative sum holds it:

    index_i = min { j : u_i < C_j }          (``np.searchsorted(C, u, side="right")``)

* stratified: one uniform per stratum, ``u_i = (i + U_i) / N`` with ``U_i ~ U[0, 1)``
  independent;
* systematic: one uniform for all, ``u_i = (i + U) / N``.

Both are unbiased (particle j is picked ``N w_j`` times in expectation). Systematic
resampling picks particle j ``floor(N w_j)`` or ``ceil(N w_j)`` times; stratified picks
it a number of times within 2 (strictly) of ``N w_j``, and with lower variance than
multinomial resampling. A particle of weight zero is never picked.

Weights need not sum to one: they are divided by their cumulative sum's last element
(so already-normalised weights whose running sum ends at exactly 1.0 are used as given,
as ``filterpy.monte_carlo`` does), and that element is exactly 1.0. A position
``(i + U) / N`` can round up to exactly 1.0 for U within ~N ulps of 1; positions are
clamped below 1, so no index runs past the end (filterpy raises IndexError there, as
it can when its running sum ends an ulp short of 1). The same algorithm as
``filterpy.monte_carlo.stratified_resample`` / ``systematic_resample`` (a Python loop
over NumPy's global random state), vectorised and driven by a ``numpy.random.Generator``::

    from cdf_mj.inference.resampling import stratified_resample, effective_sample_size

    if effective_sample_size(w) < 0.5 * len(w):
        idx = stratified_resample(w, rng)      # rng: numpy.random.Generator
        particles, w = particles[idx], np.full(len(w), 1.0 / len(w))
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "effective_sample_size",
    "stratified_indexes_from_uniforms",
    "stratified_resample",
    "systematic_indexes_from_uniform",
    "systematic_resample",
]


def _check_weights(weights: np.ndarray) -> np.ndarray:
    """Weights as a 1-D float array; ValueError if empty, not finite, negative or all
    zero (one reduction on the good path; the message is worked out on the bad one)."""
    w = np.asarray(weights, dtype=float)
    if w.ndim != 1 or len(w) == 0:
        raise ValueError(f"weights must be a non-empty 1-D array, got shape {w.shape}")
    if not w.min() >= 0.0:  # False for NaN too
        _raise_bad(w)
    return w


def _raise_bad(w: np.ndarray) -> None:
    bad = np.count_nonzero(~np.isfinite(w))
    if bad:
        raise ValueError(f"weights must be finite, got {bad} NaN or infinite values")
    if np.any(w < 0):
        raise ValueError(f"weights must be non-negative, got minimum {w.min()!r}")
    with np.errstate(over="ignore"):
        total = w.sum()
    raise ValueError(f"weights must have a positive finite sum, got {total!r}")


def _cumulative(w: np.ndarray) -> np.ndarray:
    """Normalised cumulative sum of checked weights, last element exactly 1.0."""
    with np.errstate(over="ignore"):
        c = np.cumsum(w)
    total = c[-1]
    if not 0.0 < total < np.inf:
        _raise_bad(w)
    if total != 1.0:
        c /= total
    c[-1] = 1.0  # already exact (x / x == 1), kept as the invariant the search relies on
    return c


# The largest double below 1. A position (i + U) / N rounds to exactly 1.0 when U is
# within about N ulps of 1 (e.g. 4 + (1 - 2**-53) == 5.0): clamped here, such a position
# picks the last particle with weight instead of running off the end (filterpy's loop
# raises IndexError there).
_BELOW_ONE = np.nextafter(1.0, 0.0)


def _search(w: np.ndarray, positions: np.ndarray) -> np.ndarray:
    # Positions < 1 = cumulative[-1], so every index is < N; side="right" skips the
    # slices of zero-weight particles (equal consecutive cumulative sums).
    np.minimum(positions, _BELOW_ONE, out=positions)
    return np.searchsorted(_cumulative(w), positions, side="right")


def _stratified(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    n = len(w)
    positions = np.arange(n) + u
    positions /= n  # as filterpy: (U_i + i) / N, bit for bit
    return _search(w, positions)


def stratified_indexes_from_uniforms(weights: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """Stratified resampling given the N uniform draws ``U_i`` in [0, 1): indexes ``(N,)``
    (``np.intp``) of the particles to keep. Deterministic; see the module docstring."""
    w = _check_weights(weights)
    u = np.asarray(uniforms, dtype=float)
    if u.shape != w.shape:
        raise ValueError(f"need {len(w)} uniforms, one per weight, got shape {u.shape}")
    if not (np.all(u >= 0.0) and np.all(u < 1.0)):
        raise ValueError("uniforms must lie in [0, 1)")
    return _stratified(w, u)


def stratified_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Stratified (low-variance) resampling: indexes ``(N,)`` of the particles to keep,
    drawing N uniforms from ``rng`` (``rng.random(N)``)."""
    w = _check_weights(weights)
    return _stratified(w, rng.random(len(w)))


def systematic_indexes_from_uniform(weights: np.ndarray, uniform: float) -> np.ndarray:
    """Systematic resampling given the one uniform draw ``U`` in [0, 1): indexes ``(N,)``."""
    w = _check_weights(weights)
    u = float(uniform)
    if not 0.0 <= u < 1.0:
        raise ValueError(f"the uniform must lie in [0, 1), got {u!r}")
    n = len(w)
    positions = u + np.arange(n)
    positions /= n
    return _search(w, positions)


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: indexes ``(N,)``, one uniform drawn from ``rng``
    (``rng.random()``)."""
    return systematic_indexes_from_uniform(weights, rng.random())


def effective_sample_size(weights: np.ndarray) -> float:
    """Effective sample size ``1 / sum(w_i^2)`` of the normalised weights (unnormalised
    weights are normalised first): N for equal weights, 1 when one particle has all."""
    w = _check_weights(weights)
    with np.errstate(over="ignore"):
        total = w.sum()
    if not 0.0 < total < np.inf:
        _raise_bad(w)
    w = w / total
    # Clipped to [1, N], which rounding could leave by an ulp.
    return float(min(max(1.0 / np.dot(w, w), 1.0), len(w)))
