"""Bit-identity check of the effects library across a refactor: save the outputs, then compare.

Run from the repository root::

    python benchmarks/effects_bits.py --save /tmp/effects_bits.npz     # before the change
    python benchmarks/effects_bits.py --check /tmp/effects_bits.npz    # after it: same arrays?

Evaluates ``Model([effect]).evaluate`` for every registered effect and ``Model(all effects)``
on two inputs: the paper's at 100 Hz (7001 samples) and the same drive read at jittered,
irregular sample times (the first 30 s, steps uniform in 5-15 ms). Each model gets twelve
parameter sets: every effect off, its test parameters, and ten random sets (fixed seed)
in which each effect parameter is, with probability 0.7, uniform within its bounds, else at
its ``off`` value; the GPI at Table 1. A parameter's random values depend only on its name
(the seed is the name's CRC32), and the saved file keeps each model's parameter names:
``--check`` puts a parameter the saved model did not have at its ``off`` value, so the
others keep their values and the check also shows that a new parameter's off setting
leaves the old form bit for bit. ``--check`` compares the outputs and validity masks with
``np.array_equal`` (NaN equal to NaN) and exits 1 on any difference.
"""

from __future__ import annotations

import argparse
import sys
import zlib

import numpy as np

from model import EFFECTS, TABLE1, Model, paper_current

SEED = 20261130
N_RANDOM = 10


def inputs() -> dict:
    """``{label: (time, current)}``: the paper's input at 100 Hz and on an irregular grid."""
    time, current = paper_current(fs=100.0)
    rng = np.random.default_rng(SEED)
    irregular = np.cumsum(np.r_[0.0, rng.uniform(0.005, 0.015, 3000)])
    irregular = irregular[irregular <= 30.0]
    return {"paper_100hz": (time, current), "irregular": (irregular, np.interp(irregular, time, current))}


def parameter_sets(m: Model, known=None) -> np.ndarray:
    """``(2 + N_RANDOM, P)``: off, test parameters, random sets (see the module docstring); a
    parameter not in ``known`` (names; default all) stays off in the random sets."""
    rows = [m.default_theta(TABLE1)]
    test = m.default_theta(TABLE1)
    for effect in m.effects:
        for name, value in type(effect).get_test_parameters().items():
            test[m.names.index(name)] = value
    rows.append(test)
    for k in range(N_RANDOM):
        theta = m.default_theta(TABLE1)
        for effect in m.effects:
            for p in effect.parameters:
                rng = np.random.default_rng([SEED, zlib.crc32(p.name.encode()), k])
                on, value = rng.uniform() < 0.7, rng.uniform(p.lower, p.upper)
                if on and (known is None or p.name in known):
                    theta[m.names.index(p.name)] = value
        rows.append(theta)
    return np.array(rows)


def outputs(saved=None) -> dict:
    """``{key: array}``: every model's output, validity and parameter names on every input;
    the random sets use only the parameters ``saved`` (a loaded file) has for that model."""
    models = {name: Model([name]) for name in EFFECTS}
    models["all"] = Model(list(EFFECTS))
    out = {}
    for label, (time, current) in inputs().items():
        for key, m in models.items():
            names_key = f"{label}/{key}/names"
            known = None if saved is None or names_key not in saved.files else set(saved[names_key].tolist())
            y, valid = m.evaluate(parameter_sets(m, known), time, current)
            out[f"{label}/{key}/y"] = y
            out[f"{label}/{key}/valid"] = valid
            out[names_key] = np.array(m.names)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", metavar="NPZ", help="write the outputs here")
    group.add_argument("--check", metavar="NPZ", help="compare the outputs with this file")
    args = parser.parse_args(argv)
    saved = np.load(args.check) if args.check else None
    got = outputs(saved)
    if args.save:
        np.savez_compressed(args.save, **got)
        print(f"saved {len(got)} arrays to {args.save}")
        return 0
    results = [k for k in saved.files if not k.endswith("/names")]
    differ = [k for k in results if k not in got or not np.array_equal(saved[k], got[k], equal_nan=True)]
    missing = [k for k in got if k not in saved.files and not k.endswith("/names")]
    for k in results:
        if k in got and k.endswith("/y") and k not in differ:
            print(f"same  {k} {got[k].shape}")
    for k in differ:
        print(f"DIFFERS {k}")
    for k in missing:
        print(f"new (not compared) {k}")
    print(f"{len(results) - len(differ)} of {len(results)} arrays bit for bit the same")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
