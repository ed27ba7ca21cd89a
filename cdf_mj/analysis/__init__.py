"""Metrics and tables of episode records: rates with intervals (:mod:`~cdf_mj.analysis.metrics`),
the paper's tables beside ours as text or Markdown (:mod:`~cdf_mj.analysis.tables`). Reads
records (counted by the rules of :mod:`cdf_mj.records`); runs nothing."""
