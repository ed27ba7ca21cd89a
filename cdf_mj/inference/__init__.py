"""The particle filter over the CDF's dynamic Bayesian network, and its resamplers.
Built from a junction's static :class:`~cdf_mj.model.layout.Layout` and the driver model
(:mod:`cdf_mj.model`); never from a live simulation."""
