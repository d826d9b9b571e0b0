"""Tests of the uncertainty report (identify.output.report, identify.output.plots, identify.cli.report).

End-to-end tests run the real ``study`` on a small simulated record (tests/report_fixture.py,
~15 s of CPU once per session) and parse the page it writes back: every figure and table
is there, the page refers only to files of its folder, and every number shown equals summary.json to the
6 significant digits printed (relative tolerance 5e-6 plus rounding of the last digit).
"""

from __future__ import annotations

import json
import shutil
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from report_fixture import FixtureSettings, build_results_folder
from scipy.stats import norm

import model
from identify.cli import main as identify_main
from identify.data.reversals import default_min_swing, find_reversals
from identify.output import plots, report, report_sections

#: Relative tolerance of a number printed with report.DIGITS = 6 significant digits.
PRINT_RTOL = 1e-5


# --------------------------------------------------------------------------------------
# parsing the page
# --------------------------------------------------------------------------------------
class PageParser(HTMLParser):
    """Collects images, table ids, ``data-key`` cells and every ``src``/``href``."""

    def __init__(self):
        super().__init__()
        self.images = []
        self.table_ids = []
        self.values = {}
        self.links = []
        self.element_ids = []
        self._key = None
        self._text = []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if "id" in attrs:
            self.element_ids.append(attrs["id"])
        if tag == "img":
            self.images.append(attrs)
        if tag == "table":
            self.table_ids.append(attrs.get("id"))
        for name in ("src", "href"):
            if name in attrs:
                self.links.append(attrs[name])
        if "data-key" in attrs:
            self._key, self._text = attrs["data-key"], []

    def handle_data(self, data):
        if self._key is not None:
            self._text.append(data)

    def handle_endtag(self, tag):
        if self._key is not None and tag in ("td", "span"):
            self.values[self._key] = "".join(self._text).strip()
            self._key = None


def parse_page(path) -> PageParser:
    parser = PageParser()
    parser.feed(Path(path).read_text(encoding="utf-8"))
    return parser


def assert_shown(text, expected, key):
    """``text`` (as printed on the page) represents ``expected`` (from summary.json)."""
    if expected is None:
        assert text == "—", f"{key}: expected '—' for null, page shows {text!r}"
    elif isinstance(expected, bool):
        assert text == ("yes" if expected else "no"), f"{key}: {text!r} vs {expected}"
    else:
        assert float(text) == pytest.approx(float(expected), rel=PRINT_RTOL, abs=1e-12), (
            f"{key}: {text!r} vs {expected}"
        )


def summary_value(summary, key):
    """The summary.json value a page ``data-key`` refers to, or KeyError when it is page-derived."""
    parts = key.split(".")
    if parts[0] == "parameters":
        entry = next(p for p in summary["parameters"] if p["name"] == parts[1])
        return entry[parts[2]]
    if parts[0] == "identifiability" and parts[1] in ("exact", "near"):
        return summary["identifiability"][parts[1]][int(parts[2])][parts[3]]
    value = summary
    for part in parts:
        value = value[part]
    return value


# --------------------------------------------------------------------------------------
# fixtures
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="session")
def misfit_folder(tmp_path_factory):
    """A study of a record with a hidden 2 um ripple (misfit), not converged; report written by study."""
    return build_results_folder(tmp_path_factory.mktemp("report") / "misfit", FixtureSettings(hidden_ripple=2.0))


@pytest.fixture(scope="session")
def misfit_page(misfit_folder):
    return parse_page(misfit_folder / "report.html")


@pytest.fixture
def folder_copy(misfit_folder, tmp_path):
    """A private copy of the misfit folder (to break it)."""
    return Path(shutil.copytree(misfit_folder, tmp_path / "copy"))


# --------------------------------------------------------------------------------------
# pure pieces
# --------------------------------------------------------------------------------------
def test_reversals_of_the_paper_input_are_its_peaks_and_troughs():
    # Eq. (15)-(16), literal reading: the quiet start ends in a trough at t = 10 s (where the
    # drive starts to move), troughs exactly 0 A at t = 20, 30, ..., 60 s; peaks of the
    # decaying sine near t = 15, 25, ..., 65 s (the decay shifts them by < 0.1 s).
    time, current = model.paper_current(fs=10.0)
    reversals = find_reversals(current).index
    troughs = reversals[current[reversals] < 1.0]
    peaks = reversals[current[reversals] > 1.0]
    np.testing.assert_allclose(time[troughs], [10, 20, 30, 40, 50, 60], atol=1e-9)
    np.testing.assert_allclose(time[peaks], [15, 25, 35, 45, 55, 65], atol=0.15)
    # noise on the input (0.5 % of its range, a read-back current) must not add reversals:
    # the default swing grows with the input's own noise
    noisy = current + 0.025 * np.random.default_rng(3).standard_normal(current.size)
    assert default_min_swing(noisy) > 2 * default_min_swing(current)
    noisy_reversals = find_reversals(noisy).index
    assert noisy_reversals.size == reversals.size
    # the first trough is the noisy plateau's lowest sample: anywhere in the quiet start
    assert time[noisy_reversals[0]] <= 10.0
    assert np.max(np.abs(time[noisy_reversals[1:]] - time[reversals[1:]])) < 1.0
    # with the noiseless drive's swing (2 % of the range) the same noise splits branches
    assert find_reversals(noisy, default_min_swing(current)).index.size > reversals.size


def test_reversals_of_monotone_and_constant_inputs():
    # a monotone input turns only at its first sample (a branch of its own: none is split)
    assert find_reversals(np.linspace(0, 1, 50)).index.tolist() == [0]
    assert len(report.branches(50, find_reversals(np.linspace(0, 1, 50)))) == 1
    assert find_reversals(np.zeros(50)).index.size == 0
    # fall first, then rise: the start is a peak and the trough the one interior reversal
    assert find_reversals(np.r_[np.linspace(1, 0, 20), np.linspace(0, 1, 20)[1:]]).index.tolist() == [0, 19]
    with pytest.raises(ValueError, match="1-D"):
        find_reversals(np.zeros((3, 3)))


def test_branches_cover_the_record_and_are_monotone():
    _, current = model.paper_current(fs=10.0)
    branch_list = report.branches(current.size, find_reversals(current))
    assert branch_list[0].start == 0 and branch_list[-1].stop == current.size - 1
    for before, after in zip(branch_list[:-1], branch_list[1:]):
        assert before.stop == after.start  # consecutive branches share the reversal sample
        assert before.rising != after.rising
    for b in branch_list:
        steps = np.diff(current[b.start : b.stop + 1])
        assert (steps >= -1e-12).all() if b.rising else (steps <= 1e-12).all()


def test_cycle_errors_split_at_the_input_minima():
    time, current = model.paper_current(fs=10.0)
    energised = time >= 10.0
    branch_list = report.branches(current.size, find_reversals(current))
    # an error that is constant within each 10 s cycle: level k in cycle k
    error = np.floor((time - 10.0) / 10.0) + 1.0
    error[~energised] = 0.0
    cycles = report.cycle_errors(time, current, error, energised, branch_list, displacement_range=200.0)
    assert [c.index for c in cycles] == [1, 2, 3, 4, 5, 6]
    np.testing.assert_allclose([c.time_start for c in cycles], [10, 20, 30, 40, 50, 60])
    np.testing.assert_allclose([c.rms for c in cycles[:5]], [1, 2, 3, 4, 5])
    np.testing.assert_allclose([c.max_error_pct for c in cycles[:5]], [0.5, 1.0, 1.5, 2.0, 2.5])
    with pytest.raises(ValueError, match="displacement_range"):
        report.cycle_errors(time, current, error, energised, branch_list, displacement_range=0.0)


def test_mixture_quantile_against_closed_forms():
    from identify.output.bands import mixture_quantile

    sigma = np.array([0.5])
    centres = np.array([[0.0, 3.0, -2.0]])
    # one component: the normal quantile c + sigma z_p
    np.testing.assert_allclose(
        mixture_quantile(centres, sigma, 0.025), centres[0] + 0.5 * norm.ppf(0.025), atol=1e-3 * 0.5
    )
    # two far-apart unit components: 0.5 Phi(x) + 0.5 Phi(x - 20) = 0.025  =>  Phi(x) = 0.05
    two = np.array([[0.0], [20.0]])
    np.testing.assert_allclose(mixture_quantile(two, np.array([1.0, 1.0]), 0.025), norm.ppf(0.05), atol=1e-3)
    # unequal sigmas, equal centres: solve 0.5 Phi(x/1) + 0.5 Phi(x/3) = 0.975 by bisection with scipy
    from scipy.optimize import brentq

    expected = brentq(lambda x: 0.5 * norm.cdf(x) + 0.5 * norm.cdf(x / 3.0) - 0.975, 0, 20)
    np.testing.assert_allclose(mixture_quantile(np.zeros((2, 1)), np.array([1.0, 3.0]), 0.975), expected, atol=1e-3)


def test_zoom_window_grows_until_the_curve_moves_enough():
    curve = np.arange(1000.0)  # 1 unit per sample
    window = report.zoom_samples(curve, 500, band_half_width=4.0)  # target: 15 x 4 = 60 units
    assert 60 <= np.ptp(curve[window]) <= 60 * 1.3 + 2
    flat = report.zoom_samples(np.zeros(1000), 500, band_half_width=1.0)
    assert flat.stop - flat.start - 1 <= 2 * 50  # capped at 5 % of the record either side


def test_loop_bands_are_polygons_over_each_branch_own_samples():
    time, current = model.paper_current(fs=10.0)
    median = model.Model()(model.TABLE1, time, current)
    lo, hi = median - 1.0, median + 1.0
    branch_list = report.branches(current.size, find_reversals(current))
    segments = [(b.start, b.stop) for b in branch_list]
    fig = plots.loops_figure(
        current,
        median,
        median,
        lo,
        hi,
        segments=segments,
        rising=[b.rising for b in branch_list],
        zoom_box=((2.0, 3.0), (100.0, 150.0)),
    )
    polygons = [
        p.vertices
        for ax in fig.axes[:1]
        for c in ax.collections
        if isinstance(c, PolyCollection)
        for p in c.get_paths()
    ]
    assert len(polygons) == len(segments)
    expected = {(a, b) for a, b in segments}
    for vertices in polygons:
        if len(vertices) % 2:  # the closing vertex
            vertices = vertices[:-1]
        n = len(vertices) // 2
        forward = vertices[:n]
        match = [(a, b) for a, b in expected if b - a + 1 == n and np.allclose(forward[:, 0], current[a : b + 1])]
        assert match, "a band polygon does not follow one branch's own current samples"
        a, b = match[0]
        np.testing.assert_allclose(forward[:, 1], hi[a : b + 1])
        np.testing.assert_allclose(vertices[n : 2 * n, 1], lo[a : b + 1][::-1])
        expected.discard((a, b))
    assert not expected


def test_figures_label_their_axes_with_units():
    time = np.linspace(0, 10, 200)
    current = np.abs(np.sin(time))
    y = 100 * current
    figures = [
        plots.input_figure(time, current),
        plots.displacement_figure(time, y, y, y - 1, y + 1, y - 2, y + 2),
        plots.error_figure(time, y - y, y - y - 1, y - y + 1, noise_sigma=0.5, max_error_pct=1.0, max_error_index=3),
    ]
    for fig in figures:
        ax = fig.axes[0]
        assert ax.get_xlabel() == "time [s]"
        assert ax.get_ylabel().endswith(("[A]", "[µm]"))
        assert ax.get_legend() is not None or fig.legends  # on the axes, or the figure's below them
    assert plots.unit_label("um") == "µm" and plots.unit_label("") == "-" and plots.unit_label("um/A") == "µm/A"


def test_corner_figure_shows_what_corner_corner_showed():
    """The corner plot drawn as artists on one figure labels what corner.corner (2.3) labelled
    with the report's former options: the same tick labels on the outer panels (the same
    axis ranges, MaxNLocator and ScalarFormatter) and the names under the bottom row and left
    of the first column (the figures were compared by eye on the bundled study); a tick label
    within a line of a panel's low edge is left out (there it meets the next panel's label or the
    other axis's at the corner), one at most per axis."""
    import corner
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rng = np.random.default_rng(2)
    samples = rng.multivariate_normal([5.7, 0.01, 14.9], [[4e-3, 1e-5, 0.0], [1e-5, 6e-5, 0.0], [0.0, 0.0, 0.16]], 3000)
    labels = ["rho [µm/A]", "tau [1/A]", "a0 [A]"]
    ours = plots.corner_figure(samples, labels, reference=[5.7, 0.012, 15.0])
    FigureCanvasAgg(ours).draw()
    theirs = Figure(figsize=(6, 6))
    theirs.subplots(3, 3)
    corner.corner(
        samples,
        labels=labels,
        truths=[5.7, 0.012, 15.0],
        quantiles=[0.025, 0.5, 0.975],
        fig=theirs,
        max_n_ticks=3,
        plot_datapoints=False,
        plot_density=False,
        no_fill_contours=True,
        levels=(1 - np.exp(-0.5), 1 - np.exp(-2.0)),
        bins=20,
        labelpad=0.3,
    )
    FigureCanvasAgg(theirs).draw()
    axes = np.array(theirs.axes).reshape(3, 3)

    def drawn(axis, view):  # tick labels inside the view (matplotlib lists one beyond it too)
        low, high = sorted(view)
        return {t.get_text() for t, x in zip(axis.get_ticklabels(), axis.get_ticklocs()) if low <= x <= high}

    def lowest(axis, view):  # the label of the lowest tick inside the view
        low, high = sorted(view)
        inside = [(x, t.get_text()) for t, x in zip(axis.get_ticklabels(), axis.get_ticklocs()) if low <= x <= high]
        return {min(inside)[1]} if inside else set()

    expected, at_low_edges = set(labels), set()
    for j in range(3):
        expected |= drawn(axes[2, j].xaxis, axes[2, j].get_xlim())
        at_low_edges |= lowest(axes[2, j].xaxis, axes[2, j].get_xlim())
    for i in range(1, 3):
        expected |= drawn(axes[i, 0].yaxis, axes[i, 0].get_ylim())
        at_low_edges |= lowest(axes[i, 0].yaxis, axes[i, 0].get_ylim())
    shown = {t.get_text() for t in ours.texts} - {ours.get_suptitle()}
    assert shown <= expected and set(labels) <= shown
    assert expected - shown <= at_low_edges, expected - shown


# --------------------------------------------------------------------------------------
# the page written by study
# --------------------------------------------------------------------------------------
def test_every_figure_is_written_as_png_and_shown_from_the_folder(misfit_folder, misfit_page):
    """Each figure is stored once, as ``DIR/<stem>.png``, and the page shows it by its path
    relative to the folder (no base64 copy in the page)."""
    alts = [img["alt"] for img in misfit_page.images]
    assert alts == list(report.FIGURES.values())
    for stem, img in zip(report.FIGURES, misfit_page.images):
        assert img["src"] == f"{stem}.png"
        assert (misfit_folder / img["src"]).read_bytes().startswith(b"\x89PNG\r\n\x1a\n")
    assert "base64" not in (misfit_folder / "report.html").read_text()


def test_every_table_is_present(misfit_page):
    expected = {
        "fit-quality",
        "cycle-errors",
        "parameters",
        "posterior-settings",
        "identifiability-normalisation",
        "identifiability-exact",
        "identifiability-near",
        "provenance",
    }
    assert expected <= set(misfit_page.table_ids)
    for section in (
        "glance",
        "measurement",
        "fit-quality-section",
        "parameters-section",
        "diagnosis",
        "provenance-section",
    ):
        assert section in misfit_page.element_ids
    assert "interval-calibration" in misfit_page.element_ids  # which interval to quote, with the bench's coverage


def test_page_refers_only_to_its_own_folder(misfit_folder, misfit_page):
    """Every reference of the page is an anchor on it or a file of the results folder, by a
    relative path that stays inside it: the folder (or a copy of it) shows the whole page."""
    root = misfit_folder.resolve()
    for link in misfit_page.links:
        if link.startswith("#"):
            continue
        assert ":" not in link and not link.startswith("/"), f"external reference {link[:80]!r}"
        target = (misfit_folder / link).resolve()
        assert target.is_relative_to(root) and target.is_file(), f"{link!r} is not a file of the folder"
    assert not list(misfit_folder.glob("*.tmp")) and not list(misfit_folder.glob(".*.tmp"))


def test_numbers_on_the_page_equal_summary_json(misfit_folder, misfit_page):
    summary = json.loads((misfit_folder / "summary.json").read_text())
    checked = 0
    for key, text in misfit_page.values.items():
        if key.startswith(("derived.", "cycles.", "diagnosis.")):
            continue
        assert_shown(text, summary_value(summary, key), key)
        checked += 1
    # every parameter's seven numbers, the fit, noise and posterior blocks
    assert checked >= 7 * len(summary["parameters"]) + 10
    for p in summary["parameters"]:
        for field in ("table1", "lsq", "lsq_stderr", "median", "lo95", "hi95", "tau", "ess"):
            assert f"parameters.{p['name']}.{field}" in misfit_page.values
    for key in (
        "fit.rms",
        "fit.reduced_chi2",
        "fit.max_error_pct",
        "noise.sigma",
        "posterior.converged",
        "posterior.tau_max",
    ):
        assert key in misfit_page.values


def test_page_derived_numbers_are_consistent(misfit_folder, misfit_page):
    summary = json.loads((misfit_folder / "summary.json").read_text())
    values = misfit_page.values
    assert float(values["derived.rms_ratio"]) == pytest.approx(
        summary["fit"]["rms"] / summary["noise"]["sigma"], rel=PRINT_RTOL
    )
    # the posterior-median curve and the least-squares curve are close: their max errors agree within 25 %
    assert float(values["derived.max_error_pct"]) == pytest.approx(summary["fit"]["max_error_pct"], rel=0.25)
    # the worst cycle's max error is the page's max error
    cycle_max = max(float(v) for k, v in values.items() if k.startswith("cycles.") and k.endswith(".max_error_pct"))
    assert cycle_max == pytest.approx(float(values["derived.max_error_pct"]), rel=1e-3)
    assert 0.0 <= float(values["derived.inside_predictive_pct"]) <= 100.0


def test_misfit_and_non_convergence_are_stated_prominently(misfit_folder, misfit_page):
    text = (misfit_folder / "report.html").read_text(encoding="utf-8")
    summary = json.loads((misfit_folder / "summary.json").read_text())
    assert summary["fit"]["rms"] > 1.2 * summary["noise"]["sigma"]  # the hidden ripple is a misfit
    assert "misfit-alert" in misfit_page.element_ids and "fit-ok" not in misfit_page.element_ids
    assert "conditional on a model that misses something" in text
    assert summary["posterior"]["converged"] is False
    assert "convergence-alert" in misfit_page.element_ids and "NOT CONVERGED" in text
    assert misfit_page.values["posterior.converged"] == "no"


def test_pinned_parameter_is_marked(misfit_folder):
    summary = json.loads((misfit_folder / "summary.json").read_text())
    text = (misfit_folder / "report.html").read_text(encoding="utf-8")
    pinned = [p["name"] for p in summary["parameters"] if not p["vary"]]
    assert pinned == list(summary["identifiability"]["normalisation"])
    for name in pinned:
        assert f'<tr class="pinned"><td>{name}</td>' in text
    assert text.count("pinned by normalisation") == len(pinned)


def test_provenance_shows_the_manifest(misfit_folder):
    manifest = json.loads((misfit_folder / "manifest.json").read_text())
    text = (misfit_folder / "report.html").read_text(encoding="utf-8")
    for shown in (
        manifest["data"]["file"],
        manifest["data"]["sha256"],
        manifest["git"]["commit"],
        str(manifest["seed"]),
    ):
        assert str(shown) in text


def test_bands_come_from_one_vectorised_model_call(misfit_folder, monkeypatch):
    data = report.load_report_data(misfit_folder)
    chain = report.read_chain(data)
    draws = report.posterior_draws(data, chain, 50, np.random.default_rng(0))
    calls = []
    original = model.Model.evaluate

    def counting(self, theta, time, current):
        calls.append(np.shape(theta))
        return original(self, theta, time, current)

    monkeypatch.setattr(model.Model, "evaluate", counting)
    bands = report.model_bands(data, draws)
    assert calls == [(51, data.model.n_parameters)]  # 50 draws + the least-squares vector
    assert (bands.credible_lo <= bands.median).all() and (bands.median <= bands.credible_hi).all()
    assert (bands.predictive_lo < bands.credible_lo).all() and (bands.predictive_hi > bands.credible_hi).all()
    # pinned parameters keep their normalisation value in every draw
    pinned = ~data.fit.vary
    assert (draws.theta[:, pinned] == data.fit.theta[pinned]).all()


def test_diagnosis_hook_renders_verdict_ranking_and_figures(folder_copy):
    diagnosis = {
        "status": "missing_effect",
        "missing": "thermal",
        "ranking": [
            {"effect": "thermal", "rms_after": 0.51, "delta_bic": -120.0},
            {"effect": "creep", "rms_after": 1.2},
        ],
    }
    (folder_copy / "diagnosis.json").write_text(json.dumps(diagnosis))
    (folder_copy / "diagnosis").mkdir()
    shutil.copy(folder_copy / "fig7_error.png", folder_copy / "diagnosis" / "residual_vs_time.png")
    section = report_sections.diagnosis_html(report.load_report_data(folder_copy))
    parser = PageParser()
    parser.feed(section)
    assert "diagnosis-ranking" in parser.table_ids and "diagnosis-verdict" in parser.element_ids
    assert "--effects thermal" in section
    assert parser.values["diagnosis.thermal.rms_after"] == "0.51"
    assert parser.values["diagnosis.thermal.delta_bic"] == "-120"
    assert [img["alt"] for img in parser.images] == ["Diagnosis: residual vs time"]
    assert [img["src"] for img in parser.images] == ["diagnosis/residual_vs_time.png"]  # relative to the folder


def test_unreadable_folders_raise_clear_errors(tmp_path, folder_copy):
    with pytest.raises(report.ResultsError, match="cannot read the results folder"):
        report.write_report(tmp_path / "missing")
    with pytest.raises(ValueError, match="n_draws"):
        report.write_report(folder_copy, n_draws=1)
    summary_path = folder_copy / "summary.json"
    summary = json.loads(summary_path.read_text())
    summary["posterior"] = None
    summary_path.write_text(json.dumps(summary))
    with pytest.raises(report.ResultsError, match="no posterior yet"):
        report.write_report(folder_copy)
    assert not list(folder_copy.glob(".*.tmp"))


def test_chain_that_does_not_match_the_model_is_refused(folder_copy):
    fit_path = folder_copy / "fit.json"
    fit = json.loads(fit_path.read_text())
    fit["vary"][fit["names"].index("rho")] = False  # one fewer free parameter than the chain holds
    fit_path.write_text(json.dumps(fit))
    data = report.load_report_data(folder_copy)
    with pytest.raises(report.ResultsError, match="coordinates"):
        report.read_chain(data)


# --------------------------------------------------------------------------------------
# slow: other folders, the command line
# --------------------------------------------------------------------------------------
@pytest.mark.slow
def test_clean_record_is_reported_at_the_noise_level(tmp_path):
    folder = build_results_folder(tmp_path / "clean", FixtureSettings())
    page = parse_page(folder / "report.html")
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["fit"]["rms"] < 1.2 * summary["noise"]["sigma"]
    assert "fit-ok" in page.element_ids and "misfit-alert" not in page.element_ids
    # model + noise cover about 95 % of the samples (short chain, 701 samples: allow 90-99 %)
    assert 90.0 <= float(page.values["derived.inside_predictive_pct"]) <= 99.5


@pytest.mark.slow
def test_free_noise_sigma_is_reported_with_its_posterior(tmp_path):
    folder = build_results_folder(tmp_path / "free", FixtureSettings(free_noise=True))
    page = parse_page(folder / "report.html")
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["noise"]["source"] == "free"
    assert "fit-free-noise" in page.element_ids and "misfit-alert" not in page.element_ids
    for field in ("median", "lo95", "hi95", "tau", "ess"):
        assert_shown(page.values[f"noise.posterior.{field}"], summary["noise"]["posterior"][field], field)
    data = report.load_report_data(folder)
    chain = report.read_chain(data)
    assert chain.names[-1] == report.NOISE_COORDINATE
    draws = report.posterior_draws(data, chain, 40, np.random.default_rng(1))
    lo95, hi95 = summary["noise"]["posterior"]["lo95"], summary["noise"]["posterior"]["hi95"]
    assert np.median(draws.noise_sigma) == pytest.approx(summary["noise"]["posterior"]["median"], rel=0.05)
    assert ((draws.noise_sigma > 0.8 * lo95) & (draws.noise_sigma < 1.2 * hi95)).all()


@pytest.mark.slow
def test_report_command_rewrites_the_page(misfit_folder, capsys):
    page = misfit_folder / "report.html"
    before = page.stat().st_mtime_ns
    assert identify_main(["report", str(misfit_folder), "--draws", "40", "--seed", "3"]) == 0
    assert str(page) in capsys.readouterr().out
    assert page.stat().st_mtime_ns > before
    assert parse_page(page).values["posterior.n_walkers"] == "40"
    with pytest.raises(SystemExit) as exited:  # a folder that does not exist is an option error: argparse's exit 2
        identify_main(["report", str(misfit_folder / "nowhere")])
    assert exited.value.code == 2
    assert "no such folder" in capsys.readouterr().err


def test_no_domain_wall_note_even_for_a_summary_that_still_counts_proposals(folder_copy):
    """The GPI has no domain wall any more (model/gpi.py, "The whole domain"): a summary
    written before, with its ``outside_domain_fraction``, renders without a wall note."""
    path = folder_copy / "summary.json"
    summary = json.loads(path.read_text())
    summary["posterior"]["outside_domain_fraction"] = 0.07
    path.write_text(json.dumps(summary))
    data = report.load_report_data(folder_copy)
    section = report_sections.glance_html(data, report.analyse_report(data, 20, np.random.default_rng(0)))
    assert "domain-wall" not in section and "% of the proposals" not in section


def test_the_calibration_note_says_calibrated_only_when_the_bench_coverage_is_near_nominal():
    from identify.fitting.posterior import BENCH_COVERAGE
    from identify.output.report_sections import calibration_reading

    good = {**BENCH_COVERAGE, "posterior": 0.948, "least_squares": 0.951}
    assert calibration_reading(good).startswith("Both are calibrated there")
    short = calibration_reading({**BENCH_COVERAGE, "posterior": 0.91, "least_squares": 0.951})
    assert "less than nominal" in short and "posterior 95 % interval holds the truth about 91%" in short
    assert "least-squares" not in short


def test_a_term_pinned_off_is_named_in_the_parameter_table(folder_copy):
    """``fit.terms`` (identify.fitting.terms) marks the parameters of a term the record did not
    support; the table says so instead of 'pinned by normalisation'."""
    path = folder_copy / "summary.json"
    summary = json.loads(path.read_text())
    summary["fit"]["terms"] = [
        {"effect": "thermal", "term": "core", "parameters": ["d3"], "delta_chi2": 0.6, "penalty": 26.6, "pinned": True}
    ]
    entry = next(p for p in summary["parameters"] if p["name"] == "d3")
    entry["vary"] = False
    path.write_text(json.dumps(summary))
    data = report.load_report_data(folder_copy)
    html = report_sections.parameters_html(data, report.analyse_report(data, 20, np.random.default_rng(0)), "")
    assert (
        "<td>pinned off: thermal term &#x27;core&#x27; not supported by the record (chi-square +0.6 &lt;= BIC "
        "26.6)</td>" in html
    )
