"""One style for every figure of ngbet: fonts, sizes, colours, captions, round ticks, file formats.

Every figure is a :class:`matplotlib.figure.Figure` made here (:func:`figure`, :func:`subplots`;
no pyplot state), drawn inside :func:`style` and written by :class:`FigureWriter` in the formats
asked for. matplotlib is imported inside the functions only.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import textwrap
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "FORCE_LABEL",
    "FORMATS",
    "NB",
    "PNG_COMPRESSION",
    "PNG_DPI",
    "SHEAR_LABEL",
    "STUDY_FORMATS",
    "STYLE",
    "U0_LABEL",
    "VECTOR_RASTER_DPI",
    "FigureWriter",
    "can_fork",
    "caption",
    "check_formats",
    "colormap",
    "figure",
    "in_style",
    "legend_below",
    "nice_ceil",
    "put_caption",
    "round_ticks",
    "save",
    "short_log_axis",
    "subplots",
    "texts_outside",
    "tidy_log_axes",
    "write_png",
]

PNG_DPI = 130
#: resolution of the rasterized parts of a PDF or SVG (a map's colour field; lines and text stay vector)
VECTOR_RASTER_DPI = 200
#: zlib level of the PNG files: 1 writes them 3-4 times faster than the default 6, 20 % larger
PNG_COMPRESSION = 1
#: the formats a figure can be written in (``outputs.figure_formats``)
FORMATS = ("png", "pdf", "svg")
#: the studies' figures: PNG to look at, PDF for a paper
STUDY_FORMATS = ("png", "pdf")

#: one style for every figure (matplotlib's rcParams)
STYLE: Any = {
    "font.size": 9,
    "axes.titlesize": 9,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "lines.linewidth": 1.4,
    "lines.markersize": 4,
    "legend.frameon": True,
    "legend.framealpha": 0.9,
    "figure.dpi": 100,
    "axes.formatter.use_mathtext": False,
    "axes.formatter.limits": (-4, 5),
    "savefig.dpi": PNG_DPI,
    "image.cmap": "viridis",
}

#: one angle convention in every figure of both models: the shear angle γ, the change of the
#: angle between the yarns (0 at rest; 90° − γ between the yarns of a ±45° fabric)
SHEAR_LABEL = "shear angle γ [°] (0 at rest)"
U0_LABEL = "clamp displacement u₀ [mm]"
FORCE_LABEL = "force on the moving clamp [N]"
NB = "\u00a0"  # a no-break space: "name = value unit" stays on one line of a caption


@contextlib.contextmanager
def in_style() -> Iterator[None]:
    """Draw inside this block: the rcParams of :data:`STYLE` (artists read them when they are made)."""
    import matplotlib as mpl

    with mpl.rc_context(STYLE):
        yield


def figure(width: float, height: float, layout: str = "constrained") -> Figure:
    """A figure of ``width`` × ``height`` inches laid out by matplotlib (labels inside the canvas).

    ``layout``: "constrained", or "compressed" for grids of maps (equal aspect: no gaps between them).
    """
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout=layout)  # type: ignore[arg-type]


def subplots(
    nrows: int = 1,
    ncols: int = 1,
    *,
    size: tuple[float, float] = (6.4, 4.0),
    squeeze: bool = True,
    layout: str = "constrained",
    **kwargs: Any,
) -> tuple[Figure, Any]:
    """A :func:`figure` and its axes (as :meth:`matplotlib.figure.Figure.subplots`)."""
    fig = figure(*size, layout=layout)
    return fig, fig.subplots(nrows, ncols, squeeze=squeeze, **kwargs)


# ------------------------------------------------------------------------------------------------
# captions
# ------------------------------------------------------------------------------------------------
_PREFIXES = ((1e9, "G"), (1e6, "M"), (1e3, "k"), (1.0, ""), (1e-3, "m"), (1e-6, "µ"), (1e-9, "n"))


def eng(value: float, unit: str, digits: int = 3) -> str:
    """``value`` [``unit``] in engineering notation with an SI prefix on the unit's first symbol.

    3.33e6 Pa → "3.33 MPa", 1e-3 Pa m² → "1 mPa m²", 2000 Pa m² → "2 kPa m²"; ``digits``
    significant digits, no trailing zeros; 0 and non-finite values without a prefix.
    """
    v = float(value)
    if v == 0 or not math.isfinite(v):
        return f"{v:g}{NB}{unit}" if unit else f"{v:g}"
    rounded = float(f"{v:.{digits}g}")
    scale, prefix = next((p for p in _PREFIXES if abs(rounded) >= p[0] * (1 - 1e-12)), _PREFIXES[-1])
    return f"{rounded / scale:.{digits}g}{NB}{prefix}{unit}"


def eng_scale(largest: float, unit: str) -> tuple[float, str]:
    """(factor, prefixed unit) showing values up to ``largest`` [``unit``] as numbers of 1 to 1000 (an axis's unit)."""
    a = abs(float(largest))
    for scale, prefix in _PREFIXES:
        if a >= scale:
            return 1.0 / scale, prefix + unit
    return 1.0, unit


def _q(name: str, value: float, unit: str = "") -> str:
    return f"{name}{NB}={NB}{value:g}" + (f"{NB}{unit}" if unit else "")


def _qe(name: str, value: float, unit: str) -> str:
    """``name = value unit`` with the value in engineering notation (:func:`eng`)."""
    return f"{name}{NB}={NB}{eng(value, unit)}"


def caption(scene: Any) -> str:
    """One line naming the specimen (W × L mm, yarn angle, thickness) and the material of a scene.

    ``scene``: a :class:`ngbet.scene.document.Scene`, its dictionary (a study's ``base_scene``), or None ("").
    """
    if scene is None:
        return ""
    if isinstance(scene, dict):
        from ..scene.document import Scene, SceneWarning
        from ..scene.validate import SceneError

        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)
                scene = Scene.from_dict(scene)
        except SceneError:
            return ""
    sp = scene.specimen
    name = f"{_name_of(sp)}: " if _name_of(sp) else ""
    spec = (
        f"{name}specimen {sp.width_mm:g}{NB}×{NB}{sp.length_mm:g}{NB}mm (W{NB}×{NB}L), yarns{NB}±"
        f"{sp.yarn_angle_deg:g}°, {_q('t', sp.thickness_mm, 'mm')}"
    )
    if getattr(scene, "test", "") == "picture_frame":
        pf = scene.picture_frame
        turned = f" turned{NB}{pf.misalignment_deg:g}° from the bars" if pf.misalignment_deg else ""
        arms = " (arms sheared)" if pf.arms == "sheared" and pf.fabric_mm < pf.frame_mm else ""
        spec = (
            f"{name}picture-frame test, frame{NB}{pf.frame_mm:g}{NB}mm pin to pin, fabric square"
            f"{NB}{pf.fabric_mm:g}{NB}mm{arms}, yarns{NB}±{sp.yarn_angle_deg:g}°{turned}, "
            f"{_q('t', sp.thickness_mm, 'mm')}"
        )
    if scene.model == "discrete":
        d = scene.discrete
        return (
            f"{spec}; yarn network: {_qe('EI1', d.EI1, f'N{NB}m²')}, {_qe('EI2', d.EI2, f'N{NB}m²')}, "
            f"{_qe('EA', d.EA1, 'N')}, {_qe('K_φ', d.K_phi, f'N{NB}m')}, {_qe('K_slip', d.K_slip, 'N/m')}, "
            f"spacing{NB}{d.spacing_mm:g}{NB}mm"
        )
    m = scene.material
    shear = (
        f"tabulated shear law ({len(m.shear_stress_steps_Pa)} rises)"
        if scene.effects.shear_law == "table"
        else _qe("K_sh", m.K_sh, "Pa")
    )
    return (
        f"{spec}; material: {shear}, {_qe('α1', m.alpha1, f'Pa{NB}m²')}, "
        f"{_qe('α2', m.alpha2, f'Pa{NB}m²')}, {_qe('K_el', m.K_el, 'Pa')}"
    )


def _name_of(specimen: Any) -> str:
    """The specimen's name, without a size suffix ("-100x250") that is not its width × length.

    A fitted scene run at another size keeps the name of the specimen it was fitted on; the caption
    must not title a 100 × 300 mm run "…-100x250".
    """
    name = str(getattr(specimen, "name", "") or "")
    m = re.search(r"[-_ ]?(\d+(?:\.\d+)?)\s*[x×]\s*(\d+(?:\.\d+)?)$", name)
    if m and (float(m.group(1)), float(m.group(2))) != (specimen.width_mm, specimen.length_mm):
        return name[: m.start()]
    return name


#: the space between a number and its unit, where a caption's line must not break ("66.8 %", "145 mm")
_NUMBER_UNIT = re.compile(r"(?<=\d) (?=(?:%|°|[kMG]?Pa|N/mm|mm|N|s|J)(?![\w/]))")


def put_caption(fig: Figure, text: str) -> None:
    """The caption line(s) above the panels, broken at the figure's width (8 pt: at most 14.5 characters an inch).

    DejaVu Sans at 8 pt sets about 15 characters of mixed text an inch; the margin keeps every
    line inside the canvas (:func:`texts_outside` checks it). A number and its unit stay on one
    line (:data:`NB` between them).
    """
    if text:
        text = _NUMBER_UNIT.sub(NB, text)
        fig.suptitle(textwrap.fill(text, width=int((fig.get_figwidth() - 0.3) * 14.5)), fontsize=8)


# ------------------------------------------------------------------------------------------------
# axes
# ------------------------------------------------------------------------------------------------
def nice_ceil(x: float) -> float:
    """The smallest of 1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8 × 10^k not below x (x > 0): a round scale end."""
    if not x > 0:
        return 1.0
    k = math.floor(math.log10(x))
    for m in (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if m * 10**k >= x * (1 - 1e-12):
            return cast(float, m * 10**k)
    return 10.0 ** (k + 1)  # pragma: no cover


def round_ticks(ax: Axes, axis: str = "both", nbins: int = 6) -> None:
    """Ticks at round numbers (1, 2, 2.5, 5 × 10^k) on a linear axis."""
    from matplotlib.ticker import MaxNLocator

    for a in (ax.xaxis, ax.yaxis) if axis == "both" else (ax.xaxis,) if axis == "x" else (ax.yaxis,):
        a.set_major_locator(MaxNLocator(nbins=nbins, steps=[1, 2, 2.5, 5, 10]))


def short_log_axis(ax: Axes, axis: str = "x") -> None:
    """Readable tick labels on a log axis: plain numbers at 1, 2 (3) and 5 × 10^k over less than two decades.

    Over less than a factor 3 every minor tick is labelled, below a decade 2, 3 and 5, below two
    decades 2 and 5; over more, the decades alone (matplotlib's 10^k labels).
    """
    from matplotlib.ticker import FuncFormatter, NullFormatter

    lo, hi = ax.get_xlim() if axis == "x" else ax.get_ylim()
    lo, hi = min(lo, hi), max(lo, hi)
    a = ax.xaxis if axis == "x" else ax.yaxis
    if lo > 0 and hi / lo < 100:
        digits = "123456789" if hi / lo < 3 else "235" if hi / lo < 10 else "25"
        a.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        a.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}" if f"{v:e}"[0] in digits else ""))
    else:
        a.set_minor_formatter(NullFormatter())


def tidy_log_axes(fig: Figure) -> None:
    """:func:`short_log_axis` on every log axis of ``fig`` (at its final limits)."""
    for ax in fig.axes:
        for axis in ("x", "y"):
            if (ax.get_xscale() if axis == "x" else ax.get_yscale()) == "log":
                short_log_axis(ax, axis)


def colormap(name: str = "viridis") -> Any:
    """A sequential colour map without its palest end (readable on white and on shaded bands)."""
    import matplotlib as mpl
    from matplotlib.colors import ListedColormap

    return ListedColormap(mpl.colormaps[name](np.linspace(0.0, 0.85, 256)), name=f"{name}_dark")


def legend_below(fig: Figure, handles: Sequence[Any] | None = None, ncol: int = 2) -> Any:
    """The figure's legend below the panels, off the data (constrained layout makes room for it).

    Without ``handles``: those of every panel, each label once.
    """
    if handles is None:
        seen: dict[str, Any] = {}
        for ax in fig.axes:
            for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
                seen.setdefault(lab, h)
        labels, handles = list(seen), list(seen.values())
    else:
        handles = list(handles)
        labels = [h.get_label() for h in handles]
    return fig.legend(handles, labels, loc="outside lower center", ncol=min(ncol, max(len(handles), 1)))


def texts_outside(fig: Figure) -> list[str]:
    """What of ``fig`` is drawn beyond its canvas, measured with the renderer's bounding boxes; [] when nothing.

    Each text that sticks out is named (titles, axis labels, legends, annotations, the caption), and
    the whole drawing's extent (tick labels included) is checked against the canvas.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()  # type: ignore[no-untyped-call]
    renderer = canvas.get_renderer()  # type: ignore[no-untyped-call]
    box = fig.bbox

    def outside(bb: Any) -> bool:
        return bool(bb.x0 < box.x0 - 0.5 or bb.y0 < box.y0 - 0.5 or bb.x1 > box.x1 + 0.5 or bb.y1 > box.y1 + 0.5)

    sup = getattr(fig, "_suptitle", None)
    texts: list[Any] = [*fig.texts, *([sup] if sup is not None else []), *fig.legends]
    for ax in fig.axes:
        texts += [*ax.texts, ax.title, ax.xaxis.label, ax.yaxis.label]
        if ax.get_legend() is not None:
            texts.append(ax.get_legend())
    bad = []
    for t in texts:
        if not t.get_visible() or (hasattr(t, "get_text") and not t.get_text().strip()):
            continue
        if outside(t.get_window_extent(renderer)):
            bad.append(t.get_text() if hasattr(t, "get_text") else type(t).__name__)
    tight = fig.get_tightbbox(renderer).transformed(fig.dpi_scale_trans)
    if outside(tight):
        bad.append(f"the drawing spans {tight.bounds} beyond the canvas {box.bounds}")
    return bad


# ------------------------------------------------------------------------------------------------
# files
# ------------------------------------------------------------------------------------------------
def check_formats(formats: Sequence[str]) -> tuple[str, ...]:
    """The formats as a tuple, each one of :data:`FORMATS` (ValueError naming the bad one)."""
    out = tuple(str(f).lower().lstrip(".") for f in formats)
    for f in out:
        if f not in FORMATS:
            raise ValueError(f"unknown figure format {f!r}; known: {', '.join(FORMATS)}")
    return out


class FigureWriter:
    """Writes each figure in the formats asked for (:data:`FORMATS`; the first one is returned).

    The constrained layout is solved once, for the first format, then frozen: the other formats get
    the same layout (solving it again would cost as much as drawing). A PNG is drawn once
    (:func:`write_png`), not twice as ``savefig`` does with a layout engine.
    """

    def __init__(self, formats: Sequence[str] = ("png",)) -> None:
        self.formats = check_formats(formats) or ("png",)

    def save(self, fig: Figure, stem: Path) -> Path:
        """Write ``stem``.png (and the other formats); returns the file of the first format."""
        first = None
        for k, fmt in enumerate(self.formats):
            path = stem.with_suffix(f".{fmt}")
            tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")  # complete, then renamed: never half a figure
            try:
                if fmt == "png":
                    write_png(fig, tmp)
                else:
                    fig.savefig(tmp, format=fmt, dpi=VECTOR_RASTER_DPI)
                os.replace(tmp, path)
            finally:
                tmp.unlink(missing_ok=True)
            if k == 0:
                fig.set_layout_engine("none")
                first = path
        assert first is not None
        return first


#: the rcParams under which :func:`write_png` draws as ``savefig`` would (else it calls ``savefig``)
_SAVEFIG_DEFAULTS = {"savefig.facecolor": "auto", "savefig.edgecolor": "auto", "savefig.bbox": None}


def write_png(fig: Figure, path: Path | Any, dpi: float = PNG_DPI) -> None:
    """Write ``fig`` as a PNG at ``dpi`` (zlib level :data:`PNG_COMPRESSION`) to ``path`` (a file or a stream).

    The same pixels as ``fig.savefig(path, format="png", dpi=dpi)``, drawn once: ``savefig``
    draws a figure with a layout engine twice (a draw without output that solves the layout,
    then the drawing, which solves it again). Here the Agg canvas draws it once (the layout is
    solved at the start of that draw) and its buffer is written. Under rcParams that ``savefig``
    would apply (a face or edge colour, a tight bounding box, transparency) it is ``savefig``.
    """
    import matplotlib as mpl
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.image import imsave

    pil_kwargs = {"compress_level": PNG_COMPRESSION}
    rc: Any = mpl.rcParams
    if any(rc[k] != v for k, v in _SAVEFIG_DEFAULTS.items()) or rc["savefig.transparent"]:
        fig.savefig(path, format="png", dpi=dpi, pil_kwargs=pil_kwargs)
        return
    dpi0 = fig.dpi
    fig.dpi = dpi
    try:
        canvas: Any = FigureCanvasAgg(fig)
        canvas.draw()
        imsave(path, canvas.buffer_rgba(), format="png", origin="upper", dpi=fig.dpi, pil_kwargs=pil_kwargs)
    finally:
        fig.dpi = dpi0


def save(fig: Figure, out: Path, name: str, formats: Sequence[str] = STUDY_FORMATS) -> Path:
    """Write ``out/name`` in ``formats`` (a study's figure: PNG and PDF), log axes tidied; returns the first file."""
    tidy_log_axes(fig)
    return FigureWriter(formats).save(fig, Path(out) / name)


def can_fork() -> bool:
    """Whether this process may fork to draw (POSIX, and no other thread is running in it)."""
    import threading

    return hasattr(os, "fork") and threading.active_count() == 1
