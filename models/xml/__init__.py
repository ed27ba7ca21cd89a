"""The MJCF files of cdf_mj. This folder is installed as the package ``cdf_mj.assets``
(see pyproject.toml) so that installed copies read it with ``importlib.resources``."""
