"""The scenario: two agents and a world. The obstacle agent looks, believes and drives
(:mod:`~cdf_mj.scenario.obstacle_agent`, with the driver families of
:mod:`~cdf_mj.scenario.drivers` and the after-merge option); the ego agent senses, asks its
planner and drives (:mod:`~cdf_mj.scenario.ego_agent`, with :mod:`~cdf_mj.scenario.sensing`);
the world keeps the scene, the random streams, physics and the episode's end
(:mod:`~cdf_mj.scenario.world`). One episode is a pure function of its seed
(:mod:`~cdf_mj.scenario.episode`: measure, the ego acts, the world steps); the CDF monitor
serves simulations that someone else steps (:mod:`~cdf_mj.scenario.monitor`)."""
