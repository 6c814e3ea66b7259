"""The collapse figure of ``ngbet normalise``: the measured curves' normalised shear force against the shear angle."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .curves import FSH_GAMMA_MAX_DEG
from .style import figure, in_style, put_caption

__all__ = ["collapse_figure"]

if TYPE_CHECKING:
    from matplotlib.figure import Figure


#: what a picture-frame file gives, where two curves of one frame and laboratory need telling apart
_GIVEN = {"force": "from the crosshead force", "shear_force": "from F_s", "normalised_shear_force": "F_norm as given"}


def _given(c: Any) -> str:
    """What a picture-frame curve's file gives, in words ("" for a bias extension curve)."""
    return _GIVEN.get(c.given, "") if c.test == "picture_frame" else ""


def _stem(c: Any) -> str:
    """The name of a curve's file without its folder and suffix."""
    return Path(c.source).stem


def _labels(curves: Sequence[Any]) -> list[str]:
    """Each curve's legend name: its test, size and laboratory; told apart where two are alike.

    The laboratory is the header's (:attr:`ngbet.normalise.Normalised.laboratory`); curves still
    alike are told apart by what their files give (a frame's shear force or normalised shear force)
    where that differs, then by the files' stems, then numbered.
    """
    test = {"bias_extension": "bias extension "}
    out = [
        test.get(c.test, "picture frame, ") + c.label + (f" ({c.laboratory})" if c.laboratory else "") for c in curves
    ]
    for more in (_given, _stem):
        alike = [{more(d) for d, e in zip(curves, out, strict=True) if e == b} for b in out]
        out = [
            b + (f", {more(c)}" if len(a) > 1 and more(c) else "") for b, c, a in zip(out, curves, alike, strict=True)
        ]
    return [b if out.count(b) == 1 else f"{b} ({out[: k + 1].count(b)})" for k, b in enumerate(out)]


def _panel(ax: Any, curves: Sequence[Any]) -> bool:
    """The curves of one fabric on ``ax``, one colour each; whether a curve goes beyond the drawn range."""
    beyond = False
    for k, (c, lab) in enumerate(zip(curves, _labels(curves), strict=True)):
        col = f"C{k % 10}"
        keep = c.gamma_deg <= FSH_GAMMA_MAX_DEG
        beyond = beyond or bool(np.any(~keep))
        g = np.r_[0.0, c.gamma_deg[keep]]
        if c.test == "bias_extension":
            ax.plot(g, np.r_[0.0, c.fsh[keep]], "-", color=col, lw=1.4, label=f"{lab}: Eq. 18")
            ax.plot(g, np.r_[0.0, c.fsh_energy[keep]], "--", color=col, lw=1.0, label=f"{lab}: energy method")
        else:
            ax.plot(g, np.r_[0.0, c.fsh[keep]], "-.", color=col, lw=1.4, label=f"{lab}: Eq. 10")
    ax.set_xlabel("shear angle γ [°]")
    ax.set_ylabel("normalised shear force [N/mm]")
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=min(0.0, ax.get_ylim()[0]))
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(loc="upper left", fontsize=7)
    return beyond


def collapse_figure(panels: Sequence[tuple[str, Sequence[Any], str]], spread_text: str) -> Figure:
    """F_sh (Eq. 18, energy method) and F_norm (Eq. 10) against γ, one colour per curve, the spread in the caption.

    ``panels``: (fabric, its curves, its spreads in words) for each fabric, the curves
    :class:`ngbet.normalise.Normalised`; one fabric ("" where the curves name one): one panel, the
    spread in the caption; several: a panel each, titled with the fabric and its spreads (fabrics
    differ by more than sizes or tests do, and one panel of them all has more lines than a legend
    can name). Drawn up to :data:`~ngbet.figures.curves.FSH_GAMMA_MAX_DEG` (towards yarn locking
    Eq. 18 divides by cos γ → 0).
    """
    with in_style():
        fig = figure(7.0, 4.8 if len(panels) == 1 else 4.2 * len(panels))
        axes = fig.subplots(len(panels), 1, squeeze=False)[:, 0]
        beyond = False
        for ax, (fabric, mine, words) in zip(axes, panels, strict=True):
            beyond = _panel(ax, mine) or beyond
            if len(panels) > 1:
                width = int((fig.get_figwidth() - 0.3) * 14.5)
                ax.set_title(textwrap.fill(f"{fabric}: {words}", width=width), fontsize=8, loc="left")
        curves = [c for _, mine, _ in panels for c in mine]
        tests = {c.test for c in curves}
        how = []
        if "bias_extension" in tests:
            how.append(
                "bias extension tests by Cao et al. (2008) Eq. 18 (solid) and by the energy balance of the "
                "same ideal zones (dashed), γ from Eq. 13"
            )
        if "picture_frame" in tests:
            how.append("picture-frame tests by Eqs. 1–3 and 10 (dash-dotted)")
        cut = f"; beyond γ = {FSH_GAMMA_MAX_DEG:g}° (near yarn locking) not drawn" if beyond else ""
        said = f" {spread_text[0].upper()}{spread_text[1:]}." if len(panels) == 1 else " Each panel one fabric."
        put_caption(fig, f"Measured normalised shear force: {'; '.join(how)}{cut}.{said}")
    return fig
