"""Independent test-record generator for the MSMA generalized Prandtl-Ishlinskii project.

Written "blind" from the seed paper (eqs. 5-17, Table 1) and the physics of each
hidden effect.  Imports only numpy, scipy and the standard library.

Command line::

    python benchmarks/independent/generator.py --suite clean|effects|all --out DIR [--seed S] [--n N]
        [--drive paper|holds|triangle|mixed] [--new-forms] [--records-per-transducer K]
        [--run-parameters redraw|keep] [--omega-at-hold last|rising]
    python benchmarks/independent/generator.py --like DIR/STEM.truth.json (--input next.csv | --drive NAME)
        --out OUT [--stem NAME] [--run J] [--run-parameters redraw|keep] [--noise-key original|s,i,...]

Without the later options (drive paper, K = 1, no new forms) every file is what the
generator always wrote for that seed.

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
# Drives (see "Drives" below).  A record without a "drive" entry is on the paper's drive.
DRIVES = ["paper", "holds", "triangle"]
I_RIG = (0.0, 5.0)  # A, the rig's current range (coils at 5 A)
PAPER_MAX_SLEW = 0.2 * np.pi * 2.5  # A/s, steepest slope of the paper's undecayed sine (1.571 A/s)
DRIVE_KEY = 2  # spawn key (s, i, 2): drive of record i of suite s
RUN_KEY = 3  # spawn key (s, i, 3, j, .): run j >= 1 of the transducer of record (s, i)
# Omega at dv = 0 (a hold): "last" keeps the branch of the last move (c before any move);
# "rising" is eq. (13) read literally (dv/dt >= 0 -> c).  They differ only where the input
# holds still after a fall, which the paper's drive never does.
HOLD_CONVENTIONS = ("last", "rising")
HOLD_DEFAULT = "last"


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
# Other drives (opt-in): same 10 s unenergised start, 0-5 A, the paper's slow rates
# ----------------------------------------------------------------------------------
def grid(duration, fs):
    """Sample times k/fs, k = 0..round(duration*fs)."""
    n = int(round(duration * fs)) + 1
    return np.arange(n) / float(fs)


def _lu(rng, lo, hi):
    """Log-uniform draw in [lo, hi]."""
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_drive(rng, name):
    """Drive description drawn from its own stream.

    The draws are made in the same order whatever the name (drive index, paper reading,
    holds parameters, triangle parameters), so a "mixed" record that draws drive d is the
    record of drive d.  name: "paper", "holds", "triangle" or "mixed" (uniform choice).
    """
    k = int(rng.integers(len(DRIVES)))
    if name == "mixed":
        name = DRIVES[k]
    reading = str(rng.choice(["literal", "centred"]))
    # holds: raised-cosine cycles at the paper's 0.1 Hz from 0 A, peaks falling from p_hi to
    # p_lo and rising back, the last peak held; then a long unenergised end
    n_down = int(rng.integers(2, 4))
    p_hi = float(rng.uniform(4.5, 5.0))
    p_lo = float(rng.uniform(1.0, 2.5))
    t_hold = round(float(rng.uniform(8.0, 20.0)), 1)
    t_end = round(float(rng.uniform(30.0, 60.0)), 1)
    # triangle: constant slew, varying peaks, troughs between 0 A and half the lower neighbour peak
    slew = float(rng.uniform(0.5, 1.5))
    n_tri = int(rng.integers(6, 10))
    tri_peaks = [float(rng.uniform(4.0, 5.0))] + [float(x) for x in rng.uniform(1.0, 5.0, size=n_tri - 1)]
    tri_fr = rng.uniform(0.0, 0.5, size=n_tri - 1)
    if name == "paper":
        return dict(name="paper", reading=reading)
    if name == "holds":
        period = 10.0
        peaks = list(np.linspace(p_hi, p_lo, n_down + 1)) + list(np.linspace(p_lo, p_hi, n_down + 1)[1:])
        peaks = [float(x) for x in peaks]
        hold_start = T_ON + period * (len(peaks) - 1) + period / 2
        hold_end = hold_start + t_hold
        quiet_from = hold_end + period / 2
        return dict(
            name="holds",
            period=period,
            peaks=peaks,
            t_hold=t_hold,
            t_end=t_end,
            hold_start=hold_start,
            hold_end=hold_end,
            quiet_from=quiet_from,
            duration=round(quiet_from + t_end, 1),
            max_slew=float(np.pi * p_hi / period),
        )
    if name == "triangle":
        troughs = [float(f * min(a, b)) for f, a, b in zip(tri_fr, tri_peaks[:-1], tri_peaks[1:])] + [0.0]
        tc, vc = [T_ON], [0.0]
        for pk, tr in zip(tri_peaks, troughs):
            for v in (pk, tr):
                tc.append(tc[-1] + abs(v - vc[-1]) / slew)
                vc.append(v)
        return dict(
            name="triangle",
            slew=slew,
            peaks=tri_peaks,
            troughs=troughs,
            corner_times=[float(x) for x in tc],
            corner_currents=[float(x) for x in vc],
            duration=float(np.ceil(tc[-1] * 10.0 - 1e-9) / 10.0),
            max_slew=slew,
        )
    raise ValueError(name)


def _holds_current(t, d):
    P, peaks = d["period"], d["peaks"]
    i = np.zeros_like(t)
    t0 = T_ON
    for A in peaks[:-1]:
        m = (t >= t0) & (t < t0 + P)
        i[m] = A * 0.5 * (1.0 - np.cos(2 * np.pi * (t[m] - t0) / P))
        t0 += P
    A = peaks[-1]
    m = (t >= t0) & (t < d["hold_start"])
    i[m] = A * 0.5 * (1.0 - np.cos(2 * np.pi * (t[m] - t0) / P))
    i[(t >= d["hold_start"]) & (t < d["hold_end"])] = A
    m = (t >= d["hold_end"]) & (t < d["quiet_from"])
    i[m] = A * 0.5 * (1.0 + np.cos(2 * np.pi * (t[m] - d["hold_end"]) / P))
    return i


def drive_arrays(fs, reading, drive=None):
    """(time, commanded current) of a drive; drive None is the paper's (eqs. 15-17)."""
    if drive is None or drive["name"] == "paper":
        t = time_axis(fs)
        return t, commanded_current(t, reading if drive is None else drive["reading"])
    if drive["name"] == "holds":
        t = grid(drive["duration"], fs)
        return t, _holds_current(t, drive)
    if drive["name"] == "triangle":
        t = grid(drive["duration"], fs)
        return t, np.interp(t, drive["corner_times"], drive["corner_currents"], left=0.0, right=0.0)
    if drive["name"] == "file":
        return drive["_t"], drive["_i"]
    raise ValueError(drive["name"])


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


def gpi(theta, v, n_op=N_OPERATORS, z0=None, thr_scale=None, v_env=None, return_state=False, hold="rising"):
    """Generalized PI output y_k = Omega_k + sum_j p_j z_j(t_k).

    v         : input whose increments decide the branch (dv>0 rising, dv<0 falling).
    v_env     : input fed to the envelopes and to Omega (default v).
    thr_scale : optional per-sample factor on all thresholds r_j (time-varying widths;
                the weights p_j keep the nominal thresholds).
    z0        : initial operator memory (default: the virgin memory at v_env[0]).
    hold      : Omega's branch where dv = 0: "rising" (eq. 13 literally, dv >= 0 -> c) or
                "last" (the branch of the last nonzero dv; c before any).  The two differ
                only where v holds still after a fall.

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
    if hold == "last":
        sgn = np.r_[1.0, np.sign(dv)]
        last = np.maximum.accumulate(np.where(sgn != 0, np.arange(sgn.size), 0))
        rising = sgn[last] > 0
    elif hold == "rising":
        rising = np.r_[True, dv >= 0]
    else:
        raise ValueError(hold)
    om = np.where(rising, _tanh4(c, ve), _tanh4(d, ve))
    y = om + Z @ p
    if return_state:
        return y, Z[-1].copy()
    return y


def gpi_reference_loop(theta, v, n_op=N_OPERATORS, hold="rising"):
    """Plain sample-by-sample loop (used only by the self-check)."""
    _, _, _, a, b, c, d = _split(theta)
    r, p = thresholds_weights(theta, n_op)
    z = np.maximum(_tanh4(a, v[0]) - r, np.minimum(_tanh4(b, v[0]) + r, 0.0))
    y = np.empty(len(v))
    y[0] = _tanh4(c, v[0]) + p @ z
    up = True
    for k in range(1, len(v)):
        dv = v[k] - v[k - 1]
        if dv > 0:
            z = np.maximum(_tanh4(a, v[k]) - r, z)
            up = True
        elif dv < 0:
            z = np.minimum(_tanh4(b, v[k]) + r, z)
            up = False
        elif hold == "rising":
            up = True
        om = _tanh4(c, v[k]) if up else _tanh4(d, v[k])
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


def _start_heat(T, p, c, tau):
    """Add the residual heat of earlier runs (run parameter T_start, in A^2, absent = 0):
    the temperature starts T_start above the steady state of the first sample and relaxes
    with tau."""
    if p.get("T_start", 0.0):
        T = T + p["T_start"] * np.exp(-c["t"] / tau)
    return T


def _therm1_apply(p, c):
    T = lowpass1(c["u"] ** 2, p["tau_th"], c["h"])
    T = _start_heat(T, p, c, p["tau_th"])
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
    return X[0], X[1], V, lam


def _therm2_apply(p, c):
    Tc, Ts, V, lam = _two_node(c["u"] ** 2, p, c["h"])
    if p.get("T_start", 0.0):  # residual heat: both nodes start T_start warmer and relax
        g0 = np.linalg.solve(V, np.array([p["T_start"], p["T_start"]]))
        Xh = V @ (g0[:, None] * np.exp(lam[:, None] * c["t"][None, :]))
        Tc, Ts = Tc + Xh[0], Ts + Xh[1]
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
    T = _start_heat(T, p, c, p["tau_th"])
    if "i2_ref" in p:  # the transducer's reference, frozen from the record that defined it
        Tref = p["i2_ref"]
    else:
        Tref = float(np.mean(c["u"][c["t"] >= T_ON] ** 2))  # ~ steady-state temperature
    c["refs"]["gain_vs_temperature"] = dict(i2_ref=Tref)
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
    scale = p["i2_ref"] if "i2_ref" in p else float(np.mean(P[t >= T_ON]))
    c["refs"]["sensor_temperature"] = dict(i2_ref=scale)
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
def _first_peak_trough_or_none(u):
    """first_peak_trough, with None for a missing peak or trough (any drive)."""
    try:
        return first_peak_trough(u)
    except RuntimeError:
        runs = [r for r in runs_of_direction(u) if r[0] != 0]
        ups = [b for sg, _a, b in runs if sg > 0]
        return (ups[0] if ups else None), None


def _fc_extra(p, c, fading):
    y, y0 = c["y"], c["y0"]
    kap, mu = p["kappa"], p["mu"]
    form = "retained_offset_fading" if fading else "retained_offset_fixed"
    if not p.get("virgin", True):
        # a run that starts in the state an earlier run left: offset kappa*E retained at
        # rest, the later-cycle law from the start, s against the reference excursion
        E = p["E"]
        s = (y - y0) / p["Y1_ref"]
        c["refs"][form] = dict(Y1_ref=p["Y1_ref"])
        off = kap * E
        if fading:
            off = off * np.exp(-(p.get("cycles_before", 0.0) + cycles(c["u"])) / p["n_fade"])
        return off - mu * E * s
    kp, kq = _first_peak_trough_or_none(c["u"])
    if kp is None:  # never a reversal after rising: the whole record is the virgin rise
        Y1 = p["Y1_ref"] if "Y1_ref" in p else float(np.max(y) - y0)
        c["refs"][form] = dict(Y1_ref=Y1)
        return p["E"] * (y - y0) / Y1
    if kq is None:  # no trough after the first peak: the unloading runs to the end
        kq = y.size - 1
    Y1 = y[kp] - y0
    c["refs"][form] = dict(Y1_ref=float(Y1))
    # on another drive the overshoot scales with this run's first excursion: E_run = E*Y1/Y1_ref
    E = p["E"] if "Y1_ref" not in p else p["E"] * (Y1 / p["Y1_ref"])
    s = (y - y0) / Y1
    sq = s[kq]
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


def _field_fraction(i, i_c, width):
    """Share of the virgin reorientation done by the current i: a smooth step around the
    switching current i_c, 0 at 0 A, 1 well above i_c."""
    a = np.tanh(i_c / width)
    return (np.tanh((i - i_c) / width) + a) / (1.0 + a)


def _vf_draw(rng):
    return dict(i_c=U(rng, 1.5, 3.0), width=U(rng, 0.3, 1.0), kappa=U(rng, 0.3, 0.7))


def _vf_extra(p, c):
    """Virgin overshoot set by the field.

    M is the largest current seen (since the sample was reset); the virgin loading beyond M
    adds E*dF: kappa of it stays (the spring cannot push those variants back), the rest is a
    stock S >= 0 that falling current spends, (1 - kappa)*E*|dF| per step.  The later cycles
    below M neither regain S nor lose the retained kappa*E*F(M): their maximum strain is
    lower than the virgin loading's, and the rest strain higher.
    """
    u = c["u"]
    E, kap = p["E"], p["kappa"]
    F = _field_fraction(u, p["i_c"], p["width"]).tolist()
    if p.get("virgin", True):
        M, fM = -np.inf, 0.0
    else:  # an earlier run reached i_max_before and returned to rest: S spent
        M = p["i_max_before"]
        fM = float(_field_fraction(M, p["i_c"], p["width"]))
    S = 0.0
    out = np.empty(u.size)
    ul = u.tolist()
    for k, uk in enumerate(ul):
        if uk > M:
            S += (1.0 - kap) * E * (F[k] - fM)
            M, fM = uk, F[k]
        elif k > 0 and uk < ul[k - 1]:
            S = max(0.0, S - (1.0 - kap) * E * (F[k - 1] - F[k]))
        out[k] = kap * E * fM + S
    return out


def _vf_apply(p, c):
    c["y"] = c["y"] + _vf_extra(p, c)


_form(
    "virgin_field_overshoot",
    "first_cycle",
    "output",
    11,
    "F(i) = (tanh((i - i_c)/width) + tanh(i_c/width))/(1 + tanh(i_c/width)); M = largest i so far; "
    "y += kappa*E*F(M) + S, S >= 0 grows by (1-kappa)*E*dF(i) while i exceeds M and falls by (1-kappa)*E*|dF(i)| "
    "while i falls  (virgin overshoot shaped by the field, kappa of it retained)",
    "E",
    True,
    0.0,
    60.0,
    2.0,
)((_vf_draw, _vf_apply))


# ---------------- training ----------------
def _tr1_draw(rng):
    return dict(n_c=U(rng, 1.0, 4.0))


def _cycles_run(p, c):
    """Accumulated cycles, plus those an earlier run left (run parameter cycles_before)."""
    N = cycles(c["u"])
    if p.get("cycles_before", 0.0):
        N = N + p["cycles_before"]
    return N


def _tr1_apply(p, c):
    g = 1.0 - p["delta"] * (1.0 - np.exp(-_cycles_run(p, c) / p["n_c"]))
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
    c["thr_scale"] = c["thr_scale"] * (1.0 - p["delta"] * (1.0 - np.exp(-_cycles_run(p, c) / p["n_c"])))


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
    ymax = p["y_max_ref"] if "y_max_ref" in p else float(np.max(c["y"]))
    c["refs"]["hard_stop"] = dict(y_max_ref=ymax)
    ystop = ymax - p["headroom"]
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
    rate = p["rate_ref"] if "rate_ref" in p else max(du.max(), 1e-12)
    c["refs"]["rate_dependent_width"] = dict(rate_ref=float(rate))
    c["thr_scale"] = c["thr_scale"] * (1.0 + p["beta"] * du / rate)


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
    span = p["span_ref"] if "span_ref" in p else float(np.max(y) - y0)
    c["refs"]["sensor_bow_nonlinearity"] = dict(span_ref=span)
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


def simulate(fs, reading, theta_dict, effects, drive=None, hold=HOLD_DEFAULT, refs=None):
    """Noiseless displacement of the transducer with the listed hidden effects.

    drive None is the paper's drive with the given reading.  refs, if a dict, receives the
    drive-derived references the forms used (per form), which another run of the same
    transducer keeps (see like_spec)."""
    theta = _theta_array(theta_dict)
    t, i = drive_arrays(fs, reading, drive)
    c = dict(
        t=t,
        i=i,
        u=i.copy(),
        h=1.0 / fs,
        theta=theta,
        y0=rest_level(theta),
        z0=None,
        thr_scale=np.ones(t.size),
        refs={},
    )
    effs = sorted(effects, key=lambda e: FORMS[e["form"]]["order"])
    for e in effs:
        if FORMS[e["form"]]["stage"] == "input":
            FORMS[e["form"]]["apply"](e["params"], c)
    # A lagged current settles on a held command: within 1e-9 A of it, it is the command
    # (no last-bit wiggles, no hold found only when an exponential underflows).  The paper's
    # command holds only in the quiet start, where the lagged current is the command already.
    held = np.r_[False, i[1:] == i[:-1]]
    snap = held & (np.abs(c["u"] - i) < 1e-9) & (c["u"] != i)
    if snap.any():
        c["u"] = np.where(snap, i, c["u"])
    for e in effs:
        if FORMS[e["form"]]["stage"] == "gpi":
            FORMS[e["form"]]["apply"](e["params"], c)
    ts = None if np.all(c["thr_scale"] == 1.0) else c["thr_scale"]
    c["y"] = gpi(theta, c["u"], z0=c["z0"], thr_scale=ts, hold=hold)
    for e in effs:
        if FORMS[e["form"]]["stage"] in ("output", "sensor"):
            FORMS[e["form"]]["apply"](e["params"], c)
    if refs is not None:
        refs.update(c["refs"])
    return t, i, c["y"]


def _sim(base, effects, refs=None):
    """simulate() on a record's (or a record base's) drive and Omega convention."""
    return simulate(
        base["fs"],
        base["input_reading"],
        base["gpi_theta"],
        effects,
        drive=base.get("drive"),
        hold=base.get("omega_at_hold", HOLD_DEFAULT),
        refs=refs,
    )


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
        _, _, y = _sim(base, [dict(category=F["category"], form=form, params=params)])
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


def _record_drive(seed, suite, i, drive):
    """Drive of record i of a suite: None on the paper's drive (the records as they always
    were), else a description drawn from the record's own drive stream (s, i, 2), which the
    record's main stream never sees: theta, reading, fs and noise are drawn as on the paper's
    drive (the reading is drawn and then used only by the paper's drive)."""
    if drive in (None, "paper"):
        return None
    ss = np.random.SeedSequence(seed, spawn_key=(SUITE_KEY[suite], i, DRIVE_KEY))
    return draw_drive(np.random.default_rng(ss), drive)


def _put_drive(spec, drive, hold):
    """Attach a drawn drive to a record (or record base)."""
    if drive["name"] == "paper":  # the paper's drive takes the reading of the main stream
        drive = dict(drive, reading=spec["input_reading"])
    else:
        spec["input_reading"] = None
    spec["drive"] = drive
    spec["omega_at_hold"] = hold


def clean_records(n=100, seed=0, drive=None, hold=HOLD_DEFAULT):
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
        dr = _record_drive(seed, "clean", i, drive)
        if dr is not None:
            _put_drive(spec, dr, hold)
            spec["stem"] += "_" + dr["name"]
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
# Forms added after the suites were fixed: in the effects suite only with --new-forms, as
# records appended after the others (so every earlier record keeps its index and stream).
NEW_FORMS = ["virgin_field_overshoot"]


def effect_plan(per_form=3, new_forms=False):
    plan = []
    for f in SINGLE_FORMS:
        plan += [(f,)] * per_form
    plan += list(COMBOS)
    plan += [(f,) for f in OUTSIDE_FORMS]
    if new_forms:
        for f in NEW_FORMS:
            plan += [(f,)] * per_form
    return plan


def _size_record(rng, i, forms, drive=None, hold=HOLD_DEFAULT):
    base = dict(
        gpi_theta=_draw_theta(rng),
        input_reading=str(rng.choice(["literal", "centred"])),
        fs=1000 if i % 5 == 2 else 100,
    )
    if drive is not None:
        _put_drive(base, drive, hold)
    noise = _draw_noise(rng, 0.45, 0.9)
    sigma = noise["sigma"]
    t, _, y_plain = _sim(base, [])
    if len(forms) == 1:
        targets = [U(rng, 1.7, 3.6)]
    else:
        targets = [U(rng, 1.55, 2.5) for _ in forms]
    for _attempt in range(6):
        effs = [_scaled_effect(rng, f, base, tg, sigma, y_plain, t) for f, tg in zip(forms, targets)]
        _, _, y = _sim(base, effs)
        r = visible_ratio(y, y_plain, t, sigma)
        if 1.5 <= r <= 4.0:
            return base, noise, effs, r
        targets = [min(3.8, 1.3 * tg) for tg in targets] if r < 1.5 else [max(1.55, 0.8 * tg) for tg in targets]
    raise RuntimeError(f"could not size combination {forms}")


def _effect_spec(seed, i, forms, drive=None, hold=HOLD_DEFAULT):
    """One effects record.  If an effect cannot reach the size window for the drawn
    GPI parameters and noise level (e.g. a prior excursion that is bounded by the
    fully raised memory), the whole record is redrawn from the same stream."""
    rng = _record_rng(seed, "effects", i)
    dr = _record_drive(seed, "effects", i, drive)
    for _redraw in range(20):
        try:
            base, noise, effs, r = _size_record(rng, i, forms, dr, hold)
            break
        except RuntimeError:
            continue
    else:
        raise RuntimeError(f"record {i}: could not size {forms}")
    cats = [FORMS[f]["category"] for f in forms]
    tag = "_".join(cats) if len(forms) > 1 else cats[0]
    if dr is not None:
        tag += "_" + dr["name"]
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


def effect_records(seed=0, per_form=3, drive=None, new_forms=False, hold=HOLD_DEFAULT):
    plan = effect_plan(per_form, new_forms)
    return [_effect_spec(seed, i, forms, drive, hold) for i, forms in enumerate(plan)]


# ----------------------------------------------------------------------------------
# The same transducer in another run (another drive, another day)
# ----------------------------------------------------------------------------------
# Run parameters, per form: the conditions of a run rather than properties of the
# transducer.  Everything else (GPI parameters, each effect's time constants, coefficients,
# gains and shapes, the noise kind and level) and the drive-derived references below belong
# to the transducer and are kept.
RUN_PARAMETERS = {
    "one_pole_expansion": {
        "T_start": "heat left by earlier runs: temperature rise at t = 0 (A^2, the form's temperature unit), relaxing "
        "with tau_th"
    },
    "two_node_network": {
        "T_start": "heat left by earlier runs: coil and sample both start T_start (A^2) warm and relax through the "
        "network"
    },
    "gain_vs_temperature": {
        "T_start": "heat left by earlier runs: temperature rise at t = 0 (A^2), relaxing with tau_th"
    },
    "linear_drift": {"sign": "direction of the sensor's offset drift that day", "rate": "the day's drift rate (um/s)"},
    "exponential_warmup": {
        "sign": "direction of the sensor electronics' warm-up that day",
        "amplitude": "size of the warm-up (um): depends on how long the sensor was off",
        "tau_w": "time constant of the warm-up that day (s)",
    },
    "sensor_temperature": {
        "amb_rel": "the day's ambient temperature swing, relative to i2_ref",
        "amb_period": "period of the ambient swing (s)",
        "amb_phase": "phase of the ambient swing at t = 0",
    },
    "retained_offset_fixed": {
        "virgin": "true: the sample was reset before the run and its first cycle is virgin; false: it starts in the "
        "state an earlier run left (offset kappa*E at rest, the later-cycle law from t = 0, s against Y1_ref)"
    },
    "retained_offset_fading": {
        "virgin": "as retained_offset_fixed",
        "cycles_before": "cycles done since the sample's first unloading before this run (not virgin): the offset "
        "is kappa*E*exp(-(cycles_before + N(t))/n_fade)",
    },
    "virgin_field_overshoot": {
        "virgin": "true: reset before the run (M starts at -inf, S = 0); false: an earlier run reached i_max_before",
        "i_max_before": "largest current an earlier run reached (A, not virgin): retained kappa*E*F(i_max_before) at "
        "the start, S = 0, and only currents above it load virgin ground",
    },
    "gain_decay_with_cycles": {
        "cycles_before": "training cycles the sample kept from earlier runs: N -> N + cycles_before"
    },
    "threshold_shrink": {"cycles_before": "training cycles the sample kept from earlier runs: N -> N + cycles_before"},
    "prior_excursion": {"v_prior": "largest current of the earlier run that set the initial memory (A)"},
    "raised_memory": {
        "delta": "size of the memory the earlier runs left raised (um)",
        "q": "how much more the wide operators keep",
    },
}
RUN_DEFAULTS = dict(T_start=0.0, virgin=True, cycles_before=0.0, i_max_before=0.0)
# Drive-derived normalisations of the forms, frozen from the record that defined the transducer.
REFERENCE_PARAMETERS = {
    "gain_vs_temperature": ["i2_ref"],
    "sensor_temperature": ["i2_ref"],
    "retained_offset_fixed": ["Y1_ref"],
    "retained_offset_fading": ["Y1_ref"],
    "hard_stop": ["y_max_ref"],
    "rate_dependent_width": ["rate_ref"],
    "sensor_bow_nonlinearity": ["span_ref"],
}
RUN_RULE = (
    "Transducer (kept in every run): the GPI parameters; every effect's time constants, coefficients, gains and "
    "shapes (material, coil and core, spring, mounting, sensor hardware); the noise kind, sigma and phi; the "
    "references frozen from the record that defined the transducer (reference_parameters: i2_ref, Y1_ref, y_max_ref, "
    "rate_ref, span_ref; Y1_ref scales the retained_offset overshoot with the run's own first excursion, "
    "E_run = E*Y1/Y1_ref).  Run (run_parameters): the sensor's drift of the day, the ambient swing, the heat and the "
    "sample state (memory, virgin or not, cycles done) that earlier runs left, and the noise realisation.  redraw: "
    "run parameters drawn afresh from the run's key (s, i, 3, j, 2); keep: identical to the given record (absent = "
    "T_start 0, virgin, cycles_before 0)."
)


def _keep_run_parameters(form, p):
    q = dict(p)
    for name in RUN_PARAMETERS.get(form, {}):
        if name in RUN_DEFAULTS:
            q.setdefault(name, RUN_DEFAULTS[name])
    return q


def _redraw_run_parameters(form, p, rng):
    """Fresh run parameters: the day's conditions from the forms' own priors, sizes of the
    day's drift within a factor 2 of the given record's."""
    q = dict(p)
    if form in ("one_pole_expansion", "two_node_network", "gain_vs_temperature"):
        q["T_start"] = U(rng, 0.0, 5.0)
    elif form == "linear_drift":
        q["sign"] = _sign(rng)
        q["rate"] = p["rate"] * _lu(rng, 0.5, 2.0)
    elif form == "exponential_warmup":
        q["sign"] = _sign(rng)
        q["amplitude"] = p["amplitude"] * _lu(rng, 0.5, 2.0)
        q["tau_w"] = U(rng, 5.0, 30.0)
    elif form == "sensor_temperature":
        q["amb_rel"] = U(rng, 0.2, 1.0)
        q["amb_period"] = U(rng, 60.0, 300.0)
        q["amb_phase"] = U(rng, 0.0, 2 * np.pi)
    elif form in ("retained_offset_fixed", "retained_offset_fading", "virgin_field_overshoot"):
        q["virgin"] = bool(rng.random() < 0.5)
        if form == "retained_offset_fading":
            q["cycles_before"] = 0.0 if q["virgin"] else U(rng, 1.0, 6.0)
        if form == "virgin_field_overshoot":
            q["i_max_before"] = 0.0 if q["virgin"] else U(rng, 2.5, 5.0)
    elif form in ("gain_decay_with_cycles", "threshold_shrink"):
        q["cycles_before"] = U(rng, 0.0, 6.0)
    elif form == "prior_excursion":
        q["v_prior"] = U(rng, 0.0, 5.0)
    elif form == "raised_memory":
        q["delta"] = p["delta"] * U(rng, 0.0, 2.0)
        q["q"] = U(rng, 0.0, 2.0)
    return q


def run_rng(spec, j, stream):
    """Stream of run j of the transducer of record `spec`: key (s, i, 3, j, stream) with
    stream 0 = drive, 1 = noise, 2 = run parameters; (s, i) is the transducer's record."""
    s, i0 = spec["seed"]["spawn_key"][:2]
    ss = np.random.SeedSequence(spec["seed"]["base"], spawn_key=(s, i0, RUN_KEY, j, stream))
    return np.random.default_rng(ss)


def _ratio_any(y, y_plain, t, sigma):
    m = t >= T_ON
    if not m.any():
        m = np.ones(t.size, bool)
    return float(np.sqrt(np.mean((y[m] - y_plain[m]) ** 2)) / sigma)


def like_spec(given, j, drive, mode="redraw", noise_key=None, hold=None, stem=None):
    """Run j of the transducer of record `given` (a spec) on `drive`.

    drive: a description from draw_drive, or a "file" drive (read_drive_csv) with arrays.
    mode : "redraw" (run parameters drawn from key (s, i, 3, j, 2)) or "keep" (identical).
    noise_key: spawn key of the noise (default (s, i, 3, j, 1)); the noise kind and level
    are the transducer's.
    """
    if mode not in ("redraw", "keep"):
        raise ValueError(mode)
    refs = {}
    _sim(given, given["effects"], refs=refs)  # the references of the given record
    rng = run_rng(given, j, 2)
    effects = []
    for e in given["effects"]:
        p = dict(e["params"])
        for k in REFERENCE_PARAMETERS.get(e["form"], []):
            p[k] = refs[e["form"]][k]
        p = _redraw_run_parameters(e["form"], p, rng) if mode == "redraw" else _keep_run_parameters(e["form"], p)
        effects.append(
            dict(
                category=e["category"],
                form=e["form"],
                params=p,
                equation=FORMS[e["form"]]["equation"],
                visible_rms_over_sigma=None,
            )
        )
    s, i0 = given["seed"]["spawn_key"][:2]
    tstem = given.get("transducer", {}).get("stem", given["stem"])
    spec = dict(
        stem=stem or f"{tstem}_run{j}_{drive['name']}",
        suite=given["suite"],
        physics=list(given["physics"]),
        forms=list(given["forms"]),
        effects=effects,
        gpi_theta=dict(given["gpi_theta"]),
        input_reading=drive["reading"] if drive["name"] == "paper" else None,
        fs=drive.get("fs", given["fs"]),
        noise=dict(given["noise"]),
        seed=dict(base=int(given["seed"]["base"]), spawn_key=[s, i0, RUN_KEY, j]),
        noise_spawn_key=[int(k) for k in noise_key] if noise_key is not None else [s, i0, RUN_KEY, j, 1],
        visible_rms_over_sigma=None,
        drive=drive,
        omega_at_hold=hold or given.get("omega_at_hold", HOLD_DEFAULT),
        run=int(j),
        transducer=dict(stem=tstem, spawn_key=[s, i0]),
        derived_from=given["stem"],
        run_parameter_mode=mode,
    )
    a = realise(spec)
    sigma = spec["noise"]["sigma"]
    spec["visible_rms_over_sigma"] = _ratio_any(a["noiseless"], a["noiseless_without_effects"], a["time"], sigma)
    for e in effects:
        _, _, y1 = _sim(spec, [e])
        e["visible_rms_over_sigma"] = _ratio_any(y1, a["noiseless_without_effects"], a["time"], sigma)
    return spec


def run_drive(spec, j, drive):
    """Drive of run j >= 1 of the transducer of record `spec` for --records-per-transducer:
    with "mixed" the drives rotate from the record's own (run j: DRIVES[(k0 + j) % 3]);
    otherwise the named drive; its parameters from the run's drive stream (s, i, 3, j, 0)."""
    name = drive or "paper"
    if name == "mixed":
        k0 = DRIVES.index(spec["drive"]["name"]) if "drive" in spec else 0
        name = DRIVES[(k0 + j) % len(DRIVES)]
    return draw_drive(run_rng(spec, j, 0), name)


def read_drive_csv(path):
    """A drive from a CSV with columns time,current (header; other columns ignored).

    time must start at 0 and be uniformly sampled (any rate).  If the step is 1/fs for an
    integer fs, the generator's own grid k/fs is used."""
    with open(path) as fh:
        cols = [h.strip().lower() for h in fh.readline().strip().split(",")]
    if "time" not in cols or "current" not in cols:
        raise ValueError(f"{path}: the header must name the columns time and current")
    d = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    t, i = d[:, cols.index("time")], d[:, cols.index("current")].copy()
    n = t.size
    if n < 2 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(i))):
        raise ValueError(f"{path}: need at least two finite samples")
    if abs(t[0]) > 1e-9:
        raise ValueError(f"{path}: time must start at 0")
    dt = np.diff(t)
    h = (t[-1] - t[0]) / (n - 1)
    if np.any(dt <= 0) or np.max(np.abs(dt - h)) > 1e-6 * h:
        raise ValueError(f"{path}: time must increase in equal steps (resample the drive first)")
    fs_int = int(round(1.0 / h))
    if fs_int >= 1 and np.max(np.abs(t - np.arange(n) / fs_int)) <= 1e-9 * max(1.0, t[-1]):
        fs = fs_int
        tg = np.arange(n) / float(fs)
    else:
        fs = 1.0 / h
        tg = np.arange(n) * h
    lo, hi = I_RIG
    return dict(
        name="file",
        file=os.path.basename(path),
        n_samples=int(n),
        duration=float(tg[-1]),
        fs=fs,
        i_min=float(i.min()),
        i_max=float(i.max()),
        max_slew=float(np.max(np.abs(np.diff(i))) * fs) if n > 1 else 0.0,
        within_rig_limits=bool(i.min() >= lo and i.max() <= hi),
        _t=tg,
        _i=i,
    )


def spec_from_truth(path):
    """Rebuild a record spec from its STEM.truth.json (a "file" drive is read back from
    STEM.npz, else STEM.csv, next to it)."""
    with open(path) as fh:
        tr = json.load(fh)
    stem = os.path.basename(path)
    stem = stem[: -len(".truth.json")] if stem.endswith(".truth.json") else os.path.splitext(stem)[0]
    effects = []
    for cat, d in tr["effect_parameters"].items():
        d = dict(d)
        form, eq, vr = d.pop("form"), d.pop("equation"), d.pop("visible_rms_over_sigma")
        effects.append(dict(category=cat, form=form, params=d, equation=eq, visible_rms_over_sigma=vr))
    spec = dict(
        stem=stem,
        suite=tr["suite"],
        physics=list(tr["physics"]),
        forms=list(tr["forms"]),
        effects=effects,
        gpi_theta=dict(tr["gpi_theta"]),
        input_reading=tr["input_reading"],
        fs=tr["fs"],
        noise=dict(tr["noise"]),
        seed=dict(tr["seed"]),
        noise_spawn_key=list(tr["noise_spawn_key"]),
        visible_rms_over_sigma=tr["visible_rms_over_sigma"],
    )
    for k in ("drive", "omega_at_hold", "run", "transducer", "derived_from", "run_parameter_mode"):
        if k in tr:
            spec[k] = tr[k]
    if spec.get("drive", {}).get("name") == "file":
        base = os.path.join(os.path.dirname(path), stem)
        if os.path.exists(base + ".npz"):
            z = np.load(base + ".npz")
            spec["drive"]["_t"], spec["drive"]["_i"] = z["time"], z["current"]
        else:
            d = np.loadtxt(base + ".csv", delimiter=",", skiprows=1, ndmin=2)
            spec["drive"]["_t"], spec["drive"]["_i"] = d[:, 0], d[:, 1]
    return spec


# ----------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------
def realise(spec):
    """Arrays of a record: time, commanded current, noiseless, noise, plain GPI."""
    if "_arrays" in spec:
        return spec["_arrays"]
    t, i, y = _sim(spec, spec["effects"])
    if spec["effects"]:
        _, _, y_plain = _sim(spec, [])
    else:
        y_plain = y
    ss = np.random.SeedSequence(spec["seed"]["base"], spawn_key=tuple(spec["noise_spawn_key"]))
    noise = make_noise(np.random.default_rng(ss), t.size, spec["noise"])
    arr = dict(time=t, current=i, noiseless=y, noise=noise, noiseless_without_effects=y_plain)
    spec["_arrays"] = arr
    return arr


_NEW_FIELDS = ("drive", "omega_at_hold", "run", "transducer", "derived_from", "run_parameter_mode")


def truth_of(spec):
    new = any(k in spec for k in _NEW_FIELDS)  # a record of the later options
    eff = {}
    for e in spec["effects"]:
        params = _keep_run_parameters(e["form"], e["params"]) if new else e["params"]  # explicit run defaults
        eff[e["category"]] = dict(
            form=e["form"], equation=e["equation"], visible_rms_over_sigma=e["visible_rms_over_sigma"], **params
        )
    out = dict(
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
        n_samples=int(round(DURATION * spec["fs"])) + 1 if "drive" not in spec else int(realise(spec)["time"].size),
        units=dict(time="s", current="A", displacement="um"),
        generator="benchmarks/independent/generator.py",
    )
    if new:
        for k in _NEW_FIELDS:
            if k in spec:
                v = spec[k]
                out[k] = {a: b for a, b in v.items() if not a.startswith("_")} if isinstance(v, dict) else v
        out["run_parameters"] = [
            f"{e['category']}.{n}" for e in spec["effects"] for n in RUN_PARAMETERS.get(e["form"], {})
        ]
        out["run_parameter_meaning"] = {
            f"{e['category']}.{n}": m for e in spec["effects"] for n, m in RUN_PARAMETERS.get(e["form"], {}).items()
        }
        out["reference_parameters"] = [
            f"{e['category']}.{n}" for e in spec["effects"] for n in REFERENCE_PARAMETERS.get(e["form"], [])
        ]
        out["run_parameter_rule"] = RUN_RULE
    return out


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
    out = dict(stem=spec["stem"], **{k: tr[k] for k in keep})
    if "drive" in tr:
        out["drive"] = tr["drive"]["name"]
    if "run" in tr:
        out["run"] = tr["run"]
        out["transducer"] = tr["transducer"]["stem"]
    return out


def _parse_key(text):
    return [int(x) for x in text.replace("(", "").replace(")", "").split(",") if x.strip()]


def like_main(args):
    """--like: one more record of the transducer of a written record."""
    given = spec_from_truth(args.like)
    j = args.run if args.run is not None else int(given.get("run", 0)) + 1
    if j < 1:
        raise SystemExit("--run must be >= 1 (run 0 is the record that defined the transducer)")
    if args.input:
        drive = read_drive_csv(args.input)
        if not drive["within_rig_limits"]:
            print(
                f"warning: {args.input} leaves the rig's 0-5 A ({drive['i_min']:.3g} to {drive['i_max']:.3g} A)",
                file=sys.stderr,
            )
    elif args.drive:
        drive = draw_drive(run_rng(given, j, 0), args.drive)
    else:
        raise SystemExit("--like needs --input FILE.csv or --drive NAME")
    if args.noise_key is None:
        noise_key = None
    elif args.noise_key == "original":
        noise_key = given["noise_spawn_key"]
    else:
        noise_key = _parse_key(args.noise_key)
    spec = like_spec(given, j, drive, args.run_parameters, noise_key, args.omega_at_hold, args.stem)
    path = write_record(spec, args.out)
    print(f"{path}: run {j} of {spec['transducer']['stem']} on {drive['name']}, {spec['run_parameter_mode']}")
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--suite", choices=["clean", "effects", "all"], default="all")
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n", type=int, default=100, help="number of clean records")
    ap.add_argument("--per-form", type=int, default=3, help="effects records per single form")
    ap.add_argument(
        "--drive",
        choices=DRIVES + ["mixed"],
        default=None,
        help="paper (default, the records as always), holds, triangle, or mixed (each record draws one)",
    )
    ap.add_argument(
        "--new-forms", action="store_true", help="append records of the forms added later (virgin_field_overshoot)"
    )
    ap.add_argument(
        "--records-per-transducer",
        type=int,
        default=1,
        metavar="K",
        help="write K records of each transducer: the suite's record and K-1 runs on other drives",
    )
    ap.add_argument("--run-parameters", choices=["redraw", "keep"], default="redraw")
    ap.add_argument("--omega-at-hold", choices=list(HOLD_CONVENTIONS), default=None)
    ap.add_argument("--like", metavar="TRUTH_JSON", help="one more run of the transducer of this record")
    ap.add_argument("--input", metavar="CSV", help="with --like: the drive, columns time,current")
    ap.add_argument("--stem", help="with --like: the new record's stem")
    ap.add_argument("--run", type=int, help="with --like: run index j >= 1 (default: the given record's run + 1)")
    ap.add_argument("--noise-key", help="with --like: 'original' or a comma list (default s,i,3,j,1)")
    args = ap.parse_args(argv)
    if args.like:
        return like_main(args)
    hold = args.omega_at_hold or HOLD_DEFAULT
    K = max(1, args.records_per_transducer)
    index = []
    timing = {}

    def emit(specs):
        for spec in specs:
            if K > 1:
                spec["run"] = 0
                spec["transducer"] = dict(stem=spec["stem"], spawn_key=list(spec["seed"]["spawn_key"]))
            write_record(spec, args.out)
            index.append(_summary(spec))
            for j in range(1, K):
                rs = like_spec(spec, j, run_drive(spec, j, args.drive), args.run_parameters, hold=hold)
                write_record(rs, args.out)
                index.append(_summary(rs))
            spec.pop("_arrays", None)

    if args.suite in ("clean", "all"):
        t0 = _time.time()
        emit(clean_records(args.n, args.seed, args.drive, hold))
        timing["clean"] = _time.time() - t0
    if args.suite in ("effects", "all"):
        t0 = _time.time()
        emit(effect_records(args.seed, args.per_form, args.drive, args.new_forms, hold))
        timing["effects"] = _time.time() - t0
    head = dict(seed=args.seed, n_clean=args.n if args.suite != "effects" else 0)
    if args.drive not in (None, "paper") or args.new_forms or K > 1:
        head.update(
            drive=args.drive or "paper",
            new_forms=args.new_forms,
            records_per_transducer=K,
            run_parameter_mode=args.run_parameters if K > 1 else None,
            omega_at_hold=hold,
        )
    with open(os.path.join(args.out, "index.json"), "w") as fh:
        json.dump(dict(**head, records=index), fh, indent=1)
    for k, v in timing.items():
        print(f"{k}: {sum(1 for r in index if r['suite'] == k)} records in {v:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
