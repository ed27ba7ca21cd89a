"""The particle filter over the CDF's dynamic Bayesian network, and its resamplers.
Built from the scene's geometry and the driver model (:mod:`cdf_mj.model`); never from a
live simulation."""
