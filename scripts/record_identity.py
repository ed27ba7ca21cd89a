#!/usr/bin/env python3
"""Are the records of two checkouts byte-identical? Dump one set of episodes, compare two dumps.

A refactor that must not change what the package computes (issue 34: the tick split into
two agents, one road vocabulary) is checked by dumping the same episodes on both
checkouts and comparing the dumps line by line. A dump holds, one JSON line each:

- ``reproduce``: the paper's experiment, ``cdf`` and ``reactive`` on seeds 0-999 of the
  default world, labelled (the records ``cdf-mj reproduce`` writes);
- ``planners``: every registered planner on ``--episodes`` held-out seeds (from ``--seed``)
  of the default world, with traces;
- ``presets``: every preset (the stress suite, the belief presets) with ``cdf``,
  ``imm-layered`` and ``reactive`` on the same seeds, with traces;
- ``env``: Gymnasium trajectories (observations, rewards, infos) under seeded random
  actions, with and without the filter in the observation.

Run it on each checkout (``PYTHONPATH=CHECKOUT`` chooses the package), then compare::

    python scripts/record_identity.py dump /tmp/before.jsonl
    PYTHONPATH=/tmp/new python scripts/record_identity.py dump /tmp/after.jsonl
    python scripts/record_identity.py compare /tmp/before.jsonl /tmp/after.jsonl

A quick check while working: dump a few seeds (``--episodes 5 --groups planners presets env``)
and compare with ``--subset`` against a full dump. The flags are the ``cdf-mj`` ones
(``--seed``, ``--episodes``); the old ``--seed0`` and ``--seeds`` (a count here) still work,
with a note on stderr after the dump.

``compare`` prints how many lines of each group agree, names the first keys that differ,
and exits 1 when any do. The default held-out seeds, 700000-700119, are a range no page
of this project reports.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

PROG = "record_identity"
_GROUPS = ("reproduce", "planners", "presets", "env")
_PRESET_PLANNERS = ("cdf", "imm-layered", "reactive")


def _jobs(groups: Sequence[str], seed0: int, n: int) -> Iterator[tuple[str, str, str, int]]:
    from cdf_mj.planners import PLANNERS
    from cdf_mj.presets import preset_names

    if "reproduce" in groups:
        for planner in ("cdf", "reactive"):
            yield ("reproduce", "default", planner, -1)  # -1: seeds 0-999 in one job
    if "planners" in groups:
        for planner in sorted(PLANNERS):
            yield ("planners", "default", planner, -2)
    if "presets" in groups:
        for preset in preset_names():
            for planner in _PRESET_PLANNERS:
                yield ("presets", preset, planner, -2)
    if "env" in groups:
        for filt in (False, True):
            yield ("env", "default", "filter" if filt else "plain", -3)


def _run(job: tuple[str, str, str, int], seed0: int, n: int) -> list[str]:
    group, preset, planner, kind = job
    if kind == -3:
        return _env(planner == "filter", seed0, min(n, 12))
    from cdf_mj import Scene, run_episode
    from cdf_mj.presets import load_preset

    config = load_preset(preset)
    scene = Scene.load(names=config.names)
    seeds = range(1000) if kind == -1 else range(seed0, seed0 + n)
    out = []
    for seed in seeds:
        record = run_episode(config, seed=seed, planner=planner, scene=scene, trace=kind != -1).to_dict()
        out.append(json.dumps({"key": [group, preset, planner, seed], "record": record}, sort_keys=True))
    return out


def _env(with_filter: bool, seed0: int, n: int) -> list[str]:
    import gymnasium as gym
    import numpy as np

    import cdf_mj  # noqa: F401  (registers the environment)

    kwargs: dict[str, bool] = ({"posterior_in_observation": True, "command_in_observation": True} if with_filter
                               else {"run_filter": False})
    env = gym.make("cdf_mj/TIntersection-v0", **kwargs)
    out = []
    for seed in range(seed0, seed0 + n):
        obs, info = env.reset(seed=seed)
        env.action_space.seed(seed)
        steps: list[Any] = [[np.asarray(obs).tolist(), _plain(info)]]
        done = False
        while not done:
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            steps.append([np.asarray(obs).tolist(), float(reward), bool(terminated), bool(truncated), _plain(info)])
            done = terminated or truncated
        out.append(json.dumps({"key": ["env", "default", "filter" if with_filter else "plain", seed],
                               "record": steps}, sort_keys=True))
    env.close()
    return out


def _plain(value: Any) -> Any:
    import numpy as np

    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def dump(path: str, groups: Sequence[str], seed0: int, n: int, workers: int) -> int:
    jobs = list(_jobs(groups, seed0, n))
    lines: list[str] = []
    with ProcessPoolExecutor(workers) as pool:
        for i, got in enumerate(pool.map(_run, jobs, [seed0] * len(jobs), [n] * len(jobs))):
            lines.extend(got)
            print(f"{i + 1}/{len(jobs)} {jobs[i][:3]}", file=sys.stderr, flush=True)
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    print(f"{len(lines)} lines to {path}")
    return 0


def _read(path: str) -> dict[str, str]:
    out: dict[str, str] = {}
    with open(path, encoding="utf-8") as f:
        for no, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
                out[json.dumps(row["key"])] = json.dumps(row["record"], sort_keys=True)
            except (ValueError, KeyError, TypeError):
                raise ValueError(f"{path}, line {no}: not a line of a dump (a JSON object with key and "
                                 "record)") from None
    return out


def compare(before: str, after: str, show: int = 10, subset: bool = False) -> int:
    a, b = _read(before), _read(after)
    if subset:  # the second dump ran fewer seeds or groups: only its keys are compared
        a = {k: v for k, v in a.items() if k in b}
    common = sorted(set(a) & set(b))
    differ = [k for k in common if a[k] != b[k]]
    by_group: dict[str, list[int]] = {}
    for k in common:
        g = json.loads(k)[0]
        by_group.setdefault(g, [0, 0])[0] += 1
        by_group[g][1] += a[k] != b[k]
    for g, (total, bad) in sorted(by_group.items()):
        print(f"{g}: {total - bad} of {total} identical")
    only = len(set(a) ^ set(b))
    if only:
        print(f"{only} keys in one dump only")
    for k in differ[:show]:
        ra, rb = json.loads(a[k]), json.loads(b[k])
        fields = sorted(f for f in set(ra) | set(rb) if ra.get(f) != rb.get(f)) if isinstance(ra, dict) else ["steps"]
        print(f"differs: {k}: {', '.join(fields)}")
    return 1 if differ or only else 0


def _option(parser: argparse.ArgumentParser, name: str, old: str, **kwargs: Any) -> None:
    """``name``, with ``old`` its old spelling (:func:`cdf_mj.cli.args.add_option`, which leaves a
    note); a checkout older than the one vocabulary (issue 34) takes both, without one."""
    try:
        from cdf_mj.cli.args import add_option
    except ImportError:
        parser.add_argument(name, old, **kwargs)
    else:
        add_option(parser, name, old=(old,), **kwargs)


def _notes(args: argparse.Namespace) -> list[str]:
    """The old spellings' notes (none where the checkout keeps none)."""
    try:
        from cdf_mj.cli.args import notes
    except ImportError:
        return []
    return notes(args)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    d = sub.add_parser("dump", help="run the episodes and write one JSON line each")
    d.add_argument("out")
    d.add_argument("--groups", nargs="+", choices=_GROUPS, default=list(_GROUPS))
    _option(d, "--seed", "--seed0", type=int, default=700000, help="first held-out seed (default 700000)")
    _option(d, "--episodes", "--seeds", type=int, default=120,
            help="held-out seeds per planner and preset (default 120)")
    d.add_argument("--workers", type=int, default=2)
    c = sub.add_parser("compare", help="compare two dumps; exit 1 if any line differs")
    c.add_argument("before")
    c.add_argument("after")
    c.add_argument("--subset", action="store_true", help="compare only the keys of the second dump")
    try:
        args = parser.parse_args(argv)
    except ValueError as exc:  # cdf_mj.cli.args.CLIError: a flag and its old spelling together
        parser.error(str(exc))
    try:
        if args.command != "dump":
            return compare(args.before, args.after, subset=args.subset)
        status = dump(args.out, args.groups, args.seed, args.episodes, args.workers)
    except (OSError, ValueError, KeyError) as exc:  # a missing or damaged dump, an unwritable path
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    for text in _notes(args):
        print(f"{PROG}: note: {text}", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
