"""Figures and the static HTML report of the demo (matplotlib, no JavaScript).

One home for the demo's plotting: image grids (:func:`image_grid`), the per-stage time bar chart
(:func:`timing_chart`), the metric comparison chart (:func:`metric_chart`), tables
(:func:`markdown_table`, :func:`html_table`) and the page itself (:func:`write_report`). Every
figure is written atomically; the page references figures by relative paths so the output folder
can be moved or zipped as a whole.

Example:
    >>> print(markdown_table(["method", "MAE"], [["ours", 3.14159], ["baseline", float("nan")]]), end="")
    | method | MAE |
    |---|---|
    | ours | 3.142 |
    | baseline | n/a |
"""

from __future__ import annotations

import html
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pbrdf.io.atomic import atomic_open, atomic_write_text

__all__ = [
    "image_grid",
    "timing_chart",
    "metric_chart",
    "markdown_table",
    "html_table",
    "placeholder_caption",
    "write_report",
]


def _plt():
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def _save(fig, path: Path, dpi: int = 100) -> Path:
    """Write ``fig`` atomically to ``path`` (format from the suffix), close it and return the path."""
    path = Path(path)
    try:
        with atomic_open(path) as f:
            fig.savefig(f, dpi=dpi, format=path.suffix.lstrip(".") or "png")
    finally:
        _plt().close(fig)
    return path


def image_grid(
    path: str | os.PathLike,
    rows: Sequence[Sequence[np.ndarray | None]],
    titles: Sequence[Sequence[str]],
    limits: Sequence | None = None,
    cmaps: Sequence | None = None,
    *,
    row_labels: Sequence[str] | None = None,
    cell: tuple[float, float] = (2.4, 2.2),
    nan_colour: str | None = None,
) -> Path:
    """Save a grid of images.

    Args:
        path: output PNG.
        rows: ``rows[r][c]`` an ``(H, W, 3)`` RGB image in [0, 1] (clipped), an ``(H, W)`` scalar
            image (drawn with a colour bar; NaN is transparent, or ``nan_colour``), or None for an
            empty cell.
        titles: one title per cell.
        limits: ``(vmin, vmax)`` tuples per column, or a list per row of them; default the data range.
        cmaps: colour map names per column, or a list per row of them; default ``viridis``.
        row_labels: optional label drawn left of each row.
        cell: size of one cell in inches.
        nan_colour: matplotlib colour of NaN pixels in scalar images (e.g. off the object), so
            that they differ from a colour map's own white; None: transparent.

    Returns:
        The written path.
    """
    plt = _plt()
    import matplotlib as mpl  # noqa: PLC0415

    def pick(table, r: int, c: int, default):
        if table is None:
            return default
        v = table[r][c] if isinstance(table[0], list) else table[c]  # a list per row, else one entry per column
        return default if v is None else v

    nrows, ncols = len(rows), max(len(r) for r in rows)
    fig, axes = plt.subplots(nrows, ncols, figsize=(cell[0] * ncols, cell[1] * nrows), squeeze=False)
    for r in range(nrows):
        for c in range(ncols):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            for s in ax.spines.values():
                s.set_visible(False)
            img = rows[r][c] if c < len(rows[r]) else None
            if img is None:
                continue
            img = np.asarray(img, dtype=np.float32)
            if img.ndim == 3 and img.shape[-1] == 1:
                img = img[..., 0]
            if img.ndim == 3:
                ax.imshow(np.clip(np.nan_to_num(img), 0, 1), interpolation="nearest")
            else:
                finite = img[np.isfinite(img)]
                lo, hi = pick(limits, r, c, (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0))
                cmap = mpl.colormaps[pick(cmaps, r, c, "viridis")]
                if nan_colour is not None:
                    cmap = cmap.with_extremes(bad=nan_colour)
                im = ax.imshow(img, cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest")
                fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
            ax.set_title(titles[r][c], fontsize=8)
        if row_labels:
            axes[r, 0].set_ylabel(row_labels[r], fontsize=9)
    fig.tight_layout()
    return _save(fig, Path(path))


def timing_chart(path: str | os.PathLike, seconds: dict[str, float], title: str = "time per stage") -> Path:
    """Save a horizontal bar chart of seconds per stage (in pipeline order) with the total in the title.

    Args:
        path: output PNG.
        seconds: ``{stage: seconds}`` in the order to draw, top to bottom.
        title: chart title; `` (total N s)`` is appended.

    Returns:
        The written path.
    """
    plt = _plt()
    names = list(seconds)
    vals = [seconds[n] for n in names]
    fig, ax = plt.subplots(figsize=(6.5, 0.45 * len(names) + 1.0))
    bars = ax.barh(names[::-1], vals[::-1], color="#4c72b0")
    for bar, v in zip(bars, vals[::-1], strict=True):
        ax.text(bar.get_width(), bar.get_y() + bar.get_height() / 2, f" {v:.1f} s", va="center", fontsize=8)
    ax.set_xlabel("seconds")
    ax.set_title(f"{title} (total {sum(vals):.1f} s)", fontsize=10)
    ax.set_xlim(0, max(vals + [1e-3]) * 1.25)
    fig.tight_layout()
    return _save(fig, Path(path))


def metric_chart(
    path: str | os.PathLike, rows: dict[str, dict[str, float]], metrics: Sequence[tuple[str, str, bool]]
) -> Path:
    """Save grouped bars comparing methods, one panel per metric.

    Args:
        path: output PNG.
        rows: ``{method: {metric: value}}``; a missing, None or NaN value is drawn as "n/a".
        metrics: ``(key, label, lower_is_better)`` per panel.

    Returns:
        The written path.
    """
    plt = _plt()
    methods = list(rows)
    fig, axes = plt.subplots(1, len(metrics), figsize=(2.3 * len(metrics), 2.6), squeeze=False)
    colours = ["#c44e52", "#4c72b0", "#55a868", "#8172b2", "#ccb974", "#64b5cd"]
    for ax, (key, label, lower) in zip(axes[0], metrics, strict=True):
        vals = [float("nan") if rows[m].get(key) is None else float(rows[m][key]) for m in methods]
        ax.bar(range(len(methods)), np.nan_to_num(vals), color=colours[: len(methods)])
        for i, v in enumerate(vals):
            ax.text(i, np.nan_to_num(v), "n/a" if not np.isfinite(v) else f"{v:.3g}", ha="center", va="bottom",
                    fontsize=7)  # fmt: skip
        ax.set_xticks(range(len(methods)), methods, rotation=20, ha="right", fontsize=7)
        ax.set_title(f"{label} ({'lower' if lower else 'higher'} is better)", fontsize=8)
    fig.tight_layout()
    return _save(fig, Path(path))


def _fmt(v) -> str:
    """A table cell: floats with 4 significant digits, NaN and infinities as n/a."""
    if isinstance(v, float):
        return "n/a" if not np.isfinite(v) else f"{v:.4g}"
    return str(v)


def markdown_table(header: Sequence[str], rows: Sequence[Sequence]) -> str:
    """A GitHub-flavoured Markdown table (floats with 4 significant digits, NaN as n/a).

    Args:
        header: column titles.
        rows: one sequence of cells per row.

    Returns:
        The table, one line per row, ending with a newline.
    """
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_fmt(v) for v in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def html_table(header: Sequence[str], rows: Sequence[Sequence]) -> str:
    """The same table as :func:`markdown_table`, as one HTML ``<table>`` (cells escaped).

    Args:
        header: column titles.
        rows: one sequence of cells per row.

    Returns:
        The HTML fragment.

    Example:
        >>> html_table(["a"], [["<b>"]])
        '<table><thead><tr><th>a</th></tr></thead><tbody><tr><td>&lt;b&gt;</td></tr></tbody></table>'
    """
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1200px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;margin:.8em 0;font-size:.9em}th,td{border:1px solid #ccc;padding:.3em .6em;
text-align:right}th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}figcaption{font-size:.85em;color:#555}
.muted{color:#666;font-size:.9em}code{background:#f5f5f5;padding:0 .25em}
"""


#: Fewest words a figure caption may have: it says what the figure shows and how to read it.
MIN_CAPTION_WORDS = 6


def placeholder_caption(rel: str, caption: str) -> bool:
    """Whether ``caption`` of the figure at ``rel`` is a placeholder rather than a reading guide.

    A placeholder is shorter than :data:`MIN_CAPTION_WORDS` words, or is the file's name (with
    ``_``/``-`` as spaces, optionally after "figure"), or says TODO/TBD/placeholder.

    Example:
        >>> placeholder_caption("pbrdfs/figure_generated.png", "figure generated")
        True
    """
    words = caption.lower().split()
    stem = Path(rel).stem.lower().replace("_", " ").replace("-", " ")
    text = " ".join(words)
    return (
        len(words) < MIN_CAPTION_WORDS
        or text in (stem, f"figure {stem}")
        or any(w.strip(".:,;()") in ("todo", "tbd", "placeholder") for w in words)
    )


def write_report(path: str | os.PathLike, title: str, sections: Sequence[dict]) -> Path:
    """Write a self-contained static HTML page (figures referenced relative to the page).

    Args:
        path: the ``report.html`` to write.
        title: page title.
        sections: each ``{"title": str, "text": str (optional, HTML-escaped), "html": str (optional,
            trusted HTML such as tables), "figures": [(relative path, caption), ...]}``.

    Returns:
        The written path.

    Raises:
        FileNotFoundError: when a referenced figure does not exist (a report never points at
            missing files).
        ValueError: when a figure's caption is a placeholder (:func:`placeholder_caption`).
    """
    path = Path(path)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>",
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
    ]
    for sec in sections:
        parts.append(f"<h2>{html.escape(sec['title'])}</h2>")
        if sec.get("text"):
            parts.extend(f"<p>{html.escape(p)}</p>" for p in sec["text"].split("\n\n"))
        if sec.get("html"):
            parts.append(sec["html"])
        for rel, caption in sec.get("figures", ()):
            if not (path.parent / rel).is_file():
                raise FileNotFoundError(f"{path.parent / rel}: figure referenced by the report does not exist")
            if placeholder_caption(rel, caption):
                raise ValueError(f"{rel}: caption {caption!r} is a placeholder; say what it shows and how to read it")
            src = html.escape(Path(rel).as_posix(), quote=True)
            parts.append(
                f'<figure><img src="{src}" alt="{html.escape(caption, quote=True)}" loading="lazy">'
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
            )
    parts.append("</body></html>\n")
    atomic_write_text(path, "\n".join(parts))
    return path
