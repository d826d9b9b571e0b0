"""What a results folder's files weigh against issue 70's targets, and what each stored precision
of posterior.nc's pointwise groups costs in bytes and moves in ``az.loo``.

For a finished study (a results folder), first prints the sizes (``du -b``, bytes as
stored) of ``posterior.nc`` (and of each of its variables over 0.1 MB), ``chain.h5`` (and
its compressed chain data) and the whole folder against the targets :data:`TARGETS_MB`.
``--sizes`` stops there. Otherwise it recomputes the float64 pointwise log-likelihood
of the draws ``posterior.nc`` holds, and for each way of storing it (float32; rounded to
2^-e nats; HDF5's scale-offset filter) writes it alone with the file's filters (gzip level
6, byte shuffle, chunks of all draws x 64 samples) and prints the stored megabytes and how
far ``az.loo`` moves against the float64 values: elpd_loo, p_loo, the largest change of a
Pareto k and how many samples' k move by more than 0.01. Then the posterior predictive
(read from the file, so steps finer than the file's own give its size) rounded to a power
of two near sigma / 2^e. Usage::

    python benchmarks/posterior_storage.py DIR [--sizes]

(``DIR`` from ``python -m identify study data/bench_default.csv --out DIR``.)
"""

from __future__ import annotations

import argparse
import tempfile
import warnings
from pathlib import Path

import numpy as np

PACKED = dict(compression="gzip", compression_opts=6, shuffle=True)

#: Issue 70's targets [MB] for the results folder of ``study data/bench_default.csv``.
TARGETS_MB = {"posterior.nc": 10.0, "folder": 15.0}


def print_sizes(folder: Path) -> None:
    """The folder's and its two large files' sizes [MB = 1e6 B] against :data:`TARGETS_MB`."""
    import h5py

    def verdict(name, size):
        target = TARGETS_MB.get(name)
        return "" if target is None else f"  (target <= {target:g} MB: {'met' if size <= target * 1e6 else 'NOT met'})"

    files = [p for p in folder.rglob("*") if p.is_file()]
    total = sum(p.stat().st_size for p in files)
    nc, chain = folder / "posterior.nc", folder / "chain.h5"
    for path in (nc, chain):
        if path.exists():
            print(f"{path.name:14s} {path.stat().st_size / 1e6:7.2f} MB{verdict(path.name, path.stat().st_size)}")
            with h5py.File(path, "r") as f:
                stored = []
                f.visititems(
                    lambda name, obj: (
                        stored.append((name, obj.id.get_storage_size())) if isinstance(obj, h5py.Dataset) else None
                    )
                )
            data = sum(n for _, n in stored)
            print(
                f"{'':14s} {data / 1e6:7.2f} MB of stored data; "
                + ", ".join(f"{name} {n / 1e6:.2f}" for name, n in sorted(stored, key=lambda x: -x[1]) if n > 1e5)
            )
    others = sorted(((p.stat().st_size, p.relative_to(folder)) for p in files if p not in (nc, chain)), reverse=True)
    print(
        "others         " + ", ".join(f"{name} {n / 1e6:.2f}" for n, name in others[:6]) + f" ... ({len(others)} files)"
    )
    print(f"{'folder':14s} {total / 1e6:7.2f} MB{verdict('folder', total)}")


def stored_megabytes(values, chunks, **filters) -> tuple[float, np.ndarray]:
    """Bytes ``values`` take as one HDF5 dataset with ``filters`` [MB], and the values read back."""
    import h5py

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "one.h5"
        with h5py.File(path, "w") as f:
            f.create_dataset("x", data=values, chunks=chunks, **filters)
        with h5py.File(path, "r") as f:
            return f["x"].id.get_storage_size() / 1e6, f["x"][:]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--sizes", action="store_true", help="only the sizes against the targets")
    args = parser.parse_args(argv)
    print_sizes(Path(args.folder))
    if args.sizes:
        return 0

    from identify.fitting.inference import POINTWISE_CHUNK_SAMPLES, pointwise_log_likelihood
    from identify.fitting.posterior import LogPosterior, import_arviz
    from identify.output.results import load_data, load_fit

    az = import_arviz()
    folder = Path(args.folder)
    idata = az.from_netcdf(folder / "posterior.nc")
    fit, record = load_fit(folder), load_data(folder)
    log_post = LogPosterior(record, fit.model, fit.noise)
    stored = idata.log_likelihood["displacement"]
    draws = np.stack([idata.posterior[n].sel(draw=stored["draw"]).values for n in log_post.names], axis=-1)
    y, _ = log_post.model.evaluate(
        log_post.full_theta(draws.reshape(-1, draws.shape[-1])), log_post.time, log_post.current
    )
    exact = pointwise_log_likelihood(log_post.data[None, :] - y, log_post.noise, time=log_post.time)
    exact = exact.reshape(stored.shape)
    chunks = (*stored.shape[:2], min(POINTWISE_CHUNK_SAMPLES, stored.shape[2]))

    def loo(values):
        idata.log_likelihood["displacement"] = (stored.dims, np.asarray(values, dtype=float))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return az.loo(idata, pointwise=True)

    ref = loo(exact)
    print(
        f"{folder}: {stored.shape[0]} x {stored.shape[1]} draws x {stored.shape[2]} samples; exact elpd_loo "
        f"{ref.elpd_loo:.2f}, p_loo {ref.p_loo:.2f}, largest Pareto k {float(ref.pareto_k.max()):.3f}"
    )
    ways = [("float32", exact.astype(np.float32), PACKED)]
    for e in (20, 17, 15, 14):
        q = 2.0**-e
        ways.append((f"rounded to 2^-{e} nats", (np.round(exact / q) * q).astype(np.float32), PACKED))
    ways.append(("scale-offset 4 decimals + gzip", exact, dict(scaleoffset=4, compression="gzip")))
    for label, values, filters in ways:
        megabytes, back = stored_megabytes(values, chunks, **filters)
        moved = loo(back)
        dk = np.abs(moved.pareto_k.values - ref.pareto_k.values)
        print(
            f"log-likelihood {label:32s} {megabytes:6.2f} MB; elpd_loo {moved.elpd_loo - ref.elpd_loo:+.1e}, "
            f"p_loo {moved.p_loo - ref.p_loo:+.1e}, largest k moved {dk.max():.3f} ({int((dk > 0.01).sum())} > 0.01)"
        )
    predictive = idata.posterior_predictive["displacement"].values.astype(float)
    sigma = float(np.min(fit.noise.sigma))
    for e in (4, 5, 6, 7):
        q = 2.0 ** np.floor(np.log2(sigma / 2**e))
        megabytes, _ = stored_megabytes((np.round(predictive / q) * q).astype(np.float32), chunks, **PACKED)
        print(f"predictive rounded to {q:.2e} (sigma/{sigma / q:.0f}): {megabytes:.2f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
