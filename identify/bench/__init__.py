"""The simulated bench: synthetic records of the paper's transducer with known truth
(:mod:`identify.bench.synthetic`), the interval-coverage calibration and the closed loop
that check the method against that truth."""

from .synthetic import DEFAULT_FS, DEFAULT_NOISE_SIGMA, parse_effect_spec, sensor_noise, simulate

__all__ = ["DEFAULT_FS", "DEFAULT_NOISE_SIGMA", "parse_effect_spec", "sensor_noise", "simulate"]
