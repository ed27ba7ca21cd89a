"""Drive the Gymnasium environment with a small hand-written policy and save a video.

The policy is what a user might write on top of ``cdf_mj/TIntersection-v0`` with the CDF
posterior in the observation: keep the lane and 13.4 m/s with two proportional
controllers, and brake hard once P(cut-off) passes a threshold. ::

    python scripts/drive_env.py --seed 1 --out drive.mp4
    python scripts/drive_env.py --seed 1 --scene models/xml/scene_fourway.xml --camera ego_chase

Without a display, the environment renders through EGL (or OSMesa) unless ``MUJOCO_GL``
says otherwise.
"""

from __future__ import annotations

import argparse
import math
import sys

import gymnasium as gym
import imageio.v2 as imageio
import numpy as np

import cdf_mj  # registers the environment
from cdf_mj.sim.scene import DEFAULT_SCENE


def cautious_policy(obs: np.ndarray, lane_y: float, brake_at: float = 0.5) -> np.ndarray:
    """[acceleration m/s^2, steering rad] from the observation (pose + posterior)."""
    _, y, theta, v = obs[:4]
    p_cutoff = obs[10]
    # Brake at the car's maximum rate (the action is clipped to the range anyway), else hold
    # the lane's speed.
    accel = -4.877 if p_cutoff >= brake_at else 1.0 * (13.4 - v)
    steer = -0.05 * (y - lane_y) - 0.8 * math.remainder(theta, 2 * math.pi)
    return np.array([accel, steer], dtype=np.float32)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=1, help="episode seed (default 1: a cut-off)")
    p.add_argument("--scene", default=str(DEFAULT_SCENE), help="MJCF scene file")
    p.add_argument("--camera", default="top", help="camera name (top, ego_chase, obstacle_chase)")
    p.add_argument("--out", default="drive.mp4", help="video file (.mp4 or .gif)")
    p.add_argument("--brake-at", type=float, default=0.5, help="P(cut-off) that triggers braking")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--max-steps", type=int, default=None, help="stop after this many steps")
    args = p.parse_args(argv)

    env = gym.make(cdf_mj.ENV_ID, render_mode="rgb_array", scene=args.scene,
                   posterior_in_observation=True, camera=args.camera, width=args.width,
                   height=args.height)
    lane_y = float(env.unwrapped.scene.layout().ego_lane.center[1])
    obs, info = env.reset(seed=args.seed)
    frames = [env.render()]
    total, done = 0.0, False
    while not done and (args.max_steps is None or len(frames) <= args.max_steps):
        obs, reward, terminated, truncated, info = env.step(cautious_policy(obs, lane_y, args.brake_at))
        frames.append(env.render())
        total += reward
        done = terminated or truncated
    env.close()
    fps = env.metadata["render_fps"]
    imageio.mimsave(args.out, frames, fps=fps) if args.out.endswith(".gif") else \
        imageio.mimsave(args.out, frames, fps=fps, macro_block_size=1)
    print(f"seed {args.seed}: label {info['label']}, collision {info['collision']}, "
          f"{len(frames)} frames at {fps} fps, return {total:.1f}; video {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
