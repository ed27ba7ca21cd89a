"""The adversarial search: CMA-ES over a space's unit cube, lowering the robustness of
one planner's episodes until they fail.

Why CMA-ES (the ``cma`` package, N. Hansen's reference implementation): the robustness is
a noisy, non-smooth function of 20-odd mixed dimensions with no gradient; CMA-ES needs
no gradient, learns which dimensions matter together (its covariance), works in batches
(one generation is one batch of episodes for the workers), handles the cube's bounds,
keeps choices alive with a least step per coordinate, and is a small pure-Python
package. Restarts with a doubled population (IPOP) follow a stagnating run or one that
has settled on failures, so the budget finds several failure modes, not one many times.

Each candidate is one episode of a point of the space (a choice's coordinate cut into
equal parts) with a seed of its own (:func:`~cdf_mj.falsify.evaluate.episode_seed`): the
search ranks points by what one episode of each shows, as a tester would. Everything is
replayed from the journal on a restart of the command: CMA-ES asks the same candidates
given the same answers, so a killed search goes on where it stopped, and a larger budget
extends a finished one.
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

__all__ = ["Generation", "SearchResult", "run_search"]

#: Generations without a better robustness (by 1 mm or 1 ms) before a restart.
PATIENCE = 15
#: Generations in a row with half or more failing before a restart (a mode found).
SETTLED = 3
#: Largest population, as a multiple of the first (IPOP doubles it at each restart).
MAX_POP_FACTOR = 8


@dataclass(frozen=True)
class Generation:
    """One generation of the search."""

    index: int
    restart: int
    episodes: int  # episodes of the search so far, this generation's included
    best: float  # least robustness of this generation [the margin's unit: m or s]
    best_so_far: float  # [m or s]
    failures_so_far: int


@dataclass
class SearchResult:
    """What a search found: every candidate's evaluation in order, the generations, and
    the episode count at the first failure (None: none within the budget)."""

    planner: str
    evaluations: list[Evaluation] = field(default_factory=list)
    generations: list[Generation] = field(default_factory=list)
    first_failure: int | None = None

    @property
    def failures(self) -> list[Evaluation]:
        return [e for e in self.evaluations if e.failed]

    @property
    def errors(self) -> list[Evaluation]:
        return [e for e in self.evaluations if e.error is not None]

    def to_dict(self) -> dict[str, Any]:
        return {"planner": self.planner, "episodes": len(self.evaluations), "failures": len(self.failures),
                "first_failure": self.first_failure,
                "best": min((e.robustness for e in self.evaluations), default=None),
                "generations": [g.__dict__ for g in self.generations]}


def _strategy(cma: Any, x0: np.ndarray, popsize: int, sigma0: float, minstd: list[float],
              rng: np.random.Generator, seed: int) -> Any:
    opts = {"bounds": [0.0, 1.0], "popsize": popsize, "seed": seed, "verbose": -9, "verb_log": 0,
            "verb_disp": 0, "minstd": minstd, "randn": lambda lam, n: rng.standard_normal((lam, n))}
    return cma.CMAEvolutionStrategy(list(x0), sigma0, opts)


def run_search(evaluator: Evaluator, planner: str, budget: int, *, seed: int = 0, popsize: int | None = None,
               sigma0: float = 0.3, on_generation: Callable[[Generation], None] | None = None) -> SearchResult:
    """Search ``evaluator``'s space for failures of ``planner`` within ``budget`` episodes.

    ``popsize``: the first population (default CMA-ES's 4 + 3 ln d); ``sigma0``: the first
    step in the unit cube. The same ``seed``, budget and space give the same candidates and
    results on any backend and worker count.
    """
    import cma  # a dependency; imported where the search runs (its import takes 0.2 s)

    space = evaluator.space
    d = len(space.dims)
    if d < 2:  # CMA-ES itself would stop with "not yet initialized (dimension needed)"
        raise SpaceError(f"space {printable(space.source or space.name)}: the search (CMA-ES) needs at least 2 "
                         f"dimensions, this space has {d}; add one, or estimate its failure rate instead")
    lam0 = popsize or 4 + int(3 * math.log(max(d, 2)))
    minstd = [0.5 / len(dim.values) if isinstance(dim, Choice) else 0.0 for dim in space.dims]
    rng = np.random.default_rng([int(seed), 7])
    result = SearchResult(planner)
    best_so_far, restart, gen = math.inf, 0, 0
    while len(result.evaluations) < budget:
        lam = min(lam0 * 2**restart, lam0 * MAX_POP_FACTOR)
        es = _strategy(cma, rng.random(d), lam, sigma0, minstd, rng, int(rng.integers(1, 2**31 - 1)))
        best_here, stale, settled = math.inf, 0, 0
        while len(result.evaluations) < budget:
            asked = es.ask()
            n = min(len(asked), budget - len(result.evaluations))
            start = len(result.evaluations)
            points = [tuple(space.from_unit(u)) for u in asked[:n]]
            items = [(p, episode_seed(seed, start + i)) for i, p in enumerate(points)]
            got = [e[planner] for e in evaluator.evaluate(items, [planner])]
            result.evaluations.extend(got)
            for i, ev in enumerate(got):
                if ev.failed and result.first_failure is None:
                    result.first_failure = start + i + 1
            values = [ev.robustness for ev in got]
            gen_best = min(values)
            best_so_far = min(best_so_far, gen_best)
            result.generations.append(Generation(gen, restart, len(result.evaluations), gen_best, best_so_far,
                                                 len(result.failures)))
            if on_generation is not None:
                on_generation(result.generations[-1])
            gen += 1
            if n < len(asked):  # the budget ended within the generation
                break
            es.tell(asked, values)
            stale = 0 if gen_best < best_here - 1e-3 else stale + 1
            best_here = min(best_here, gen_best)
            settled = settled + 1 if sum(ev.failed for ev in got) * 2 >= len(got) else 0
            if es.stop() or stale >= PATIENCE or settled >= SETTLED:
                break
        restart += 1
    return result
