"""The scenario: the world that ticks both cars (:class:`World`), one episode as a pure
function of its seed (:func:`run_episode`), and the CDF monitor for simulations that
someone else steps."""
