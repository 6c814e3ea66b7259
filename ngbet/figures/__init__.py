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

__all__: list[str] = []
