"""The MuJoCo side: load a scene and read it by name, validate it, step it
(:mod:`~cdf_mj.sim.scene`, :mod:`~cdf_mj.sim.checks`), place cars in a spec
(:mod:`~cdf_mj.sim.spec`), cast rays for line of sight (:mod:`~cdf_mj.sim.visibility`),
find the MJCF files (:mod:`~cdf_mj.sim.assets`), render offscreen (:mod:`~cdf_mj.sim.gl`).
Imports :mod:`cdf_mj.model` and nothing above it."""
