"""Self-check of the independent generator (not a project test).

    python benchmarks/independent/selfcheck.py [--out DIR]

Checks: the vectorised GPI equals a plain sample-by-sample loop; Table 1 with the
paper's input rests at about -0.56 um and peaks near 296 um; a small generation
(clean n=5 + effects) has consistent files (csv = noiseless + noise, exact time
grid, 19 parameters, effect sizes inside 1.5-4 sigma, all categories present).
"""

import argparse
import json
import os
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
    print(f"model: rest {y[0]:.3f} um, peak {y.max():.2f} um, vectorised == loop")


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


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/independent_check")
    a = ap.parse_args()
    check_model()
    check_files(a.out)
