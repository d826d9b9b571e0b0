"""Where the time of one report goes: the analysis and each figure (built, then drawn as PNG).

Reads a finished results folder (``python -m identify study ... --out DIR``) and times, in
wall and CPU seconds, what :func:`identify.output.report.write_report` does: importing the
report module, loading the folder, the analysis (chain, bands, reversals, autocorrelation)
and each figure's construction and PNG rendering. Nothing is written.

Usage::

    python benchmarks/report_stages.py DIR
"""

from __future__ import annotations

import argparse
import os
import time
import warnings


def _clock():
    return time.perf_counter(), time.process_time()


def _since(start) -> str:
    wall, cpu = _clock()
    return f"{wall - start[0]:.2f} s (CPU {cpu - start[1]:.2f} s)"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    print(f"load {os.getloadavg()[0]:.2f}")
    begin = start = _clock()
    import numpy as np

    import identify.output.report as report
    from identify.output.page import png_bytes

    print(f"import {_since(start)}")
    start = _clock()
    data = report.load_report_data(args.folder)
    print(f"load {_since(start)}")
    rng = np.random.default_rng(0)
    start = _clock()
    analysis = report.analyse_report(data, 200, rng)
    print(f"analysis {_since(start)}")
    figures = report.report_figures(data, analysis, rng)
    while True:
        start = _clock()
        try:
            stem, figure, _caption = next(figures)
        except StopIteration:
            break
        built = _since(start)
        start = _clock()
        png = png_bytes(figure, report.DPI.get(stem, report.DPI["default"]))
        drawn = _since(start)
        print(f"{stem:<18} built {built}, PNG {drawn}, {len(png) / 1e3:.0f} kB")
    print(f"total {_since(begin)}; load {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
