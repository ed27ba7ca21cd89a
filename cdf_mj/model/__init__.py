"""The models behind the scenario, in NumPy and compiled Numba kernels (no MuJoCo):
geometry, the cars' dimensions (:mod:`~cdf_mj.model.vehicle`), the junction's static
layout (:mod:`~cdf_mj.model.layout`), the road's words that every caller shares (in the
lane, ahead, gap, the IDM, the RSS distance, car following: :mod:`~cdf_mj.model.road`), the
drivers' modes and intents (:mod:`~cdf_mj.model.modes`), the drivers and the kinematic
bicycle (their per-car code in :mod:`~cdf_mj.model.kernels`), line of sight against
building boxes, the conflict map and the risk rule's rollouts (:mod:`~cdf_mj.model.conflict`).

This is the lowest layer above the configuration: the simulator (:mod:`cdf_mj.sim`), the
particle filter (:mod:`cdf_mj.inference`) and the planners (:mod:`cdf_mj.planners`) build
on it, and it imports none of them.
"""
