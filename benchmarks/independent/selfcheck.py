"""Self-check of the independent generator (not a project test).

    python benchmarks/independent/selfcheck.py [--out DIR]

Checks: the vectorised GPI equals a plain sample-by-sample loop (both Omega conventions
at holds); Table 1 with the paper's input rests at about -0.56 um and peaks near 296 um;
a small generation (clean n=5 + effects) has consistent files (csv = noiseless + noise,
exact time grid, 19 parameters, effect sizes inside 1.5-4 sigma, all categories present)
and is the same, byte for byte, as the generator wrote before the drive options (a
fingerprint of its csv and json files).  Then the later options: the holds, triangle and
mixed drives (rig limits, quiet start, equal time steps, the holds' hold and quiet end,
the triangles' constant slew, a mixed record is the record of the drive it drew); --like
(the same drive, run parameters kept and the original noise key give the original files
byte for byte; another drive keeps every transducer parameter); --records-per-transducer;
and the virgin_field_overshoot form.
"""

import argparse
import glob
import hashlib
import json
import os
import shutil
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import generator as g


def check_model():
    rng = np.random.default_rng(123)
    t = g.time_axis(100)
    for reading in ("literal", "centred"):
        for k in range(3):
            th = g.TABLE1 * rng.uniform(0.9, 1.1, g.TABLE1.size)
            v = g.commanded_current(t, reading)
            if k == 2:
                v = g.lowpass1(v, 0.03, 0.01)
            err = np.abs(g.gpi(th, v) - g.gpi_reference_loop(th, v)).max()
            assert err < 1e-9, err
    y = g.gpi(g.TABLE1, g.commanded_current(t, "literal"))
    assert abs(y[0] + 0.56) < 0.01 and abs(y.max() - 296) < 1.0, (y[0], y.max())
    # holds after rises and after falls: both Omega conventions against the loop
    d = g.draw_drive(np.random.default_rng(5), "holds")
    th = g.TABLE1 * rng.uniform(0.9, 1.1, g.TABLE1.size)
    _, v = g.drive_arrays(100, None, d)
    v = np.r_[v[:3000], np.full(50, v[2999]), v[3000:]]  # a hold entered on a fall too
    ys = {}
    for hold in g.HOLD_CONVENTIONS:
        ys[hold] = g.gpi(th, v, hold=hold)
        err = np.abs(ys[hold] - g.gpi_reference_loop(th, v, hold=hold)).max()
        assert err < 1e-9, (hold, err)
    quiet = g.grid(d["duration"], 100) >= d["quiet_from"]
    quiet = np.r_[quiet[:3000], np.zeros(50, bool), quiet[3000:]]
    jump = ys["rising"][quiet][-1] - ys["last"][quiet][-1]
    assert np.ptp(ys["last"][quiet]) < 1e-9 and abs(jump) > 0.5, jump
    print(
        f"model: rest {y[0]:.3f} um, peak {y.max():.2f} um, vectorised == loop (both Omega conventions at holds; "
        f"the literal one steps {jump:+.2f} um at the quiet end)"
    )


def check_files(out):
    g.main(["--suite", "all", "--n", "5", "--out", out, "--seed", "0"])
    idx = json.load(open(os.path.join(out, "index.json")))["records"]
    cats = set()
    for r in idx:
        stem = os.path.join(out, r["stem"])
        tr = json.load(open(stem + ".truth.json"))
        z = np.load(stem + ".npz")
        with open(stem + ".csv") as fh:
            assert fh.readline().strip() == "time,current,displacement"
        d = np.loadtxt(stem + ".csv", delimiter=",", skiprows=1)
        k = np.arange(d.shape[0])
        assert d.shape[0] == tr["n_samples"]
        assert np.all(d[:, 0] == np.array([float(f"{x:.10g}") for x in k / tr["fs"]]))
        assert np.allclose(d[:, 2], z["noiseless"] + z["noise"], rtol=1e-9, atol=1e-6)
        assert len(tr["gpi_theta"]) == 19 and tr["n_operators"] == 12
        f = np.array([tr["gpi_theta"][n] for n in g.PARAM_NAMES]) / g.TABLE1
        assert np.all((f > 0.9 - 1e-12) & (f < 1.1 + 1e-12))
        if tr["suite"] == "effects":
            assert 1.5 <= tr["visible_rms_over_sigma"] <= 4.0, r["stem"]
            assert set(tr["physics"]) <= set(g.CATEGORIES)
            cats |= set(tr["physics"])
    assert cats == set(g.CATEGORIES), cats
    fs = {(r["suite"], r["fs"]) for r in idx}
    assert ("clean", 1000) in fs and ("effects", 1000) in fs
    print(f"files: {len(idx)} records consistent, categories {sorted(cats)}")
    fp = fingerprint(out)
    assert fp == FINGERPRINT, (
        f"the csv/json files differ from those the generator wrote before the drive options ({fp}); "
        f"the reference was made with numpy 2.4.6 and scipy 1.17.1, this is numpy {np.__version__}"
    )
    print("old seeds: the 145 csv/json files of --suite all --n 5 --seed 0 are byte for byte those of before")


# sha256 over (name, sha256(file)) of the csv and json files of `--suite all --n 5 --seed 0`,
# written by the generator before the drive options (commit ff4cb08; numpy 2.4.6, scipy 1.17.1)
FINGERPRINT = "2f11ef14293c7fd8143732b6c929bf218758a242535ca200018a325c6d3c9fd4"


def fingerprint(directory):
    h = hashlib.sha256()
    for n in sorted(os.listdir(directory)):
        if n.endswith((".csv", ".json")):
            h.update(n.encode())
            with open(os.path.join(directory, n), "rb") as fh:
                h.update(hashlib.sha256(fh.read()).digest())
    return h.hexdigest()


def _load(stem):
    with open(stem + ".truth.json") as fh:
        tr = json.load(fh)
    return tr, np.load(stem + ".npz"), np.loadtxt(stem + ".csv", delimiter=",", skiprows=1)


def _check_drive_arrays(t, i, fs, d):
    """Rig limits, the quiet start, equal steps, the paper's slow rates, and the shape."""
    k = np.arange(t.size)
    assert np.all(np.diff(t) > 0) and np.array_equal(t, k / float(fs)), "time k/fs"
    lo, hi = g.I_RIG
    assert i.min() >= lo and i.max() <= hi, (i.min(), i.max())
    assert np.all(i[t <= g.T_ON] == 0.0), "quiet start"
    slew = np.abs(np.diff(i)) * fs
    assert slew.max() <= g.PAPER_MAX_SLEW + 1e-9, slew.max()
    assert abs(t[-1] - d["duration"]) < 1e-9
    if d["name"] == "holds":
        pk = np.array(d["peaks"])
        m = len(pk) // 2
        assert np.all(np.diff(pk[: m + 1]) < 0) and np.all(np.diff(pk[m:]) > 0), "peaks fall, then rise"
        held = i[(t >= d["hold_start"]) & (t < d["hold_end"])]
        assert d["t_hold"] >= 8.0 and held.size >= 8.0 * fs and np.all(held == pk[-1]) and pk[-1] >= 4.5, "the hold"
        assert d["t_end"] >= 30.0 and np.all(i[t >= d["quiet_from"]] == 0.0), "the quiet end"
        assert np.sum(i[t >= d["quiet_from"]] == 0.0) >= 30.0 * fs
    elif d["name"] == "triangle":
        legs = np.abs(np.diff(i))
        inner = np.ones(legs.size, bool)
        for tc in d["corner_times"]:  # steps that straddle a corner
            inner &= ~((t[:-1] <= tc) & (t[1:] >= tc))
        inner &= (t[:-1] >= g.T_ON) & (t[1:] <= d["corner_times"][-1])
        assert np.allclose(legs[inner], d["slew"] / fs, rtol=1e-9, atol=1e-12), "constant slew"
        assert 0.5 <= d["slew"] <= 1.5 and max(d["peaks"]) <= hi
        assert len(set(np.round(d["peaks"], 6))) == len(d["peaks"]), "peaks vary"


def check_drives(out):
    # many drawn drives (cheap: no simulation)
    for name in ("holds", "triangle"):
        for s in range(40):
            d = g.draw_drive(np.random.default_rng(s), name)
            for fs in (100, 1000):
                t, i = g.drive_arrays(fs, None, d)
                _check_drive_arrays(t, i, fs, d)
    # written records on each drive: a clean suite and effects records
    names = {}
    for drive in ("holds", "triangle", "mixed"):
        dd = os.path.join(out, drive)
        g.main(["--suite", "clean", "--n", "5", "--out", dd, "--drive", drive])
        for i, forms in ((2, ("retained_offset_fixed",)), (5, ("two_poles", "one_pole_expansion"))):
            spec = g._effect_spec(0, 60 + i, forms, drive)
            g.write_record(spec, dd)
        for tj in sorted(glob.glob(os.path.join(dd, "*.truth.json"))):
            stem = tj[: -len(".truth.json")]
            tr, z, d = _load(stem)
            dr = tr["drive"]
            assert dr["name"] in g.DRIVES and (drive == "mixed" or dr["name"] == drive)
            assert d.shape[0] == tr["n_samples"] == z["time"].size
            assert np.allclose(d[:, 2], z["noiseless"] + z["noise"], rtol=1e-9, atol=1e-6)
            assert tr["omega_at_hold"] == "last" and "run_parameters" in tr
            if dr["name"] == "paper":
                assert tr["input_reading"] == dr["reading"] and np.array_equal(
                    z["current"], g.commanded_current(z["time"], dr["reading"])
                )
            else:
                assert tr["input_reading"] is None
                _check_drive_arrays(z["time"], z["current"], tr["fs"], dr)
            if tr["suite"] == "effects":
                assert 1.5 <= tr["visible_rms_over_sigma"] <= 4.0, stem
            names[(drive, os.path.basename(stem))] = dr["name"]
    # a mixed record is the record of the drive it drew (paper: the paper suite's record)
    seen = set()
    for (drive, stem), name in names.items():
        if drive != "mixed":
            continue
        seen.add(name)
        if name == "paper":
            a = g.clean_records(5, 0)[int(stem[6:9])] if stem.startswith("clean") else None
            if a is None:
                continue
            ref = g.realise(a)
        else:
            ref = np.load(os.path.join(out, name, stem + ".npz"))
        z = np.load(os.path.join(out, "mixed", stem + ".npz"))
        assert all(np.array_equal(z[k], ref[k]) for k in z.files), stem
    assert seen == set(g.DRIVES), seen
    n = sum(1 for k in names if k[0] != "mixed")
    print(f"drives: 80 drawn holds/triangle drives in limits; {len(names)} records ({n} holds/triangle) consistent;")
    print("        mixed records are those of the drives they drew")


def _drive_csv(z, path):
    np.savetxt(
        path,
        np.column_stack([z["time"], z["current"]]),
        fmt="%.17g",
        delimiter=",",
        header="time,current",
        comments="",
    )


def check_like(out, files_out):
    """--like: the same drive + keep + the original noise key rebuild the record byte for
    byte; another drive keeps the transducer."""
    dd = os.path.join(out, "like")
    picks = sorted(glob.glob(os.path.join(files_out, "effects_*.truth.json")))[::2]
    picks += [os.path.join(files_out, "clean_004.truth.json")]
    picks += sorted(glob.glob(os.path.join(out, "holds", "effects_*.truth.json")))
    picks += sorted(glob.glob(os.path.join(out, "triangle", "effects_*.truth.json")))
    forms = set()
    for tj in picks:
        stem = tj[: -len(".truth.json")]
        tr, z, _ = _load(stem)
        _drive_csv(z, os.path.join(out, "drive.csv"))
        args = ["--like", tj, "--input", os.path.join(out, "drive.csv"), "--out", dd, "--stem", "again"]
        g.main(args + ["--run-parameters", "keep", "--noise-key", "original"])
        z2 = np.load(os.path.join(dd, "again.npz"))
        assert all(np.array_equal(z[k], z2[k]) for k in z.files), stem
        with open(stem + ".csv", "rb") as a, open(os.path.join(dd, "again.csv"), "rb") as b:
            assert a.read() == b.read(), stem
        forms |= set(tr["forms"])
        # same drive, run parameters kept, default (fresh) noise key: same noiseless, new noise
        g.main(args + ["--run-parameters", "keep"])
        z3 = np.load(os.path.join(dd, "again.npz"))
        assert np.array_equal(z3["noiseless"], z["noiseless"]) and not np.array_equal(z3["noise"], z["noise"])
    # another drive: the transducer's parameters kept, the run's redrawn, keys documented
    tj = picks[0]
    redrawn = 0
    for tj in picks[::3]:
        tr = json.load(open(tj))
        g.main(["--like", tj, "--drive", "triangle", "--out", dd, "--stem", "other", "--run", "2"])
        tr2, z2, _ = _load(os.path.join(dd, "other"))
        assert (
            tr2["gpi_theta"] == tr["gpi_theta"] and tr2["noise"] == tr["noise"] and tr2["drive"]["name"] == "triangle"
        )
        s, i = tr["seed"]["spawn_key"][:2]
        assert tr2["seed"]["spawn_key"] == [s, i, 3, 2] and tr2["noise_spawn_key"] == [s, i, 3, 2, 1]
        assert tr2["run"] == 2 and tr2["run_parameter_mode"] == "redraw"
        run = {n.split(".")[1] for n in tr2["run_parameters"]}
        for cat, e in tr["effect_parameters"].items():
            e2 = tr2["effect_parameters"][cat]
            for k, v in e.items():
                if k not in run and k != "visible_rms_over_sigma":
                    assert e2[k] == v, (tj, cat, k)
            redrawn += sum(e2[k] != e.get(k, g.RUN_DEFAULTS.get(k)) for k in run if k in e2)
            for r in g.REFERENCE_PARAMETERS.get(e["form"], []):
                assert r in e2, (cat, r)
        _check_drive_arrays(z2["time"], z2["current"], tr2["fs"], tr2["drive"])
    assert redrawn > 0
    print(f"like: {len(picks)} records ({len(forms)} forms) rebuilt byte for byte from their drive with keep + the")
    print("      original noise key; a fresh key changes only the noise; on a triangle the transducer is kept")


def check_runs(out):
    dd = os.path.join(out, "runs")
    g.main(["--suite", "clean", "--n", "3", "--drive", "mixed", "--records-per-transducer", "3", "--out", dd])
    idx = json.load(open(os.path.join(dd, "index.json")))
    assert idx["records_per_transducer"] == 3 and len(idx["records"]) == 9
    by = {}
    for r in idx["records"]:
        tr = json.load(open(os.path.join(dd, r["stem"] + ".truth.json")))
        by.setdefault(tr["transducer"]["stem"], []).append(tr)
    for trs in by.values():
        assert [t["run"] for t in trs] == [0, 1, 2]
        assert len({t["drive"]["name"] for t in trs}) == 3, "three drives"
        assert all(t["gpi_theta"] == trs[0]["gpi_theta"] and t["noise"] == trs[0]["noise"] for t in trs)
    print(f"runs: {len(by)} transducers x 3 records, each on paper, holds and triangle, theta and noise level kept")


def check_new_form():
    F = g.FORMS["virgin_field_overshoot"]
    assert F["category"] == "first_cycle" and "virgin_field_overshoot" not in g.SINGLE_FORMS
    assert len(g.effect_plan(3)) == 67 and g.effect_plan(3, new_forms=True)[67:] == [("virgin_field_overshoot",)] * 3
    p = dict(i_c=2.2, width=0.6, kappa=0.45, E=4.0)
    t = g.time_axis(100)
    u = g.commanded_current(t, "literal")
    c = dict(u=u)
    x = g._vf_extra(p, c)
    Fu = g._field_fraction(u, p["i_c"], p["width"])
    kp, kq = g.first_peak_trough(u)
    assert np.allclose(x[: kp + 1], p["E"] * Fu[: kp + 1], atol=1e-12), "virgin loading: E*F(i)"
    ret = p["kappa"] * p["E"] * Fu[kp]
    assert np.allclose(x[kq:], ret, atol=1e-12), "kappa*E*F(M) retained, later cycles below M"
    assert np.all(np.diff(x[kp : kq + 1]) <= 1e-12), "first unloading gives the extra back"
    # the shape along the first loading is the field's, not the strain's
    y = g.gpi(g.TABLE1, u)
    s = (y - y[0]) / (y[kp] - y[0])
    assert np.abs(x[: kp + 1] / p["E"] - s[: kp + 1]).max() > 0.1
    # a run that finds the sample cycled: the retained part from the start
    q = dict(p, virgin=False, i_max_before=4.0)
    x2 = g._vf_extra(q, c)
    assert abs(x2[0] - p["kappa"] * p["E"] * g._field_fraction(4.0, 2.2, 0.6)) < 1e-12
    assert x2.max() < x.max()
    spec = g._effect_spec(0, 67, ("virgin_field_overshoot",))
    assert 1.5 <= spec["visible_rms_over_sigma"] <= 4.0
    print(
        f"new form: virgin_field_overshoot E*F(i) on the virgin loading, {ret:.3f} um of {p['E'] * Fu[kp]:.3f} "
        f"retained, sized to {spec['visible_rms_over_sigma']:.2f} sigma; plan without --new-forms unchanged"
    )


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/independent_check")
    a = ap.parse_args()
    if os.path.isdir(a.out):
        shutil.rmtree(a.out)  # the fingerprint covers every csv/json file of the directory
    check_model()
    check_files(a.out)
    extra = a.out + "_later"
    if os.path.isdir(extra):
        shutil.rmtree(extra)
    check_drives(extra)
    check_like(extra, a.out)
    check_runs(extra)
    check_new_form()
