"""The baseline planners' names where version 0.3 kept them, one module for both; each
now lives with its predictor. Kept so that code and registry targets written against 0.3
(``"cdf_mj.planners.baselines:IMMPlanner"``) still work; new code imports from the homes:

==================================================  ====================================
``CVConfig``, ``CVPlanner``, ``CVRiskPlanner``,     :mod:`cdf_mj.planners.cv`
``CVLayeredPlanner``
``IMMConfig``, ``IMMPlanner``, ``IMMRiskPlanner``,  :mod:`cdf_mj.planners.imm` (filterpy)
``IMMLayeredPlanner``, ``RouteKalmanFilter``
``BASELINE_LAYERS``, ``first_conflict``,            :mod:`cdf_mj.planners.baseline_common`
``straight_path``, ``route_heading``
``boxes_overlap``                                   :mod:`cdf_mj.model.geometry`
==================================================  ====================================

Importing this module imports both, and so filterpy (about 1 s).
"""

from __future__ import annotations

from cdf_mj.model.geometry import boxes_overlap
from cdf_mj.planners.baseline_common import BASELINE_LAYERS, first_conflict, route_heading, straight_path
from cdf_mj.planners.cv import CVConfig, CVLayeredPlanner, CVPlanner, CVRiskPlanner
from cdf_mj.planners.imm import IMMConfig, IMMLayeredPlanner, IMMPlanner, IMMRiskPlanner, RouteKalmanFilter

__all__ = [
    "BASELINE_LAYERS",
    "CVConfig",
    "CVLayeredPlanner",
    "CVPlanner",
    "CVRiskPlanner",
    "IMMConfig",
    "IMMLayeredPlanner",
    "IMMPlanner",
    "IMMRiskPlanner",
    "RouteKalmanFilter",
    "boxes_overlap",
    "first_conflict",
    "route_heading",
    "straight_path",
]
