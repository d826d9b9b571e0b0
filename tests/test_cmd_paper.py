"""``python -m identify paper``: files written, numbers stated, bad options refused."""

from __future__ import annotations

import re

import numpy as np
import pytest

from identify.cli import main
from identify.workflows.paper import FIGURE_FILES, reading_evidence
from model import TABLE1, gpi, paper_current

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    code = main(["paper", "--out", str(out)])
    return code, out


def test_writes_every_figure_as_a_png(default_run):
    code, out = default_run
    assert code == 0
    for name in FIGURE_FILES.values():
        data = (out / name).read_bytes()
        assert data.startswith(PNG_SIGNATURE), name
        assert len(data) > 10_000, f"{name} looks empty ({len(data)} bytes)"
    assert not list(out.glob(".*.tmp")), "temporary files left behind"


def test_markdown_states_the_reading_and_its_evidence(default_run):
    _, out = default_run
    text = (out / "paper.md").read_text(encoding="utf-8")
    assert "Reading of eq. (5) used: swapped" in text
    _, current = paper_current(100.0, "literal")
    swapped = gpi(TABLE1, current)
    literal = gpi(TABLE1, current, reading="literal")
    # The numbers in the table are the model's, formatted as stated (4 decimals rest, 2 extremes).
    assert re.search(
        rf"\| swapped \(used\) \| {swapped[0]:.4f} \| 0 \| {swapped.min():.2f} \| {swapped.max():.2f} \|", text
    )
    assert re.search(rf"\| literal \| {literal[0]:.4f} \| 0 \| {literal.min():.2f} \| {literal.max():.2f} \|", text)
    # Cross-check against the values pinned in test_gpi (rest -0.5598, peak 295.70; literal 217.05, -569.18, 649.64).
    for stated in ("-0.5598", "295.70", "217.0473", "-569.18", "649.64"):
        assert stated in text
    assert "0.0157 at 5.00 A" in text  # smallest bound margin of the swapped reading
    assert "| 100 % |" in text and "| 0 % |" in text  # literal bounds cross everywhere, swapped nowhere
    assert "7001 samples" in text and "**literal** reading" in text
    for name in FIGURE_FILES.values():
        assert f"]({name})" in text


def test_literal_reading_and_centred_input_are_stated(tmp_path):
    code = main(["paper", "--out", str(tmp_path), "--reading", "literal", "--input", "centred", "--fs", "20"])
    assert code == 0
    text = (tmp_path / "paper.md").read_text(encoding="utf-8")
    assert "Reading of eq. (5) used: literal" in text
    assert "**centred** reading" in text and "1401 samples" in text
    assert re.search(r"\| literal \(used\) \| 217\.0473 \|", text)
    _, current = paper_current(20.0, "centred")
    peak = gpi(TABLE1, current).max()
    assert re.search(rf"\| swapped \| -0\.5598 \| 0 \| -0\.56 \| {peak:.2f} \|", text)


def test_bad_sampling_rate_is_refused_without_writing(tmp_path, capsys):
    out = tmp_path / "never"
    assert main(["paper", "--out", str(out), "--fs", "0"]) == 2
    assert "fs must be a positive sampling rate" in capsys.readouterr().err
    assert not out.exists()


def test_unknown_reading_is_refused_by_the_parser(tmp_path):
    with pytest.raises(SystemExit) as exit_info:
        main(["paper", "--out", str(tmp_path), "--reading", "mirrored"])
    assert exit_info.value.code == 2


def test_reading_evidence_margins():
    time, current = paper_current(100.0)
    swapped = reading_evidence(time, current, "swapped")
    literal = reading_evidence(time, current, "literal")
    assert swapped.crossing_fraction == 0.0 and swapped.smallest_margin > 0
    assert swapped.margin_at_current == pytest.approx(5.0)
    assert literal.crossing_fraction == 1.0 and literal.smallest_margin < 0
    np.testing.assert_array_equal(swapped.displacement, gpi(TABLE1, current))
    assert swapped.quiet_spread_um == 0.0 and swapped.rest_um == pytest.approx(-0.5598355820, abs=1e-9)
