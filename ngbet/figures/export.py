"""The figure of ``ngbet export``: the card's points on the model's pure-shear law."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .style import NB, PNG_DPI, SHEAR_LABEL, caption, eng_scale, in_style, put_caption, round_ticks, subplots

__all__ = ["shear_law_figure"]


def shear_law_figure(card: Any, sigma: Callable[[np.ndarray], np.ndarray], scene: Any, path: Path) -> Path:
    """shear_law.png at ``path``: σ_s(γ) of the model (line) and the card's points, C_s on the right axis.

    ``card``: an :class:`ngbet.export.ShearCard`; ``sigma``: the model's σ_s(γ) [Pa], γ [rad].
    """
    with in_style():
        fig, ax = subplots(size=(6.4, 4.2))
        g_max = float(card.gamma_rad[-1])
        g = np.linspace(0.0, g_max, 600)
        s = sigma(g)
        k, unit = eng_scale(float(np.max(np.abs(s))), "Pa")
        ax.plot(np.degrees(g), s * k, color="C0", label="model: pure shear, σ_s = dW/dγ")
        ax.plot(
            np.degrees(card.gamma_rad),
            card.stress_Pa * k,
            "o",
            ms=3,
            mfc="none",
            color="C1",
            label=f"card: {len(card.gamma_rad)} points, linear between them",
        )
        ax.set_xlabel(SHEAR_LABEL)
        ax.set_ylabel(f"shear stress σ_s [{unit}]")
        ax.set_xlim(0.0, math.degrees(g_max) * 1.02)
        ax.set_ylim(0.0, None)
        round_ticks(ax)
        t = card.thickness_mm
        # C_s = t σ_s [N·mm/mm²] on the right (plain numbers: the benchmark's unit, about 0.1 for fabrics)
        c = 1e-6 * t / k  # axis value of σ_s → C_s
        right = ax.secondary_yaxis("right", functions=(lambda v: v * c, lambda v: v / c))
        right.set_ylabel(f"shear torque per area C_s = t σ_s [N{NB}mm/mm²]")
        ax.legend(loc="upper left")
        put_caption(
            fig,
            f"{caption(scene)}. The card reproduces the model's shear stress within "
            f"{card.tolerance:.2g} of the local stress (of 1 % of the largest where it is smaller; "
            f"measured {card.deviation:.2g}); it leaves out the yarns' in-plane bending (second "
            "gradient) and the jamming barrier.",
        )
        fig.savefig(path, format="png", dpi=PNG_DPI)
    return path
