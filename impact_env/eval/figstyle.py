"""One style for every figure the project writes: 150 dpi for raster files, the format from the
file's suffix (png, pdf or svg: ``--format`` on the commands that plot), a figure closed once
written.  Matplotlib is imported lazily (the core never needs it)."""

from __future__ import annotations

from pathlib import Path

DPI = 150
FORMATS = ("png", "pdf", "svg")


def check_format(fmt: str, option: str = "--format") -> str:
    """``fmt`` if it is one of :data:`FORMATS`; ValueError naming the option otherwise."""
    if fmt not in FORMATS:
        raise ValueError(f"{option} {fmt!r} must be one of {', '.join(FORMATS)}")
    return fmt


def figure_path(path, fmt: str | None = None) -> Path:
    """``path`` with the suffix of ``fmt`` (when given), checked."""
    p = Path(path)
    if fmt is not None:
        p = p.with_suffix("." + check_format(fmt))
    check_format(p.suffix.lstrip(".").lower(), f"figure file {str(p)!r}: its suffix")
    return p


def save_figure(fig, path) -> Path:
    """Write ``fig`` to ``path`` (its suffix picks png, pdf or svg) at :data:`DPI`, then close it."""
    import matplotlib.pyplot as plt

    p = figure_path(path)
    fig.savefig(p, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return p
