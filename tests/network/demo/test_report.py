"""network.demo.report: tables, figures and the static report page."""

import numpy as np
import pytest
from PIL import Image

from network.demo import report


def test_tables_format_numbers_and_escape():
    md = report.markdown_table(["a", "b"], [["x", 1.23456789], ["y", float("nan")]])
    assert md.splitlines() == ["| a | b |", "|---|---|", "| x | 1.235 |", "| y | n/a |"]
    html = report.html_table(["<a>"], [["<b>&"]])
    assert "&lt;a&gt;" in html and "&lt;b&gt;&amp;" in html and "<b>" not in html


def test_image_grid_and_charts_write_pngs(tmp_path):
    rgb = np.random.default_rng(0).uniform(size=(8, 10, 3))
    scalar = np.where(np.eye(8, 10) > 0, np.nan, 1.0)
    grid = report.image_grid(tmp_path / "f" / "grid.png", [[rgb, scalar], [None, scalar[..., None]]],
                             [["rgb", "scalar"], ["", "scalar (H, W, 1)"]], cmaps=[None, "magma"])  # fmt: skip
    timing = report.timing_chart(tmp_path / "t.png", {"a": 1.0, "b": 2.5})
    chart = report.metric_chart(tmp_path / "m.png", {"ours": {"mae": 1.0}, "base": {"mae": float("nan")}},
                                [("mae", "MAE", True)])  # fmt: skip
    for path in (grid, timing, chart):
        with Image.open(path) as img:
            assert img.format == "PNG" and img.size[0] > 50
    assert not list(tmp_path.rglob("*.tmp*"))


def test_report_links_figures_relatively_and_refuses_missing_ones(tmp_path):
    report.timing_chart(tmp_path / "figures" / "t.png", {"a": 1.0})
    page = report.write_report(tmp_path / "report.html", "T <1>", [
        {"title": "S", "text": "one\n\ntwo <3>", "html": "<p>raw</p>",
         "figures": [("figures/t.png", "seconds per stage, longest bar is the slowest stage")]},
    ])  # fmt: skip
    text = page.read_text()
    assert '<img src="figures/t.png"' in text and "<p>two &lt;3&gt;</p>" in text and "<p>raw</p>" in text
    assert "<title>T &lt;1&gt;</title>" in text
    with pytest.raises(FileNotFoundError, match="does not exist"):
        report.write_report(tmp_path / "bad.html", "T", [{"title": "S", "figures": [("figures/none.png", "c")]}])
    assert not (tmp_path / "bad.html").exists()


@pytest.mark.parametrize("caption", ["figure t", "t", "", "TODO: say what this shows and how", "wall-clock seconds"])
def test_report_refuses_placeholder_captions(tmp_path, caption):
    report.timing_chart(tmp_path / "figures" / "t.png", {"a": 1.0})
    with pytest.raises(ValueError, match="placeholder"):
        report.write_report(tmp_path / "r.html", "T", [{"title": "S", "figures": [("figures/t.png", caption)]}])
    assert not (tmp_path / "r.html").exists()


def test_image_grid_draws_nan_in_the_given_colour(tmp_path):
    scalar = np.full((20, 20), np.nan)
    scalar[5:15, 5:15] = 0.0
    path = report.image_grid(tmp_path / "g.png", [[scalar]], [["x"]], [(-1.0, 1.0)], ["RdBu_r"], nan_colour="0.5")
    rgb = np.asarray(Image.open(path).convert("RGB"))
    assert (np.abs(rgb.astype(int) - 128).max(-1) <= 1).sum() > 100  # the grey of the NaN pixels is drawn
