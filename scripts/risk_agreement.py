#!/usr/bin/env python3
"""How closely the risk rule's compiled rollouts agree with the filter's own model rolled forward.

On every tick of CDF episodes (the ego driven by the ``cdf`` planner's decisions), the
risk rule's assessment (:meth:`cdf_mj.planners.decision.RiskRule.assess`: each particle's
future in closed form, compiled) is compared with the reference
(:func:`cdf_mj.planners.rollout_reference.rollout_assessment`: every particle rolled through the
filter's own look, belief, driver and bicycle stages, with process noise). Prints, over
the ticks where either reads a risk above 0.01, the mean and largest absolute
difference of the deferred risk, how often the two agree on braking at the rule's
threshold, and the time of each::

    python scripts/risk_agreement.py --seeds 0-19
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.model.driver import ego_control
from cdf_mj.planners.base import PlannerContext
from cdf_mj.planners.cdf import CDFPlanner
from cdf_mj.planners.decision import GivenFutures, RiskRule
from cdf_mj.planners.rollout_reference import rollout_assessment
from cdf_mj.scenario.world import World
from cdf_mj.sim.scene import Scene


def _seeds(text: str) -> range:
    lo, _, hi = text.partition("-")
    return range(int(lo), int(hi or lo) + 1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="risk_agreement", description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=_seeds, default=range(0, 20), help="seed range A-B (default 0-19)")
    parser.add_argument("--verbose", action="store_true", help="print every tick with a risk")
    args = parser.parse_args(argv)
    scene, config, cdf = Scene.load(), ScenarioConfig(), CDFConfig(decision="risk")
    threshold = cdf.risk.brake
    diffs: list[float] = []
    fast: list[float] = []
    slow: list[float] = []
    agree = 0
    for seed in args.seeds:
        world = World(scene, config)
        world.reset(seed)
        planner = CDFPlanner(cdf)
        planner.reset(PlannerContext.of(world.layout, config), world.rng["planner"])
        rule = planner.rule
        assert isinstance(rule, RiskRule)
        pf, braking, started = planner.filter, False, False
        reference_rng = np.random.default_rng(seed)
        while not world.done:
            m = world.measure()
            if not started:
                pf.reset(m.poses)
                started = True
            else:
                pf.update(m.poses)
            t0 = time.perf_counter()
            braking = rule.decide(GivenFutures(pf.futures(rule.react_ticks)), m.poses[0], braking)
            t1 = time.perf_counter()
            a = rule.last
            assert a is not None
            r = rollout_assessment(pf, rule, m.poses[0], reference_rng)
            t2 = time.perf_counter()
            fast.append(t1 - t0)
            slow.append(t2 - t1)
            if max(a.deferred, r.deferred) > 0.01:
                if args.verbose:
                    a = rule.assess(m.poses[0], pf.futures(rule.react_ticks), exact=True)
                    print(f"seed {seed} t {m.t:.1f}: compiled go {a.go:.3f} deferred {a.deferred:.3f} "
                          f"brake {a.brake:.3f}; rollout go {r.go:.3f} deferred {r.deferred:.3f} brake {r.brake:.3f}")
                diffs.append(abs(a.deferred - r.deferred))
                agree += (a.deferred >= threshold) == (r.deferred >= threshold)
            pf.predict(m.poses)
            world.step(ego_control(world.driver, world.layout.ego, m.poses[0], braking))
    n = len(diffs)
    print(f"seeds {args.seeds.start}-{args.seeds.stop - 1}: {n} ticks with a risk above 0.01")
    if n:
        print(f"deferred risk, |compiled - rollout|: mean {statistics.fmean(diffs):.3f}, "
              f"median {statistics.median(diffs):.3f}, largest {max(diffs):.3f}")
        print(f"same side of the threshold {threshold:g}: {agree}/{n} ticks ({100 * agree / n:.1f} %)")
    print(f"time per tick: compiled {1e6 * statistics.median(fast):.0f} us, rollout "
          f"{1e3 * statistics.median(slow):.1f} ms (medians)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
