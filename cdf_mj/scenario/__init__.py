"""The scenario: the world that ticks both cars (:mod:`~cdf_mj.scenario.world`), one episode
as a pure function of its seed (:mod:`~cdf_mj.scenario.episode`), and the CDF monitor for
simulations that someone else steps (:mod:`~cdf_mj.scenario.monitor`)."""
