"""ngbet's figures: one small plotting package, object-oriented matplotlib (``Figure``, ``Axes``), one style.

- :mod:`.style`: fonts, sizes, colours, the caption line naming specimen and material, round
  ticks, the file formats (:class:`FigureWriter`), and :func:`texts_outside` (what sticks out of
  the canvas);
- :mod:`.data`: what the figures are drawn from (map files, measured curves, table columns);
- :mod:`.curves`: force, F_sh and the shear angles, the S-profile; snap-throughs drawn as jumps,
  error bars with caps;
- :mod:`.maps`: triangulated maps on the deformed specimen, one colour scale per figure
  (symmetric and diverging where the sign matters, clipping marked);
- :mod:`.run`: a run folder's figures (:func:`draw_run`), drawn by the plot process or the run;
- :mod:`.study`: what the studies' figures share (base-scene caption, formats).

Importing the package costs nothing: matplotlib is imported inside the functions that draw, so
that a run without figures starts fast and a run writes its map data through :func:`save_map`
without matplotlib.
"""

from __future__ import annotations

from .curves import (
    FSH_GAMMA_MAX_DEG,
    curve_with_jumps,
    error_bars,
    force_curve,
    force_figure,
    profile_figure,
    shear_force_figure,
    stations_of,
)
from .data import (
    MapData,
    Measured,
    column,
    increasing_curve,
    load_maps,
    map_file_name,
    measured_fsh,
    read_scene,
    save_map,
)
from .maps import ColourScale, colour_bar, colour_scale, map_panel, shear_map_figure, yarn_network_figure
from .run import NO_MATPLOTLIB, RUN_FIGURES, draw_force, draw_run, formats_of, start_plot, warm_up
from .study import key_label, key_value, study_caption, symbol, unit_of
from .style import (
    FORCE_LABEL,
    FORMATS,
    PNG_DPI,
    SHEAR_LABEL,
    STUDY_FORMATS,
    STYLE,
    U0_LABEL,
    FigureWriter,
    caption,
    check_formats,
    colormap,
    eng,
    eng_scale,
    figure,
    in_style,
    legend_below,
    nice_ceil,
    put_caption,
    round_ticks,
    save,
    short_log_axis,
    subplots,
    texts_outside,
    tidy_log_axes,
)

__all__ = [
    "FORCE_LABEL", "FORMATS", "FSH_GAMMA_MAX_DEG", "NO_MATPLOTLIB", "PNG_DPI", "RUN_FIGURES", "SHEAR_LABEL",
    "STUDY_FORMATS", "STYLE", "U0_LABEL", "ColourScale", "FigureWriter", "MapData", "Measured", "caption",
    "check_formats", "colormap", "colour_bar", "colour_scale", "column", "curve_with_jumps", "draw_force",
    "draw_run", "error_bars", "figure", "force_curve", "force_figure", "formats_of", "increasing_curve",
    "legend_below", "load_maps", "map_file_name", "map_panel", "measured_fsh", "nice_ceil", "profile_figure",
    "put_caption", "read_scene", "round_ticks", "save", "save_map", "shear_force_figure",
    "shear_map_figure", "short_log_axis", "start_plot", "stations_of", "study_caption", "in_style", "subplots",
    "unit_of", "key_label", "key_value", "symbol", "eng", "eng_scale",
    "texts_outside", "tidy_log_axes", "warm_up", "yarn_network_figure",
]
