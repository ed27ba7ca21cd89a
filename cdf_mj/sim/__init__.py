"""The MuJoCo side: load a scene and read it by name, step it, place cars in a spec, cast
rays for line of sight. Imports :mod:`cdf_mj.model` and nothing above it."""
