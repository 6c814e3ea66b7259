"""Picture-frame curves on faulty input: shear angles in the wrong unit, files without a header,
files that name no frame. The one reader of measured curves refuses or reads them the same way for
``ngbet run --data``, ``ngbet fit`` and ``ngbet normalise``; nothing here runs a model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ngbet.calibration.command import Inputs
from ngbet.cli import _parser, main
from ngbet.figures.frame import read_frame_measured
from ngbet.measured.curves import read_any, read_frame_curve, read_measured
from ngbet.measured.table import read_table
from ngbet.scene.validate import SceneError

ROOT = Path(__file__).resolve().parents[1]
PF = ROOT / "data" / "cao2008_pf"
UN22 = PF / "cao2008_pf_plain_UN_fig22_shear_force.csv"
BET_SCENE = ROOT / "geometry" / "twintex_plain.toml"
PF_SCENE = ROOT / "geometry" / "twintex_plain_pf_UN.toml"
#: the line of UN22's largest shear angle, 52.778°, its last row
LAST = 391


def _err(call, *args, **kwargs) -> str:
    with pytest.raises(SceneError) as info:
        call(*args, **kwargs)
    return str(info.value)


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


def _in_rad(tmp_path: Path) -> Path:
    """UN22 with its header saying rad and kN: its values are degrees and N."""
    head = "shear_angle_deg,shear_force_N,on_frame_edge"
    return _write(
        tmp_path / "rad.csv",
        [("shear_angle_rad,shear_force_kN,on_frame_edge" if ln == head else ln) for ln in _lines(UN22)],
    )


def _no_comments(tmp_path: Path) -> Path:
    return _write(tmp_path / "nocomments.csv", [ln for ln in _lines(UN22) if not ln.startswith("#")])


def _no_header(tmp_path: Path, name: str = "nohdr.csv", cut: bool = False) -> Path:
    """UN22 without its comment lines and header: rows of numbers (and its third column, unless ``cut``)."""
    rows = [ln for ln in _lines(UN22) if not ln.startswith("#")][1:]
    return _write(tmp_path / name, [",".join(r.split(",")[:2]) if cut else r for r in rows])


# --- shear angles no frame reaches ----------------------------------------------------------------------------------

RAD = (
    "line 391: the column 'shear_angle_rad' holds 52.78 rad (3024°): a shear angle of 3024° is impossible in a "
    "picture frame (at most 90°): is the column in degrees rather than rad? Write its unit in the header "
    "(shear_angle_deg, shear_angle_rad) or give it with --columns 'shear_angle_rad:deg,...'"
)


def test_shear_angles_in_degrees_headed_rad_are_refused_by_every_command(tmp_path, capsys):
    """52.778 (degrees, line 391) read as rad is 3024°: refused naming the column, its unit and the cause,
    by the reader and so by run --data, fit and normalise alike (exit 2), none of which drops the points."""
    p = _in_rad(tmp_path)
    assert _err(read_table, p) == f"{p}, {RAD}"
    assert main(["normalise", str(p), "--out", str(tmp_path / "n")]) == 2
    assert capsys.readouterr().err == f"ngbet normalise: {p}, {RAD}\n"
    assert main(["fit", str(p), "--scene", str(BET_SCENE), "--out", str(tmp_path / "f")]) == 2
    assert capsys.readouterr().err == f"ngbet fit: {p}, {RAD}\n"
    assert main(["run", str(PF_SCENE), "--data", str(p), "--out", str(tmp_path / "r"), "--quiet"]) == 2
    assert capsys.readouterr().err == f"ngbet: bad data: {p}, {RAD}\n"
    assert not any((tmp_path / d).exists() for d in ("n", "f", "r"))


@pytest.mark.parametrize(
    "shift, message",
    [
        (
            90.0,  # the angle between the yarns, 90° + γ: up to 142.778° at the last row
            "line 391: the column 'shear_angle_deg' holds 142.8°: a shear angle of 142.8° is impossible in a "
            "picture frame (at most 90°): is it the shear angle γ (0° in the square frame), not the angle between "
            "the yarns (90° + γ)? Write its unit in the header (shear_angle_deg, shear_angle_rad) or give it with "
            "--columns 'shear_angle_deg:deg,...'",
        ),
        (
            -40.0,  # γ - 40°: 250 of the 381 angles below 0° (those of UN22 below 40°)
            "250 of 381 shear angles in the column 'shear_angle_deg' lie below 0° (down to -40° at line 12): a "
            "picture frame shears from 0° (the square frame) up to 90°: is it the shear angle γ, counted positive "
            "as the frame shears?",
        ),
    ],
)
def test_shear_angles_no_frame_reaches_are_refused_saying_what_they_may_be(tmp_path, shift, message):
    head, rows = [], []
    for ln in _lines(UN22):
        if ln[0].isdigit():
            g, rest = ln.split(",", 1)
            rows.append(f"{float(g) + shift:.6g},{rest}")
        else:
            head.append(ln)
    p = _write(tmp_path / "shifted.csv", head + rows)
    assert _err(read_table, p) == f"{p}{',' if shift > 0 else ':'} {message}"


@pytest.mark.parametrize(
    "name, rows, largest",
    [
        ("cao2008_pf_plain_UML_fig22_shear_force.csv", 133, 52.575),
        ("cao2008_pf_plain_UML_fig28_normalized_energy.csv", 168, 48.199),
        ("cao2008_pf_plain_UN_fig22_shear_force.csv", 381, 52.778),
        ("cao2008_pf_plain_UN_fig28_normalized_energy.csv", 433, 47.371),
        ("cao2008_pf_twill_balanced_UML_fig29_normalized_energy.csv", 176, 52.775),
        ("cao2008_pf_twill_unbalanced_UN_fig30_normalized_energy.csv", 384, 40.613),
    ],
)
def test_the_shipped_frame_curves_are_read_whole(name, rows, largest):
    """Every row of the shipped curves is read (their shear angles lie between 0 and 90°), as before."""
    t = read_table(PF / name)
    assert (len(t.x), t.x.max(), t.test) == (rows, largest, "picture_frame")
    assert t.x.min() > 0


def test_the_fit_says_which_points_of_a_frame_curve_it_leaves_out(tmp_path):
    """A row at 0° (the square frame) has no crosshead travel to fit: left out, and said."""
    lines = _lines(UN22)
    first = next(k for k, ln in enumerate(lines) if ln[0].isdigit())
    p = _write(tmp_path / "zero.csv", [*lines[:first], "0,0,", *lines[first:]])
    c = read_frame_curve(p)
    assert "1 point at a shear angle of 0° or 90° and beyond left out" in c.notes
    np.testing.assert_array_equal(c.u_mm, read_frame_curve(UN22).u_mm)
    assert not any("left out" in n for n in read_frame_curve(UN22).notes)


# --- a file without a header ----------------------------------------------------------------------------------------

ROW = (
    "line 1: a row of numbers where the header should be: name the columns in a header line above it, with their units"
)
BOTH = (
    f"{ROW} (displacement_mm,force_N; a picture frame's shear_angle_deg,shear_force_N), or give them by number "
    "with their units: --columns 1:mm,2:N (a picture frame's: --columns 1:deg,2:shear_force_N)"
)
FRAME = (
    f"{ROW} (shear_angle_deg,shear_force_N or shear_angle_deg,normalised_shear_force_N_per_mm), or give them by "
    "number with their units: --columns 1:deg,2:shear_force_N"
)
BET = f"{ROW} (displacement_mm,force_N), or give them by number with their units: --columns 1:mm,2:N"


def test_a_file_without_a_header_is_refused_with_the_columns_of_its_test(tmp_path, capsys):
    """Its first row (with a text cell, or numbers only) is data, not a header: the advice names the columns
    of the test the curve is read for, both tests' where nothing says which."""
    for p in (_no_header(tmp_path), _no_header(tmp_path, "cut.csv", cut=True)):
        assert _err(read_table, p) == f"{p}, {BOTH}"
        assert _err(read_table, p, expect="picture_frame") == f"{p}, {FRAME}"  # a frame run's
        assert _err(read_table, p, test="picture_frame") == f"{p}, {FRAME}"  # --test, the fit of a frame curve
        assert _err(read_measured, p) == f"{p}, {BET}"  # a bias extension run's
        assert main(["run", str(PF_SCENE), "--data", str(p), "--out", str(tmp_path / "r"), "--quiet"]) == 2
        assert f"{p}, {ROW} (" in capsys.readouterr().err
    said = _write(tmp_path / "said.csv", ["# test: picture-frame", *_lines(_no_header(tmp_path))])
    assert _err(read_table, said) == f"{said}, {FRAME}".replace("line 1:", "line 2:")


def test_unknown_column_names_in_a_frame_read_are_refused_with_the_frame_columns(tmp_path):
    p = _write(tmp_path / "xy.csv", ["x,y", "1,2", "2,3", "3,4"])
    assert _err(read_table, p, expect="picture_frame") == (
        f"{p}, line 1: the header names the columns 'x', 'y', none of which is a shear angle and a shear force "
        "this reader knows; name them with their units (shear_angle_deg,shear_force_N or "
        "shear_angle_deg,normalised_shear_force_N_per_mm) or choose them with --columns NAME:deg,NAME:shear_force_N"
    )
    assert "none of which is a displacement and a force" in _err(read_table, p)


def test_columns_by_number_read_every_row_of_a_file_without_a_header(tmp_path):
    """``--columns 1:deg,2:shear_force_N`` names the shear force F_s (a unit of N alone is the crosshead force,
    ``N/mm`` the normalised shear force); the first row is data: the file's 381 rows from line 1."""
    ref = read_table(UN22)
    for p in (_no_header(tmp_path), _no_header(tmp_path, "cut.csv", cut=True)):
        for columns, quantity in (
            ("1:deg,2:shear_force_N", "shear_force"),
            ("1:shear_angle_deg,2:Fs_N", "shear_force"),
            ("1:deg,2:N/mm", "normalised_shear_force"),
            ("1:deg,2:N", "force"),
        ):
            t = read_table(p, columns=columns)
            assert (t.x_quantity, t.y_quantity, t.test, t.lines[0], len(t.x)) == (
                "shear_angle",
                quantity,
                "picture_frame",
                1,
                381,
            )
            np.testing.assert_array_equal(t.x, ref.x)
            np.testing.assert_array_equal(t.y, ref.y)
        assert "no header: line 1 is a row of numbers, read as data with the columns of --columns" in t.notes
        m = read_frame_measured(p, columns="1:deg,2:shear_force_N")  # ngbet run --data of a frame scene
        assert (m.quantity, len(m.shear_angle_deg)) == ("shear_force_N", 381)
        c = read_frame_curve(p, columns="1:deg,2:shear_force_N", scene_frame=ref.frame)  # ngbet fit
        np.testing.assert_allclose(c.u_mm, read_frame_curve(UN22).u_mm)


@pytest.mark.parametrize(
    "columns, message",
    [
        (
            "Weg:deg,2:shear_force_N",
            "--columns 'Weg:deg,2:shear_force_N': {p} has no header (line 1 is a row of numbers): give each column "
            "by its number with its unit, --columns 1:mm,2:N (a picture frame's: --columns 1:deg,2:shear_force_N)",
        ),
        (
            "1,2:N",
            "--columns '1,2:N': {p} has no header (line 1 is a row of numbers): give each column by its number with "
            "its unit, --columns 1:mm,2:N (a picture frame's: --columns 1:deg,2:shear_force_N)",
        ),
        (
            "1:deg,2:shear_force_mm",
            "--columns '1:deg,2:shear_force_mm': 'shear_force_mm': a shear force in mm? give it in N, kN, "
            "e.g. 2:shear_force_N",
        ),
        (
            "1:deg,2:lbf",
            "--columns '1:deg,2:lbf': unknown unit 'lbf' (known: mm, cm, m; deg, °, rad; N, kN; N/mm, N/m, kN/m)",
        ),
    ],
)
def test_columns_of_a_file_without_a_header_need_numbers_and_units(tmp_path, columns, message):
    p = _no_header(tmp_path)
    assert _err(read_table, p, columns=columns) == message.format(p=p)


def test_a_quantity_with_its_unit_in_columns_names_a_column_of_a_file_with_a_header(tmp_path):
    p = _write(tmp_path / "winkel.csv", ["Winkel;Kraft", *(f"{g};{2 * g}" for g in range(1, 30))])
    t = read_table(p, columns="Winkel:deg,Kraft:shear_force_kN")
    assert (t.y_quantity, t.y[0], t.lines[0]) == ("shear_force", 2000.0, 2)
    assert read_table(p, columns="Winkel:deg,Kraft:kN").y_quantity == "force"  # 'Kraft' by its name, a force


# --- a frame curve whose header names no frame ------------------------------------------------------------------


def _inputs(*args: str) -> Inputs:
    return Inputs(_parser("fit").parse_args(["fit", *args]))


def test_the_fit_takes_the_frame_of_a_frame_scene_for_a_file_that_names_none(tmp_path):
    """The scene's frame, after --set, with a note; the curve then is the same as with the frame in its header."""
    p = _no_comments(tmp_path)
    params = "material.shear_stress_steps_Pa"
    inp = _inputs(str(p), "--scene", str(PF_SCENE), "--params", params)
    (c,) = inp.curves
    assert c.frame == {"picture_frame.frame_mm": 145.0, "picture_frame.fabric_mm": 120.0}
    note = f"{p}: its header names no frame: picture_frame.frame_mm = 145, picture_frame.fabric_mm = 120 from the scene"
    assert note in inp.notes
    np.testing.assert_allclose(c.u_mm, read_any(UN22).u_mm)
    np.testing.assert_allclose(c.force_N, read_any(UN22).force_N)
    wider = _inputs(str(p), "--scene", str(PF_SCENE), "--params", params, "--set", "picture_frame.frame_mm=150")
    assert wider.curves[0].frame == {"picture_frame.frame_mm": 150.0, "picture_frame.fabric_mm": 120.0}
    both = ("--set", "picture_frame.frame_mm=145", "--set", "picture_frame.fabric_mm=120")
    assert _inputs(str(p), "--scene", str(BET_SCENE), *both).curves[0].frame == c.frame  # a BET scene, given one
    assert _inputs(str(UN22), "--scene", str(PF_SCENE), "--params", params).curves[0].notes == read_any(UN22).notes


def test_a_frame_curve_that_names_no_frame_with_a_scene_of_none_is_refused_naming_both_remedies(tmp_path, capsys):
    p = _no_comments(tmp_path)
    out = tmp_path / "fit"
    for extra in ((), ("--set", "picture_frame.frame_mm=150")):  # a bias extension scene; one key alone
        assert main(["fit", str(p), "--scene", str(BET_SCENE), *extra, "--out", str(out)]) == 2
        assert capsys.readouterr().err == (
            f"ngbet fit: {p}: a picture-frame curve whose header names no picture_frame.frame_mm and no "
            "picture_frame.fabric_mm, fitted with a scene of no picture frame: add the frame to its header "
            "(# picture_frame.frame_mm = 145, # picture_frame.fabric_mm = 120), or fit with the scene of its frame "
            "(--scene of a picture-frame scene, or --set picture_frame.frame_mm=145 "
            "--set picture_frame.fabric_mm=120)\n"
        )
    assert not out.exists()
