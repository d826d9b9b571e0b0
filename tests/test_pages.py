"""Every HTML page the project writes reads well (issue 67).

One module fixture writes each kind of page with the real commands on small simulated
records: the study report of a record with a hidden thermal effect (the study diagnoses
itself), the report of the study that adds the effect (``--compare``: the error before and
after), the prediction and compensation pages, the batch index and the design page. Then:

* the page text (not the attributes) holds no Python repr (``True``, ``False``, ``None``) and
  no snake_case identifier outside ``<code>`` (names a person types, such as effect,
  parameter and file names, are shown as code);
* in headless Chromium at 1400 px no element is wider than the page (a wide table scrolls in
  its own box), and every figure shows (the study's report links its PNGs by paths relative
  to its folder). The browser is Debian's ``chromium`` found on PATH, driven by playwright
  (the ``test`` extra); without it the test is skipped with the reason, unless
  ``CI_REQUIRE_BROWSER=1`` (then it fails: CI installs the browser, ``.ci/run``);
* no figure the report and the diagnosis draw has tick or axis labels that overlap.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import os
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from identify.bench import simulate
from identify.cli import main as identify_main
from identify.data.records import write_record

#: Python reprs that must never reach a page.
REPRS = re.compile(r"\b(True|False|None)\b")
#: A snake_case identifier (two words or more joined by underscores).
SNAKE = re.compile(r"\b[A-Za-z][A-Za-z0-9]*_[A-Za-z0-9_]*[A-Za-z0-9]\b")
#: The hidden effect of the test records.
THERMAL = "thermal_tau=20,thermal_sensitivity=0.2,thermal_expansion=1.5"
#: The browser's window width [px].
VIEWPORT = 1400


def _run(argv):
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        code = identify_main([str(a) for a in argv])
    return code, out.getvalue()


def _study(csv, out, *extra):
    argv = ["study", csv, "--out", out, "--seed", 1, "--n-starts", 1, "--max-steps", 160, "--check-every", 80]
    code, text = _run([*argv, "--progress", "off", *extra])
    assert code in (0, 1), text
    return out


def _thermal_record(path, seed=1) -> Path:
    """A short bench record (5 Hz, 351 samples) of the paper's transducer with a hidden thermal effect."""
    sim = simulate(THERMAL, seed=seed, fs=5.0)
    write_record(path, sim.record, sidecar=sim.truth)
    return path


def _diagnose_into(folder: Path):
    """The diagnosis of a study's fit, among two candidates (quick), stored as ``study`` stores it."""
    from identify.diagnosis import diagnose
    from identify.output.diagnosis_files import write_diagnosis
    from identify.output.results import load_results

    study = load_results(folder)
    found = diagnose(
        study.record,
        study.fit.model,
        fit=study.fit,
        noise=study.fit.noise,
        candidates=["thermal", "creep"],
        progress=False,
    )
    write_diagnosis(found, study.record, out_dir=folder)
    code, text = _run(["report", folder, "--draws", 40])
    assert code == 0, text
    return found


def _batch_index(folder: Path) -> Path:
    from identify.workflows import batch

    results = [
        batch.JobResult(
            "bench_default__thermal",
            "diagnose",
            "bench_default",
            "thermal",
            "ok",
            rms=0.51,
            max_error_pct=0.4,
            statistic_name="delta_bic[thermal]",
            statistic=120.0,
            verdict="missing_effect: add thermal",
            seconds=3.2,
            output_unit="um",
            report="bench_default__thermal/report.html",
        ),
        batch.JobResult(
            "broken__gpi", "fit", "broken", "gpi", "failed", seconds=0.4, error="error: broken.csv, line 7"
        ),
    ]
    batch.write_summary(folder, results)
    return folder / "index.html"


#: Every figure saved while the pages are written: ``[(page kind, labels that overlap)]``.
SAVED_FIGURES = []


@pytest.fixture(scope="module")
def pages(tmp_path_factory) -> dict:
    """``{name: path}`` of one page of each kind (every figure they save checked for overlapping
    labels as it is saved: :data:`SAVED_FIGURES`)."""
    draw = FigureCanvasAgg.draw
    checking = []

    def checked_draw(canvas):
        """Every figure drawn on an Agg canvas: by ``savefig`` or by identify.output.page.png_bytes
        (which draws on the canvas itself)."""
        draw(canvas)
        if not checking:  # the check draws the figure again
            checking.append(True)
            try:
                SAVED_FIGURES.append((_kind[0], overlapping_labels(canvas.figure)))
            finally:
                checking.clear()

    _kind = ["study"]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(FigureCanvasAgg, "draw", checked_draw)
        return _pages(tmp_path_factory, _kind)


def _pages(tmp_path_factory, kind) -> dict:
    base = tmp_path_factory.mktemp("pages")
    csv = _thermal_record(base / "thermal.csv")
    first = _study(csv, base / "first", "--no-diagnose", "--no-report")
    found = _diagnose_into(first)
    second = _study(csv, base / "second", "--effects", "thermal", "--compare", first, "--no-diagnose")
    new_csv = _thermal_record(base / "new.csv", seed=2)
    kind[0] = "prediction"
    code, text = _run(["predict", second, new_csv, "--out", base / "prediction", "--draws", 30])
    assert code == 0, text
    t = np.arange(0.0, 32.0, 0.2)
    target = 30.0 + 230.0 * np.abs(((t / 16.0) % 1.0) * 2 - 1)
    (base / "target.csv").write_text("time,displacement\n" + "".join(f"{a:.6g},{b:.6g}\n" for a, b in zip(t, target)))
    kind[0] = "compensation"
    code, text = _run(["compensate", second, "--target", base / "target.csv", "--out", base / "comp", "--draws", 20])
    assert code == 0, text
    kind[0] = "design"
    design = ["design", csv, "--out", base / "design", "--candidates", "creep,thermal", "--duration", "90"]
    code, text = _run([*design, "--drives", "2", "--n-starts", "1", "--quiet"])
    assert code == 0, text
    return {
        "diagnosis": found,
        "study report (diagnosed)": first / "report.html",
        "study report (compared)": second / "report.html",
        "prediction": base / "prediction" / "prediction.html",
        "compensation": base / "comp" / "compensation.html",
        "batch index": _batch_index(base / "batch"),
        "design": base / "design" / "design.html",
    }


class _Text(HTMLParser):
    """The text a person reads, outside ``<code>``, ``<style>`` and ``<script>``, the text of links
    (a link's text is the name of the file or folder it opens) and ``<title>`` (the tab's title
    cannot hold markup; the page's heading repeats it with the names as code)."""

    def __init__(self):
        super().__init__()
        self.depth, self.chunks = 0, []

    def handle_starttag(self, tag, attrs):
        if tag in ("code", "style", "script", "a", "title"):
            self.depth += 1

    def handle_endtag(self, tag):
        if tag in ("code", "style", "script", "a", "title"):
            self.depth -= 1

    def handle_data(self, data):
        if self.depth == 0 and data.strip():
            self.chunks.append(data.strip())


def _page_files(pages) -> dict:
    return {name: path for name, path in pages.items() if isinstance(path, Path)}


def test_the_report_states_the_verdict_and_the_next_study_shows_the_error_fall(pages):
    first = pages["study report (diagnosed)"].read_text()
    assert 'id="next-step"' in first and "No diagnosis in this folder" not in first
    if pages["diagnosis"].status == "missing_effect":
        missing = pages["diagnosis"].missing
        assert f"--effects {missing} --out" in first and "--compare" in first
    second = pages["study report (compared)"].read_text()
    assert 'id="comparison-table"' in second and 'src="comparison.png"' in second  # the figure beside the page
    assert (pages["study report (compared)"].parent / "comparison.png").exists()
    assert not (pages["study report (compared)"].parent / "diagnosis.json").exists()  # --no-diagnose


@pytest.mark.parametrize(
    "name",
    [
        "study report (diagnosed)",
        "study report (compared)",
        "prediction",
        "compensation",
        "batch index",
        "design",
    ],
)
def test_no_python_repr_and_no_bare_identifier_in_the_page_text(pages, name):
    parser = _Text()
    parser.feed(pages[name].read_text())
    reprs = [c for c in parser.chunks if REPRS.search(c)]
    snake = [c for c in parser.chunks if SNAKE.search(c)]
    assert not reprs, f"{name}: Python reprs in {reprs[:5]}"
    assert not snake, f"{name}: snake_case outside <code> in {snake[:5]}"
    assert not re.search(r"\d\s*um\b|\[um\b", " ".join(parser.chunks)), f"{name}: 'um' instead of µm"


def _browser():
    """Debian's chromium from PATH, or a skip (a failure with CI_REQUIRE_BROWSER=1) naming what is missing."""
    executable = shutil.which("chromium") or shutil.which("chromium-browser")
    try:
        import playwright.sync_api  # the test extra installs it
    except ImportError:
        playwright = None
    missing = []
    if executable is None:
        missing.append("no chromium on PATH (Debian: apt-get install -y chromium; .ci/run does it)")
    if playwright is None:
        missing.append('no playwright (pip install -e ".[test]")')
    if missing:
        reason = "the browser test needs a headless browser: " + "; ".join(missing)
        if os.environ.get("CI_REQUIRE_BROWSER") == "1":
            pytest.fail(reason + " (CI_REQUIRE_BROWSER=1)")
        pytest.skip(reason)
    return executable


#: Elements wider than the window, except inside a box that scrolls or clips sideways.
_TOO_WIDE = """() => {
  const width = document.documentElement.clientWidth;
  const clipped = (el) => {
    for (let p = el.parentElement; p; p = p.parentElement) {
      const o = getComputedStyle(p).overflowX;
      if (o === 'auto' || o === 'scroll' || o === 'hidden') return true;
    }
    return false;
  };
  const wide = [];
  for (const el of document.body.querySelectorAll('*')) {
    const r = el.getBoundingClientRect();
    if ((r.right > width + 1 || r.left < -1) && !clipped(el)) wide.push(el.tagName + '#' + el.id + ' ' + r.right);
  }
  return {page: document.documentElement.scrollWidth, width: width, wide: wide.slice(0, 5)};
}"""


#: Figures whose image did not load (a page shows its PNGs from its folder by relative paths).
_NOT_SHOWN = """() => Array.from(document.images)
  .filter((img) => !(img.complete && img.naturalWidth > 0))
  .map((img) => img.getAttribute('src').slice(0, 80))"""


def test_no_element_is_wider_than_the_page_and_every_figure_shows_in_chromium(pages):
    executable = _browser()
    from playwright.sync_api import sync_playwright

    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--no-first-run"]
    with sync_playwright() as driver:
        browser = driver.chromium.launch(executable_path=executable, args=flags)
        try:
            view = browser.new_page(viewport={"width": VIEWPORT, "height": 900})
            for name, path in _page_files(pages).items():
                view.goto(path.as_uri())
                found = view.evaluate(_TOO_WIDE)
                assert found["page"] <= found["width"] and not found["wide"], f"{name}: {found}"
                missing = view.evaluate(_NOT_SHOWN)
                assert not missing, f"{name}: figures the browser cannot show (a missing PNG?): {missing}"
        finally:
            browser.close()


# -- figures -------------------------------------------------------------------------------------
def _shown(text) -> bool:
    return text.get_visible() and bool(text.get_text().strip())


def overlapping_labels(figure) -> list[tuple[str, str]]:
    """Pairs of visible labels of ``figure`` whose boxes overlap after a draw: tick labels of one
    axis that run into each other, an axis label on any other label, and the figure's own texts
    (the corner plot draws its ticks and names as texts of the figure) on each other."""
    FigureCanvasAgg(figure)
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()

    def boxes(texts):
        return [(t.get_text(), t.get_window_extent(renderer).padded(-1.0)) for t in texts if _shown(t)]

    def clashes(items):
        return [(a, b) for (a, box_a), (b, box_b) in itertools.combinations(items, 2) if box_a.overlaps(box_b)]

    found, every_label, axis_labels = [], [], []
    for ax in figure.axes:
        for axis in (ax.xaxis, ax.yaxis):
            if not axis.get_visible():
                continue
            ticks = boxes(axis.get_ticklabels())
            found += clashes(ticks)
            every_label += ticks
            axis_labels += boxes([axis.label])
    found += [(a, b) for a, box_a in axis_labels for b, box_b in every_label if box_a.overlaps(box_b)]
    found += clashes(axis_labels)
    found += clashes(boxes(figure.texts))
    return found


@pytest.fixture(scope="module")
def drawn_figures(pages) -> dict:
    """Every figure of the two study reports and of the diagnosis, drawn again from their folders."""
    from identify.output import report
    from identify.output.diagnosis_plots import diagnosis_figures

    figures = {}
    for name in ("study report (diagnosed)", "study report (compared)"):
        folder = pages[name].parent
        data = report.load_report_data(folder)
        rng = np.random.default_rng(0)
        analysis = report.analyse_report(data, 40, rng)
        for stem, figure, _ in report.report_figures(data, analysis, rng):
            figures[f"{name}: {stem}"] = figure
        comparison = report.load_comparison(data, analysis)
        if isinstance(comparison, report.Comparison):
            figures[f"{name}: comparison"] = report.comparison_figure(data, comparison)
    data = report.load_report_data(pages["study report (diagnosed)"].parent)
    for stem, figure in diagnosis_figures(pages["diagnosis"], data.record).items():
        figures[f"diagnosis: {stem}"] = figure
    return figures


def test_no_figure_has_overlapping_labels(drawn_figures):
    assert len(drawn_figures) >= 10
    overlaps = {name: pairs[:3] for name, fig in drawn_figures.items() if (pairs := overlapping_labels(fig))}
    assert not overlaps, overlaps


def test_no_figure_saved_by_any_page_has_overlapping_labels(pages):
    """The figures of every page as they were saved (prediction, compensation and design pages
    included), not only those drawn again from the study folders."""
    kinds = {kind for kind, _ in SAVED_FIGURES}
    assert {"study", "prediction", "compensation", "design"} <= kinds, kinds
    overlaps = [(kind, pairs[:3]) for kind, pairs in SAVED_FIGURES if pairs]
    assert not overlaps, overlaps


def test_the_overlap_check_finds_overlapping_labels():
    """The check can fail: long tick labels side by side on a narrow axis overlap."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(2, 2))
    ax = figure.add_subplot()
    ax.bar(range(4), [1, 2, 3, 4])
    ax.set_xticks(range(4), ["incomplete_reset", "rate_width", "thermal_expansion", "creep"])
    assert overlapping_labels(figure)


# -- the study's own diagnosis and the next step -------------------------------------------------
def test_next_step_names_the_command_for_each_verdict():
    from identify.output.diagnosis_files import next_step

    sentence, command = next_step(
        {"status": "missing_effect", "missing": "thermal"}, data_file="data/r.csv", effects=[], out_dir="reports/r"
    )
    assert "thermal" in sentence
    assert command == (
        "python -m identify study data/r.csv --effects thermal --out reports/r-thermal --compare reports/r"
    )
    sentence, command = next_step(
        {"status": "tied", "tied": ["creep", "thermal"]}, data_file="d.csv", effects=["lag"], out_dir="o"
    )
    assert "creep or thermal" in sentence and command == "python -m identify design d.csv --out o-design"
    assert next_step({"status": "adequate"}, data_file="d.csv", effects=[], out_dir="o")[1] is None


def test_the_earlier_study_is_found_by_its_manifest(tmp_path):
    """A sibling folder with the same record (SHA-256) and fewer effects, finished; not one of another record."""
    import json

    from identify.output.diagnosis_files import earlier_study

    def folder(name, sha, effects, finished=True, missing=None):
        path = tmp_path / name
        path.mkdir()
        manifest = {"data": {"sha256": sha}, "settings": {"effects": effects}, "finished": "2026-12-03T00:00:00"}
        (path / "manifest.json").write_text(json.dumps(manifest))
        (path / "summary.json").write_text(json.dumps({"posterior": {"n_steps": 10} if finished else None}))
        if missing:
            (path / "diagnosis.json").write_text(json.dumps({"status": "missing_effect", "missing": missing}))
        return path

    folder("other", "b" * 64, "")
    folder("unfinished", "a" * 64, "", finished=False)
    plain = folder("plain", "a" * 64, "", missing="thermal")
    folder("same", "a" * 64, "thermal")
    new = tmp_path / "plain-thermal"
    new.mkdir()
    assert earlier_study(new, "a" * 64, ["thermal"]) == plain
    assert earlier_study(new, "c" * 64, ["thermal"]) is None


@pytest.mark.slow
def test_the_study_diagnoses_itself_when_the_residual_is_above_the_noise(tmp_path):
    """A record with a hidden thermal effect: the plain study runs the whole diagnosis by default, stores
    it as diagnose --out does, prints the next command, and its report states it."""
    import json

    csv = _thermal_record(tmp_path / "thermal.csv")
    out = tmp_path / "plain"
    argv = ["study", csv, "--out", out, "--seed", 1, "--n-starts", 2, "--max-steps", 200, "--check-every", 100]
    code, text = _run([*argv, "--progress", "off"])
    assert code in (0, 1), text
    diagnosis = json.loads((out / "diagnosis.json").read_text())
    assert diagnosis["status"] == "missing_effect" and diagnosis["missing"] == "thermal", diagnosis["status"]
    assert list((out / "diagnosis").glob("*.png"))
    command = f"python -m identify study {csv} --effects thermal --out {out}-thermal --compare {out}"
    assert f"next: {command}" in text
    assert command in (out / "report.html").read_text()


# -- progress from Python --------------------------------------------------------------------------
def test_python_progress_is_shown_by_default_and_silenced_by_false(monkeypatch, capsys):
    """Without any logging configuration the package's progress lines reach stderr (as emcee's and
    lmfit's do); progress=False shows nothing; a configured root logger keeps its say."""
    import logging

    from identify.logs import get_logger, progress_function

    logger = get_logger()
    monkeypatch.setattr(logger, "handlers", [])
    monkeypatch.setattr(logger, "propagate", True)
    monkeypatch.setattr(logger, "level", logging.NOTSET)
    monkeypatch.setattr(logging.getLogger(), "handlers", [])
    progress_function(False)("hidden line")
    assert "hidden line" not in capsys.readouterr().err
    progress_function(None, "diagnosis: ")("a stage")
    assert "diagnosis: a stage" in capsys.readouterr().err

    def own(message):
        return message

    assert progress_function(own) is own  # a callable is used as it is
