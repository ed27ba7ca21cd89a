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
over NumPy's global random state), compiled (one walk along ``C``: the search of
:func:`cdf_mj.inference.kernels.resample_indexes`, which the particle filter's own
resampling runs) and driven by a ``numpy.random.Generator``::

    from cdf_mj.inference.resampling import stratified_resample, effective_sample_size

    if effective_sample_size(w) < 0.5 * len(w):
        idx = stratified_resample(w, rng)      # rng: numpy.random.Generator
        particles, w = particles[idx], np.full(len(w), 1.0 / len(w))
"""

from __future__ import annotations

import numpy as np

from cdf_mj.inference import kernels

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


def _indexes(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Indexes for checked weights and uniforms: the compiled search that the particle
    filter's resampling runs too (:func:`cdf_mj.inference.kernels.resample_indexes`)."""
    try:
        out: np.ndarray = kernels.resample_indexes(np.ascontiguousarray(w), np.ascontiguousarray(u, dtype=float))
    except ValueError:
        _raise_bad(w)  # says which: not finite, negative, or no positive finite sum
        raise
    return out


def stratified_indexes_from_uniforms(weights: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """Stratified resampling given the N uniform draws ``U_i`` in [0, 1): indexes ``(N,)``
    (``np.intp``) of the particles to keep. Deterministic; see the module docstring."""
    w = _check_weights(weights)
    u = np.asarray(uniforms, dtype=float)
    if u.shape != w.shape:
        raise ValueError(f"need {len(w)} uniforms, one per weight, got shape {u.shape}")
    if not (np.all(u >= 0.0) and np.all(u < 1.0)):
        raise ValueError("uniforms must lie in [0, 1)")
    return _indexes(w, u)


def stratified_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Stratified (low-variance) resampling: indexes ``(N,)`` of the particles to keep,
    drawing N uniforms from ``rng`` (``rng.random(N)``)."""
    w = _check_weights(weights)
    return _indexes(w, rng.random(len(w)))


def systematic_indexes_from_uniform(weights: np.ndarray, uniform: float) -> np.ndarray:
    """Systematic resampling given the one uniform draw ``U`` in [0, 1): indexes ``(N,)``."""
    w = _check_weights(weights)
    u = float(uniform)
    if not 0.0 <= u < 1.0:
        raise ValueError(f"the uniform must lie in [0, 1), got {u!r}")
    return _indexes(w, np.array([u]))


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
