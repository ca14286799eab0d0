"""One style for every figure the project writes: 150 dpi for raster files, the format from the
file's suffix (png, pdf or svg: ``--format`` on the commands and scripts that plot), a figure
closed once written.  Matplotlib is imported lazily (the core never needs it).

It sits in the lowest layer (beside :mod:`impact_env.config`) because every layer that plots uses
it: ``eval`` (compare, sweep, drop) and ``rig`` (the episode log's plot) alike."""

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


def output_figure(path, fmt: str | None, option: str) -> Path:
    """The file a ``option FILE [--format FMT]`` pair names, checked before anything runs: without
    ``fmt`` the suffix picks the format and must be one of :data:`FORMATS`; with ``fmt`` a file
    without a suffix gets it, and a different suffix is refused (``--plot x.png --format pdf``
    would otherwise write a file its name misdescribes, or not the one asked for).  ValueError
    naming ``option``."""
    p = Path(path)
    suffix = p.suffix.lstrip(".").lower()
    if fmt is None:
        if suffix not in FORMATS:
            raise ValueError(f"{option} {str(path)!r}: the suffix picks the format and must be one of "
                             f".{', .'.join(FORMATS)} (or give --format)")
        return p
    check_format(fmt)
    if not suffix:
        return p.with_suffix("." + fmt)
    if suffix != fmt:
        raise ValueError(f"{option} {str(path)!r} has the suffix .{suffix} but --format is {fmt}: give "
                         "one of them, or make them agree")
    return p


def save_figure(fig, path) -> Path:
    """Write ``fig`` to ``path`` (its suffix picks png, pdf or svg) at :data:`DPI`, then close it."""
    import matplotlib.pyplot as plt

    p = figure_path(path)
    fig.savefig(p, dpi=DPI, bbox_inches="tight", format=p.suffix.lstrip(".").lower())
    plt.close(fig)
    return p
