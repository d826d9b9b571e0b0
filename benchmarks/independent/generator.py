"""Independent test-record generator for the MSMA generalized Prandtl-Ishlinskii project.

Written "blind" from the seed paper (eqs. 5-17, Table 1) and the physics of each
hidden effect.  Imports only numpy, scipy and the standard library.

Command line::

    python benchmarks/independent/generator.py --suite clean|effects|all --out DIR [--seed S] [--n N]

Python::

    from generator import clean_records, effect_records, write_record
    for spec in clean_records(5, seed=1):
        write_record(spec, "/tmp/x")

A record spec is a JSON-serialisable dict (plus a private "_arrays" cache); it holds
everything needed to rebuild the record: GPI parameters, input reading, sampling rate,
the hidden effects with their final (size-scaled) parameters, the noise description
and the seed key of the noise stream.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time as _time

import numpy as np
from scipy import signal

# ----------------------------------------------------------------------------------
# Paper constants
# ----------------------------------------------------------------------------------
PARAM_NAMES = [
    "alpha",
    "rho",
    "tau",
    "a0",
    "a1",
    "a2",
    "a3",
    "b0",
    "b1",
    "b2",
    "b3",
    "c0",
    "c1",
    "c2",
    "c3",
    "d0",
    "d1",
    "d2",
    "d3",
]
TABLE1 = np.array(
    [
        -0.1993,
        5.6438,
        0.0714,
        8.5043,
        0.5140,
        -0.0612,
        -6.1533,
        3.3505,
        1.3916,
        -0.9146,
        3.6876,
        1.5687,
        6.6176,
        -11.5359,
        25.7303,
        2.1349,
        7.1117,
        -9.2777,
        28.1546,
    ]
)
N_OPERATORS = 12
DURATION = 70.0  # s
T_ON = 10.0  # s, energising starts
I_PEAK = 5.0  # A, peak of the undecayed command
CATEGORIES = ["thermal", "lag", "creep", "sensor_drift", "first_cycle", "training", "initial_state", "outside"]
SUITE_KEY = {"clean": 0, "effects": 1}


# ----------------------------------------------------------------------------------
# Input (eqs. 14-17)
# ----------------------------------------------------------------------------------
def time_axis(fs):
    n = int(round(DURATION * fs)) + 1
    return np.arange(n) / float(fs)


def commanded_current(t, reading):
    """Current command of eqs. (15)-(17).

    literal: V = v * (1 - 0.01 (t-20)) for t >= 20 (troughs stay at 0 A, peaks fall).
    centred: V = 2.5 + (v - 2.5)(1 - 0.01 (t-20)) (the sine decays around 2.5 A).
    """
    t = np.asarray(t, float)
    on = t >= T_ON
    v = np.where(on, 2.5 * np.sin(0.2 * np.pi * t - np.pi / 2) + 2.5, 0.0)
    f = np.where(t >= 20.0, 1.0 - 0.01 * (t - 20.0), 1.0)
    if reading == "literal":
        out = v * f
    elif reading == "centred":
        out = np.where(on, 2.5 + (v - 2.5) * f, 0.0)
    else:
        raise ValueError(reading)
    return out


# ----------------------------------------------------------------------------------
# Generalized Prandtl-Ishlinskii model (own implementation, eqs. 5-13)
# ----------------------------------------------------------------------------------
def _split(theta):
    th = np.asarray(theta, float)
    return th[0], th[1], th[2], th[3:7], th[7:11], th[11:15], th[15:19]


def thresholds_weights(theta, n_op=N_OPERATORS):
    alpha, rho, tau, *_ = _split(theta)
    r = alpha * np.arange(1, n_op + 1)
    return r, rho * np.exp(-tau * r)


def _tanh4(q, x):
    return q[0] * np.tanh(q[1] * x + q[2]) + q[3]


def virgin_memory(theta, v0, n_op=N_OPERATORS):
    """z_j(t0) = max(gamma_a(v0) - r_j, min(gamma_b(v0) + r_j, 0))."""
    _, _, _, a, b, _, _ = _split(theta)
    r, _ = thresholds_weights(theta, n_op)
    return np.maximum(_tanh4(a, v0) - r, np.minimum(_tanh4(b, v0) + r, 0.0))


def rest_level(theta, n_op=N_OPERATORS):
    """Output of the virgin transducer at 0 A (rising Omega branch)."""
    _, _, _, _, _, c, _ = _split(theta)
    _, p = thresholds_weights(theta, n_op)
    return float(_tanh4(c, 0.0) + p @ virgin_memory(theta, 0.0, n_op))


def gpi(theta, v, n_op=N_OPERATORS, z0=None, thr_scale=None, v_env=None, return_state=False):
    """Generalized PI output y_k = Omega_k + sum_j p_j z_j(t_k).

    v         : input whose increments decide the branch (dv>0 rising, dv<0 falling).
    v_env     : input fed to the envelopes and to Omega (default v).
    thr_scale : optional per-sample factor on all thresholds r_j (time-varying widths;
                the weights p_j keep the nominal thresholds).
    z0        : initial operator memory (default: the virgin memory at v_env[0]).

    Within a run of equal sign of dv the law z_k = max(gamma_a(v_k) - r_j, z_{k-1})
    is a running maximum (running minimum on falling runs), which is how it is
    vectorised here; it is exactly the sample-by-sample law of eq. (5).
    """
    v = np.asarray(v, float)
    ve = v if v_env is None else np.asarray(v_env, float)
    _, _, _, a, b, c, d = _split(theta)
    r, p = thresholds_weights(theta, n_op)
    K = v.size
    ga = _tanh4(a, ve)
    gb = _tanh4(b, ve)
    if thr_scale is None:
        R = np.broadcast_to(r, (K, n_op))
    else:
        R = np.asarray(thr_scale, float)[:, None] * r[None, :]
    up = ga[:, None] - R
    dn = gb[:, None] + R
    if z0 is None:
        zc = np.maximum(up[0], np.minimum(dn[0], 0.0))
    else:
        zc = np.asarray(z0, float).copy()
    Z = np.empty((K, n_op))
    Z[0] = zc
    dv = np.diff(v)
    sg = np.sign(dv)
    if K > 1:
        brk = np.flatnonzero(np.diff(sg)) + 1
        starts = np.r_[0, brk]
        ends = np.r_[brk, sg.size]
        for s0, e0 in zip(starts, ends):
            k0, k1 = s0 + 1, e0 + 1
            if sg[s0] > 0:
                blk = np.maximum(np.maximum.accumulate(up[k0:k1], axis=0), zc)
            elif sg[s0] < 0:
                blk = np.minimum(np.minimum.accumulate(dn[k0:k1], axis=0), zc)
            else:
                blk = np.broadcast_to(zc, (k1 - k0, n_op))
            Z[k0:k1] = blk
            zc = Z[k1 - 1].copy()
    rising = np.r_[True, dv >= 0]
    om = np.where(rising, _tanh4(c, ve), _tanh4(d, ve))
    y = om + Z @ p
    if return_state:
        return y, Z[-1].copy()
    return y


def gpi_reference_loop(theta, v, n_op=N_OPERATORS):
    """Plain sample-by-sample loop (used only by the self-check)."""
    _, _, _, a, b, c, d = _split(theta)
    r, p = thresholds_weights(theta, n_op)
    z = np.maximum(_tanh4(a, v[0]) - r, np.minimum(_tanh4(b, v[0]) + r, 0.0))
    y = np.empty(len(v))
    y[0] = _tanh4(c, v[0]) + p @ z
    for k in range(1, len(v)):
        dv = v[k] - v[k - 1]
        if dv > 0:
            z = np.maximum(_tanh4(a, v[k]) - r, z)
        elif dv < 0:
            z = np.minimum(_tanh4(b, v[k]) + r, z)
        om = _tanh4(c, v[k]) if dv >= 0 else _tanh4(d, v[k])
        y[k] = om + p @ z
    return y


# ----------------------------------------------------------------------------------
# Small signal helpers
# ----------------------------------------------------------------------------------
def lowpass1(x, tau, h):
    """First-order lag tau*y' = x - y, exact for a piecewise-linear x (first-order hold),
    started in steady state with x[0]."""
    x = np.asarray(x, float)
    if tau <= 0:
        return x.copy()
    e = np.exp(-h / tau)
    g = tau / h * (1.0 - e)
    bcoef = [1.0 - g, g - e]
    acoef = [1.0, -e]
    zi = signal.lfilter_zi(bcoef, acoef) * x[0]
    y, _ = signal.lfilter(bcoef, acoef, x, zi=zi)
    return y


def runs_of_direction(u):
    """Runs of equal sign of du (sample indices).  Returns list of
    (sign, first_sample, last_sample); samples k with du_k = u_k - u_{k-1}."""
    sg = np.sign(np.diff(u))
    if sg.size == 0:
        return []
    brk = np.flatnonzero(np.diff(sg)) + 1
    starts = np.r_[0, brk]
    ends = np.r_[brk, sg.size]
    return [(int(sg[s]), int(s + 1), int(e)) for s, e in zip(starts, ends)]


def reversals(u):
    """Sample indices where a monotone leg of u ends and the opposite one starts,
    with the sign of the new leg."""
    out = []
    runs = [r for r in runs_of_direction(u) if r[0] != 0]
    for r0, r1 in zip(runs[:-1], runs[1:]):
        if r1[0] == -r0[0]:
            out.append((r0[2], r1[0]))
    return out


def cycles(u):
    """Accumulated cycles: total current travel / (2 * 5 A)."""
    return np.r_[0.0, np.cumsum(np.abs(np.diff(u)))] / (2.0 * I_PEAK)


def first_peak_trough(u):
    """Index of the first input maximum (end of the first rising run) and of the
    following minimum (end of the next falling run)."""
    runs = [r for r in runs_of_direction(u) if r[0] != 0]
    kp = kq = None
    for n, (sg, _a, b) in enumerate(runs):
        if sg > 0:
            kp = b
            for sg2, _a2, b2 in runs[n + 1 :]:
                if sg2 < 0:
                    kq = b2
                    break
            break
    if kp is None or kq is None:
        raise RuntimeError("input has no first peak / trough")
    return kp, kq


# ----------------------------------------------------------------------------------
# Hidden physics: forms
# ----------------------------------------------------------------------------------
# Each form: category, stage ('input' | 'gpi' | 'output' | 'sensor'), order,
# equation text, draw(rng) -> shape parameters, knob (name, lo, hi, linear, start),
# apply(params, ctx) -> modifies ctx.
FORMS = {}


def _form(name, category, stage, order, equation, knob, linear, lo, hi, start):
    def deco(pair):
        draw, apply = pair
        FORMS[name] = dict(
            name=name,
            category=category,
            stage=stage,
            order=order,
            equation=equation,
            knob=knob,
            linear=linear,
            lo=lo,
            hi=hi,
            start=start,
            draw=draw,
            apply=apply,
        )
        return pair

    return deco


def U(rng, lo, hi):
    return float(rng.uniform(lo, hi))


# ---------------- thermal ----------------
def _therm1_draw(rng):
    return dict(tau_th=U(rng, 8.0, 40.0))


def _therm1_apply(p, c):
    T = lowpass1(c["u"] ** 2, p["tau_th"], c["h"])
    c["y"] = c["y"] + p["kappa"] * T
    c["temperature"] = T


_form(
    "one_pole_expansion",
    "thermal",
    "output",
    30,
    "tau_th dT/dt = i^2 - T;  y += kappa*T  (thermal expansion, kappa in um/A^2)",
    "kappa",
    True,
    0.0,
    10.0,
    0.05,
)((_therm1_draw, _therm1_apply))


def _therm2_draw(rng):
    return dict(
        tau_c=U(rng, 2.0, 6.0),
        tau_cs=U(rng, 5.0, 15.0),
        tau_sc=U(rng, 15.0, 40.0),
        tau_s=U(rng, 40.0, 150.0),
        xi=U(rng, -0.4, 0.6),
    )


def _two_node(P, p, h):
    A = np.array(
        [[-(1 / p["tau_c"] + 1 / p["tau_cs"]), 1 / p["tau_cs"]], [1 / p["tau_sc"], -(1 / p["tau_sc"] + 1 / p["tau_s"])]]
    )
    B = np.array([1 / p["tau_c"], 0.0])
    lam, V = np.linalg.eig(A)
    lam = lam.real
    V = V.real
    g = np.linalg.solve(V, B)
    modes = np.array([g[m] * (-1 / lam[m]) * lowpass1(P, -1 / lam[m], h) for m in range(2)])
    X = V @ modes  # rows: coil temperature, sample temperature
    return X[0], X[1]


def _therm2_apply(p, c):
    Tc, Ts = _two_node(c["u"] ** 2, p, c["h"])
    c["y"] = c["y"] + p["kappa"] * (Ts + p["xi"] * Tc)
    c["temperature"] = Ts


_form(
    "two_node_network",
    "thermal",
    "output",
    30,
    "dTc/dt = (i^2 - Tc)/tau_c - (Tc - Ts)/tau_cs;  dTs/dt = (Tc - Ts)/tau_sc - Ts/tau_s;  y += kappa*(Ts + xi*Tc)",
    "kappa",
    True,
    0.0,
    10.0,
    0.05,
)((_therm2_draw, _therm2_apply))


def _therm3_draw(rng):
    return dict(tau_th=U(rng, 5.0, 30.0))


def _therm3_apply(p, c):
    T = lowpass1(c["u"] ** 2, p["tau_th"], c["h"])
    Tref = float(np.mean(c["u"][c["t"] >= T_ON] ** 2))  # ~ steady-state temperature
    theta_n = T / Tref
    c["y"] = c["y0"] + (1.0 - p["beta"] * theta_n) * (c["y"] - c["y0"])
    c["temperature"] = theta_n


_form(
    "gain_vs_temperature",
    "thermal",
    "output",
    12,
    "tau_th dT/dt = i^2 - T;  y = y0 + (1 - beta*T/<i^2>)*(y_gpi - y0)  (strain response falls as the sample warms)",
    "beta",
    True,
    0.0,
    0.5,
    0.01,
)((_therm3_draw, _therm3_apply))


# ---------------- lag ----------------
def _lag1_draw(rng):
    return dict()


def _lag1_apply(p, c):
    t = c["t"]
    c["u"] = np.interp(t - p["dead_time"], t, c["u"], left=c["u"][0])


_form(
    "dead_time",
    "lag",
    "input",
    0,
    "u(t) = i(t - Td)  (linear interpolation between samples)",
    "dead_time",
    False,
    0.0,
    0.25,
    0.02,
)((_lag1_draw, _lag1_apply))


def _lag2_draw(rng):
    return dict(ratio=U(rng, 0.2, 0.7))


def _lag2_apply(p, c):
    u = lowpass1(c["u"], p["tau1"], c["h"])
    c["u"] = lowpass1(u, p["ratio"] * p["tau1"], c["h"])


_form(
    "two_poles",
    "lag",
    "input",
    0,
    "U(s) = I(s) / ((1 + s tau1)(1 + s ratio*tau1))  (coil L/R + eddy currents)",
    "tau1",
    False,
    0.0,
    0.3,
    0.02,
)((_lag2_draw, _lag2_apply))


def _lag3_draw(rng):
    return dict(dead_over_tau=U(rng, 0.3, 1.0))


def _lag3_apply(p, c):
    t = c["t"]
    u = np.interp(t - p["dead_over_tau"] * p["tau"], t, c["u"], left=c["u"][0])
    c["u"] = lowpass1(u, p["tau"], c["h"])


_form(
    "first_order_plus_dead_time",
    "lag",
    "input",
    0,
    "U(s) = exp(-s Td) I(s) / (1 + s tau),  Td = dead_over_tau*tau",
    "tau",
    False,
    0.0,
    0.3,
    0.02,
)((_lag3_draw, _lag3_apply))


# ---------------- creep ----------------
def _creep1_draw(rng):
    return dict(t0=U(rng, 0.05, 0.5))


def _creep1_apply(p, c):
    y, t, u = c["y"], c["t"], c["u"]
    runs = [r for r in runs_of_direction(u) if r[0] != 0]
    add = np.zeros_like(y)
    for _sg, a, b in runs:
        if b >= len(y) - 1:
            continue  # the last leg never reverses
        dY = y[b] - y[a - 1]  # change of the output over the leg
        tm = t[b]
        m = t > tm
        add[m] += dY * np.log1p((t[m] - tm) / p["t0"])
    c["y"] = y + p["gamma"] * add


_form(
    "log_after_reversal",
    "creep",
    "output",
    20,
    "y += gamma * sum_m dY_m * ln(1 + (t - t_m)/t0) for t > t_m  (dY_m: output change over leg m ending at reversal "
    "t_m)",
    "gamma",
    True,
    0.0,
    1.0,
    0.003,
)((_creep1_draw, _creep1_apply))


def _creep2_draw(rng):
    w = rng.dirichlet([2.0, 2.0, 2.0])
    return dict(tau_a=U(rng, 0.2, 1.0), w1=float(w[0]), w2=float(w[1]), w3=float(w[2]))


def _creep2_apply(p, c):
    y = c["y"]
    x = y - y[0]
    add = np.zeros_like(y)
    for w, tau in ((p["w1"], p["tau_a"]), (p["w2"], 10 * p["tau_a"]), (p["w3"], 100 * p["tau_a"])):
        add += w * (x - lowpass1(x, tau, c["h"]))
    c["y"] = y + p["g"] * add


_form(
    "exponential_spectrum",
    "creep",
    "output",
    20,
    "y += g * sum_i w_i * integral (1 - exp(-(t-s)/tau_i)) dy(s),  tau_i = tau_a*(1, 10, 100)",
    "g",
    True,
    0.0,
    0.5,
    0.005,
)((_creep2_draw, _creep2_apply))


def _creep3_draw(rng):
    return dict(n=U(rng, 0.1, 0.35), t0=1.0)


def _creep3_apply(p, c):
    y = c["y"]
    dy = np.r_[0.0, np.diff(y)]
    kern = (np.arange(y.size) * c["h"] / p["t0"]) ** p["n"]
    add = signal.fftconvolve(dy, kern)[: y.size]
    c["y"] = y + p["gamma"] * add


_form(
    "power_law_kernel",
    "creep",
    "output",
    20,
    "y += gamma * integral ((t - s)/t0)^n dy(s)  (Andrade-type hereditary creep, t0 = 1 s)",
    "gamma",
    True,
    0.0,
    0.5,
    0.005,
)((_creep3_draw, _creep3_apply))


# ---------------- sensor drift ----------------
def _sign(rng):
    return float(rng.choice([-1.0, 1.0]))


def _drift1_draw(rng):
    return dict(sign=_sign(rng))


def _drift1_apply(p, c):
    c["y"] = c["y"] + p["sign"] * p["rate"] * c["t"]


_form("linear_drift", "sensor_drift", "sensor", 50, "y += sign*rate*t  (rate in um/s)", "rate", True, 0.0, 1.0, 0.02)(
    (_drift1_draw, _drift1_apply)
)


def _drift2_draw(rng):
    return dict(sign=_sign(rng), tau_w=U(rng, 5.0, 30.0))


def _drift2_apply(p, c):
    c["y"] = c["y"] + p["sign"] * p["amplitude"] * (1.0 - np.exp(-c["t"] / p["tau_w"]))


_form(
    "exponential_warmup",
    "sensor_drift",
    "sensor",
    50,
    "y += sign*A*(1 - exp(-t/tau_w))  (sensor electronics warming up and settling)",
    "amplitude",
    True,
    0.0,
    30.0,
    1.0,
)((_drift2_draw, _drift2_apply))


def _drift3_draw(rng):
    return dict(
        sign=_sign(rng),
        tau1=U(rng, 10.0, 30.0),
        tau2=U(rng, 20.0, 60.0),
        amb_rel=U(rng, 0.2, 1.0),
        amb_period=U(rng, 60.0, 300.0),
        amb_phase=U(rng, 0.0, 2 * np.pi),
    )


def _drift3_apply(p, c):
    t = c["t"]
    P = c["u"] ** 2
    heat = lowpass1(lowpass1(P, p["tau1"], c["h"]), p["tau2"], c["h"])
    scale = float(np.mean(P[t >= T_ON]))
    w = 2 * np.pi / p["amb_period"]
    amb = p["amb_rel"] * scale * (np.sin(w * t + p["amb_phase"]) - np.sin(p["amb_phase"]))
    Ts = heat + amb
    c["y"] = c["y"] + p["sign"] * p["beta"] * Ts


_form(
    "sensor_temperature",
    "sensor_drift",
    "sensor",
    50,
    "Ts = LP(tau2) LP(tau1) [i^2] + amb_rel*<i^2>*(sin(w t + phi) - sin phi);  y += sign*beta*Ts",
    "beta",
    True,
    0.0,
    10.0,
    0.1,
)((_drift3_draw, _drift3_apply))


# ---------------- first cycle ----------------
def _fc_extra(p, c, fading):
    y, y0 = c["y"], c["y0"]
    kp, kq = first_peak_trough(c["u"])
    Y1 = y[kp] - y0
    s = (y - y0) / Y1
    sq = s[kq]
    E, kap, mu = p["E"], p["kappa"], p["mu"]
    extra = np.empty_like(y)
    extra[: kp + 1] = E * s[: kp + 1]
    extra[kp + 1 : kq + 1] = E * (kap + (1 - kap) * (s[kp + 1 : kq + 1] - sq) / (1 - sq))
    off = np.full(y.size - kq - 1, kap * E)
    if fading:
        cyc = cycles(c["u"])
        off = off * np.exp(-(cyc[kq + 1 :] - cyc[kq]) / p["n_fade"])
    extra[kq + 1 :] = off - mu * E * (s[kq + 1 :] - sq)
    return extra


def _fc1_draw(rng):
    return dict(kappa=U(rng, 0.3, 0.7), mu=U(rng, 0.2, 0.6))


def _fc1_apply(p, c):
    c["y"] = c["y"] + _fc_extra(p, c, False)


_form(
    "retained_offset_fixed",
    "first_cycle",
    "output",
    11,
    "s=(y-y0)/Y1; virgin rise: y+=E*s; first unloading: y+=E*(kappa+(1-kappa)(s-s_q)/(1-s_q)); "
    "later: y+=kappa*E - mu*E*(s-s_q)",
    "E",
    True,
    0.0,
    60.0,
    2.0,
)((_fc1_draw, _fc1_apply))


def _fc2_draw(rng):
    return dict(kappa=U(rng, 0.3, 0.7), mu=U(rng, 0.2, 0.6), n_fade=U(rng, 0.7, 2.5))


def _fc2_apply(p, c):
    c["y"] = c["y"] + _fc_extra(p, c, True)


_form(
    "retained_offset_fading",
    "first_cycle",
    "output",
    11,
    "as retained_offset_fixed but later: y += kappa*E*exp(-(N(t)-N(t_q))/n_fade) - mu*E*(s-s_q), N = cycles",
    "E",
    True,
    0.0,
    60.0,
    2.0,
)((_fc2_draw, _fc2_apply))


# ---------------- training ----------------
def _tr1_draw(rng):
    return dict(n_c=U(rng, 1.0, 4.0))


def _tr1_apply(p, c):
    g = 1.0 - p["delta"] * (1.0 - np.exp(-cycles(c["u"]) / p["n_c"]))
    c["y"] = c["y0"] + g * (c["y"] - c["y0"])


_form(
    "gain_decay_with_cycles",
    "training",
    "output",
    10,
    "y = y0 + (1 - delta*(1 - exp(-N(t)/n_c)))*(y_gpi - y0),  N = accumulated cycles",
    "delta",
    True,
    0.0,
    0.5,
    0.01,
)((_tr1_draw, _tr1_apply))


def _tr2_draw(rng):
    return dict(n_c=U(rng, 1.0, 4.0))


def _tr2_apply(p, c):
    c["thr_scale"] = c["thr_scale"] * (1.0 - p["delta"] * (1.0 - np.exp(-cycles(c["u"]) / p["n_c"])))


_form(
    "threshold_shrink",
    "training",
    "gpi",
    5,
    "r_j(t) = alpha*j*(1 - delta*(1 - exp(-N(t)/n_c)))  (play widths narrow with cycling; weights fixed)",
    "delta",
    False,
    0.0,
    0.95,
    0.05,
)((_tr2_draw, _tr2_apply))


# ---------------- initial state ----------------
def _is1_draw(rng):
    return dict()


def _is1_apply(p, c):
    th = c["theta"]
    vm = p["v_prior"]
    path = np.r_[np.linspace(0.0, vm, 201), np.linspace(vm, 0.0, 201)[1:]]
    _, z = gpi(th, path, return_state=True)
    c["z0"] = z


_form(
    "prior_excursion",
    "initial_state",
    "gpi",
    5,
    "z_j(t0) = memory after an earlier run 0 -> v_prior -> 0 A, i.e. min(gamma_b(0)+r_j, max(gamma_a(v_prior)-r_j, "
    "z_virgin))",
    "v_prior",
    False,
    0.0,
    5.0,
    1.0,
)((_is1_draw, _is1_apply))


def _is2_draw(rng):
    return dict(q=U(rng, 0.0, 2.0))


def _is2_apply(p, c):
    j = np.arange(1, N_OPERATORS + 1)
    c["z0"] = virgin_memory(c["theta"], 0.0) + p["delta"] * (j / N_OPERATORS) ** p["q"]


_form(
    "raised_memory",
    "initial_state",
    "gpi",
    5,
    "z_j(t0) = z_virgin_j + delta*(j/N)^q  (wide operators keep more of the earlier elongation)",
    "delta",
    False,
    0.0,
    30.0,
    1.0,
)((_is2_draw, _is2_apply))


# ---------------- outside ----------------
def _o1_draw(rng):
    return dict()


def _o1_apply(p, c):
    ystop = float(np.max(c["y"])) - p["headroom"]
    c["y"] = np.minimum(c["y"], ystop)
    c["stop_level"] = ystop


_form(
    "hard_stop",
    "outside",
    "output",
    40,
    "y = min(y, y_stop),  y_stop = max(y_plain) - headroom  (mechanical end stop)",
    "headroom",
    False,
    0.0,
    150.0,
    5.0,
)((_o1_draw, _o1_apply))


def _o2_draw(rng):
    return dict(f_n=U(rng, 4.0, 12.0), zeta=U(rng, 0.02, 0.06))


def _o2_apply(p, c):
    t, y, h = c["t"], c["y"], c["h"]
    wn = 2 * np.pi * p["f_n"]
    z = p["zeta"]
    num, den = [wn**2], [1.0, 2 * z * wn, wn**2]
    bd, ad, _ = signal.cont2discrete((num, den), h, method="foh")
    bd = np.atleast_1d(np.squeeze(bd))
    zi = signal.lfilter_zi(bd, ad) * y[0]
    x, _ = signal.lfilter(bd, ad, y, zi=zi)
    wd = wn * np.sqrt(1 - z**2)
    ring = np.zeros_like(y)
    for k, sg in reversals(c["u"]):
        m = t > t[k]
        tt = t[m] - t[k]
        ring[m] += sg * np.exp(-z * wn * tt) * np.sin(wd * tt)
    c["y"] = x + p["amplitude"] * ring


_form(
    "resonance_ringing",
    "outside",
    "output",
    40,
    "y = H(s) y_gpi, H = wn^2/(s^2 + 2 zeta wn s + wn^2), plus A*sum_m sgn_m exp(-zeta wn (t-t_m)) sin(wd (t-t_m)) at "
    "input reversals",
    "amplitude",
    False,
    0.0,
    80.0,
    2.0,
)((_o2_draw, _o2_apply))


def _o3_draw(rng):
    return dict()


def _o3_apply(p, c):
    du = np.abs(np.gradient(c["u"], c["h"]))
    c["thr_scale"] = c["thr_scale"] * (1.0 + p["beta"] * du / max(du.max(), 1e-12))


_form(
    "rate_dependent_width",
    "outside",
    "gpi",
    5,
    "r_j(t) = alpha*j*(1 + beta*|di/dt|/max|di/dt|)  (loop widens with input rate)",
    "beta",
    False,
    0.0,
    6.0,
    0.3,
)((_o3_draw, _o3_apply))


def _o4_draw(rng):
    return dict()


def _o4_apply(p, c):
    y = c["y"].tolist()
    bw = p["half_width"]
    w = y[0]
    out = [w]
    for yk in y[1:]:
        if yk - bw > w:
            w = yk - bw
        elif yk + bw < w:
            w = yk + bw
        out.append(w)
    c["y"] = np.array(out)


_form(
    "output_backlash",
    "outside",
    "output",
    40,
    "y_meas = play_b[y]:  w_k = max(y_k - b, min(y_k + b, w_{k-1}))  (mechanical play between push rod and sensor)",
    "half_width",
    False,
    0.0,
    30.0,
    1.0,
)((_o4_draw, _o4_apply))


def _o5_draw(rng):
    return dict(sign=_sign(rng))


def _o5_apply(p, c):
    y, y0 = c["y"], c["y0"]
    span = float(np.max(y) - y0)
    s = (y - y0) / span
    c["y"] = y + p["sign"] * p["bow"] * span * s * (1.0 - s)


_form(
    "sensor_bow_nonlinearity",
    "outside",
    "sensor",
    55,
    "y_meas = y + sign*bow*span*s*(1-s), s = (y-y0)/span  (static sensor nonlinearity calibrated at both ends)",
    "bow",
    True,
    0.0,
    0.2,
    0.01,
)((_o5_draw, _o5_apply))


# ----------------------------------------------------------------------------------
# Simulation of a record
# ----------------------------------------------------------------------------------
def _theta_array(theta_dict):
    return np.array([theta_dict[k] for k in PARAM_NAMES], float)


def simulate(fs, reading, theta_dict, effects):
    """Noiseless displacement of the transducer with the listed hidden effects."""
    theta = _theta_array(theta_dict)
    t = time_axis(fs)
    i = commanded_current(t, reading)
    c = dict(t=t, i=i, u=i.copy(), h=1.0 / fs, theta=theta, y0=rest_level(theta), z0=None, thr_scale=np.ones(t.size))
    effs = sorted(effects, key=lambda e: FORMS[e["form"]]["order"])
    for e in effs:
        if FORMS[e["form"]]["stage"] == "input":
            FORMS[e["form"]]["apply"](e["params"], c)
    for e in effs:
        if FORMS[e["form"]]["stage"] == "gpi":
            FORMS[e["form"]]["apply"](e["params"], c)
    ts = None if np.all(c["thr_scale"] == 1.0) else c["thr_scale"]
    c["y"] = gpi(theta, c["u"], z0=c["z0"], thr_scale=ts)
    for e in effs:
        if FORMS[e["form"]]["stage"] in ("output", "sensor"):
            FORMS[e["form"]]["apply"](e["params"], c)
    return t, i, c["y"]


def visible_ratio(y_eff, y_plain, t, sigma):
    m = t >= T_ON
    return float(np.sqrt(np.mean((y_eff[m] - y_plain[m]) ** 2)) / sigma)


def make_noise(rng, n, noise):
    s = noise["sigma"]
    w = rng.standard_normal(n)
    if noise["kind"] == "white":
        return s * w
    phi = noise["phi"]
    e = signal.lfilter([np.sqrt(1 - phi**2) * s], [1.0, -phi], w[1:], zi=[phi * s * w[0]])[0]
    return np.r_[s * w[0], e]


# ----------------------------------------------------------------------------------
# Size scaling
# ----------------------------------------------------------------------------------
def _fit_knob(form, shape, base, target, sigma, y_plain, t):
    """Find the knob value that makes the RMS of (with effect - plain) over t >= 10 s
    equal target*sigma.  Returns (knob, achieved ratio) or None if out of reach."""
    F = FORMS[form]
    knob = F["knob"]

    def ratio(k):
        params = dict(shape)
        params[knob] = float(k)
        _, _, y = simulate(
            base["fs"],
            base["input_reading"],
            base["gpi_theta"],
            [dict(category=F["category"], form=form, params=params)],
        )
        return visible_ratio(y, y_plain, t, sigma)

    if F["linear"]:
        r1 = ratio(F["start"])
        k = F["start"] * target / r1
        return k, ratio(k)
    lo, hi = F["lo"], F["hi"]
    r_hi = ratio(hi)
    if r_hi < target:
        return None
    r_lo = ratio(lo)
    if r_lo >= target:  # the form is visible even at the knob's lower end
        return lo, r_lo
    k = F["start"]
    for _ in range(60):
        rk = ratio(k)
        if abs(rk / target - 1) < 0.003:
            return k, rk
        if rk < target:
            lo, r_lo = k, rk
        else:
            hi, r_hi = k, rk
        # regula falsi step, safeguarded by bisection
        kn = lo + (target - r_lo) * (hi - lo) / (r_hi - r_lo)
        if not (lo + 0.02 * (hi - lo) < kn < hi - 0.02 * (hi - lo)):
            kn = 0.5 * (lo + hi)
        k = kn
    return k, ratio(k)


def _scaled_effect(rng, form, base, target, sigma, y_plain, t, tries=8):
    F = FORMS[form]
    for _ in range(tries):
        shape = F["draw"](rng)
        res = _fit_knob(form, shape, base, target, sigma, y_plain, t)
        if res is None:
            target = max(1.55, 0.8 * target)
            continue
        k, r = res
        if 1.5 <= r <= 4.0:
            params = dict(shape)
            params[F["knob"]] = float(k)
            return dict(
                category=F["category"],
                form=form,
                params=params,
                equation=F["equation"],
                visible_rms_over_sigma=float(r),
            )
    raise RuntimeError(f"could not size form {form}")


# ----------------------------------------------------------------------------------
# Record specs
# ----------------------------------------------------------------------------------
def _draw_theta(rng):
    f = rng.uniform(0.9, 1.1, size=TABLE1.size)
    return {k: float(v) for k, v in zip(PARAM_NAMES, TABLE1 * f)}


def _draw_noise(rng, smin, smax):
    kind = str(rng.choice(["white", "ar1"]))
    sigma = U(rng, smin, smax)
    phi = U(rng, 0.3, 0.8) if kind == "ar1" else 0.0
    return dict(kind=kind, sigma=sigma, phi=phi)


def _record_rng(seed, suite, i):
    ss = np.random.SeedSequence(seed, spawn_key=(SUITE_KEY[suite], i))
    return np.random.default_rng(ss)


def clean_records(n=100, seed=0):
    """Plain GPI + noise; every 5th record (i % 5 == 4) sampled at 1 kHz."""
    specs = []
    for i in range(n):
        rng = _record_rng(seed, "clean", i)
        spec = dict(
            stem=f"clean_{i:03d}",
            suite="clean",
            physics=[],
            forms=[],
            effects=[],
            gpi_theta=_draw_theta(rng),
            input_reading=str(rng.choice(["literal", "centred"])),
            fs=1000 if i % 5 == 4 else 100,
            noise=_draw_noise(rng, 0.3, 1.0),
            seed=dict(base=int(seed), spawn_key=[SUITE_KEY["clean"], i]),
            noise_spawn_key=[SUITE_KEY["clean"], i, 1],
            visible_rms_over_sigma=0.0,
        )
        specs.append(spec)
    return specs


SINGLE_FORMS = [
    "one_pole_expansion",
    "two_node_network",
    "gain_vs_temperature",
    "dead_time",
    "two_poles",
    "first_order_plus_dead_time",
    "log_after_reversal",
    "exponential_spectrum",
    "power_law_kernel",
    "linear_drift",
    "exponential_warmup",
    "sensor_temperature",
    "retained_offset_fixed",
    "retained_offset_fading",
    "gain_decay_with_cycles",
    "threshold_shrink",
    "prior_excursion",
    "raised_memory",
]
COMBOS = [
    ("two_node_network", "two_poles"),
    ("log_after_reversal", "linear_drift"),
    ("retained_offset_fixed", "one_pole_expansion"),
    ("dead_time", "power_law_kernel"),
    ("gain_decay_with_cycles", "exponential_warmup"),
    ("prior_excursion", "gain_vs_temperature"),
    ("first_order_plus_dead_time", "retained_offset_fading"),
    ("threshold_shrink", "exponential_spectrum"),
]
OUTSIDE_FORMS = ["hard_stop", "resonance_ringing", "rate_dependent_width", "output_backlash", "sensor_bow_nonlinearity"]


def effect_plan(per_form=3):
    plan = []
    for f in SINGLE_FORMS:
        plan += [(f,)] * per_form
    plan += list(COMBOS)
    plan += [(f,) for f in OUTSIDE_FORMS]
    return plan


def _size_record(rng, i, forms):
    base = dict(
        gpi_theta=_draw_theta(rng),
        input_reading=str(rng.choice(["literal", "centred"])),
        fs=1000 if i % 5 == 2 else 100,
    )
    noise = _draw_noise(rng, 0.45, 0.9)
    sigma = noise["sigma"]
    t, _, y_plain = simulate(base["fs"], base["input_reading"], base["gpi_theta"], [])
    if len(forms) == 1:
        targets = [U(rng, 1.7, 3.6)]
    else:
        targets = [U(rng, 1.55, 2.5) for _ in forms]
    for _attempt in range(6):
        effs = [_scaled_effect(rng, f, base, tg, sigma, y_plain, t) for f, tg in zip(forms, targets)]
        _, _, y = simulate(base["fs"], base["input_reading"], base["gpi_theta"], effs)
        r = visible_ratio(y, y_plain, t, sigma)
        if 1.5 <= r <= 4.0:
            return base, noise, effs, r
        targets = [min(3.8, 1.3 * tg) for tg in targets] if r < 1.5 else [max(1.55, 0.8 * tg) for tg in targets]
    raise RuntimeError(f"could not size combination {forms}")


def _effect_spec(seed, i, forms):
    """One effects record.  If an effect cannot reach the size window for the drawn
    GPI parameters and noise level (e.g. a prior excursion that is bounded by the
    fully raised memory), the whole record is redrawn from the same stream."""
    rng = _record_rng(seed, "effects", i)
    for _redraw in range(20):
        try:
            base, noise, effs, r = _size_record(rng, i, forms)
            break
        except RuntimeError:
            continue
    else:
        raise RuntimeError(f"record {i}: could not size {forms}")
    cats = [FORMS[f]["category"] for f in forms]
    tag = "_".join(cats) if len(forms) > 1 else cats[0]
    return dict(
        stem=f"effects_{i:03d}_{tag}",
        suite="effects",
        physics=cats,
        forms=list(forms),
        effects=effs,
        **base,
        noise=noise,
        seed=dict(base=int(seed), spawn_key=[SUITE_KEY["effects"], i]),
        noise_spawn_key=[SUITE_KEY["effects"], i, 1],
        visible_rms_over_sigma=r,
    )


def effect_records(seed=0, per_form=3):
    return [_effect_spec(seed, i, forms) for i, forms in enumerate(effect_plan(per_form))]


# ----------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------
def realise(spec):
    """Arrays of a record: time, commanded current, noiseless, noise, plain GPI."""
    if "_arrays" in spec:
        return spec["_arrays"]
    t, i, y = simulate(spec["fs"], spec["input_reading"], spec["gpi_theta"], spec["effects"])
    if spec["effects"]:
        _, _, y_plain = simulate(spec["fs"], spec["input_reading"], spec["gpi_theta"], [])
    else:
        y_plain = y
    ss = np.random.SeedSequence(spec["seed"]["base"], spawn_key=tuple(spec["noise_spawn_key"]))
    noise = make_noise(np.random.default_rng(ss), t.size, spec["noise"])
    arr = dict(time=t, current=i, noiseless=y, noise=noise, noiseless_without_effects=y_plain)
    spec["_arrays"] = arr
    return arr


def truth_of(spec):
    eff = {}
    for e in spec["effects"]:
        eff[e["category"]] = dict(
            form=e["form"], equation=e["equation"], visible_rms_over_sigma=e["visible_rms_over_sigma"], **e["params"]
        )
    return dict(
        suite=spec["suite"],
        physics=list(spec["physics"]),
        forms=list(spec["forms"]),
        effect_parameters=eff,
        gpi_theta=dict(spec["gpi_theta"]),
        n_operators=N_OPERATORS,
        input_reading=spec["input_reading"],
        fs=spec["fs"],
        noise=dict(spec["noise"]),
        seed=dict(spec["seed"]),
        noise_spawn_key=list(spec["noise_spawn_key"]),
        visible_rms_over_sigma=float(spec["visible_rms_over_sigma"]),
        n_samples=int(round(DURATION * spec["fs"])) + 1,
        units=dict(time="s", current="A", displacement="um"),
        generator="benchmarks/independent/generator.py",
    )


def write_record(spec, directory):
    os.makedirs(directory, exist_ok=True)
    a = realise(spec)
    stem = os.path.join(directory, spec["stem"])
    data = np.column_stack([a["time"], a["current"], a["noiseless"] + a["noise"]])
    np.savetxt(stem + ".csv", data, fmt="%.10g", delimiter=",", header="time,current,displacement", comments="")
    with open(stem + ".truth.json", "w") as fh:
        json.dump(truth_of(spec), fh, indent=1)
    np.savez_compressed(stem + ".npz", **a)
    return stem


def _summary(spec):
    tr = truth_of(spec)
    keep = ["suite", "physics", "forms", "input_reading", "fs", "noise", "visible_rms_over_sigma", "n_samples"]
    return dict(stem=spec["stem"], **{k: tr[k] for k in keep})


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--suite", choices=["clean", "effects", "all"], default="all")
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n", type=int, default=100, help="number of clean records")
    ap.add_argument("--per-form", type=int, default=3, help="effects records per single form")
    args = ap.parse_args(argv)
    index = []
    timing = {}
    if args.suite in ("clean", "all"):
        t0 = _time.time()
        for spec in clean_records(args.n, args.seed):
            write_record(spec, args.out)
            index.append(_summary(spec))
        timing["clean"] = _time.time() - t0
    if args.suite in ("effects", "all"):
        t0 = _time.time()
        for spec in effect_records(args.seed, args.per_form):
            write_record(spec, args.out)
            index.append(_summary(spec))
        timing["effects"] = _time.time() - t0
    with open(os.path.join(args.out, "index.json"), "w") as fh:
        json.dump(dict(seed=args.seed, n_clean=args.n if args.suite != "effects" else 0, records=index), fh, indent=1)
    for k, v in timing.items():
        print(f"{k}: {sum(1 for r in index if r['suite'] == k)} records in {v:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
