#!/usr/bin/env python3
"""Falsification page: every planner searched for failures on the default space, the
failures clustered and replayed on the others, and each planner's probability of failure
per encounter by importance sampling beside plain Monte Carlo (docs/FALSIFY.md).

Parts, each resumable (the same command goes on where a killed run stopped; results in
``OUT/<part>``):

1. **Search** (:func:`cdf_mj.falsify.run.falsify`): ``--runs`` independent CMA-ES
   searches of ``--episodes`` episodes for the first planner (a collision of ``cdf`` in
   each run), one for each other planner; each planner's first run replays its
   counterexamples (likeliest first, with their log-likelihoods) on every other planner.
   The first planner's counterexamples are written to ``docs/falsify/`` so that a reader
   can replay them (``cdf-mj episode --preset docs/falsify/cdf/01-seed-S.toml --seed S
   --planner cdf``).
2. **Probabilities** (:mod:`cdf_mj.falsify.estimate`): for every planner, cross-entropy
   importance sampling and plain Monte Carlo on the same budget (``--estimate-episodes``).
3. **Validation**: on ``--validate`` (a planner whose rate plain Monte Carlo resolves:
   ``cdf``, 1.9 % in a first 1000-episode probe, inside the issue's 0.5-5 %; ``cdf-risk``
   read 2.8 %), ``--validate-episodes`` (20 000) episodes of Monte Carlo against importance
   sampling with a fifth of them: do the intervals overlap?
4. **Near the default world**: the first planner on the ``near-default`` space (the same
   options, each nominally near the default world's value), both estimators on
   ``--near-episodes`` episodes each.
5. **A rare case with a reference**: ``cdf-risk`` on the ``rare-stop`` space (the merged car
   stops in 1 encounter of 10^4), both estimators on ``--rare-episodes`` episodes each,
   against the reference 1e-4 x P(failure | the stop), the second factor by plain Monte
   Carlo with the stop pinned (400 episodes).
6. **First failure against Monte Carlo** (issue 37): for every planner on the default
   space, the first planner on ``near-default``, ``drivers`` and ``world`` and ``cdf-risk``
   on ``rare-stop``,
   :data:`FIRST_RUNS` searches that stop at their first failure, their median against the
   episodes plain Monte Carlo expects at the rate measured above; and the mixture
   estimator (``--method mixture``) beside the validation's and near the default world.

Nothing is tuned here: the spaces (cdf_mj/falsify/spaces/), the search and the
estimators run with their defaults; the seeds are the runs' seeds 0, 1, ... Results are
as measured, whichever planner they favour. ::

    python scripts/falsify.py                                  # everything (about 40 minutes on 2 cores)
    python scripts/falsify.py --episodes 100 --runs 1 --estimate-episodes 200 --validate-episodes 400 \\
        --near-episodes 200 --rare-episodes 200 --planner cdf,cdf-risk --doc /tmp/f.md --out /tmp/f  # a look

Bad input (an unknown planner, a count out of range, a result directory of other settings)
is one line ``falsify: error: ...`` and exit status 2; episodes that raised are counted as
no failure, named on the page, and make the exit status 1. The flags are ``cdf-mj``'s
(``--planner``, a comma-separated list here; ``--episodes`` for a budget); the old
``--planners``, ``--budget``, ``--estimate-budget``, ``--near-budget`` and ``--rare-budget``
still work, with a note on stderr once the page is written.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

from cdf_mj.analysis.metrics import mcnemar_exact, wilson_interval
from cdf_mj.analysis.pages import ScriptParser, command_line, markdown_table, write_page
from cdf_mj.cli.args import CLIError, add_option, notes
from cdf_mj.cli.args import episode_count as _episodes
from cdf_mj.cli.args import int_in as _int_in
from cdf_mj.cli.args import out_path as _out_path
from cdf_mj.cli.args import planner_list as _planner_list
from cdf_mj.cli.args import worker_count as _workers
from cdf_mj.experiments.runner import WorkerDiedError
from cdf_mj.falsify.counterexamples import write_counterexamples
from cdf_mj.falsify.estimate import Estimate, agree
from cdf_mj.falsify.evaluate import JOURNAL_FILE, Evaluation, Evaluator, Journal
from cdf_mj.falsify.report import counterexample_table, progress_figure
from cdf_mj.falsify.run import FalsifyResult, estimate, falsify
from cdf_mj.falsify.search import run_search
from cdf_mj.falsify.space import Choice, Range, SearchSpace, load_space

PROG = "falsify"
PLANNERS = ("cdf", "cdf-risk", "cdf-threshold", "imm-layered", "reactive")
BUDGET, RUNS = 500, 5
#: Run seeds of each first-failure measurement (the target's median is over them), and the
#: most episodes each may take on a space (a run stops at its first failure).
FIRST_RUNS = 5
FIRST_CAP = {"default": 500, "near-default": 1000, "rare-stop": 2500, "drivers": 500, "world": 500}
#: Other shipped spaces whose first failures the first planner's searches are timed on
#: (against a Monte Carlo estimate of --estimate-episodes); `sumo` needs the extra and is
#: left out.
EXTRA_SPACES = ("drivers", "world")
ESTIMATE_BUDGET = 2000
VALIDATE, VALIDATE_EPISODES = "cdf", 20000
#: The near case: the first planner on the space of small departures from the default world.
NEAR_SPACE, NEAR_BUDGET = "near-default", 4000
#: The rare case with a reference: a planner that fails often once the merged car stops, on
#: the space in which it stops in 1 encounter of 10^4; the reference pins the stop.
RARE_SPACE, RARE_PLANNER, RARE_BUDGET, RARE_REFERENCE = "rare-stop", "cdf-risk", 2000, 400
RARE_KEY, RARE_VALUE = "after_merge.behaviour", "stop"
FIGURE = Path("docs/img/falsify/progress.png")
SHIPPED = Path("docs/falsify")


def _say(quiet: bool, text: str) -> None:
    if not quiet:
        print(text, file=sys.stderr, flush=True)


def space_table(space: SearchSpace) -> list[str]:
    """Markdown: each dimension's range or choices and its nominal."""
    rows = []
    for d in space.dims:
        if isinstance(d, Range):
            nominal = (f"normal({d.mean:g}, {d.std:g}) truncated" if d.mean is not None and d.std is not None
                       else "uniform")
            rows.append([f"`{d.key}`", f"[{d.low:g}, {d.high:g}]" + (" (pinned pair)" if d.pair else ""), nominal])
        else:
            rows.append([f"`{d.key}`", ", ".join(map(str, d.values)), ", ".join(f"{w:.3g}" for w in d.weights)])
    return markdown_table(["option", "range or choices", "nominal"], rows)


def _stages(e: Estimate, unit: str = "s") -> str:
    return "; ".join(f"level {s['level']:.3g} {unit}, {s['failures']} failures of {s['episodes']}"
                     for s in e.stages)


def _mc_rel_error(p: float, n: int) -> float:
    """Plain Monte Carlo's relative standard error at rate ``p`` with ``n`` episodes."""
    return math.sqrt((1 - p) / (n * p)) if 0 < p < 1 else math.inf


def pinned(space: SearchSpace, key: str, value: object) -> SearchSpace:
    """``space`` with the choice ``key`` pinned to ``value`` (the conditional world)."""
    dims = tuple(Choice(d.key, (value,), (1.0,)) if d.key == key else d for d in space.dims)
    return dataclasses.replace(space, name=f"{space.name} with {key} = {value}", dims=dims)


#: Episodes of the first-failure runs that raised (counted as no failure), and the other
#: spaces' Monte Carlo estimates, for the exit status.
FIRST_ERRORS: list[Evaluation] = []
EXTRA_ESTIMATES: list[Estimate] = []


def first_failures(space: SearchSpace, planner: str, seeds: range, cap: int, out: Path,
                   workers: int | None) -> list[int | None]:
    """Each run seed's episodes to its first failure of ``planner`` on ``space`` (a search
    that stops there; None: none within ``cap``), each run resumable in ``out/seed-S``;
    episodes that raised are kept in :data:`FIRST_ERRORS`."""
    found: list[int | None] = []
    for seed in seeds:
        directory = out / f"seed-{seed}"
        directory.mkdir(parents=True, exist_ok=True)
        journal = Journal(directory / JOURNAL_FILE)
        evaluator = Evaluator(space, [planner], journal, workers=workers)
        try:
            result = run_search(evaluator, planner, cap, seed=seed, until_failure=True)
            found.append(result.first_failure)
            FIRST_ERRORS.extend(result.errors)
        finally:
            evaluator.close()
            journal.close()
    return found


def _median(values: Sequence[float]) -> float:
    ordered = sorted(values)
    mid = len(ordered) // 2
    return ordered[mid] if len(ordered) % 2 else (ordered[mid - 1] + ordered[mid]) / 2


def first_failure_rows(parts: Parts) -> tuple[list[str], list[str]]:
    """The table of first failures against Monte Carlo's expectation, and the target lines."""
    rows, missed, rare_missed = [], [], []
    unmeasured, behind_median = [], []
    for (space, planner), (found, rate, source) in parts.first.items():
        med = _median([math.inf if f is None else f for f in found])
        shown = ", ".join("none" if f is None else str(f) for f in found)
        if rate <= 0:  # Monte Carlo saw no failure: no rate to set the search against
            unmeasured.append(f"`{planner}` on `{space}`")
            rows.append([f"`{space}`", f"`{planner}`", f"0 ({source})", "-", shown,
                         "none" if math.isinf(med) else f"{med:g}", "-", "no rate measured"])
            continue
        expect = 1 / rate
        mc_median = math.ceil(math.log(0.5) / math.log1p(-rate)) if rate < 1 else 1  # Monte Carlo's median wait
        rare = rate <= 0.005
        ok = med <= expect and (not rare or med <= expect / 10)
        (rare_missed if rare and not ok else missed if not ok else []).append(f"`{planner}` on `{space}`")
        if med > (mc_median / 10 if rare else mc_median):
            behind_median.append(f"`{planner}` on `{space}`")
        rows.append([f"`{space}`", f"`{planner}`", f"{rate:.3g} ({source})", f"{expect:.0f} ({mc_median})", shown,
                     "none" if math.isinf(med) else f"{med:g}", f"{med / expect:.2f}" if math.isfinite(med) else "-",
                     ("met" if ok else "**missed**") + (" (<= 1/10: rate <= 0.5 %)" if rare else "")])
    table = markdown_table(["space", "planner", "failure rate (from)",
                            "Monte Carlo expects a first failure after (its median)",
                            f"first failures of {FIRST_RUNS} runs", "median", "median / Monte Carlo",
                            "target"], rows)
    n = len(parts.first) - len(unmeasured)
    lines = [f"- **First failure no later than Monte Carlo's expectation, on every space and planner measured** "
             f"(median of {FIRST_RUNS} run seeds; a tenth of it where the rate is 0.5 % or less): "
             f"{n - len(missed) - len(rare_missed)} of {n} met"
             + (f"; missed: {', '.join(missed + rare_missed)}" if missed or rare_missed else "")
             + (f"; no rate measured (Monte Carlo saw no failure): {', '.join(unmeasured)}" if unmeasured else "")
             + ". The expectation is Monte Carlo's mean wait, 1 / rate; its median wait is 0.69 of it, and "
             + (f"against that median (a tenth of it at rates <= 0.5 %) the search is behind on "
                f"{', '.join(behind_median)}." if behind_median else "the search is no later than that either.")]
    return table, lines


@dataclasses.dataclass
class Parts:
    """Everything the page reports."""

    space: SearchSpace
    searches: dict[str, list[FalsifyResult]]
    estimates: dict[str, tuple[Estimate, Estimate]]
    validation: tuple[str, Estimate, Estimate] | None  # planner, Monte Carlo, importance sampling
    near: tuple[str, Estimate, Estimate]  # planner, importance sampling, Monte Carlo
    rare: tuple[str, float, Estimate, Estimate, Estimate]  # planner, nominal weight, IS, MC, conditional MC
    rare_other: tuple[int, int]  # failures, episodes of the rare runs in which the merged car did not stop
    paired: dict[str, dict[tuple[int, tuple[float, ...]], bool]]  # planner -> (seed, point) -> failed, Monte Carlo
    budget: int
    # (space, planner) -> the run seeds' first failures (None: none within the cap), Monte Carlo's rate, its source
    first: dict[tuple[str, str], tuple[list[int | None], float, str]] = dataclasses.field(default_factory=dict)
    validation_mixture: Estimate | None = None  # the mixture estimator beside the validation's
    near_mixture: Estimate | None = None


def targets(parts: Parts) -> list[str]:
    """The issue's targets, met or missed, from the numbers."""
    planners = list(parts.searches)
    first, runs = planners[0], parts.searches[planners[0]]
    found = [r.search.first_failure for r in runs]
    hit = sum(f is not None and f <= parts.budget for f in found)
    lines = [f"- **`{first}`: a collision found within {parts.budget} episodes in {hit} of {len(runs)} independent "
             f"runs** ({'met' if hit == len(runs) else 'missed'}); first failure after "
             + ", ".join("none" if f is None else str(f) for f in found) + " episodes."]
    if parts.first:
        lines += first_failure_rows(parts)[1]
    if parts.validation is not None and parts.validation_mixture is not None:
        name, mc, _ = parts.validation
        mix = parts.validation_mixture
        inside = not mix.upper_only and mc.ci[0] <= mix.ci[0] and mix.ci[1] <= mc.ci[1]
        mc_rel = _mc_rel_error(mc.p, mix.episodes)
        ok = (mix.ess or 0) >= 100 and inside and (mix.rel_error or math.inf) <= mc_rel / 2
        lines.append(f"- **The mixture estimator on a planner with several failure modes** (`{name}`): {mix.text()} "
                     f"from {mix.episodes} episodes, ESS {mix.ess or 0:.0f} (>= 100: "
                     f"{'yes' if (mix.ess or 0) >= 100 else 'no'}), its interval "
                     f"{'inside' if inside else 'not inside'} Monte Carlo's {mc.episodes}-episode {mc.text()}, "
                     f"relative s.e. {mix.rel_error or math.inf:.3f} against {mc_rel:.3f} for Monte Carlo on "
                     f"{mix.episodes} episodes (at most half: "
                     f"{'yes' if (mix.rel_error or math.inf) <= mc_rel / 2 else 'no'}) "
                     f"({'met' if ok else 'missed'}).")
    if parts.validation is not None:
        name, mc, ce = parts.validation
        ok = agree(mc, ce) and ce.episodes * 5 <= mc.episodes and ce.reliable
        lines.append(f"- **Importance sampling against {mc.episodes}-episode Monte Carlo** (`{name}`, a rate of "
                     f"{mc.p:.2%}): {ce.text()} from {ce.episodes} episodes against {mc.text()}: intervals "
                     f"{'overlap' if agree(mc, ce) else 'do not overlap'} with {mc.episodes / ce.episodes:.0f}x "
                     f"fewer episodes ({'met' if ok else 'missed'}). At this rate importance sampling buys little: "
                     f"its relative standard error {ce.rel_error or math.inf:.2f} against the "
                     f"{_mc_rel_error(mc.p, ce.episodes):.2f} plain Monte Carlo would have at that rate on "
                     f"{ce.episodes} episodes.")
    name, weight, ce, mc, cond = parts.rare
    lo, hi = wilson_interval(cond.failures, cond.n)
    ref = (weight * lo, weight * hi)
    bounded = not ce.upper_only and ce.ci[1] < 1e-4 and ce.reliable
    overlap = not ce.upper_only and ce.ci[0] <= ref[1] and ref[0] <= ce.ci[1]
    other_fail, other_n = parts.rare_other
    lines.append(f"- **Below 1e-4** (`{name}` on space `{RARE_SPACE}`): importance sampling {ce.text()}, Monte "
                 f"Carlo on the same {mc.episodes} episodes {mc.text()}; the reference {weight:g} x P(failure | "
                 f"the stop) = [{ref[0]:.2g}, {ref[1]:.2g}] ({cond.failures}/{cond.n} with the stop pinned): "
                 f"{'a bounded estimate below 1e-4' if bounded else 'no reliable bounded estimate below 1e-4'}, "
                 f"{'overlapping' if overlap else 'not overlapping'} the reference's interval, Monte Carlo "
                 f"{'sees no failure' if mc.failures == 0 else f'sees {mc.failures}'} "
                 f"({'met' if bounded and overlap and mc.failures == 0 else 'missed'}). The reference assumes "
                 f"that failures without the stop are far rarer than 1e-4: the runs' {other_n} episodes in which "
                 f"the merged car kept going had {other_fail} failures (which bounds that share only below about "
                 f"{3 / max(other_n, 1):.0e}; see docs/DECISION_RESULTS.md for `{name}` on 1000 held-out seeds of "
                 "the default world).")
    return lines


def page(parts: Parts, figure: str | None) -> str:
    """The Markdown of docs/FALSIFY.md."""
    space, planners = parts.space, list(parts.searches)
    lines = ["# Falsification: where each planner fails, and how often", "",
             "Every planner is searched for failures on the same declared space of worlds (`cdf-mj falsify`), "
             "its failures are clustered, minimised and replayed on the other planners, and its probability of "
             "failure per encounter is estimated by importance sampling beside plain Monte Carlo "
             f"(`cdf-mj estimate`). Failure: {space.failure.text}. The space file, the search and the estimators: "
             "[FALSIFICATION.md](FALSIFICATION.md).", "", "## Targets", "", *targets(parts),
             "", "## Search", "",
             f"CMA-ES on the least time to collision in the space's standard-normal coordinates, from its nominal "
             f"(the first generation is a nominal sample), {parts.budget} episodes a run, runs seeded 0, 1, ...; "
             "each candidate one episode with its own seed.", ""]
    rows = []
    for p, results in parts.searches.items():
        for seed, r in enumerate(results):
            s = r.search
            rows.append([f"`{p}`", str(seed), str(len(s.evaluations)), str(len(s.failures)),
                         "none" if s.first_failure is None else str(s.first_failure), str(len(r.counterexamples)),
                         f"{min((e.robustness for e in s.evaluations), default=0):.3g}", str(len(s.errors))])
    lines += markdown_table(["planner", "run seed", "episodes", "failures", "first failure after", "clusters",
                             "least robustness [s]", "episodes that raised"], rows)
    if figure:
        lines += ["", f"![search progress]({figure})"]
    if parts.first:
        lines += ["", "### First failure against plain Monte Carlo", "",
                  f"Episodes to the first failure, {FIRST_RUNS} run seeds per space and planner (a run seeded 0, "
                  "1, ... that stops at its first failure; on the default space the full searches above count "
                  "for their seeds), against the episodes plain Monte Carlo expects at the measured failure "
                  "rate (1 / rate; in brackets Monte Carlo's median wait, ln 2 / -ln(1 - rate)). The search's "
                  "first generation is a nominal sample, so it starts as Monte "
                  "Carlo does; the target asks that its median be no later, and a tenth of it where the rate is "
                  "0.5 % or less.", "", *first_failure_rows(parts)[0]]
    for p, results in parts.searches.items():
        r = results[0]
        others = [q for q in planners if q != p]
        lines += ["", f"### Counterexamples of `{p}` (run seeded 0)", ""]
        if not r.counterexamples:
            lines.append("No failure within the budget.")
            continue
        lines += ["Traits: the options the minimisation could not put back to the default world's. Speeds at "
                  "the first touch. Other planners: whether each fails on the minimised case, and on how many "
                  "of the cluster's failures (up to 20 replayed).", ""]
        lines += counterexample_table(r.counterexamples, others)
        if p == planners[0]:
            lines += ["", f"Replay: `cdf-mj episode --preset {SHIPPED}/{p}/NN-seed-S.toml --seed S --planner {p}` "
                          f"(`cdf-mj render` the same to watch); the files are in [{SHIPPED}/{p}](falsify/{p})."]
    n_est = next(iter(parts.estimates.values()))[0].episodes if parts.estimates else 0
    lines += ["", "## Probability of failure per encounter", "",
              f"Under the default space's nominal mix (its table below); each estimate its own {n_est} episodes, "
              "95 % intervals (importance sampling: normal on the weighted mean, read with its effective "
              "sample size; Monte Carlo: Wilson).", ""]
    rows = []
    for p, (ce, mc) in parts.estimates.items():
        rows.append([f"`{p}`", ce.text(), str(ce.failures), "-" if ce.ess is None else f"{ce.ess:.1f}",
                     "-" if ce.rel_error is None else f"{ce.rel_error:.2f}", mc.text(), str(mc.failures),
                     "-" if mc.rel_error is None else f"{mc.rel_error:.2f}", "yes" if agree(ce, mc) else "**no**"])
    lines += markdown_table(["planner", "importance sampling (CE)", "failures in its last stage",
                             "ESS of the failures' weights", "relative s.e.", "Monte Carlo, same budget",
                             "failures", "relative s.e.", "intervals overlap"], rows)
    first = planners[0]
    if first in parts.paired and len(parts.paired) > 1:
        ours = parts.paired[first]
        lines += ["", f"Seed by seed: every planner's Monte Carlo ran on the same nominal points and seeds, so "
                      f"`{first}` is compared with each other planner episode by episode (exact McNemar test).", ""]
        rows = []
        for other, theirs in parts.paired.items():
            if other == first:
                continue
            common = sorted(set(ours) & set(theirs))
            only_first = sum(ours[k] and not theirs[k] for k in common)
            only_other = sum(theirs[k] and not ours[k] for k in common)
            both = sum(ours[k] and theirs[k] for k in common)
            rows.append([f"`{first}` / `{other}`", str(len(common)), str(both), str(only_first), str(only_other),
                         f"{mcnemar_exact(only_first, only_other):.2g}"])
        lines += markdown_table(["pair", "episodes", "both fail", f"only `{first}` fails", "only the other fails",
                                 "McNemar p"], rows)
    if parts.validation is not None:
        name, mc, ce = parts.validation
        lo, hi = wilson_interval(mc.failures, mc.n)
        lines += ["", "### Validation against long Monte Carlo", "",
                  f"`{name}`: Monte Carlo {mc.failures}/{mc.n} = {mc.p:.4f} [{lo:.4f}, {hi:.4f}]; importance "
                  f"sampling {ce.p:.4f} [{ce.ci[0]:.4f}, {ce.ci[1]:.4f}] from {ce.episodes} episodes "
                  f"({ce.failures} failures in its last stage of {ce.n}, ESS {ce.ess or 0:.1f}; stages: "
                  f"{_stages(ce)})."]
        mix = parts.validation_mixture
        if mix is not None:
            lines += ["", "The estimators on the same planner, each against Monte Carlo's relative standard error "
                          "at its own number of episodes:", ""]
            rows = [[label, e.text(), str(e.episodes), "-" if e.ess is None else f"{e.ess:.0f}",
                     "-" if e.rel_error is None else f"{e.rel_error:.3f}", f"{_mc_rel_error(mc.p, e.episodes):.3f}"]
                    for label, e in (("Monte Carlo", mc), ("cross-entropy (one proposal)", ce),
                                     ("cross-entropy, mixture of failure modes", mix))]
            lines += markdown_table(["estimator", "estimate [95 %]", "episodes", "ESS", "relative s.e.",
                                     "Monte Carlo's relative s.e. at as many episodes"], rows)
            modes = next((st.get("cells") for st in mix.stages if st.get("final")), None) or []
            if modes:
                lines += ["", "The failures' cells of choices in the mixture's last stage (every choice's value: "
                          "finer than its components), heaviest first: "
                          + "; ".join(f"{', '.join(f'{k} = {v}' for k, v in m['choices'].items())}: "
                                      f"{m['p']:.2g} ({m['failures']} failures)" for m in modes[:6]) + "."]
    unit = "m" if space.failure.margin == "gap" else "s"
    name, ce, mc = parts.near
    lines += ["", f"### Near the default world: `{name}` on space `{NEAR_SPACE}`", "",
              f"Importance sampling {ce.text()} from {ce.episodes} episodes ({ce.failures} failures in its last "
              f"stage of {ce.n}, ESS {ce.ess or 0:.1f}; stages: {_stages(ce, unit)}); Monte Carlo "
              f"{mc.failures}/{mc.n}: {mc.text()}."
              + (f" The mixture estimator: {parts.near_mixture.text()} from {parts.near_mixture.episodes} episodes "
                 f"(ESS {parts.near_mixture.ess or 0:.1f})." if parts.near_mixture is not None else "")]
    name, weight, ce, mc, cond = parts.rare
    lines += ["", f"### A rare case with a reference: `{name}` on space `{RARE_SPACE}`", "",
              f"Importance sampling {ce.text()} from {ce.episodes} episodes ({ce.failures} failures in its last "
              f"stage of {ce.n}, ESS {ce.ess or 0:.1f}; stages: {_stages(ce, unit)}); Monte Carlo "
              f"{mc.failures}/{mc.n}: {mc.text()}; with the stop pinned (nominal weight {weight:g}): "
              f"{cond.failures}/{cond.n}."]
    lines += ["", "## The default space", "", space.description, "", *space_table(space)]
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> Parts:
    """Every part's runs (resumable, into ``args.out``)."""
    space, out, q = load_space("default"), Path(args.out), args.quiet
    searches: dict[str, list[FalsifyResult]] = {}
    for i, planner in enumerate(args.planner):
        n_runs = args.runs if i == 0 else 1
        searches[planner] = []
        for seed in range(n_runs):
            _say(q, f"search {planner}, run {seed + 1}/{n_runs}: {args.episodes} episodes")
            compare = [p for p in args.planner if p != planner] if seed == 0 else []
            searches[planner].append(falsify(space, planner, args.episodes, out / f"search-{planner}-{seed}",
                                             compare=compare, seed=seed, workers=args.workers, figure=False))
    estimates: dict[str, tuple[Estimate, Estimate]] = {}
    for planner in args.planner:
        _say(q, f"estimate {planner}: importance sampling and Monte Carlo, {args.estimate_episodes} each")
        estimates[planner] = (
            estimate(space, planner, args.estimate_episodes, out / f"ce-{planner}", method="ce", workers=args.workers),
            estimate(space, planner, args.estimate_episodes, out / f"mc-{planner}", method="mc", workers=args.workers))
    validation = None
    if args.validate != "none":
        _say(q, f"validation {args.validate}: Monte Carlo {args.validate_episodes}, importance sampling "
                f"{args.validate_episodes // 5}")
        validation = (args.validate,
                      estimate(space, args.validate, args.validate_episodes, out / f"validate-mc-{args.validate}",
                               method="mc", workers=args.workers),
                      estimate(space, args.validate, max(args.validate_episodes // 5, 10),
                               out / f"validate-ce-{args.validate}", method="ce", workers=args.workers))
    first = args.planner[0]
    _say(q, f"near the default world: {first} on {NEAR_SPACE}, {args.near_episodes} episodes each method")
    near_space = load_space(NEAR_SPACE)
    near = (first, estimate(near_space, first, args.near_episodes, out / f"near-ce-{first}", method="ce",
                            workers=args.workers),
            estimate(near_space, first, args.near_episodes, out / f"near-mc-{first}", method="mc",
                     workers=args.workers))
    _say(q, f"rare case: {RARE_PLANNER} on {RARE_SPACE}, {args.rare_episodes} episodes each method")
    rare_space = load_space(RARE_SPACE)
    dim = next(d for d in rare_space.dims if d.key == RARE_KEY)
    assert isinstance(dim, Choice)
    weight = dim.weights[dim.values.index(RARE_VALUE)]
    rare = (RARE_PLANNER, weight,
            estimate(rare_space, RARE_PLANNER, args.rare_episodes, out / "rare-ce", method="ce", workers=args.workers),
            estimate(rare_space, RARE_PLANNER, args.rare_episodes, out / "rare-mc", method="mc", workers=args.workers),
            estimate(pinned(rare_space, RARE_KEY, RARE_VALUE), RARE_PLANNER, RARE_REFERENCE, out / "rare-reference",
                     method="mc", workers=args.workers))
    column, stop = rare_space.keys.index(RARE_KEY), dim.values.index(RARE_VALUE)
    others = [e for part in ("rare-ce", "rare-mc") for e in _journal(out / part)
              if round(e.point[column]) != stop]
    paired = {planner: {(e.seed, e.point): e.failed for e in _journal(out / f"mc-{planner}") if e.error is None}
              for planner in args.planner}
    validation_mixture = None
    if args.validate != "none":
        _say(q, f"validation {args.validate}: the mixture estimator, {args.validate_episodes // 5}")
        validation_mixture = estimate(space, args.validate, max(args.validate_episodes // 5, 100),
                                      out / f"validate-mixture-{args.validate}", method="mixture",
                                      workers=args.workers)
    _say(q, f"near the default world: {first} on {NEAR_SPACE}, the mixture estimator, {args.near_episodes}")
    near_mixture = estimate(near_space, first, args.near_episodes, out / f"near-mixture-{first}", method="mixture",
                            workers=args.workers)
    # Episodes to the first failure, FIRST_RUNS run seeds per space and planner, against the
    # episodes Monte Carlo expects at the measured rate.
    first_found: dict[tuple[str, str], tuple[list[int | None], float, str]] = {}
    for planner in args.planner:
        full = [r.search.first_failure for r in searches[planner]]
        _say(q, f"first failures: {planner} on default, run seeds {len(full)}-{FIRST_RUNS - 1}")
        more = first_failures(space, planner, range(len(full), FIRST_RUNS), FIRST_CAP["default"],
                              out / f"first-default-{planner}", args.workers)
        ce, mc = estimates[planner]
        rate, source = (mc.p, f"Monte Carlo, {mc.failures}/{mc.n}") if mc.failures else (ce.p, "importance sampling")
        first_found[("default", planner)] = ([*full, *more][:FIRST_RUNS], rate, source)
    _say(q, f"first failures: {first} on {NEAR_SPACE}")
    near_mc = near[2]
    first_found[(NEAR_SPACE, first)] = (
        first_failures(near_space, first, range(FIRST_RUNS), FIRST_CAP[NEAR_SPACE], out / f"first-near-{first}",
                       args.workers), near_mc.p, f"Monte Carlo, {near_mc.failures}/{near_mc.n}")
    for name in EXTRA_SPACES:
        extra = load_space(name)
        _say(q, f"{first} on {name}: Monte Carlo {args.estimate_episodes}, first failures")
        mc = estimate(extra, first, args.estimate_episodes, out / f"extra-mc-{name}-{first}", method="mc",
                      workers=args.workers)
        EXTRA_ESTIMATES.append(mc)
        first_found[(name, first)] = (
            first_failures(extra, first, range(FIRST_RUNS), FIRST_CAP[name], out / f"first-{name}-{first}",
                           args.workers), mc.p, f"Monte Carlo, {mc.failures}/{mc.n}")
    _say(q, f"first failures: {RARE_PLANNER} on {RARE_SPACE}")
    cond = rare[4]
    first_found[(RARE_SPACE, RARE_PLANNER)] = (
        first_failures(rare_space, RARE_PLANNER, range(FIRST_RUNS), FIRST_CAP[RARE_SPACE], out / "first-rare",
                       args.workers), weight * cond.p, f"the reference, {weight:g} x {cond.failures}/{cond.n}")
    return Parts(space, searches, estimates, validation, near, rare, (sum(e.failed for e in others), len(others)),
                 paired, args.episodes, first_found, validation_mixture, near_mixture)


def _journal(directory: Path) -> list[Evaluation]:
    """The episodes a run's journal holds."""
    journal = Journal(directory / JOURNAL_FILE)
    journal.close()
    return list(journal.entries.values())


def main(argv: Sequence[str] | None = None) -> int:
    """Run every part and write the page; returns the exit status (1 if episodes raised)."""
    p = ScriptParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_option(p, "--planner", old=("--planners",), type=_planner_list, default=list(PLANNERS), metavar="P[,P...]",
               help=f"comma-separated planners, the first searched --runs times (default {','.join(PLANNERS)})")
    add_option(p, "--episodes", old=("--budget",), type=_episodes, default=BUDGET,
               help=f"episodes per search (default {BUDGET})")
    p.add_argument("--runs", type=_int_in(1, 100, "independent searches"), default=RUNS,
                   help=f"independent searches of the first planner (default {RUNS})")
    add_option(p, "--estimate-episodes", old=("--estimate-budget",), type=_episodes, default=ESTIMATE_BUDGET,
                   help=f"episodes per estimate, each method (default {ESTIMATE_BUDGET})")
    p.add_argument("--validate", default=VALIDATE,
                   help=f"planner of the validation (default {VALIDATE}; 'none' to skip)")
    p.add_argument("--validate-episodes", type=_episodes, default=VALIDATE_EPISODES,
                   help=f"Monte Carlo episodes of the validation (default {VALIDATE_EPISODES}); importance "
                        "sampling gets a fifth")
    add_option(p, "--near-episodes", old=("--near-budget",), type=_episodes, default=NEAR_BUDGET,
                   help=f"episodes of each estimate near the default world (default {NEAR_BUDGET})")
    add_option(p, "--rare-episodes", old=("--rare-budget",), type=_episodes, default=RARE_BUDGET,
                   help=f"episodes of each estimate of the rare case (default {RARE_BUDGET})")
    p.add_argument("--workers", type=_workers, default=None, help="worker processes (default: the CPU count)")
    p.add_argument("--out", type=_out_path, default="results/falsify-page", help="result directory")
    p.add_argument("--doc", type=_out_path, default="docs/FALSIFY.md", help="Markdown page written")
    p.add_argument("--figure", type=_out_path, default=None,
                   help=f"the progress figure (default {FIGURE} for docs/FALSIFY.md, else beside --doc)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    try:
        args = p.parse_args(argv)
    except CLIError as exc:  # a flag and its old spelling together
        p.error(str(exc))
    if len(set(args.planner)) != len(args.planner):
        p.error(f"--planner names a planner twice: {','.join(args.planner)}")
    if args.validate != "none" and args.validate not in args.planner:
        p.error(f"--validate {args.validate} is not among --planner")
    doc = Path(args.doc)
    if doc.is_dir():
        p.error(f"--doc {doc} is a directory; give the path of the Markdown page to write")
    try:
        parts = run(args)
    except (ValueError, OSError, WorkerDiedError) as exc:
        p.error(str(exc))
    official = doc.resolve() == Path("docs/FALSIFY.md").resolve()
    figure_path = Path(args.figure) if args.figure else FIGURE if official else doc.with_suffix(".png")
    figure_path.parent.mkdir(parents=True, exist_ok=True)
    progress_figure({k: [r.search for r in v] for k, v in parts.searches.items()}, figure_path,
                    parts.space.failure.margin)
    if official:  # the first planner's counterexamples, for readers to replay
        shipped = SHIPPED / args.planner[0]
        if shipped.exists():
            shutil.rmtree(shipped)
        write_counterexamples(parts.space, parts.searches[args.planner[0]][0].counterexamples, shipped)
    command = command_line("scripts/falsify.py", [
        ("--planner", None if tuple(args.planner) == PLANNERS else ",".join(args.planner)),
        ("--episodes", None if args.episodes == BUDGET else args.episodes),
        ("--runs", None if args.runs == RUNS else args.runs),
        ("--estimate-episodes", None if args.estimate_episodes == ESTIMATE_BUDGET else args.estimate_episodes),
        ("--validate", None if args.validate == VALIDATE else args.validate),
        ("--validate-episodes", None if args.validate_episodes == VALIDATE_EPISODES else args.validate_episodes),
        ("--near-episodes", None if args.near_episodes == NEAR_BUDGET else args.near_episodes),
        ("--rare-episodes", None if args.rare_episodes == RARE_BUDGET else args.rare_episodes)])
    relative = Path(os.path.relpath(figure_path.resolve(), doc.resolve().parent)).as_posix()
    write_page(doc, page(parts, relative), command)
    _say(args.quiet, f"wrote {doc}, {figure_path}")
    estimates = [*(e for pair in parts.estimates.values() for e in pair), *parts.near[1:], *parts.rare[2:],
                 *(parts.validation[1:] if parts.validation else ()),
                 *(e for e in (parts.validation_mixture, parts.near_mixture) if e is not None), *EXTRA_ESTIMATES]
    errors = (sum(len(r.search.errors) for v in parts.searches.values() for r in v) + sum(e.errors for e in estimates)
              + len(FIRST_ERRORS))
    if errors:
        print(f"{PROG}: {errors} episode(s) raised (counted as no failure); see the journals in {args.out}",
              file=sys.stderr)
    for text in notes(args):  # old spellings, once the page is written (an error stays one line)
        print(f"{PROG}: note: {text}", file=sys.stderr)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
