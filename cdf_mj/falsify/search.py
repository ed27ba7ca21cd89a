"""The adversarial search: CMA-ES over a space's standard-normal coordinates, lowering the
robustness of one planner's episodes until they fail, or, with ``objective="likely"``,
raising the likelihood of the failures it finds.

The search's coordinates are the space's *latent* ones (:meth:`SearchSpace.from_latent`):
each dimension is its nominal's inverse CDF of a standard normal, so a latent ``z ~ N(0,
I)`` is a nominal draw. CMA-ES starts at the origin with a step of 1: its first generation
*is* plain Monte Carlo, and it is never behind sampling before it has learnt anything. It
then moves its mean and covariance towards lower robustness, and a point's distance from
the origin is its unlikeliness (the nominal's log-likelihood, :meth:`SearchSpace.
log_likelihood`, carried by every evaluation), so a failure found near the origin is a
likely one. Restarts with a doubled population (IPOP): after a stagnating run, from the
least robustness seen so far that did not fail, with half the step (the search adapts
from there); after a run that has settled on failures (a mode found), from the nominal
again, so that the budget finds several failure modes, not one many times.

Why CMA-ES (the ``cma`` package, N. Hansen's reference implementation): the robustness is
a noisy, non-smooth function of 20-odd mixed dimensions with no gradient; CMA-ES needs
no gradient, is rank-based (the ``likely`` objective, a penalty method, ranks a failure by
its negative log-likelihood and a non-failure by that plus a penalty per unit of
robustness left, as adaptive stress testing maximises the likelihood of a failure
path), learns which dimensions matter together,
and works in batches (one generation is one batch of episodes for the workers).

Each candidate is one episode of a point of the space with a seed of its own
(:func:`~cdf_mj.falsify.evaluate.episode_seed`): the search ranks points by what one
episode of each shows, as a tester would. Everything is replayed from the journal on a
restart of the command: CMA-ES asks the same candidates given the same answers, so a
killed search goes on where it stopped, and a larger budget extends a finished one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cdf_mj.falsify.evaluate import Evaluation, Evaluator, episode_seed
from cdf_mj.falsify.space import Choice, SpaceError
from cdf_mj.inputs import printable

__all__ = ["OBJECTIVES", "SEARCH", "Generation", "SearchResult", "run_search"]

#: Generations without a better robustness (by 1 mm or 1 ms) before a restart.
PATIENCE = 15
#: Generations in a row with half or more failing before a restart (a mode found).
SETTLED = 3
#: Largest population, as a multiple of the first (IPOP doubles it at each restart).
MAX_POP_FACTOR = 8
#: What the search ranks candidates by (:func:`run_search`).
OBJECTIVES = ("robustness", "likely")
#: Least step of a choice's latent coordinate (a choice's values stay in reach).
CHOICE_MINSTD = 0.1
#: The ``likely`` objective's penalty per unit of robustness (per second of TTC or metre of
#: gap) of an episode that did not fail, in units of log-likelihood.
LIKELY_PENALTY = 20.0
#: The version of the search, stored with a run: a journal of another search is not resumed.
SEARCH = "latent-cma-1"


@dataclass(frozen=True)
class Generation:
    """One generation of the search."""

    index: int
    restart: int
    episodes: int  # episodes of the search so far, this generation's included
    best: float  # least robustness of this generation [the margin's unit: m or s]
    best_so_far: float  # [m or s]
    failures_so_far: int
    likeliest: float | None = None  # the largest nominal log-likelihood of a failure so far (None: none yet)


@dataclass
class SearchResult:
    """What a search found: every candidate's evaluation in order, the generations, and
    the episode count at the first failure (None: none within the budget)."""

    planner: str
    evaluations: list[Evaluation] = field(default_factory=list)
    generations: list[Generation] = field(default_factory=list)
    first_failure: int | None = None
    log_likelihood: list[float] = field(default_factory=list)  # of each evaluation's point, under the nominal
    objective: str = "robustness"

    @property
    def failures(self) -> list[Evaluation]:
        return [e for e in self.evaluations if e.failed]

    @property
    def errors(self) -> list[Evaluation]:
        return [e for e in self.evaluations if e.error is not None]

    def to_dict(self) -> dict[str, Any]:
        fails = [ll for ll, e in zip(self.log_likelihood, self.evaluations, strict=True)
                 if e.failed and math.isfinite(ll)]
        return {"planner": self.planner, "objective": self.objective, "episodes": len(self.evaluations),
                "failures": len(self.failures), "first_failure": self.first_failure,
                "best": min((e.robustness for e in self.evaluations), default=None),
                "likeliest_failure": max(fails, default=None),
                "generations": [g.__dict__ for g in self.generations]}


def _strategy(cma: Any, x0: np.ndarray, popsize: int, sigma0: float, minstd: list[float],
              rng: np.random.Generator, seed: int) -> Any:
    opts = {"popsize": popsize, "seed": seed, "verbose": -9, "verb_log": 0, "verb_disp": 0, "minstd": minstd,
            "randn": lambda lam, n: rng.standard_normal((lam, n))}
    return cma.CMAEvolutionStrategy(list(x0), sigma0, opts)


def _fitness(ev: Evaluation, log_likelihood: float, objective: str) -> float:
    """What CMA-ES minimises for one episode: its robustness; with ``"likely"`` the
    negative nominal log-likelihood plus :data:`LIKELY_PENALTY` times the robustness of an
    episode that did not fail (a penalty method: the search climbs the likelihood along the
    edge of the failures, where a failure's likelihood is highest)."""
    if objective == "likely":
        return -log_likelihood + LIKELY_PENALTY * max(ev.robustness, 0.0)
    return ev.robustness


def run_search(evaluator: Evaluator, planner: str, budget: int, *, seed: int = 0, popsize: int | None = None,
               sigma0: float = 1.0, objective: str = "robustness", until_failure: bool = False,
               on_generation: Callable[[Generation], None] | None = None) -> SearchResult:
    """Search ``evaluator``'s space for failures of ``planner`` within ``budget`` episodes.

    ``popsize``: the first population (default CMA-ES's 4 + 3 ln d); ``sigma0``: the first
    step in the latent coordinates (1: the first generation is a nominal sample);
    ``objective``: ``"robustness"`` (find failures) or ``"likely"`` (then the likeliest
    failures; module docstring); ``until_failure``: stop after the generation of the first
    failure (to time it). The same ``seed``, budget and space give the same candidates and
    results on any backend and worker count.
    """
    import cma  # a dependency; imported where the search runs (its import takes 0.2 s)

    if objective not in OBJECTIVES:
        raise ValueError(f"objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}")
    space = evaluator.space
    d = len(space.dims)
    if d < 2:  # CMA-ES itself would stop with "not yet initialized (dimension needed)"
        raise SpaceError(f"space {printable(space.source or space.name)}: the search (CMA-ES) needs at least 2 "
                         f"dimensions, this space has {d}; add one, or estimate its failure rate instead")
    lam0 = popsize or 4 + int(3 * math.log(max(d, 2)))
    minstd = [CHOICE_MINSTD if isinstance(dim, Choice) else 0.0 for dim in space.dims]
    rng = np.random.default_rng([int(seed), 7])
    result = SearchResult(planner, objective=objective)
    best_so_far, restart, gen = math.inf, 0, 0
    mean, step = np.zeros(d), sigma0  # the first run starts at the nominal
    best_open: tuple[float, np.ndarray] | None = None  # the least robustness seen that did not fail, its latent
    likeliest: float | None = None
    while len(result.evaluations) < budget:
        lam = min(lam0 * 2**restart, lam0 * MAX_POP_FACTOR)
        es = _strategy(cma, mean, lam, step, minstd, rng, int(rng.integers(1, 2**31 - 1)))
        best_here, stale, settled = math.inf, 0, 0
        while len(result.evaluations) < budget:
            asked = es.ask()
            n = min(len(asked), budget - len(result.evaluations))
            start = len(result.evaluations)
            points = [tuple(space.from_latent(z)) for z in asked[:n]]
            items = [(p, episode_seed(seed, start + i)) for i, p in enumerate(points)]
            got = [e[planner] for e in evaluator.evaluate(items, [planner])]
            lls = [float(v) for v in space.log_likelihood(np.array(points))] if points else []
            result.evaluations.extend(got)
            result.log_likelihood.extend(lls)
            for i, ev in enumerate(got):
                if ev.failed:
                    if result.first_failure is None:
                        result.first_failure = start + i + 1
                    if math.isfinite(lls[i]):
                        likeliest = lls[i] if likeliest is None else max(likeliest, lls[i])
                elif ev.error is None and (best_open is None or ev.robustness < best_open[0]):
                    best_open = (ev.robustness, np.asarray(asked[i], dtype=float))
            values = [ev.robustness for ev in got]
            gen_best = min(values)
            best_so_far = min(best_so_far, gen_best)
            result.generations.append(Generation(gen, restart, len(result.evaluations), gen_best, best_so_far,
                                                 len(result.failures), likeliest))
            if on_generation is not None:
                on_generation(result.generations[-1])
            gen += 1
            if n < len(asked) or (until_failure and result.first_failure is not None):
                break  # the budget ended within the generation, or the first failure was all that was asked
            scores = [_fitness(ev, ll, objective) for ev, ll in zip(got, lls, strict=True)]
            es.tell(asked, scores)
            stale = 0 if min(scores) < best_here - 1e-3 else stale + 1
            best_here = min(best_here, min(scores))
            # A run settled on failures restarts to look for another mode, unless it is
            # climbing the likelihood among them (then only stagnation restarts it).
            if objective == "robustness":
                settled = settled + 1 if sum(ev.failed for ev in got) * 2 >= len(got) else 0
            if es.stop() or stale >= PATIENCE or settled >= SETTLED:
                break
        if until_failure and result.first_failure is not None:
            break
        restart += 1
        if settled >= SETTLED or best_open is None:  # a mode found: look for the next from the nominal
            mean, step = np.zeros(d), sigma0
        else:  # adapt from the least robustness seen
            mean, step = best_open[1], sigma0 / 2
    return result
