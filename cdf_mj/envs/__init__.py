"""Gymnasium environments. ``cdf_mj/TIntersection-v0`` is
:class:`cdf_mj.envs.t_intersection.TIntersectionEnv` (needs the ``gym`` extra); importing
this package does not import Gymnasium."""

from __future__ import annotations

from typing import Any

#: Gymnasium id of :class:`cdf_mj.envs.t_intersection.TIntersectionEnv`.
ENV_ID = "cdf_mj/TIntersection-v0"

__all__ = ["ENV_ID", "TIntersectionEnv"]


def __getattr__(name: str) -> Any:
    """``TIntersectionEnv`` on first access (imports Gymnasium then)."""
    if name == "TIntersectionEnv":
        from cdf_mj.envs.t_intersection import TIntersectionEnv

        return TIntersectionEnv
    raise AttributeError(f"module 'cdf_mj.envs' has no attribute {name!r}")
