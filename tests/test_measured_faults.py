"""The one reader of measured curves on files as they come: machine exports, reversed and sign-flipped
curves, picture frames without a test line, re-exported duplicates, unknown units, and what it says."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ngbet.cli import main
from ngbet.figures.data import Measured
from ngbet.measured.curves import read_all, read_any, read_measured
from ngbet.measured.table import read_table
from ngbet.scene.validate import SceneError

DATA = Path(__file__).resolve().parents[1] / "data"
PF30 = DATA / "cao2008_pf" / "cao2008_pf_twill_unbalanced_UN_fig30_normalized_energy.csv"
SPEC = "# fabric: a glass twill\n# specimen.width_mm = 100\n# specimen.length_mm = 250\n"
ROWS = [(2.0 * k, 0.5 * k + 0.01 * k * k) for k in range(1, 21)]  # u [mm], F [N]: increasing, 20 rows
U = np.array([r[0] for r in ROWS])
F = np.array([r[1] for r in ROWS])


def _csv(path: Path, text: str, encoding: str = "utf-8") -> Path:
    path.write_text(text, encoding=encoding)
    return path


def _body(rows=ROWS, sep=",", sign=1.0) -> str:
    return "".join(f"{sign * u:g}{sep}{sign * f:g}\n" for u, f in rows)


def _err(call, *args, **kwargs) -> str:
    with pytest.raises(SceneError) as info:
        call(*args, **kwargs)
    return str(info.value)


# --- a row of units -------------------------------------------------------------------------------------------------


def test_a_units_row_with_units_of_columns_not_read_is_a_units_row_never_data(tmp_path):
    """``s;mm;%;N``: the % of a strain column does not make the row data; --columns reads it too."""
    body = "".join(f"{k / 10:g};{u:g};{u / 2:g};{f:g}\n".replace(".", ",") for k, (u, f) in enumerate(ROWS))
    p = _csv(tmp_path / "zwick.csv", SPEC + "Time;Crosshead;Strain;Standard force\ns;mm;%;N\n" + body)
    for columns in (None, "2:mm,4:N", "Crosshead,Standard force"):
        t = read_table(p, columns=columns)
        np.testing.assert_allclose(t.x, U)
        np.testing.assert_allclose(t.y, F)
        assert t.lines[0] == 6  # the first row of numbers, under the units (line 5)
        said = "line 5 holds no number: read as a row of units (s;mm;%;N), not as data" in t.notes
        assert said == (columns == "2:mm,4:N")  # said where the row gave no unit read
    kn = _csv(
        tmp_path / "kn.csv", "Time,Extension,Load\n(s),(mm),(kN)\n" + "".join(f"0,{u},{f / 1e3}\n" for u, f in ROWS)
    )
    np.testing.assert_allclose(read_measured(kn).force_N, F, rtol=1e-12)


def test_a_units_row_with_an_unknown_unit_of_a_column_read_names_it(tmp_path):
    p = _csv(tmp_path / "a.csv", "Extension,Load\nin,lbf\n" + _body())
    assert _err(read_measured, p) == (
        f"{p}, line 2: the column 'Extension' (displacement): unknown unit 'in' (known: mm, cm, m); convert "
        "the column to one of them or choose the unit with --columns 'Extension:mm,...'"
    )
    both = _csv(tmp_path / "b.csv", "Extension (mm),Load (N)\nmm,kN\n" + _body())
    assert _err(read_measured, both) == (
        f"{both}, line 2: the column 'Load (N)' is in N by its name and in kN by the row of units: correct one"
    )


# --- signs and order ------------------------------------------------------------------------------------------------


def test_rows_in_descending_displacement_are_read_in_ascending_order_and_said(tmp_path):
    p = _csv(tmp_path / "rev.csv", SPEC + "displacement_mm,force_N\n" + _body(ROWS[::-1]))
    c = read_measured(p)
    np.testing.assert_allclose(c.u_mm, U)
    np.testing.assert_allclose(c.force_N, F)
    assert c.notes == (
        "the rows run down the displacement, from 40 mm at line 5 to 2 mm at line 24: read in ascending order",
    )
    m = Measured.read(p)  # run --data draws all of it
    np.testing.assert_allclose(m.displacement_mm, U)
    assert read_measured(p).check_window((0.1, 0.9)) is None  # fit: 16 measured points in the window


def test_a_displacement_falling_while_the_force_rises_is_refused(tmp_path):
    rows = [(u, f) for (u, _), (_, f) in zip(ROWS[::-1], ROWS, strict=True)]  # a position counted downward
    p = _csv(tmp_path / "down.csv", "displacement_mm,force_N\n" + _body(rows))
    assert _err(read_table, p) == (
        f"{p}: the displacement falls from 40 mm at line 2 to 2 mm at line 21 while the force rises from "
        "0.51 N to 14 N: a displacement counted against the pull (a crosshead position measured downward, "
        "or the sign flipped?); write the displacement increasing with the load"
    )


def test_a_displacement_and_force_both_negative_are_read_with_their_signs_changed_and_said(tmp_path):
    p = _csv(tmp_path / "neg.csv", SPEC + "displacement_mm,force_N\n0,0.01\n" + _body(sign=-1.0))
    c = read_measured(p)
    np.testing.assert_allclose(c.u_mm, np.r_[0.0, U])
    np.testing.assert_allclose(c.force_N, np.r_[-0.01, F])
    assert c.notes == (
        "the displacement and the force are negative throughout (tension counted negative): read with both "
        "signs changed",
    )


def test_a_displacement_or_a_force_alone_negative_is_refused_asking_for_the_sign(tmp_path):
    u = _csv(tmp_path / "u.csv", "displacement_mm,force_N\n" + "".join(f"{-a:g},{b:g}\n" for a, b in ROWS))
    assert _err(read_table, u) == (
        f"{u}: the displacement is negative throughout (down to -40 mm) while the force is positive: is the "
        "sign flipped? Both tests pull the fabric: write the displacement column positive under tension"
    )
    f = _csv(tmp_path / "f.csv", "displacement_mm,force_N\n" + "".join(f"{a:g},{-b:g}\n" for a, b in ROWS))
    assert _err(read_measured, f) == (
        f"{f}: the force is negative throughout (down to -14 N) while the displacement is positive: is the "
        "sign flipped? Both tests pull the fabric: write the force column positive under tension"
    )


def test_a_loading_branch_of_a_small_share_of_the_rows_is_refused_not_cut(tmp_path):
    rows = [(10.0, 0.1), (40.0, 14.0)] + [(40.0 - 2.0 * k, 14.0 - 0.7 * k) for k in range(1, 19)]
    p = _csv(tmp_path / "spike.csv", "displacement_mm,force_N\n" + _body(rows))
    assert _err(read_table, p) == (
        f"{p}, line 3: the displacement reaches its largest value, 40 mm, in row 2 of 20 and falls back to "
        "4 mm over the 18 rows after it: a loading branch of 2 rows is no curve to read; keep one loading "
        "branch in the file, its rows in the order of the test"
    )
    one = ROWS + [(U[-1] - 3.0, F[-1] * 0.8)]  # one row of unloading: left out and said, in the singular
    c = read_measured(_csv(tmp_path / "one.csv", "displacement_mm,force_N\n" + _body(one)))
    assert c.notes == (
        "a loading-unloading cycle: kept the loading branch up to the largest displacement, 40 mm (line 21); "
        "the 1 row after it is left out",
    )


# --- which test: one rule -------------------------------------------------------------------------------------------


def _without_test_line(tmp_path: Path) -> Path:
    text = "\n".join(ln for ln in PF30.read_text().splitlines() if not ln.startswith("# test:"))
    return _csv(tmp_path / "pf30_notest.csv", text + "\n")


def test_a_picture_frame_file_without_a_test_line_is_a_picture_frame_for_every_command(tmp_path, capsys):
    p = _without_test_line(tmp_path)
    t = read_table(p)
    assert (t.test, t.test_reason) == (
        "picture_frame",
        "its columns hold the shear angle, a picture frame's quantity",
    )
    c = read_any(p)  # ngbet fit
    assert (c.test, c.label) == ("picture_frame", "frame 145/120 mm")
    np.testing.assert_allclose(c.u_mm, read_any(PF30).u_mm)
    assert _err(read_measured, p) == (
        f"{p}: a picture-frame curve (its columns hold the shear angle, a picture frame's quantity), not a bias "
        "extension curve: a run of a picture-frame scene draws it (ngbet run SCENE --data), ngbet fit fits "
        "it and ngbet normalise normalises it"
    )
    out = tmp_path / "n"
    assert main(["normalise", str(p), "--out", str(out)]) == 0
    assert json.loads((out / "normalise.json").read_text())["curves"][0]["test"] == "picture_frame"
    raw = _csv(
        tmp_path / "raw.csv",
        "# picture_frame.frame_mm = 145\n# picture_frame.fabric_mm = 120\ndisplacement_mm,force_N\n" + _body(),
    )
    assert (read_table(raw).test, read_table(raw).test_reason) == (
        "picture_frame",
        "it names a picture frame and no specimen",
    )
    capsys.readouterr()


def test_a_file_naming_a_specimen_and_a_frame_without_its_test_is_refused_by_every_command(tmp_path, capsys):
    p = _csv(
        tmp_path / "both.csv", SPEC + "# Table 3 (UN): frame 145 mm, fabric 120 mm\ndisplacement_mm,force_N\n" + _body()
    )
    msg = (
        f"{p}: which test? it names both a specimen and a picture frame: add '# test: bias_extension' or "
        "'# test: picture_frame' to its header (ngbet normalise: or give --test)"
    )
    assert _err(read_any, p) == msg
    assert main(["normalise", str(p), "--out", str(tmp_path / "n")]) == 2
    assert capsys.readouterr().err == f"ngbet normalise: {msg}\n"
    assert read_table(p, test="bias_extension").test == "bias_extension"


def test_a_frame_from_the_command_line_beside_a_specimen_in_the_header_says_which_came_from_where(tmp_path):
    p = _csv(tmp_path / "bet.csv", SPEC + "displacement_mm,force_N\n" + _body())
    with pytest.raises(SceneError) as err:
        read_table(p, frame={"picture_frame.frame_mm": 145.0, "picture_frame.fabric_mm": 120.0})
    assert str(err.value) == (
        f"{p}: which test? --frame gives a picture frame and its header a specimen: drop --frame, or add "
        "'# test: bias_extension' or '# test: picture_frame' to its header"
    )


# --- the same curve twice -------------------------------------------------------------------------------------------


def test_a_curve_re_exported_in_kn_with_semicolons_is_the_same_curve(tmp_path, capsys):
    a = _csv(tmp_path / "a.csv", SPEC + "displacement_mm,force_N\n" + _body())
    b = _csv(
        tmp_path / "b.csv",
        SPEC
        + "Displacement (mm);Force (kN)\n"
        + "".join(f"{u:.4f};{f / 1e3:.7f}\n".replace(".", ",") for u, f in ROWS),
    )
    msg = (
        f"{b} and {a}: the same measured curve twice (one test and specimen; the forces agree to within 0.1 % "
        "of their range at the same displacements); give each curve once (a curve given twice counts twice "
        "and makes the uncertainties too small)"
    )
    assert _err(read_all, [a, b]) == msg
    assert main(["normalise", str(a), str(b), "--out", str(tmp_path / "n")]) == 2
    assert capsys.readouterr().err == f"ngbet normalise: {msg}\n"
    other = _csv(tmp_path / "c.csv", SPEC + "displacement_mm,force_N\n" + _body([(u, 1.01 * f) for u, f in ROWS]))
    assert len(read_all([a, other])) == 2  # 1 % apart: another measurement
    wider = _csv(tmp_path / "d.csv", SPEC.replace("250", "300") + "displacement_mm,force_N\n" + _body())
    assert len(read_all([a, wider])) == 2  # another specimen


# --- the fabric -----------------------------------------------------------------------------------------------------


def test_a_file_naming_no_fabric_beside_files_that_do_is_said_to_be_compared_with_none(tmp_path, capsys):
    a = _csv(tmp_path / "a.csv", SPEC + "displacement_mm,force_N\n" + _body())
    b = _csv(
        tmp_path / "b.csv",
        SPEC.replace("250", "300").replace("# fabric: a glass twill\n", "")
        + "displacement_mm,force_N\n"
        + _body([(u, 1.1 * f) for u, f in ROWS]),
    )
    out = tmp_path / "n"
    assert main(["normalise", str(a), str(b), "--out", str(out)]) == 0
    note = (
        "its header names no fabric ('# fabric: ...'), the other files' do: compared with none of their "
        "curves (a panel 'fabric not named'); name its fabric to compare it"
    )
    assert f"ngbet normalise: {b}: {note}\n" in capsys.readouterr().err
    curves = json.loads((out / "normalise.json").read_text())["curves"]
    assert [note in c["notes"] for c in curves] == [False, True]
    c = _csv(tmp_path / "c.csv", SPEC.replace("# fabric: a glass twill\n", "") + "displacement_mm,force_N\n" + _body())
    assert main(["normalise", str(b), str(c), "--out", str(tmp_path / "m")]) == 0  # none names one: compared
    assert note not in capsys.readouterr().err


# --- what it says ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "head, line",
    [
        (
            "displacement_in,force_N",
            "the column 'displacement_in' (displacement): unknown unit 'in' (known: mm, cm, m)",
        ),
        ("displacement_mm,force_mN", "the column 'force_mN' (force): unknown unit 'mN' (known: N, kN)"),
        ("Displacement (mm),Force (gf)", "the column 'Force (gf)' (force): unknown unit 'gf' (known: N, kN)"),
    ],
)
def test_an_unknown_unit_is_named_with_the_units_it_knows_as_users_write_them(tmp_path, head, line):
    p = _csv(tmp_path / "a.csv", head + "\n" + _body())
    assert _err(read_measured, p).startswith(f"{p}, line 1: {line}; convert the column to one of them")


def test_a_force_without_a_unit_lists_the_known_units_as_users_write_them(tmp_path):
    p = _csv(tmp_path / "a.csv", "displacement_mm,force\n" + _body())
    assert "; units N, kN)" in _err(read_measured, p)
    assert _err(read_measured, p, columns="1:mm,2:lbf") == (
        "--columns '1:mm,2:lbf': unknown unit 'lbf' (known: mm, cm, m; deg, °, rad; N, kN; N/mm, N/m, kN/m)"
    )


def test_a_table_separated_by_spaces_is_read_and_said(tmp_path):
    p = _csv(tmp_path / "a.txt", "displacement_mm force_N\n" + _body(sep="  "))
    c = read_measured(p)
    np.testing.assert_allclose(c.force_N, F)
    assert c.notes == ("columns separated by spaces",)
    q = _csv(tmp_path / "b.txt", "Displacement (mm) Force [kN]\n" + _body(ROWS, sep=" "))
    np.testing.assert_allclose(read_measured(q).force_N, 1000 * F)
    r = _csv(tmp_path / "c.txt", "Crosshead (mm) Standard force (N)\n" + _body(sep=" "))
    assert _err(read_measured, r) == (
        f"{r}, line 2: 2 cells, the header (line 1) has 3 (columns separated by spaces: write each column "
        "name as one word, displacement_mm force_N)"
    )


def test_a_spreadsheet_is_refused_saying_to_export_it_as_csv_and_utf16_text_is_read(tmp_path):
    x = tmp_path / "curve.xlsx"
    x.write_bytes(b"PK\x03\x04\x14\x00\x00\x00\x00\x00[Content_Types].xml")
    assert _err(read_table, x) == (
        f"data file {x} is a spreadsheet workbook, not a text file: export it as CSV (comma- or "
        "semicolon-separated text)"
    )
    b = tmp_path / "bin.csv"
    b.write_bytes(b"displacement_mm,force_N\n1,\x002\n")
    assert _err(read_table, b).endswith(
        "is not a text file (holds NUL bytes): export it as CSV (comma- or semicolon-separated text)"
    )
    u = _csv(tmp_path / "u16.csv", "Displacement (mm)\tForce (N)\n" + _body(sep="\t"), "utf-16")
    t = read_table(u)
    np.testing.assert_allclose(t.y, F)
    assert t.notes[:2] == ("read as UTF-16 text", "columns separated by tabs")


def test_counts_of_one_are_said_in_the_singular(tmp_path):
    one = _csv(tmp_path / "one.csv", "displacement_mm,force_N\n2,1\n")
    assert _err(read_measured, one) == f"data file {one}: 1 row of numbers; at least 3 are needed"
    c = read_measured(_csv(tmp_path / "a.csv", SPEC + "displacement_mm,force_N\n" + _body()))
    assert _err(c.check_window, (0.0, 0.05)).startswith(
        f"{c.source}: the fitted range 2 to 3.9 mm holds 1 measured point;"
    )


# --- the collapse figure --------------------------------------------------------------------------------------------


def test_the_collapse_figure_tells_apart_curves_of_one_frame_size(tmp_path):
    """The plain weave's four frame curves (two laboratories, each the shear force and the paper's
    normalised curve): each legend entry names its laboratory and what the file gives."""
    from ngbet.figures.collapse import collapse_figure
    from ngbet.normalise import normalise_pf

    pf = sorted((DATA / "cao2008_pf").glob("cao2008_pf_plain_*.csv"))
    fig = collapse_figure([("", [normalise_pf(read_table(p)) for p in pf], "")], "one spread")
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels == [
        "picture frame, frame 216 mm, fabric 140 mm (UML), from F_s: Eq. 10",
        "picture frame, frame 216 mm, fabric 140 mm (UML), F_norm as given: Eq. 10",
        "picture frame, frame 145 mm, fabric 120 mm (UN), from F_s: Eq. 10",
        "picture frame, frame 145 mm, fabric 120 mm (UN), F_norm as given: Eq. 10",
    ]
    same = _csv(tmp_path / "x.csv", PF30.read_text())
    labels = [
        t.get_text()
        for t in collapse_figure([("", [normalise_pf(read_table(p)) for p in (PF30, same)], "")], "one spread")
        .axes[0]
        .get_legend()
        .get_texts()
    ]
    assert labels == [
        f"picture frame, frame 145 mm, fabric 120 mm (UN), {PF30.stem}: Eq. 10",
        "picture frame, frame 145 mm, fabric 120 mm (UN), x: Eq. 10",
    ]
