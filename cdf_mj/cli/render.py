"""``cdf-mj render``: one episode rendered offscreen to MP4, GIF or a PNG frame; the same
seed under several planners side by side (``--planner cdf,imm,reactive``), or a monitor
trace of the user's own episode over their scene (``--trace``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from cdf_mj.cli.args import (
    CLIError,
    add_cdf_arguments,
    add_planner_option,
    add_run_arguments,
    cdf_from_args,
    command,
    config_from_args,
    finite_float,
    int_in,
    out_path,
    pixel_count,
    scene_from_args,
    seed_value,
)
from cdf_mj.config import MAX_PARTICLES, CDFConfig, ScenarioConfig
from cdf_mj.extras import install_hint
from cdf_mj.sim.checks import read_names
from cdf_mj.sim.scene import Scene


def _say_removed(stale: tuple[Path, ...], out: str) -> None:
    """One line naming the temporary files of killed renders of ``out`` that the render
    removed (:func:`cdf_mj.viz.encoding.remove_stale_temporaries`), if any."""
    from cdf_mj.viz.report import shown_path

    if stale:
        print(f"removed {len(stale)} temporary file(s) that killed renders of {shown_path(out)} left: "
              + ", ".join(shown_path(p.name) for p in stale))


def _cmd_render_trace(args: argparse.Namespace) -> int:
    from cdf_mj.viz.trace import render_trace

    unused = [flag for flag, given in (("--set", args.overrides), ("--preset", args.preset),
                                       ("--layout", args.layout != "overlay"), ("--seed", args.seed is not None),
                                       ("--planner", args.planner is not None))
              if given]
    if unused:
        raise CLIError(f"{', '.join(unused)}: not used with --trace (the trace holds the episode "
                       "and is drawn with the panel over the view)")
    names = read_names(args.names) if args.names is not None else None
    result = render_trace(args.trace, args.scene, args.out, names=names, width=args.width,
                          height=args.height, fps=args.fps, frame_time=args.frame, camera=args.camera)
    _say_removed(result.stale_removed, args.out)
    what = (f"{result.n_frames} frames, {result.duration:.2f} s of the trace at "
            f"{result.frames_per_second:g} fps" if result.n_frames > 1
            else f"the frame at {result.duration:.2f} s")
    print(f"wrote {result.path}: {what} ({result.backend}); brake {result.brake_time}")
    return 0


#: Most planners drawn side by side (tiles of one frame).
MAX_TILES = 6


def _cmd_render_compare(args: argparse.Namespace, config: ScenarioConfig, scene: Scene,
                        cdf: CDFConfig) -> int:
    from cdf_mj.viz.render import render_compare, tile_caption

    planners = tuple(args.planner)
    repeated = sorted({n for n in planners if planners.count(n) > 1})
    if repeated:
        raise CLIError(f"--planner: planner {repeated[0]!r} given twice; name each once")
    if len(planners) > MAX_TILES:
        raise CLIError(f"--planner: {len(planners)} planners; at most {MAX_TILES} are drawn side by side")
    result = render_compare(args.out, seed=args.seed, planners=planners,
                            config=config, cdf=cdf, scene=scene, camera=args.camera, width=args.width,
                            height=args.height, fps=args.fps, frame_time=args.frame,
                            layout=args.layout, max_particles=args.max_particles,
                            shadows=args.shadows, antialias=args.antialias)
    _say_removed(result.stale_removed, args.out)
    rate = result.n_frames / max(result.render_seconds, 1e-9)
    what = (f"{result.n_frames} frames of {len(result.records)} tiles, {result.duration:.2f} s at "
            f"{result.frames_per_second:g} fps; rendered at {rate:.1f} frames/s" if result.n_frames > 1
            else f"the frame at {result.duration:.2f} s of {len(result.records)} tiles")
    print(f"wrote {result.path}: {what} ({result.backend}); label {result.label}; "
          + "; ".join(tile_caption(r) for r in result.records))
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from cdf_mj.viz.render import DEFAULT_SEED, render_episode

    if args.trace is not None:
        return _cmd_render_trace(args)
    config = config_from_args(args)
    scene = scene_from_args(args, config)
    planners = args.planner or ["cdf"]
    cdf = cdf_from_args(args, planners)
    args.seed = DEFAULT_SEED if args.seed is None else args.seed
    if len(planners) > 1:
        return _cmd_render_compare(args, config, scene, cdf)
    result = render_episode(args.out, seed=args.seed, planner=planners[0], config=config,
                            cdf=cdf, scene=scene, camera=args.camera, width=args.width,
                            height=args.height, fps=args.fps, frame_time=args.frame,
                            layout=args.layout, max_particles=args.max_particles,
                            shadows=args.shadows, antialias=args.antialias)
    _say_removed(result.stale_removed, args.out)
    if result.n_frames > 1:
        rate = result.n_frames / max(result.render_seconds, 1e-9)
        what = (f"{result.n_frames} frames, {result.duration:.2f} s of simulated time at "
                f"{result.frames_per_second:g} fps; rendered at {rate:.1f} frames/s")
    else:
        what = f"the frame at {result.duration:.2f} s"
    print(f"wrote {result.path}: {what} ({result.backend}); label {result.label}, "
          f"brake {result.record.brake_time}")
    return 0


def add_render(subparsers: argparse._SubParsersAction) -> None:
    """The ``render`` command."""
    p = command(
        subparsers, "render", compiles=True, summary="render one episode offscreen to MP4, GIF or a PNG frame",
        description="Run one episode and render it offscreen (MUJOCO_GL=egl unless set, else "
                    "osmesa) at a constant frame rate in simulated time, with the obstacle's "
                    "isovist, the CDF's particles, the braking moment and P(left), P(seen), "
                    "P(cutoff) drawn in. The suffix of --out chooses MP4, GIF or PNG (--frame). "
                    "--layout side puts charts of the probabilities and both cars' speeds over "
                    "time beside the view; --planner cdf,imm,reactive draws the same seed under "
                    "each planner, tiles side by side. "
                    "With --trace FILE it draws your own episode instead: a trace that "
                    "CDFMonitor.save_trace wrote, over --scene (your junction's MJCF; --names "
                    "for its names, default those in the trace), both cars' boxes and the "
                    "posterior panel; --seed, --planner and --layout are then refused and "
                    "the CDF options not used. "
                    f"Needs imageio and Pillow ({install_hint('viz')}).")
    p.add_argument("--seed", type=seed_value, default=None,
                   help="episode seed (default 1: a cut-off the CDF brakes for, so the default "
                        "video shows a decision; `episode` defaults to seed 0, reactive, a "
                        "record rather than a picture)")
    add_planner_option(p, None, "ego planner (default cdf: the planner whose belief is drawn); several, "
                       "comma-separated (2 to 6, e.g. cdf,imm,reactive), render the seed under each, tiles side "
                       "by side, each the size of one render and captioned with its planner and brake time (a "
                       "shorter episode holds its last frame)", several=True, old=("--compare",), dest="planner")
    p.add_argument("--layout", choices=("overlay", "side"), default="overlay",
                   help="overlay (default): the posterior panel over the view's top-left; side: "
                        "charts of the probabilities with tau, both cars' speeds, the brake "
                        "decision and the obstacle's lane entry beside the view (adds 3/4 of "
                        "--height to the width; --height >= 160)")
    p.add_argument("--out", type=out_path, required=True, help="output file: .mp4, .gif, or .png with --frame")
    p.add_argument("--trace", metavar="FILE", default=None,
                   help="draw a monitor trace (CDFMonitor.save_trace, JSON lines) over --scene "
                        "instead of running an episode; --frame T is seconds from its first tick")
    p.add_argument("--camera", default=None,
                   help="a camera of the scene, e.g. top, ego_chase or obstacle_chase (default: "
                        "a view that follows both cars and the conflict zone)")
    p.add_argument("--width", type=pixel_count, default=640, help="image width [px], even for MP4 (default 640)")
    p.add_argument("--height", type=pixel_count, default=480, help="image height [px], even for MP4 (default 480)")
    p.add_argument("--fps", type=finite_float(1e-3, 1000.0, "frames per second"), default=None,
                   help="frames per simulated second (default 30 for MP4, 25 for GIF)")
    p.add_argument("--frame", type=finite_float(0.0, 600.0, "[s]"), default=None, metavar="T",
                   help="render the one frame at T seconds to a .png (T from 0 to the episode's "
                        "end; past it is an error naming the end)")
    add_cdf_arguments(p)
    p.add_argument("--max-particles", type=int_in(0, MAX_PARTICLES, "particles"), default=100,
                   help="most distinct particles drawn per frame (default 100)")
    p.add_argument("--shadows", action="store_true", help="draw shadows (slower)")
    p.add_argument("--antialias", action="store_true", help="4x multisampling (slower)")
    add_run_arguments(p, pool=False, progress=False)
    p.set_defaults(func=_cmd_render)
