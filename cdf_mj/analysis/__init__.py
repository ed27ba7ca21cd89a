"""Metrics, tables and figures of episode records: rates with intervals, the paper's
tables beside ours, paired comparisons. Reads records; runs nothing."""
