"""Virtual test bench: simulated measurements of the paper's transducer with known hidden effects.

:func:`simulate` is pure (no I/O): it drives the GPI model (Table 1 by default) plus any
effects from :mod:`model.effects` with the paper's input, eqs. (14)-(17), adds Gaussian
sensor noise (white or AR(1)) from one explicit :class:`numpy.random.Generator` seeded
by ``seed``, and returns the :class:`~identify.data.records.Record` together with the whole
truth (a JSON-ready dict for the record's sidecar). The command ``python -m identify
simulate`` (:mod:`identify.cli.simulate`) writes both to disk.

Effect specifications (:func:`parse_effect_spec`) are comma-separated items: a bare
effect name switches the effect on with its test parameters
(:meth:`model.Effect.get_test_parameters`); ``name=value`` sets one parameter and
switches its effect on (its other parameters start from the test parameters), e.g.
``"thermal,creep_amplitude=0.02"``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import model
from model import EFFECTS, INPUT_READINGS, READINGS, TABLE1, THETA_NAMES, Model
from model.signals import drive_current

from ..data.records import Record
from ..defaults import DEFAULT_FS, DEFAULT_NOISE_SIGMA
from ..fitting.noise import ar1_noise
from ..version import __version__

__all__ = [
    "simulate_like",
    "Simulation",
    "simulate",
    "parse_effect_spec",
    "sensor_noise",
    "DEFAULT_NOISE_SIGMA",
    "DEFAULT_FS",
]


@dataclass(frozen=True)
class Simulation:
    """A simulated measurement and the truth behind it.

    Attributes
    ----------
    record : identify.data.records.Record
        The measurement: time [s], current [A], displacement [um] (with noise); its
        ``sidecar`` is :attr:`truth`.
    truth : dict
        JSON-ready: everything needed to reproduce and score the record (see
        :func:`simulate`).
    clean : ndarray, shape (T,)
        Noise-free displacement [um] (model with the effects).
    plain : ndarray, shape (T,)
        Noise-free displacement of the plain GPI (no effects) [um].
    """

    record: Record
    truth: dict
    clean: np.ndarray
    plain: np.ndarray


def _known_effects() -> str:
    return "; ".join(f"{name} ({', '.join(cls.parameters.names)})" for name, cls in EFFECTS.items())


def parse_effect_spec(spec) -> dict[str, dict[str, float]]:
    """Parse an effect specification into ``{effect: {parameter: value}}``.

    Parameters
    ----------
    spec : str, or mapping, or None
        Comma-separated items, each an effect name (switch it on with its test
        parameters) or ``parameter=value`` (set that parameter; switches its effect on).
        ``None``, ``""`` or ``"none"`` mean no effects. A mapping
        ``{effect: {parameter: value}}`` is validated and completed the same way.

    Returns
    -------
    dict
        Every effect switched on, in the library's canonical order, with all of its
        parameters (test parameters overridden by the values given).

    Raises
    ------
    ValueError
        Unknown effect or parameter (the message lists the library), a value that is
        not a finite number or lies outside the parameter's bounds, a parameter given
        twice, or an empty item.
    """
    chosen: dict[str, dict[str, float]] = {}

    def switch_on(effect_name):
        if effect_name not in chosen:
            cls = EFFECTS[effect_name]
            values = {n: float(cls.off[n]) for n in cls.parameters.names}
            values.update({n: float(v) for n, v in cls.get_test_parameters().items()})
            chosen[effect_name] = values

    owner = {p.name: name for name, cls in EFFECTS.items() for p in cls.parameters}
    explicit: dict[str, float] = {}

    def set_value(param, value, where):
        if param not in owner:
            raise ValueError(
                f"{where}: unknown parameter {param!r}; the effects and their parameters are: {_known_effects()}"
            )
        if param in explicit:
            raise ValueError(f"{where}: parameter {param!r} is given twice")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: the value of {param!r} must be a number, got {value!r}") from None
        bounds = EFFECTS[owner[param]].parameters[param]
        if not np.isfinite(number) or not (bounds.lower <= number <= bounds.upper):
            raise ValueError(
                f"{where}: {param}={number!r} is outside its bounds [{bounds.lower}, {bounds.upper}] "
                f"{bounds.unit}".rstrip()
            )
        switch_on(owner[param])
        explicit[param] = number

    if spec is None:
        return {}
    if isinstance(spec, dict):
        for effect_name, params in spec.items():
            if effect_name not in EFFECTS:
                raise ValueError(f"unknown effect {effect_name!r}; the library has: {_known_effects()}")
            switch_on(effect_name)
            for param, value in (params or {}).items():
                if owner.get(param, effect_name) != effect_name:
                    raise ValueError(f"parameter {param!r} belongs to effect {owner[param]!r}, not {effect_name!r}")
                set_value(param, value, f"effect {effect_name!r}")
    else:
        text = str(spec).strip()
        if text.lower() in ("", "none"):
            return {}
        for position, item in enumerate(text.split(","), start=1):
            item = item.strip()
            where = f"effect spec item {position} ({item!r})"
            if not item:
                raise ValueError(f"effect spec {text!r}: item {position} is empty (stray comma?)")
            if "=" in item:
                param, _, value = item.partition("=")
                set_value(param.strip(), value.strip(), where)
            elif item in EFFECTS:
                switch_on(item)
            else:
                raise ValueError(
                    f"{where}: unknown effect or missing '=value'; the effects and their parameters are: "
                    f"{_known_effects()}"
                )
    for param, value in explicit.items():
        chosen[owner[param]][param] = value
    return {name: chosen[name] for name in EFFECTS if name in chosen}


def sensor_noise(rng: np.random.Generator, n_samples: int, sigma: float, rho: float = 0.0) -> np.ndarray:
    r"""Gaussian sensor noise, white or AR(1), with marginal standard deviation ``sigma``.

    .. math::  e_0 = \sigma n_0, \qquad e_k = \rho\, e_{k-1} + \sigma\sqrt{1-\rho^2}\, n_k, \qquad n_k \sim N(0, 1)

    (stationary from the first sample).

    Parameters
    ----------
    rng : numpy.random.Generator
        The one source of randomness.
    n_samples : int
        ``T``.
    sigma : float
        Standard deviation [output units], ``>= 0``.
    rho : float, default 0
        Lag-1 autocorrelation, ``-1 < rho < 1``; 0 gives white noise.

    Returns
    -------
    ndarray, shape (T,)
    """
    if not (np.isfinite(sigma) and sigma >= 0):
        raise ValueError(f"noise sigma must be a finite number >= 0, got {sigma!r}")
    if not (np.isfinite(rho) and -1.0 < rho < 1.0):
        raise ValueError(f"noise rho must lie strictly between -1 and 1, got {rho!r}")
    innovations = rng.standard_normal((1, n_samples))
    return sigma * ar1_noise(innovations, np.full(max(n_samples - 1, 0), rho))[0]


def simulate(
    effects=None,
    *,
    noise_sigma: float = DEFAULT_NOISE_SIGMA,
    noise_rho: float = 0.0,
    fs: float = DEFAULT_FS,
    input_reading: str = "literal",
    seed: int = 0,
    gpi_theta=None,
    n_operators: int = 12,
    reading: str = "swapped",
    duration: float = 70.0,
    drive: str = "paper",
    current=None,
) -> Simulation:
    """Simulate one bench measurement of the paper's transducer.

    Parameters
    ----------
    effects : str or dict or None, default None
        Hidden effects, as accepted by :func:`parse_effect_spec` (e.g. ``"thermal"`` or
        ``{"creep": {"creep_amplitude": 0.02}}``). None: the plain GPI.
    noise_sigma : float, default 0.5
        Sensor noise standard deviation [um].
    noise_rho : float, default 0.0
        Lag-1 autocorrelation of the noise (AR(1)); 0 is white.
    fs : float, default 100.0
        Sampling rate [Hz].
    input_reading : {"literal", "centred"}, default "literal"
        Reading of the paper's eq. (16) (:mod:`model.signals`).
    seed : int, default 0
        Seed of the one :class:`numpy.random.Generator` (the noise).
    gpi_theta : array_like, shape (19,), optional
        GPI parameters in Table 1 order; default Table 1.
    n_operators : int, default 12
    reading : {"swapped", "literal"}, default "swapped"
        Reading of eqs. (5)-(7) (:mod:`model.gpi`).
    duration : float, default 70.0
        Record length [s] of the paper's drive; the first 10 s are unenergised.
    drive : {"paper", "holds"}, default "paper"
        The drive (:func:`model.signals.drive_current`): the paper's, or cycles that fall and
        rise again, a hold at 4.5 A and a quiet end.
    current : tuple of (time, current) arrays, optional
        Any other drive: ``time`` [s] strictly increasing, ``current`` [A], shape (T,) each
        (e.g. a designed next record); ``drive`` and ``duration`` are then not used.

    Returns
    -------
    Simulation
        ``truth`` holds: ``theta`` (every parameter by name), ``effects`` (effect ->
        parameters), ``model`` (effects, n_operators, reading), ``noise`` (sigma, rho,
        kind), ``seed``, ``fs``, ``duration``, ``input_reading``, ``units``,
        ``software`` (package and version), and ``effect_size`` (RMS and max of the
        effects' noise-free contribution, the full scale, and the RMS-to-noise ratio).

    Raises
    ------
    ValueError
        Bad effect spec, noise settings, input reading, sampling rate or GPI theta.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if input_reading not in INPUT_READINGS:
        raise ValueError(f"input_reading must be one of {INPUT_READINGS}, got {input_reading!r}")
    if reading not in READINGS:
        raise ValueError(f"reading must be one of {sorted(READINGS)}, got {reading!r}")
    chosen = parse_effect_spec(effects)
    rng = np.random.default_rng(seed)

    given = current is not None
    if not given:
        time, current = drive_current(drive, fs=fs, reading=input_reading, duration=duration)
    else:
        time, current = (np.asarray(a, dtype=float) for a in current)
        if time.ndim != 1 or current.shape != time.shape or time.size < 2 or not np.all(np.diff(time) > 0):
            raise ValueError("current must be (time, current), two arrays of one shape (T,), time strictly increasing")
        if not (np.isfinite(time).all() and np.isfinite(current).all()):
            raise ValueError("the given drive has a value that is not finite")
    sim_model = Model(list(chosen), n_operators=n_operators, reading=reading)
    gpi_values = TABLE1 if gpi_theta is None else np.asarray(gpi_theta, dtype=float)
    if gpi_values.shape != (len(THETA_NAMES),):
        raise ValueError(f"gpi_theta must have shape ({len(THETA_NAMES)},) in Table 1 order, got {gpi_values.shape}")
    values = dict(zip(THETA_NAMES, map(float, gpi_values)))
    for params in chosen.values():
        values.update(params)
    theta = sim_model.theta_from_dict(values)
    clean = sim_model(theta, time, current)
    plain = clean if not chosen else Model(n_operators=n_operators, reading=reading)(gpi_values, time, current)
    noise = sensor_noise(rng, time.size, float(noise_sigma), float(noise_rho))
    displacement = clean + noise

    contribution = clean - plain
    effect_rms = float(np.sqrt(np.mean(contribution**2)))
    full_scale = float(np.ptp(plain))
    truth = {
        "generator": "identify.bench.simulate",
        "theta": sim_model.theta_dict(theta),
        "effects": {name: dict(params) for name, params in chosen.items()},
        "model": sim_model.to_dict(),
        "noise": {"sigma": float(noise_sigma), "rho": float(noise_rho), "kind": "ar1" if noise_rho else "white"},
        "seed": int(seed),
        "fs": float(1.0 / np.median(np.diff(time))) if given else float(fs),
        "duration": float(time[-1] - time[0]),
        "drive": "given" if given else drive,
        "n_samples": int(time.size),
        "input_reading": input_reading,
        "quiet_seconds": float(model.QUIET_SECONDS),
        "units": {"time": "s", "current": "A", "displacement": "um"},
        "software": {"package": "msma-gpi", "version": _version()},
        "effect_size": {
            "rms_um": effect_rms,
            "max_abs_um": float(np.max(np.abs(contribution))),
            "full_scale_um": full_scale,
            "max_pct_of_full_scale": 100.0 * float(np.max(np.abs(contribution))) / full_scale if full_scale else 0.0,
            "rms_over_noise_sigma": effect_rms / float(noise_sigma) if noise_sigma else None,
        },
    }
    record = Record(
        time=time,
        current=current,
        displacement=displacement,
        source=f"virtual bench (seed {seed})",
        sha256="",
        notes=("simulated by identify.bench.simulate; the truth is in the sidecar",),
        sidecar=truth,
    )
    return Simulation(record=record, truth=truth, clean=clean, plain=plain)


def _version() -> str:
    return __version__


def simulate_like(truth: dict, time, current, *, seed: int = 0, noise_sigma=None, noise_rho=None) -> Simulation:
    """Another record of the transducer a truth describes (a sidecar of :func:`simulate`: its model,
    every parameter by name, its noise) driven by ``current`` at ``time``, with fresh noise from
    ``seed``. The run's own parameters (:attr:`model.Parameter.per_record`) are kept as they were.

    Parameters
    ----------
    truth : dict
        The sidecar (``model``, ``theta``, ``noise``).
    time, current : array_like, shape (T,)
        The drive [s], [A].
    seed : int, default 0
    noise_sigma, noise_rho : float, optional
        Default: the truth's.
    """
    try:
        model = Model.from_dict(truth["model"])
        theta = model.theta_from_dict(truth["theta"])
        noise = truth["noise"]
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"the truth does not describe a transducer of the bench ({exc})") from None
    gpi_theta = theta[: len(THETA_NAMES)]
    effects = {e.name: {p: float(theta[model.names.index(p)]) for p in e.parameters.names} for e in model.effects}
    return simulate(
        effects,
        noise_sigma=float(noise["sigma"] if noise_sigma is None else noise_sigma),
        noise_rho=float(noise.get("rho", 0.0) if noise_rho is None else noise_rho),
        seed=seed,
        gpi_theta=gpi_theta,
        n_operators=model.n_operators,
        reading=model.reading,
        current=(time, current),
    )
