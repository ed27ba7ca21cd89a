"""Pictures: offscreen videos and frames of an episode (``cdf-mj render``) and the figures
of an experiment (``cdf-mj report``). Needs the ``viz`` extra."""
