"""The run's figures: what each draws is the data (computed points, jumps, error bars, colour scales)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from ngbet.figures.curves import force_figure, profile_figure, shear_force_figure
from ngbet.figures.data import MapData, Measured, measured_fsh
from ngbet.figures.maps import colour_scale, shear_map_figure, yarn_network_figure
from ngbet.figures.run import RUN_FIGURES, draw_run
from ngbet.figures.style import caption as f_caption
from ngbet.figures.style import texts_outside


def rows(snap_at=None, errors=None):
    """Rows of a results.csv: F = u0² with a jump of +30 N at ``snap_at``, errors at the rows given."""
    out = []
    for u in (2.0, 4.0, 6.0, 6.5, 8.0):
        jump = 30.0 if snap_at is not None and u >= snap_at else 0.0
        out.append(
            {
                "u0_mm": u,
                "force_N": u * u + jump,
                "snap": float(u == snap_at),
                "force_error_N": (errors or {}).get(u, ""),
            }
        )
    return out


def fresh_python(code):
    """What ``code`` prints in a new interpreter (without the MPLBACKEND the tests set)."""
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    ).stdout.strip()


def lines_of(ax):
    return [ln for ln in ax.get_lines() if len(ln.get_xdata())]


def test_a_snap_through_is_a_vertical_dashed_jump_and_the_curve_breaks_there():
    fig = force_figure(rows(snap_at=6.5))
    ax = fig.axes[0]
    dashed = [ln for ln in lines_of(ax) if ln.get_linestyle() == "--"]
    assert len(dashed) == 1
    assert list(dashed[0].get_xdata()) == [6.5, 6.5] and list(dashed[0].get_ydata()) == [36.0, 6.5**2 + 30]
    solid = [ln for ln in lines_of(ax) if ln.get_linestyle() == "-"]
    # two solid pieces: up to the row before the jump (from the origin), from the jump on
    assert [list(ln.get_xdata()) for ln in solid] == [[0.0, 2.0, 4.0, 6.0], [6.5, 8.0]]


def test_without_a_snap_the_curve_is_the_computed_points_only():
    fig = force_figure(rows())
    (curve,) = lines_of(fig.axes[0])
    assert list(curve.get_xdata()) == [0.0, 2.0, 4.0, 6.0, 6.5, 8.0]  # no points between the rows
    assert list(curve.get_ydata()) == [0.0, 4.0, 16.0, 36.0, 42.25, 64.0]


def test_error_bars_where_the_run_estimated_and_their_size_written_when_too_small_to_see():
    fig = force_figure(rows(errors={4.0: 0.05, 8.0: 3.0}))
    ax = fig.axes[0]
    (bars,) = [c for c in ax.containers if c.__class__.__name__ == "ErrorbarContainer"]
    segments = bars.lines[2][0].get_segments()
    assert [(s[0][0], s[0][1], s[1][1]) for s in segments] == [(4.0, 15.95, 16.05), (8.0, 61.0, 67.0)]
    # 2 × 0.05 N is below 2 % of the 64 N axis: its size is written; 2 × 3 N is not
    assert [t.get_text() for t in ax.texts] == ["error bars shorter than the markers:\n±0.05 N at u₀ = 4 mm"]


def test_a_load_whose_estimate_could_not_vouch_is_named_where_its_bar_would_be():
    """The scene asks for estimates at its stop (4 mm) and final load (8 mm); 8 mm has none."""
    from ngbet.scene.document import default_scene

    scene = default_scene().with_changes(**{"loading.stops_mm": [4.0], "loading.u0_mm": 8.0})
    fig = force_figure(rows(errors={4.0: 3.0}), scene)
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert texts == ["no error bar at u₀ = 8 mm:\nthe estimate could not vouch for the force"]
    # rows without a due estimate (2, 6, 6.5 mm) are not named; with estimates off, none is
    off = default_scene().with_changes(
        **{"loading.stops_mm": [4.0], "loading.u0_mm": 8.0, "outputs.error_estimate": "off"}
    )
    assert not force_figure(rows(errors={4.0: 3.0}), off).axes[0].texts
    # a bar too short to see and a missing one: one note, the sizes first
    fig = force_figure(rows(errors={4.0: 0.05}), scene)
    assert [t.get_text() for t in fig.axes[0].texts] == [
        "error bars shorter than the markers:\n±0.05 N at u₀ = 4 mm\nno error bar at u₀ = 8 mm:\n"
        "the estimate could not vouch for the force"
    ]
    # the network estimates no error (its rows have no force_error_N column): nothing is due, nothing named
    network = [{k: v for k, v in r.items() if k != "force_error_N"} for r in rows()]
    assert not force_figure(network, scene.with_changes(model="discrete")).axes[0].texts


def test_measured_curve_on_the_force_and_shear_force_figures(tmp_path):
    csv = tmp_path / "m.csv"
    csv.write_text(
        "# a comment\n# specimen.width_mm = 70\n# specimen.length_mm = 220\n"
        "displacement_mm,force_N\n0,0\n10,12\n10,14\n20,30\n"
    )
    m = Measured.read(csv)  # the points at 10 mm averaged: a curve increasing in d
    assert (m.width_mm, m.length_mm) == (70.0, 220.0) and list(m.force_N) == [0.0, 13.0, 30.0]
    fig = force_figure(rows(), measured=m)
    assert any(list(ln.get_ydata()) == [0.0, 13.0, 30.0] for ln in lines_of(fig.axes[0]))
    g, f = measured_fsh(m, 70.0, 220.0)
    # Eq. 13 at 10 and 20 mm (D = 150 mm): 0.138217 and 0.288427 rad
    assert len(g) == 2 and np.allclose(g, np.degrees([0.138217, 0.288427]), rtol=1e-5)


def test_a_measured_curve_of_another_specimen_keeps_the_legend_inside_its_panel(tmp_path):
    """Another specimen size: the legend entry names it (not the file), inside the axes."""
    from ngbet.scene.document import default_scene

    csv = tmp_path / "cao2008_twill_unbalanced_100x200_UN.csv"
    csv.write_text("# specimen.width_mm = 100\n# specimen.length_mm = 200\ndisplacement_mm,force_N\n0,0\n10,5\n20,20\n")
    fig = force_figure(rows(), default_scene(), measured=Measured.read(csv))
    fig.canvas.draw()  # matplotlib's Agg canvas of a Figure made without pyplot
    ax = fig.axes[0]
    legend = ax.get_legend()
    assert "measured, specimen 100 × 200 mm" in [t.get_text() for t in legend.texts]
    assert not any(".csv" in t.get_text() for t in legend.texts)
    box, panel = legend.get_window_extent(), ax.get_window_extent()
    assert panel.x0 <= box.x0 and box.x1 <= panel.x1, (box, panel)


@pytest.mark.parametrize("text", ["d,F\n1,2\n", "displacement_mm,force_N\n1,x\n", "displacement_mm,force_N\n1,2\n"])
def test_a_bad_measured_file_is_refused_naming_it(tmp_path, text):
    csv = tmp_path / "bad.csv"
    csv.write_text(text)
    with pytest.raises(ValueError, match="bad.csv"):
        Measured.read(csv)


def test_a_colour_scale_with_negative_angles_is_symmetric_and_marks_what_it_clips():
    # two panels: the scale is shared, round, and the corner spikes (beyond the 99.5 % quantile) are marked
    a = np.r_[np.linspace(-12.0, 30.0, 1000), 80.0]
    b = np.r_[np.linspace(-3.0, 45.0, 1000), -70.0]
    cs = colour_scale([a, b])
    assert (cs.vmin, cs.vmax, cs.cmap, cs.extend) == (-50.0, 50.0, "RdBu_r", "both")


def test_a_colour_scale_without_negative_angles_starts_at_zero():
    cs = colour_scale([np.linspace(0.0, 54.8, 1000)])
    assert (cs.vmin, cs.vmax, cs.cmap, cs.extend) == (0.0, 60.0, "viridis", "neither")


def test_the_map_panels_share_one_norm():
    tri = np.array([[0, 1, 2]])
    maps = [
        MapData(u, np.array([0.0, 10.0, 0.0]), np.array([0.0, 0.0, 10.0]), tri, np.array([0.0, g, g / 2]))
        for u, g in ((10.0, 9.0), (20.0, 18.0))
    ]
    fig = shear_map_figure(maps)
    norms = {(c.norm.vmin, c.norm.vmax) for ax in fig.axes[:2] for c in ax.collections}
    assert norms == {(0.0, 20.0)}


def test_ngbet_run_imports_no_matplotlib_before_it_solves():
    code = (
        "import sys, ngbet.cli, ngbet.run, ngbet.figures, ngbet.runner.continuum, ngbet.runner.discrete; "
        "print('matplotlib' in sys.modules)"
    )
    assert fresh_python(code) == "False"


@pytest.mark.integration
def test_run_figures_and_data_overlay_from_the_command_line(tmp_path):
    out = tmp_path / "run"
    csv = tmp_path / "m.csv"
    csv.write_text("displacement_mm,force_N\n0,0\n2,3\n4,6.5\n")
    cmd = [
        sys.executable,
        "-m",
        "ngbet",
        "run",
        "--quiet",
        "--out",
        str(out),
        "--data",
        str(csv),
        "--set",
        "loading.u0_mm=4",
        "--set",
        "loading.stops_mm=[]",
        "--set",
        "discretization.mesh_size_mm=20",
        "--set",
        "outputs.error_estimate='off'",
    ]
    p = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "MPLBACKEND": "Agg"})
    assert p.returncode == 0, p.stderr
    for name in RUN_FIGURES:  # PNG only: the scene asks for no other format
        assert (out / f"{name}.png").stat().st_size > 10000 and not (out / f"{name}.pdf").exists(), name
    csv.write_text("u,F\n")
    p = subprocess.run(cmd, capture_output=True, text=True)
    assert p.returncode == 2 and "m.csv" in p.stderr


def test_fsh_is_drawn_up_to_70_degrees_and_the_panel_says_what_it_leaves_out():
    """Towards yarn locking Eq. 18 divides by cos γ → 0: points beyond 70° are not drawn, and said so."""
    rs = [
        {"u0_mm": u, "force_N": u, "gamma_kinematic_deg": g, "fsh_N_per_mm": 0.01 * g, "gamma_centre_deg": g}
        for u, g in ((10.0, 30.0), (20.0, 60.0), (30.0, 80.0))
    ]
    ax = shear_force_figure(rs).axes[0]
    (curve,) = lines_of(ax)
    assert list(curve.get_xdata()) == [0.0, 30.0, 60.0] and "not drawn" in ax.texts[0].get_text()


# ------------------------------------------------------------------------------------------------
# one style: labels inside the canvas, honest colour scales, the formats the scene asks for
# ------------------------------------------------------------------------------------------------
def default_rows():
    """Rows like the default run's: a rising force, small error bars at the stations (the last one at the top)."""
    out = []
    for u in np.arange(2.0, 57.0, 2.0):
        out.append(
            {
                "u0_mm": float(u),
                "force_N": 0.034 * u * u + 0.1 * u,
                "snap": 0.0,
                "force_error_N": 0.14 if u in (36.0, 56.0) else "",
                "double_force_Nm": 0.07 * u,
                "gamma_kinematic_deg": 1.1 * u,
                "fsh_N_per_mm": 0.01 * u,
                "gamma_centre_deg": 0.8 * u,
            }
        )
    return out


def sheared_maps(low=-20.0):
    """Two maps on a rectangle whose angles run from ``low`` to 40° (the second twice the first)."""
    from matplotlib.tri import Triangulation

    x, y = np.meshgrid(np.linspace(0.0, 220.0, 45), np.linspace(0.0, 70.0, 15))
    x, y = x.ravel(), y.ravel()
    tri = Triangulation(x, y).triangles
    g = low + (40.0 - low) * x / 220.0
    return [MapData(u, x, y, tri, g * u / 56.0) for u in (28.0, 56.0)]


def test_every_run_figure_keeps_its_texts_inside_the_canvas():
    from ngbet.scene.document import default_scene

    scene = default_scene()
    rows = default_rows()
    figs = {
        "force": force_figure(rows, scene),
        "shear_force": shear_force_figure(rows, scene),
        "profile": profile_figure({56.0: ([0.0, 110.0, 220.0], [0.0, 2.0, 0.0])}, [56.0], scene),
        "shear_map": shear_map_figure(sheared_maps(), scene),
    }
    for name, fig in figs.items():
        assert texts_outside(fig) == [], name


def test_the_sizes_of_short_error_bars_are_written_inside_the_axes():
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = force_figure(default_rows())
    ax = fig.axes[0]
    FigureCanvasAgg(fig).draw()
    r = fig.canvas.get_renderer()
    labels = [t for t in ax.texts if t.get_text().count("±0.14 N") == 2]
    assert len(labels) == 1
    box = ax.get_window_extent(r)
    for t in labels:
        bb = t.get_window_extent(r)
        assert box.x0 <= bb.x0 and bb.x1 <= box.x1 and box.y0 <= bb.y0 and bb.y1 <= box.y1, bb


def test_a_caption_never_breaks_a_number_from_its_unit():
    """Broken at the figure's width, no line of a caption starts with the unit of the number that ended the
    line before ("66.8" / "% of"): the first word's length moves the break over every position around them."""
    from ngbet.figures.style import figure, put_caption

    for k in range(70, 100):
        fig = figure(7.0, 3.0)
        put_caption(fig, "x" * k + " error 66.8 % of the force at 145 mm, then more words to fill the second line")
        lines = fig.get_suptitle().split("\n")
        assert len(lines) > 1 and not any(line.startswith(("%", "mm")) for line in lines), lines


def test_texts_outside_finds_a_label_beyond_the_canvas():
    fig = force_figure(rows())
    fig.axes[0].text(1.4, 0.5, "far right", transform=fig.axes[0].transAxes)
    fig.set_layout_engine("none")  # the layout would otherwise not move it back: it is data, not a label
    assert "far right" in texts_outside(fig)


def test_signed_map_panels_share_one_symmetric_diverging_norm_and_say_what_they_clip():
    maps = sheared_maps(low=-20.0)
    maps[1].gamma_deg[0] = 300.0  # a corner spike: beyond the scale, marked by the arrow and the caption
    fig = shear_map_figure(maps)
    norms = [c.norm for ax in fig.axes[:2] for c in ax.collections]
    assert len(norms) == 2 and norms[0] is norms[1]  # one norm object for both panels
    assert (norms[0].vmin, norms[0].vmax) == (-40.0, 40.0)
    assert {c.get_cmap().name for ax in fig.axes[:2] for c in ax.collections} == {"RdBu_r"}
    assert "300.0°" in fig.get_suptitle() and "arrows" in fig.get_suptitle()
    cbar_ax = fig.axes[2]
    assert cbar_ax.get_ylim() == (-40.0, 40.0)


def test_the_caption_names_specimen_and_material():
    from ngbet.scene.document import default_scene

    sc = default_scene()
    text = f_caption(sc)
    sp = sc.specimen
    assert f"{sp.width_mm:g}\u00a0×\u00a0{sp.length_mm:g}\u00a0mm" in text
    assert "K_el\u00a0=\u00a0700\u00a0kPa" in text and "α1\u00a0=\u00a02\u00a0kPa\u00a0m²" in text
    # engineering notation at any size: no "1e-06 kPa m²", no "3.33e+06 Pa"
    tiny = f_caption(sc.with_changes(**{"material.alpha1": 1e-3, "material.K_el": 3.33e6}))
    assert "α1\u00a0=\u00a01\u00a0mPa\u00a0m²" in tiny and "K_el\u00a0=\u00a03.33\u00a0MPa" in tiny
    assert "e-0" not in tiny and "e+0" not in tiny
    assert "yarn network" in f_caption(sc.with_changes(model="discrete"))
    assert f_caption(sc.to_dict()) == text  # a study's base scene as its dictionary
    # a scene named after its size, run at another size, is not captioned with the other size
    named = sc.with_changes(
        **{"specimen.name": "twill-100x250", "specimen.width_mm": 100.0, "specimen.length_mm": 250.0}
    )
    assert f_caption(named).startswith("twill-100x250: specimen 100\u00a0×\u00a0250")
    other = f_caption(named.with_changes(**{"specimen.length_mm": 300.0}))
    assert other.startswith("twill: specimen 100\u00a0×\u00a0300")


def write_run(folder, formats=None):
    import csv

    from ngbet.scene.document import default_scene

    folder.mkdir()
    rows = default_rows()
    with open(folder / "results.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    sc = default_scene()
    if formats is not None:
        sc = sc.with_changes(**{"outputs.figure_formats": formats})
    (folder / "scene.toml").write_text(sc.to_toml())
    return folder


@pytest.mark.parametrize(("formats", "files"), [(None, {"png"}), (["png", "pdf"], {"png", "pdf"}), (["svg"], {"svg"})])
def test_the_figures_are_written_in_the_formats_the_scene_asks_for(tmp_path, formats, files):
    run = write_run(tmp_path / "r", formats)
    first = draw_run(run, only=["force"])
    assert first == run / f"force.{(formats or ['png'])[0]}"
    assert {p.suffix[1:] for p in run.glob("force.*")} == files


def test_the_figures_drawn_in_forked_children_are_those_drawn_here(tmp_path):
    here, there = write_run(tmp_path / "here"), write_run(tmp_path / "there")
    draw_run(here, workers=1)
    # a fresh interpreter has no other thread: the figures are shared with a forked child there
    code = (
        "from ngbet.figures.run import draw_run; from ngbet.figures.style import can_fork; assert can_fork(); "
        f"draw_run({str(there)!r}, workers=2)"
    )
    subprocess.run([sys.executable, "-c", code], check=True, env={**os.environ, "MPLBACKEND": "Agg"})
    names = sorted(p.name for p in here.glob("*.png"))
    assert names == ["force.png", "shear_force.png"] == sorted(p.name for p in there.glob("*.png"))
    from matplotlib.image import imread

    for name in names:
        np.testing.assert_array_equal(imread(here / name), imread(there / name))


FAILING_CHILD = """
import os, sys
import ngbet.figures.run as fr
from ngbet.figures.style import can_fork
assert can_fork()
# this process draws the shear map and the profile (none here), the child the force and F_sh figures
assert fr._share(fr.RUN_FIGURES, 2) == [["shear_map", "profile"], ["shear_force", "force"]]
parent, made = os.getpid(), fr.force_figure
def in_parent_only(*a, **k):
    if os.getpid() != parent:
        raise RuntimeError("a child that fails")
    return made(*a, **k)
fr.force_figure = in_parent_only
fr.draw_run(sys.argv[1], workers=2)
fr.shear_map_figure = lambda *a, **k: 1 / 0  # now this process fails: its child is still waited for
try:
    fr.draw_run(sys.argv[2], workers=2)
except ZeroDivisionError:
    pass
try:
    os.waitpid(-1, os.WNOHANG)
except ChildProcessError:
    print("no child left")
"""


def test_a_figure_whose_child_failed_is_drawn_here_and_every_child_is_waited_for(tmp_path):
    one, two = write_run(tmp_path / "one"), write_run(tmp_path / "two")
    done = subprocess.run(
        [sys.executable, "-c", FAILING_CHILD, str(one), str(two)],
        capture_output=True,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
    )
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in one.glob("*.png")) == ["force.png", "shear_force.png"]
    assert done.stdout.strip() == "no child left"


def test_the_figures_are_shared_among_the_workers_by_their_cost():
    """Each figure once; no more groups than workers or figures; the costliest spread out (greedy by cost)."""
    from ngbet.figures.run import FIGURE_COST, _share

    names = ["force", "shear_force", "profile", "shear_map", "yarns_37mm", "yarns_56mm"]
    for workers in (1, 2, 3, 4, 8):
        groups = _share(names, workers)
        assert sorted(n for g in groups for n in g) == sorted(names)
        assert len(groups) == min(workers, len(names)) and all(groups)
    two = _share(RUN_FIGURES, 2)
    cost = [sum(FIGURE_COST[n] for n in g) for g in two]
    assert sorted(map(sorted, two)) == [["force", "shear_force"], ["profile", "shear_map"]]  # 2.1 against 1.8
    assert max(cost) - min(cost) <= max(FIGURE_COST.values())
    assert _share([], 4) == [[]]


@pytest.mark.parametrize("bbox", [None, "tight"])
def test_a_png_drawn_once_has_the_pixels_of_savefig(tmp_path, bbox):
    """write_png draws once where savefig draws twice: the same pixels, the same size, for a figure
    with a legend and one with a colour bar; under a tight bounding box it is savefig itself."""
    import matplotlib as mpl
    from matplotlib.image import imread

    from ngbet.figures.style import PNG_COMPRESSION, PNG_DPI, in_style, write_png
    from ngbet.scene.document import default_scene

    scene = default_scene()
    for name, make in (
        ("force", lambda: force_figure(default_rows(), scene)),
        ("map", lambda: shear_map_figure(sheared_maps(), scene)),
    ):
        with in_style(), mpl.rc_context({"savefig.bbox": bbox}):
            write_png(make(), tmp_path / f"{name}_once.png")
            make().savefig(
                tmp_path / f"{name}_savefig.png", dpi=PNG_DPI, pil_kwargs={"compress_level": PNG_COMPRESSION}
            )
        once, twice = imread(tmp_path / f"{name}_once.png"), imread(tmp_path / f"{name}_savefig.png")
        assert once.shape == twice.shape and once.shape[0] > 100
        np.testing.assert_array_equal(once, twice)


def test_an_unknown_figure_format_is_refused_naming_the_key():
    from ngbet.scene.document import default_scene
    from ngbet.scene.validate import SceneError

    with pytest.raises(SceneError, match="outputs.figure_formats"):
        default_scene().with_changes(**{"outputs.figure_formats": ["png", "jpg"]})
    with pytest.raises(SceneError, match="outputs.figure_formats"):
        default_scene().with_changes(**{"outputs.figure_formats": []})


def test_the_package_exports_what_it_lists_without_importing_matplotlib():
    code = (
        "import sys, ngbet.figures as F; "
        "print([n for n in F.__all__ if not hasattr(F, n)], 'matplotlib' in sys.modules)"
    )
    assert fresh_python(code) == "[] False"


def test_a_small_double_force_has_a_prefixed_unit_and_no_offset():
    """T of order 1e-5 N m is drawn in µN m (values −12..0), not with a '1e−5' offset above the axis."""
    tiny = [{**r, "double_force_Nm": -1.2e-5 * r["u0_mm"] / 8.0} for r in rows()]
    fig = force_figure(tiny)
    fig.canvas.draw()
    ax2 = fig.axes[1]
    assert ax2.get_ylabel() == "double force on the moving clamp [µN\u00a0m]"
    assert min(lines_of(ax2)[0].get_ydata()) == pytest.approx(-12.0)
    assert ax2.yaxis.get_offset_text().get_text() == ""


def test_the_yarn_pictures_of_one_run_share_one_colour_scale():
    """Two states (γ up to 40° and up to 86°) drawn with each other's angles: both colour bars end at 100°."""
    x = np.array([[0.0, 0.0], [10.0, 10.0], [20.0, 0.0]])
    beams, family = np.array([[0, 1], [1, 2]]), np.array([1, 2])
    ends = x[[0, 2]]
    g1, g2 = np.array([10.0, 40.0]), np.array([20.0, 85.8])
    tops = []
    for g in (g1, g2):
        fig = yarn_network_figure(x, beams, family, g, ends, 37.0, scale_over=[g1, g2])
        tops.append(fig.axes[-1].get_ylim()[1])
    assert tops == [100.0, 100.0]
    alone = yarn_network_figure(x, beams, family, g1, ends, 37.0)
    assert alone.axes[-1].get_ylim()[1] == 40.0  # without the run's other states: its own round scale


@pytest.mark.parametrize("shape", ["softening", "stiffening"])
def test_the_shear_force_legend_covers_no_point_of_the_curve(shape):
    """The F_sh curve of the default scene softens (its upper left is empty), a fabric's stiffens
    (its lower right is empty): the legend goes where it hides no computed point."""
    from ngbet.scene.document import default_scene

    g = np.linspace(1.0, 60.0, 30)
    fsh = 0.5 * np.sin(np.radians(1.5 * g)) if shape == "softening" else 0.3 * (g / 60.0) ** 3
    data = [
        {"u0_mm": 2.0 * k, "gamma_kinematic_deg": a, "fsh_N_per_mm": f, "gamma_A_deg": a}
        for k, (a, f) in enumerate(zip(g, fsh, strict=True), 1)
    ]
    fig = shear_force_figure(data, default_scene())
    fig.canvas.draw()
    ax = fig.axes[0]
    box = ax.get_legend().get_window_extent()
    pts = ax.transData.transform(np.column_stack([g, fsh]))
    assert not any(box.contains(x, y) for x, y in pts)


def test_a_run_without_the_reaction_draws_the_figures_that_need_no_force(tmp_path):
    """``outputs.reaction = false``: no force_N column; the profile and the shear map need none."""
    import csv

    from ngbet.scene.document import default_scene

    run = tmp_path / "r"
    run.mkdir()
    rows = [{k: v for k, v in r.items() if k not in ("force_N", "force_error_N")} for r in default_rows()]
    with open(run / "results.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (run / "scene.toml").write_text(default_scene().to_toml())
    m = sheared_maps()[1]
    np.savez(
        run / "map_56mm.npz",
        u0_mm=56.0,
        X_mm=m.x_mm,
        Y_mm=m.y_mm,
        ux_mm=0 * m.x_mm,
        uy_mm=0 * m.y_mm,
        triangles=m.triangles,
        gamma_deg=m.gamma_deg,
    )
    assert draw_run(run) is None  # no force figure
    assert sorted(p.name for p in run.glob("*.png")) == ["shear_map.png"]  # (no profile.csv here)


def test_crossings_on_one_line_are_mapped_as_points(tmp_path):
    """A network whose crossings span no area has no Delaunay triangles (qhull refuses collinear points)."""
    from ngbet.figures.data import load_maps

    X = np.array([[50.0, 35.0, 0.0], [110.0, 35.0, 0.0], [170.0, 35.0, 0.0]])
    np.savez(
        tmp_path / "state_56mm.npz",
        crossing_nodes=np.array([[0, 0], [1, 1], [2, 2]]),
        X_mm=X,
        u_mm=np.zeros_like(X),
        crossing_gamma_deg=np.array([10.0, 20.0, 30.0]),
    )
    (m,) = load_maps(tmp_path)
    assert m.triangles.shape == (0, 3)
    fig = shear_map_figure([m])
    (art,) = fig.axes[0].collections
    assert list(art.get_array()) == [10.0, 20.0, 30.0]  # the points, coloured by their angles


def test_yarns_off_45_degrees_get_their_shear_angles_and_no_ideal_test():
    """Eqs. 13 and 18 are the ±45° test's: no empty F_sh panel, no legend entry for a line not drawn."""
    from ngbet.scene.document import default_scene

    scene = default_scene().with_changes(**{"specimen.yarn_angle_deg": 30.0, "specimen.length_mm": 250.0})
    rows = [{**r, "gamma_kinematic_deg": "", "fsh_N_per_mm": ""} for r in default_rows()]
    fig = shear_force_figure(rows, scene)
    (ax,) = fig.axes
    assert "yarns at ±30°" in ax.get_title()
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["computed, centre"]
    assert not texts_outside(fig)


def test_the_figures_of_a_run_short_of_its_load_say_where_it_stopped(tmp_path, monkeypatch):
    """A failed or interrupted run's figures open their caption with the load it reached of the
    one asked (the curve alone would look like a run to that load); a complete run's do not."""
    import json

    from ngbet.figures.style import FigureWriter

    said = {}
    monkeypatch.setattr(
        FigureWriter, "save", lambda self, fig, stem: said.update({stem.name: fig._suptitle.get_text()})
    )
    run = write_run(tmp_path / "r")
    for status, first in (
        ("interrupted", "The run was interrupted at u₀ = 40 mm of 56 mm. "),
        ("ok", ""),
        ("running", ""),
    ):
        (run / "summary.json").write_text(json.dumps({"status": status, "u0_reached_mm": 40.0}))
        draw_run(run, only=["force", "shear_force"])
        assert set(said) == {"force", "shear_force"}
        assert all(t.replace("\n", " ").replace("\u00a0", " ").startswith(first) for t in said.values()), said
        assert all(("The run" in t) == bool(first) for t in said.values())
        said.clear()
