"""The run's figures: what each draws is the data (computed points, jumps, error bars, colour scales)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from ngbet import figures as F  # noqa: E402


def rows(snap_at=None, errors=None):
    """Rows of a results.csv: F = u0² with a jump of +30 N at ``snap_at``, errors at the rows given."""
    out = []
    for u in (2.0, 4.0, 6.0, 6.5, 8.0):
        jump = 30.0 if snap_at is not None and u >= snap_at else 0.0
        out.append({"u0_mm": u, "force_N": u * u + jump, "snap": float(u == snap_at),
                    "force_error_N": (errors or {}).get(u, "")})
    return out


def lines_of(ax):
    return [ln for ln in ax.get_lines() if len(ln.get_xdata())]


def test_a_snap_through_is_a_vertical_dashed_jump_and_the_curve_breaks_there():
    fig = F.force_figure(rows(snap_at=6.5))
    ax = fig.axes[0]
    dashed = [ln for ln in lines_of(ax) if ln.get_linestyle() == "--"]
    assert len(dashed) == 1
    assert list(dashed[0].get_xdata()) == [6.5, 6.5] and list(dashed[0].get_ydata()) == [36.0, 6.5**2 + 30]
    solid = [ln for ln in lines_of(ax) if ln.get_linestyle() == "-"]
    # two solid pieces: up to the row before the jump (from the origin), from the jump on
    assert [list(ln.get_xdata()) for ln in solid] == [[0.0, 2.0, 4.0, 6.0], [6.5, 8.0]]


def test_without_a_snap_the_curve_is_the_computed_points_only():
    fig = F.force_figure(rows())
    (curve,) = lines_of(fig.axes[0])
    assert list(curve.get_xdata()) == [0.0, 2.0, 4.0, 6.0, 6.5, 8.0]  # no points between the rows
    assert list(curve.get_ydata()) == [0.0, 4.0, 16.0, 36.0, 42.25, 64.0]


def test_error_bars_where_the_run_estimated_and_their_size_written_when_too_small_to_see():
    fig = F.force_figure(rows(errors={4.0: 0.05, 8.0: 3.0}))
    ax = fig.axes[0]
    (bars,) = [c for c in ax.containers if c.__class__.__name__ == "ErrorbarContainer"]
    segments = bars.lines[2][0].get_segments()
    assert [(s[0][0], s[0][1], s[1][1]) for s in segments] == [(4.0, 15.95, 16.05), (8.0, 61.0, 67.0)]
    # 2 × 0.05 N is below 2 % of the 64 N axis: written beside the bar; 2 × 3 N is not
    assert [t.get_text() for t in ax.texts] == ["±0.05 N"]


def test_measured_curve_on_the_force_and_shear_force_figures(tmp_path):
    csv = tmp_path / "m.csv"
    csv.write_text("# a comment\n# specimen.width_mm = 70\n# specimen.length_mm = 220\n"
                   "displacement_mm,force_N\n0,0\n10,12\n10,14\n20,30\n")
    m = F.read_measured(csv)
    assert (m.width_mm, m.length_mm) == (70.0, 220.0) and list(m.force_N) == [0.0, 12.0, 14.0, 30.0]
    fig = F.force_figure(rows(), measured=m)
    assert any(list(ln.get_ydata()) == [0.0, 12.0, 14.0, 30.0] for ln in lines_of(fig.axes[0]))
    g, f = F.measured_fsh(m, 70.0, 220.0)  # the points at 10 mm averaged: a curve increasing in d
    # Eq. 13 at 10 and 20 mm (D = 150 mm): 0.138217 and 0.288427 rad
    assert len(g) == 2 and np.allclose(g, np.degrees([0.138217, 0.288427]), rtol=1e-5)


@pytest.mark.parametrize("text", ["d,F\n1,2\n", "displacement_mm,force_N\n1,x\n", "displacement_mm,force_N\n1,2\n"])
def test_a_bad_measured_file_is_refused_naming_it(tmp_path, text):
    csv = tmp_path / "bad.csv"
    csv.write_text(text)
    with pytest.raises(ValueError, match="bad.csv"):
        F.read_measured(csv)


def test_a_colour_scale_with_negative_angles_is_symmetric_and_marks_what_it_clips():
    # two panels: the scale is shared, round, and the corner spikes (beyond the 99.5 % quantile) are marked
    a = np.r_[np.linspace(-12.0, 30.0, 1000), 80.0]
    b = np.r_[np.linspace(-3.0, 45.0, 1000), -70.0]
    cs = F.colour_scale([a, b])
    assert (cs.vmin, cs.vmax, cs.cmap, cs.extend) == (-50.0, 50.0, "RdBu_r", "both")


def test_a_colour_scale_without_negative_angles_starts_at_zero():
    cs = F.colour_scale([np.linspace(0.0, 54.8, 1000)])
    assert (cs.vmin, cs.vmax, cs.cmap, cs.extend) == (0.0, 60.0, "viridis", "neither")


def test_the_map_panels_share_one_norm():
    tri = np.array([[0, 1, 2]])
    maps = [F.MapData(u, np.array([0.0, 10.0, 0.0]), np.array([0.0, 0.0, 10.0]), tri, np.array([0.0, g, g / 2]))
            for u, g in ((10.0, 9.0), (20.0, 18.0))]
    fig = F.shear_map_figure(maps)
    norms = {(c.norm.vmin, c.norm.vmax) for ax in fig.axes[:2] for c in ax.collections}
    assert norms == {(0.0, 20.0)}


def test_ngbet_run_imports_no_matplotlib_before_it_solves():
    code = ("import sys, ngbet.cli, ngbet.run, ngbet.figures, ngbet.continuum.run, ngbet.discrete.run; "
            "print('matplotlib' in sys.modules)")
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip() == "False"


def test_run_figures_and_data_overlay_from_the_command_line(tmp_path):
    out = tmp_path / "run"
    csv = tmp_path / "m.csv"
    csv.write_text("displacement_mm,force_N\n0,0\n2,3\n4,6.5\n")
    cmd = [sys.executable, "-m", "ngbet", "run", "--quiet", "--out", str(out), "--data", str(csv), "--set",
           "loading.u0_mm=4", "--set", "loading.stops_mm=[]", "--set", "discretization.mesh_size_mm=20",
           "--set", "outputs.error_estimate='off'"]
    p = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "MPLBACKEND": "Agg"})
    assert p.returncode == 0, p.stderr
    for name in F.RUN_FIGURES:  # PNG only: the scene asks for no other format
        assert (out / f"{name}.png").stat().st_size > 10000 and not (out / f"{name}.pdf").exists(), name
    csv.write_text("u,F\n")
    p = subprocess.run(cmd, capture_output=True, text=True)
    assert p.returncode == 2 and "m.csv" in p.stderr


def test_fsh_is_drawn_up_to_70_degrees_and_the_panel_says_what_it_leaves_out():
    """Towards yarn locking Eq. 18 divides by cos γ → 0: points beyond 70° are not drawn, and said so."""
    rs = [{"u0_mm": u, "force_N": u, "gamma_kinematic_deg": g, "fsh_N_per_mm": 0.01 * g, "gamma_centre_deg": g}
          for u, g in ((10.0, 30.0), (20.0, 60.0), (30.0, 80.0))]
    ax = F.shear_force_figure(rs).axes[0]
    (curve,) = lines_of(ax)
    assert list(curve.get_xdata()) == [0.0, 30.0, 60.0] and "not drawn" in ax.texts[0].get_text()
