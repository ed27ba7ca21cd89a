"""How likely is a failure per encounter? Plain Monte Carlo and importance sampling by
the cross-entropy method, over a space's nominal distribution
(:class:`~cdf_mj.falsify.space.SearchSpace`: each dimension drawn independently from its
declared nominal, the rest of the world from the episode's seed).

**Monte Carlo** (:func:`monte_carlo`): ``n`` points of the nominal, one episode each;
the failure rate with its 95 % Wilson interval. It sees nothing below about ``3 / n``.

**Cross-entropy importance sampling** (:func:`cross_entropy`; Rubinstein and Kroese,
*The Cross-Entropy Method*, 2004; de Boer et al. 2005): a proposal of the same form as
the nominal (a truncated normal per range, a categorical per choice) is moved towards
failures in stages: each stage draws ``stage`` points, takes the ``rho`` share with the
least robustness as its elite (its failures alone once there are ``min_failures`` of
them: where near misses of one kind are far likelier than failures of another, a
quantile of the robustness would stay on the near misses), and refits the proposal to
them, each weighted by its likelihood ratio nominal / proposal: a dimension whose elite
does not differ clearly from the nominal stays at the nominal (so that the many
dimensions a failure does not depend on add no spread to the weights); another is fitted
by the method of moments of its family, smoothed by ``smoothing``, a range's std kept
above 5 % of its width, a choice above 5 % of an equal share. Once a stage's failures
are a ``rho`` share of it (or after ``max_stages``), the rest of the budget is drawn from
the defensive mixture ``(1 - defensive) proposal + defensive nominal`` (Hesterberg 1995),
whose weights ``w = nominal / mixture`` are at most ``1 / defensive``. The estimate is
the mean of ``w * failed`` over that last stage, with a normal 95 % interval (standard
error of the weighted mean), the effective sample size of the failures' weights (Kish:
``(sum w)^2 / sum w^2``), the relative standard error, and the largest single failure's
share of the estimate; below an effective sample size of 10, or with one failure
carrying over a quarter, the interval is optimistic and the estimate is marked not
reliable (:attr:`Estimate.reliable`). No failure in the last stage gives 0 with the
bound ``3 / (n * defensive)`` (the rule of three on the mixture). At least
:data:`MIN_CE_BUDGET` episodes. An estimate of either method in which any episode raised
(counted as no failure) is not reliable either, and says how many raised.

The same command resumes a killed run: the points are drawn from generators seeded by
the run's seed and stage, the fits are made from the journal's numbers, so it repeats no
episode and gives the same estimate. Another budget draws another sample (the stages'
sizes and the points depend on it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cdf_mj.analysis.metrics import wilson_interval
from cdf_mj.falsify.evaluate import Evaluator, episode_seed
from cdf_mj.falsify.space import (
    Choice,
    Range,
    SearchSpace,
    truncnorm_logpdf,
    truncnorm_matching,
    truncnorm_moments,
    truncnorm_sample,
)

__all__ = ["MIN_CE_BUDGET", "Estimate", "Mixture", "Proposal", "agree", "cross_entropy", "monte_carlo"]

Z95 = 1.959963984540054
#: Least std of a fitted range, as a share of its width (a proposal never collapses to a point).
MIN_STD_SHARE = 0.05
#: Least probability of a choice in a fitted proposal, as a share of 1 / (its values).
MIN_CHOICE_SHARE = 0.05
#: Most choice dimensions that tell the mixture estimator's failure modes apart.
MODE_CHOICES = 2
#: Least budget of the cross-entropy estimator [episodes]: one adaptive stage of 50 and a
#: last stage of at least a fifth of the budget.
MIN_CE_BUDGET = 100


@dataclass(frozen=True)
class Proposal:
    """A product distribution over a space: per range ``(mean, std)`` of a normal truncated
    to the range (``std`` infinite: uniform), per choice its probabilities."""

    params: tuple[Any, ...]

    @classmethod
    def nominal(cls, space: SearchSpace) -> Proposal:
        """The space's declared nominal distribution."""
        return cls(tuple(d.nominal_mean_std() if isinstance(d, Range) else np.array(d.weights)
                         for d in space.dims))

    def sample(self, space: SearchSpace, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` points, shape ``(n, d)``."""
        cols = []
        for d, p in zip(space.dims, self.params, strict=True):
            if isinstance(d, Range):
                cols.append(truncnorm_sample(rng, n, p[0], p[1], d.low, d.high))
            else:
                cols.append(rng.choice(len(p), size=n, p=p).astype(float))
        return np.column_stack(cols) if cols else np.zeros((n, 0))

    def logpdf(self, space: SearchSpace, points: np.ndarray) -> np.ndarray:
        """Log density (ranges) times probability (choices) of each point."""
        out = np.zeros(len(points))
        for j, (d, p) in enumerate(zip(space.dims, self.params, strict=True)):
            x = points[:, j]
            if isinstance(d, Range):
                out += truncnorm_logpdf(x, p[0], p[1], d.low, d.high)
            else:
                with np.errstate(divide="ignore"):
                    out += np.log(p[np.clip(np.rint(x).astype(int), 0, len(p) - 1)])
        return out

    def to_dict(self, space: SearchSpace) -> dict[str, Any]:
        """Option key -> its distribution (a range's ``mean``/``std``, None: uniform; a
        choice's probability of each value), for estimate.json."""
        out: dict[str, Any] = {}
        for d, p in zip(space.dims, self.params, strict=True):
            if isinstance(d, Range):
                out[d.key] = {"mean": p[0], "std": p[1] if math.isfinite(p[1]) else None}
            else:
                out[d.key] = {str(v): float(q) for v, q in zip(d.values, p, strict=True)}
        return out


@dataclass(frozen=True)
class Mixture:
    """A mixture of :class:`Proposal` components (one per failure mode) with ``weights``
    summing to 1; :meth:`sample` and :meth:`logpdf` as a proposal's."""

    components: tuple[Proposal, ...]
    weights: tuple[float, ...]

    def sample(self, space: SearchSpace, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` points, shape ``(n, d)``: each from a component drawn by its weight."""
        which = rng.choice(len(self.components), size=n, p=np.asarray(self.weights))
        out = np.zeros((n, len(space.dims)))
        for k, comp in enumerate(self.components):
            idx = np.flatnonzero(which == k)
            if len(idx):
                out[idx] = comp.sample(space, rng, len(idx))
        return out

    def logpdf(self, space: SearchSpace, points: np.ndarray) -> np.ndarray:
        """Log density of the mixture at each point."""
        logs = [math.log(w) + c.logpdf(space, points) for c, w in zip(self.components, self.weights, strict=True)]
        return np.logaddexp.reduce(np.stack(logs), axis=0)

    def to_dict(self, space: SearchSpace) -> list[dict[str, Any]]:
        """Each component's weight and distribution, for estimate.json."""
        return [{"weight": float(w), "proposal": c.to_dict(space)}
                for c, w in zip(self.components, self.weights, strict=True)]


def _signature(space: SearchSpace, point: np.ndarray) -> tuple[int, ...]:
    """The choices of a point (its discrete coordinates): a failure mode's key."""
    return tuple(round(float(x)) for d, x in zip(space.dims, point, strict=True) if isinstance(d, Choice))


def _describe(space: SearchSpace, signature: tuple[int, ...]) -> dict[str, Any]:
    """A signature as option -> value."""
    discrete = [d for d in space.dims if isinstance(d, Choice)]
    return {d.key: d.values[i] for d, i in zip(discrete, signature, strict=True)}


def _choice_shares(x: np.ndarray, w: np.ndarray, p0: np.ndarray, n_eff: float) -> tuple[np.ndarray, bool]:
    """A choice's weighted shares of its values among points ``x`` (normalised weights
    ``w``), and whether they differ clearly from the nominal ``p0`` (any share beyond 3 of
    its standard errors at the effective size ``n_eff``)."""
    k = len(p0)
    freq = np.bincount(np.clip(np.rint(x).astype(int), 0, k - 1), weights=w, minlength=k)
    return freq, not np.all(np.abs(freq - p0) <= 3 * np.sqrt(p0 * (1 - p0) / n_eff) + 1e-12)


def _refit(space: SearchSpace, nominal: Proposal, old: Proposal, points: np.ndarray, weights: np.ndarray,
           smoothing: float) -> Proposal:
    """The proposal fitted to the elite ``points`` (likelihood-ratio ``weights``).

    A dimension whose elite does not differ clearly from the nominal (its weighted mean and
    std each within 3 standard errors of the nominal's, a choice's every share within 3
    of its standard errors; the elite's effective size sets them) stays at the nominal, so
    that the dimensions failure does not depend on add no spread to the weights; a choice
    keeps each value at 5 % of an equal share at least even then, so that a value the
    nominal makes rare (an after-merge stop in 1 of 10^4) is still tried. Another
    is fitted by the method of moments of its family (a truncated normal's mean and std
    matched, not its parameters taken as the moments), smoothed towards the last
    proposal's moments by ``smoothing``.
    """
    w = weights / weights.sum()
    n_eff = 1.0 / float((w**2).sum())
    params: list[Any] = []
    for j, (d, p0, p) in enumerate(zip(space.dims, nominal.params, old.params, strict=True)):
        x = points[:, j]
        if isinstance(d, Range):
            mean = float(w @ x)
            std = math.sqrt(float(w @ (x - mean) ** 2))
            m0, s0 = truncnorm_moments(p0[0], p0[1], d.low, d.high)
            se = s0 / math.sqrt(n_eff)
            if abs(mean - m0) <= 3 * se and abs(std - s0) <= 3 * s0 / math.sqrt(2 * n_eff):
                params.append(p0)
                continue
            m1, s1 = truncnorm_moments(p[0], p[1], d.low, d.high)
            target = (smoothing * mean + (1 - smoothing) * m1,
                      max(smoothing * std + (1 - smoothing) * s1, MIN_STD_SHARE * d.width))
            params.append(truncnorm_matching(*target, d.low, d.high))
        else:
            k = len(p)
            freq, moved = _choice_shares(x, w, p0, n_eff)
            q = smoothing * freq + (1 - smoothing) * p if moved else p0
            q = np.maximum(q, MIN_CHOICE_SHARE / k)  # every value stays explored, the nominal's rare ones too
            params.append(q / q.sum())
    return Proposal(tuple(params))


def _moved_choices(space: SearchSpace, nominal: Proposal, points: np.ndarray, weights: np.ndarray) -> list[int]:
    """The choice dimensions (their indices) whose weighted shares among ``points`` differ
    clearly from the nominal (any share beyond 3 of its standard errors, the elite's
    effective size setting them), the :data:`MODE_CHOICES` furthest from it (chi-square
    distance): the choices the failure modes are told apart by (more would split a mode
    into cells too many for the components)."""
    w = weights / weights.sum()
    n_eff = 1.0 / float((w**2).sum())
    moved: list[tuple[float, int]] = []
    for j, (d, p0) in enumerate(zip(space.dims, nominal.params, strict=True)):
        if d.discrete:
            freq, moved_j = _choice_shares(points[:, j], w, p0, n_eff)
            if moved_j:
                chi = float(np.sum((freq - p0) ** 2 / np.maximum(p0, 1e-12)))  # chi-square distance to the nominal
                moved.append((chi, j))
    return [j for _, j in sorted(moved, reverse=True)[:MODE_CHOICES]]


def _refit_modes(space: SearchSpace, nominal: Proposal, old: Proposal | Mixture, points: np.ndarray,
                 weights: np.ndarray, smoothing: float, components: int) -> Mixture:
    """The mixture fitted to failures ``points`` (likelihood-ratio ``weights``): a failure
    mode is a set of values of the choices the failures depend on (:func:`_moved_choices`,
    over all of them); one component per mode, the ``components`` heaviest by weight, each
    drawing its mode's values of those choices (all but :data:`MIN_CHOICE_SHARE` of an
    equal share) and the rest :func:`_refit` to the mode's failures from the nominal;
    weights in proportion to the modes' weight, each at least 5 % of an equal share."""
    keep = weights > 0  # a failure the nominal cannot draw (a choice of weight 0) weighs nothing
    points, weights = points[keep], weights[keep]
    if not len(points):
        return old if isinstance(old, Mixture) else Mixture((old,), (1.0,))
    moved = _moved_choices(space, nominal, points, weights)
    groups: dict[tuple[int, ...], list[int]] = {}
    for i, point in enumerate(points):
        groups.setdefault(tuple(round(float(point[j])) for j in moved), []).append(i)
    ranked = sorted(groups.items(), key=lambda kv: -float(weights[kv[1]].sum()))[:components]
    comps, mass = [], []
    for values, idx in ranked:
        fitted = _refit(space, nominal, nominal, points[idx], weights[idx], smoothing)
        params = list(fitted.params)
        for j, v in zip(moved, values, strict=True):
            k = len(params[j])
            q = np.full(k, MIN_CHOICE_SHARE / k)
            q[v] = 1.0 - q.sum() + q[v]
            params[j] = q
        comps.append(Proposal(tuple(params)))
        mass.append(float(weights[idx].sum()))
    share = np.asarray(mass) / sum(mass)
    share = np.maximum(share, MIN_CHOICE_SHARE / len(share))
    return Mixture(tuple(comps), tuple(float(x) for x in share / share.sum()))


@dataclass
class Estimate:
    """A probability of failure per encounter, with its 95 % interval."""

    method: str  # "mc" | "ce" | "mixture"
    planner: str
    episodes: int  # all episodes spent (the cross-entropy stages included)
    n: int  # episodes of the estimating stage
    failures: int  # failures among them
    p: float
    ci: tuple[float, float]
    ess: float | None = None  # effective sample size of the failures' weights (importance sampling)
    top_share: float | None = None  # the largest single failure's share of the estimate (importance sampling)
    upper_only: bool = False  # no failure seen: ``ci[1]`` is a bound, ``p`` is 0
    stages: list[dict[str, Any]] = field(default_factory=list)
    errors: int = 0  # episodes that raised (counted as no failure)

    @property
    def rel_error(self) -> float | None:
        """Standard error over the estimate (None where it is 0)."""
        if self.p <= 0:
            return None
        return (self.ci[1] - self.p) / Z95 / self.p if self.method != "mc" else math.sqrt((1 - self.p) /
                                                                                          (self.n * self.p))

    @property
    def reliable(self) -> bool:
        """Whether the interval can be read at face value: never where an episode raised
        (counted as no failure, it may have hidden one); else Monte Carlo's always;
        importance sampling's where its failures' effective sample size is at least 10 and
        no single failure carries more than a quarter of the estimate (else its normal
        interval is optimistic: a few heavy weights carry it)."""
        if self.errors:
            return False
        if self.method == "mc" or self.upper_only:
            return True
        return (self.ess or 0.0) >= 10 and (self.top_share or 0.0) <= 0.25

    def text(self) -> str:
        """The estimate and its interval (or the bound), for a line of output; where it is not
        :attr:`reliable`, why: episodes that raised (how many), too few failures to weigh
        (effective sample size under 10), or one failure carrying more than a quarter of it."""
        raised = f"not reliable: {self.errors} of {self.episodes} episodes raised, counted as no failure"
        if self.upper_only:
            seen = (f"{self.failures} failures in {self.n}, none the nominal can draw" if self.failures
                    else f"0 failures in {self.n}")
            return f"< {self.ci[1]:.2g} ({seen}{'; ' + raised if self.errors else ''})"
        shown = f"{self.p:.3g} [{self.ci[0]:.2g}, {self.ci[1]:.2g}]"
        if self.errors:
            return f"{shown} ({raised})"
        if self.reliable:
            return shown
        if (self.ess or 0.0) < 10:
            return f"{shown} (not reliable: effective sample size {self.ess or 0.0:.1f} < 10)"
        return f"{shown} (not reliable: one failure carries {self.top_share or 0.0:.0%} of it)"

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable view (estimate.json)."""
        return {"method": self.method, "planner": self.planner, "episodes": self.episodes, "n": self.n,
                "failures": self.failures, "p": self.p, "ci95": list(self.ci), "ess": self.ess,
                "top_share": self.top_share, "reliable": self.reliable, "rel_error": self.rel_error,
                "upper_only": self.upper_only, "stages": self.stages, "errors": self.errors}


def _run(evaluator: Evaluator, planner: str, points: np.ndarray, seed: int, stream: int) -> tuple[np.ndarray,
                                                                                                  int]:
    """Robustness of one episode per point (seeds of ``stream``); and how many raised."""
    items = [(p, episode_seed(seed, i, stream)) for i, p in enumerate(points)]
    got = [e[planner] for e in evaluator.evaluate(items, [planner])]
    return np.array([e.robustness for e in got]), sum(e.error is not None for e in got)


def monte_carlo(evaluator: Evaluator, planner: str, n: int, *, seed: int = 0) -> Estimate:
    """Plain Monte Carlo: ``n`` nominal points, one episode each (see the module docstring)."""
    space = evaluator.space
    points = Proposal.nominal(space).sample(space, np.random.default_rng([int(seed), 300]), n)
    r, errors = _run(evaluator, planner, points, seed, 300)
    k = int((r <= 0).sum())
    lo, hi = wilson_interval(k, n)
    return Estimate("mc", planner, n, n, k, k / n, (lo, hi), upper_only=k == 0, errors=errors)


def _defensive_sample(space: SearchSpace, q: Proposal | Mixture, nominal: Proposal, defensive: float,
                      rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` points of ``(1 - defensive) q + defensive nominal`` (each point's source drawn first)."""
    from_q = rng.random(n) >= defensive
    return np.where(from_q[:, None], q.sample(space, rng, n), nominal.sample(space, rng, n))


def _defensive_logpdf(space: SearchSpace, q: Proposal | Mixture, nominal: Proposal, defensive: float,
                      points: np.ndarray) -> np.ndarray:
    """Log density of the defensive mixture at ``points``."""
    return np.logaddexp(math.log1p(-defensive) + q.logpdf(space, points),
                        math.log(defensive) + nominal.logpdf(space, points))


def cross_entropy(evaluator: Evaluator, planner: str, budget: int, *, seed: int = 0, stage: int | None = None,
                  rho: float = 0.1, smoothing: float = 0.7, defensive: float = 0.1, max_stages: int = 4,
                  min_failures: int = 3, components: int = 1,
                  on_stage: Callable[[dict[str, Any]], None] | None = None) -> Estimate:
    """Cross-entropy importance sampling within ``budget`` episodes (see the module
    docstring). ``stage``: episodes per adaptive stage (default a fifth of the budget, at
    least 50); ``min_failures`` failures make a stage's elite whatever their share; the
    stages stop once a stage's failures are a ``rho`` share of it (the proposal then fitted
    to a well-sampled set of failures), and the last stage gets what is left (at least a
    fifth of the budget). ``components`` > 1: the mixture estimator (module docstring): once
    a stage has ``min_failures`` failures, they are grouped by their choices (a failure
    mode each) and the proposal is a mixture of one component per mode, at most
    ``components`` of them (the heaviest by their weights), each weighted by its modes'
    share of the weight."""
    if not 1 <= components <= 64:
        raise ValueError(f"cross_entropy: components must be 1 to 64, got {components}")
    if not 0 < rho < 1 or not 0 < defensive < 1 or not 0 < smoothing <= 1 or not 0 < max_stages < 100:
        raise ValueError("cross_entropy: rho and defensive must be in (0, 1), smoothing in (0, 1], "
                         "max_stages in [1, 99]")
    if budget < MIN_CE_BUDGET:
        raise ValueError(f"cross-entropy importance sampling needs a budget of at least {MIN_CE_BUDGET} episodes "
                         f"(a stage of 50 and a last stage), got {budget}; use Monte Carlo below that")
    space = evaluator.space
    stage = stage or max(50, budget // 5)
    nominal = Proposal.nominal(space)
    q: Proposal | Mixture = nominal
    spent, stages, errors = 0, [], 0
    pool_points, pool_weights = [], []  # the mixture's failures of every stage, weighted by their stage's ratio
    for k in range(max_stages):
        if budget - spent - stage < budget // 5:
            break
        rng_k = np.random.default_rng([int(seed), 100 + k])
        if components > 1:  # the mixture's stages keep the defensive share: a mode not yet fitted is still drawn
            points = _defensive_sample(space, q, nominal, defensive, rng_k, stage)
            log_q = _defensive_logpdf(space, q, nominal, defensive, points)
        else:
            points = q.sample(space, rng_k, stage)
            log_q = q.logpdf(space, points)
        r, e = _run(evaluator, planner, points, seed, 100 + k)
        spent, errors = spent + stage, errors + e
        n_fail = int((r <= 0).sum())
        if n_fail >= min_failures:
            elite, level = r <= 0.0, 0.0
        else:  # the rho share of least robustness by rank (many episodes tie at the margin's cap)
            elite = np.zeros(len(r), dtype=bool)
            elite[np.argsort(r, kind="stable")[: max(1, math.ceil(rho * len(r)))]] = True
            level = max(float(r[elite].max()), 0.0)
        w = np.exp(nominal.logpdf(space, points[elite]) - log_q[elite])
        info: dict[str, Any] = {"stage": k, "episodes": stage, "level": level, "failures": int((r <= 0).sum()),
                "elite": int(elite.sum())}
        if components > 1 and n_fail:
            pool_points.append(points[r <= 0])
            pool_weights.append(np.exp(nominal.logpdf(space, points[r <= 0]) - log_q[r <= 0]))
        if w.sum() > 0:
            if components > 1 and sum(float(x.sum()) > 0 for x in pool_weights) and \
                    sum(len(x) for x in pool_points) >= min_failures:
                q = _refit_modes(space, nominal, q, np.concatenate(pool_points), np.concatenate(pool_weights),
                                 smoothing, components)
                info["modes"] = len(q.components) if isinstance(q, Mixture) else 1
            else:
                q = _refit(space, nominal, q if isinstance(q, Proposal) else nominal, points[elite], w, smoothing)
        stages.append(info)
        if on_stage is not None:
            on_stage(info)
        if n_fail >= rho * stage:  # a well-sampled set of failures: the proposal is fitted to it
            break
    n = budget - spent
    rng = np.random.default_rng([int(seed), 200])
    points = _defensive_sample(space, q, nominal, defensive, rng, n)
    r, e = _run(evaluator, planner, points, seed, 200)
    errors += e
    w = np.exp(nominal.logpdf(space, points) - _defensive_logpdf(space, q, nominal, defensive, points))
    hw = np.where(r <= 0, w, 0.0)
    k_fail = int((r <= 0).sum())
    method = "mixture" if components > 1 else "ce"
    final: dict[str, Any] = {"stage": len(stages), "episodes": n, "level": 0.0, "failures": k_fail, "final": True,
                             "proposal": q.to_dict(space) if isinstance(q, Mixture) else dict(q.to_dict(space))}
    if components > 1:  # each cell of choices' share of the estimate, heaviest first (finer than the components)
        modes: dict[tuple[int, ...], list[float]] = {}
        for point, weight in zip(points[r <= 0], hw[r <= 0], strict=True):
            modes.setdefault(_signature(space, point), []).append(float(weight))
        final["cells"] = [{"choices": _describe(space, sig), "p": sum(ws) / n, "failures": len(ws)}
                          for sig, ws in sorted(modes.items(), key=lambda kv: -sum(kv[1]))]
    stages.append(final)
    if k_fail == 0 or hw.sum() <= 0:  # no failure, or only failures the nominal cannot draw (weight 0)
        return Estimate(method, planner, budget, n, k_fail, 0.0, (0.0, 3.0 / (n * defensive)), upper_only=True,
                        stages=stages, errors=errors)
    p = float(hw.mean())
    se = float(hw.std(ddof=1) / math.sqrt(n))
    ess = float(hw.sum() ** 2 / (hw**2).sum())
    return Estimate(method, planner, budget, n, k_fail, p, (max(p - Z95 * se, 0.0), p + Z95 * se), ess=ess,
                    top_share=float(hw.max() / hw.sum()), stages=stages, errors=errors)


def agree(a: Estimate, b: Estimate) -> bool:
    """Whether two estimates' 95 % intervals overlap."""
    return a.ci[0] <= b.ci[1] and b.ci[0] <= a.ci[1]
