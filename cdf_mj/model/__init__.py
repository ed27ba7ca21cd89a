"""The models behind the scenario, in NumPy only (no MuJoCo): geometry, the drivers and
the kinematic bicycle, line of sight against building boxes.

This is the lowest layer of the package: the simulator (:mod:`cdf_mj.sim`), the particle
filter (:mod:`cdf_mj.inference`) and the planners (:mod:`cdf_mj.planners`) build on it,
and it imports none of them.
"""
