"""Measured curves as laboratories write them: the one reader (fit, run --data, normalise) and ``ngbet normalise``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ngbet.cli import main
from ngbet.figures.data import Measured
from ngbet.kinematics import force_from_normalised, shear_angle_rad
from ngbet.measured.curves import read_all, read_measured
from ngbet.measured.table import parse_sizes, read_table
from ngbet.normalise import energy_method
from ngbet.scene.validate import SceneError

DATA = Path(__file__).resolve().parents[1] / "data"
TWINTEX = sorted(p for p in (DATA / "cao2008").glob("cao2008_*.csv") if not p.stem.endswith("_errorbars"))
SPEC = "# specimen.width_mm = 100\n# specimen.length_mm = 250\n"
ROWS = [(2.0 * k, 0.5 * k + 0.01 * k * k) for k in range(1, 21)]  # u [mm], F [N]: increasing, 20 rows


def _csv(path: Path, text: str, encoding: str = "utf-8") -> Path:
    path.write_text(text, encoding=encoding)
    return path


def _body(rows=ROWS, sep=",", fmt="{:g}", scale=(1.0, 1.0), comma=False) -> str:
    def num(v: float) -> str:
        s = fmt.format(v)
        return s.replace(".", ",") if comma else s

    return "".join(f"{num(u * scale[0])}{sep}{num(F * scale[1])}\n" for u, F in rows)


U = np.array([r[0] for r in ROWS])
F = np.array([r[1] for r in ROWS])


# --- units and columns by name --------------------------------------------------------------------------------------


def test_a_force_in_kN_is_converted_to_newtons_and_said(tmp_path):
    c = read_measured(_csv(tmp_path / "a.csv", "displacement_mm,force_kN\n" + _body(scale=(1, 1e-3))))
    np.testing.assert_allclose(c.force_N, F, rtol=1e-12)
    assert any("force_kN" in n and "kN" in n and "x 1000" in n for n in c.notes)


def test_a_displacement_in_metres_is_converted_to_mm_and_said(tmp_path):
    c = read_measured(_csv(tmp_path / "a.csv", "displacement_m,force_N\n" + _body(scale=(1e-3, 1), fmt="{:.6g}")))
    np.testing.assert_allclose(c.u_mm, U, rtol=1e-12)
    assert any("displacement_m" in n and "converted to mm" in n for n in c.notes)


def test_three_columns_are_chosen_by_name_not_position_and_the_extra_one_is_ignored(tmp_path):
    body = "".join(f"{k * 0.1:g},{F[k]},{U[k]}\n" for k in range(len(U)))  # force before displacement
    c = read_measured(_csv(tmp_path / "a.csv", "time_s,force_N,displacement_mm\n" + body))
    np.testing.assert_allclose(c.u_mm, U)
    np.testing.assert_allclose(c.force_N, F)
    assert any("ignored: 'time_s'" in n for n in c.notes)
    body = "".join(f"{k * 0.1:g},{U[k]},{F[k] / 1000}\n" for k in range(len(U)))
    c = read_measured(_csv(tmp_path / "b.csv", "time_s,displacement_mm,force_kN\n" + body))
    np.testing.assert_allclose(c.force_N, F, rtol=1e-12)


def test_an_excel_export_with_semicolons_and_decimal_commas_is_read(tmp_path):
    text = "Displacement (mm);Force (N)\n" + _body(sep=";", comma=True)
    c = read_measured(_csv(tmp_path / "a.csv", text))
    np.testing.assert_allclose(c.u_mm, U)
    np.testing.assert_allclose(c.force_N, F)
    assert any("semicolons" in n and "decimal commas" in n for n in c.notes)
    c2 = read_measured(_csv(tmp_path / "b.csv", "Displacement (mm),Force [kN]\n" + _body(scale=(1, 1e-3))))
    np.testing.assert_allclose(c2.force_N, F, rtol=1e-12)


def test_a_row_of_units_under_the_names_is_read(tmp_path):
    c = read_measured(
        _csv(
            tmp_path / "a.csv",
            "Standard force;Crosshead\nkN;mm\n" + "".join(f"{f / 1000:.9g};{u:g}\n".replace(".", ",") for u, f in ROWS),
        )
    )
    np.testing.assert_allclose(c.force_N, F, rtol=1e-9)
    np.testing.assert_allclose(c.u_mm, U)


def test_columns_are_chosen_on_the_command_line_by_name_or_number_with_units(tmp_path):
    p = _csv(
        tmp_path / "a.csv",
        "Zeitpunkt;Weg;Kraft\n"
        + "".join(f"{k};{u:g};{f / 1000:.9g}\n".replace(".", ",") for k, (u, f) in enumerate(ROWS)),
    )
    with pytest.raises(SceneError, match="--columns"):
        read_measured(p)  # 'Weg' and 'Kraft' carry no unit: refused, not guessed
    c = read_measured(p, columns="Weg:mm,Kraft:kN")
    np.testing.assert_allclose(c.force_N, F, rtol=1e-9)
    c = read_measured(p, columns="2:mm,3:kN")
    np.testing.assert_allclose(c.u_mm, U)


@pytest.mark.parametrize(
    "head, match",
    [
        ("x,y", "none of which is a displacement and a force"),
        ("displacement,force_N", "gives no unit"),
        ("displacement_mm,force_lbf", "force_lbf"),  # an unknown unit is named, not read as N
        ("displacement_mm,force_N,load_kN", "2 columns could be the force"),
    ],
)
def test_ambiguous_or_unitless_columns_are_refused_saying_what_to_write(tmp_path, head, match):
    extra = ",1" if head.count(",") == 2 else ""
    text = head + "\n" + "".join(f"{u:g},{f:g}{extra}\n" for u, f in ROWS)
    with pytest.raises(SceneError, match=match):
        read_measured(_csv(tmp_path / "a.csv", text))


def test_a_thousands_separator_is_refused_as_ambiguous(tmp_path):
    with pytest.raises(SceneError, match="ambiguous"):
        read_measured(_csv(tmp_path / "a.csv", 'displacement_mm,force_N\n1,"1,234"\n2,3\n3,4\n'))


# --- text forms ------------------------------------------------------------------------------------------------------


def test_quoted_cells_and_a_bom_are_read_by_fit_and_by_run_data_alike(tmp_path):
    quoted = '"displacement_mm","force_N"\n' + "".join(f'"{u:g}","{f:g}"\n' for u, f in ROWS)
    for p in (
        _csv(tmp_path / "q.csv", quoted),
        _csv(tmp_path / "bom.csv", "displacement_mm,force_N\n" + _body(), "utf-8-sig"),
    ):
        c = read_measured(p)
        m = Measured.read(p)
        np.testing.assert_allclose(c.force_N, F)
        np.testing.assert_allclose(m.force_N, F)


def test_a_windows_1252_file_is_read_and_said(tmp_path):
    p = _csv(tmp_path / "a.csv", "# Prüfung\nDisplacement (mm);Force (N)\n" + _body(sep=";", comma=True), "cp1252")
    assert "Windows-1252" in " ".join(read_measured(p).notes)


# --- the specimen ----------------------------------------------------------------------------------------------------


def test_specimen_keys_written_with_a_unit_are_read_not_dropped(tmp_path):
    p = _csv(
        tmp_path / "a.csv",
        "# specimen.width_mm = 100 mm\n# specimen.length = 0.25 m\n# thickness_mm = 3.3\n"
        "displacement_mm,force_N\n" + _body(),
    )
    c = read_measured(p)
    assert c.specimen == {"specimen.width_mm": 100.0, "specimen.length_mm": 250.0, "specimen.thickness_mm": 3.3}
    m = Measured.read(p)
    assert (m.width_mm, m.length_mm) == (100.0, 250.0)


def test_the_specimen_from_the_command_line_and_its_conflict_with_the_header(tmp_path):
    plain = _csv(tmp_path / "a.csv", "displacement_mm,force_N\n" + _body())
    spec = parse_sizes("100x250", "--specimen", ("specimen.width_mm", "specimen.length_mm", "specimen.thickness_mm"))
    c = read_measured(plain, specimen=spec)
    assert c.label == "100 x 250 mm" and any("--specimen" in n for n in c.notes)
    with_header = _csv(tmp_path / "b.csv", SPEC + "displacement_mm,force_N\n" + _body())
    with pytest.raises(SceneError, match="header says specimen.length_mm = 250, --specimen says 300"):
        read_measured(with_header, specimen={"specimen.width_mm": 100.0, "specimen.length_mm": 300.0})


@pytest.mark.parametrize(
    "text, match",
    [
        ("-100x250", "width -100: sizes must be > 0"),
        ("0x250", "width 0: sizes must be > 0"),
        ("100", "write sizes in mm joined by x"),
        ("100xabc", "write sizes in mm joined by x"),
    ],
)
def test_a_bad_specimen_on_the_command_line_is_refused(text, match):
    with pytest.raises(SceneError, match=match):
        parse_sizes(text, "--specimen", ("specimen.width_mm", "specimen.length_mm", "specimen.thickness_mm"))


@pytest.mark.parametrize(
    "header, match",
    [
        ("# specimen.width_mm = 100\n", "incomplete specimen.*no specimen.length_mm"),
        ("# specimen.width_mm = -100\n# specimen.length_mm = 250\n", "width_mm = -100 must be > 0"),
        ("# specimen.width_mm = 250\n# specimen.length_mm = 100\n", "length must exceed the width"),
        ("# specimen.width_mm = 100 s\n# specimen.length_mm = 250\n", "not a unit of a length"),
        ("# specimen.widht_mm = 100\n", "unknown key 'specimen.widht_mm'"),
        ("# specimen.width = 100\n# specimen.length_mm = 250\n", "gives no unit"),
    ],
)
def test_a_bad_or_incomplete_specimen_header_is_refused(tmp_path, header, match):
    with pytest.raises(SceneError, match=match):
        read_measured(_csv(tmp_path / "a.csv", header + "displacement_mm,force_N\n" + _body()))


# --- the shape of the curve ----------------------------------------------------------------------------------------


def test_a_loading_unloading_cycle_keeps_the_loading_branch_and_says_so(tmp_path):
    unloading = [(U[-1] - 3.0 * k, F[-1] * (1 - 0.2 * k)) for k in range(1, 5)]
    c = read_measured(_csv(tmp_path / "a.csv", "displacement_mm,force_N\n" + _body(ROWS + unloading)))
    np.testing.assert_allclose(c.u_mm, U)  # not the unloading sorted into the loading
    np.testing.assert_allclose(c.force_N, F)
    assert any("loading-unloading cycle" in n and "the 4 rows after it are left out" in n for n in c.notes)


def test_several_load_cycles_are_refused(tmp_path):
    cycles = ROWS[:10] + [(U[9] - 10.0, 1.0)] + ROWS[10:]
    with pytest.raises(SceneError, match="several load cycles"):
        read_measured(_csv(tmp_path / "a.csv", "displacement_mm,force_N\n" + _body(cycles)))


def test_the_same_file_or_the_same_curve_twice_is_refused(tmp_path):
    a = _csv(tmp_path / "a.csv", SPEC + "displacement_mm,force_N\n" + _body())
    with pytest.raises(SceneError, match="the same file twice"):
        read_all([a, tmp_path / "." / "a.csv"])
    b = _csv(tmp_path / "b.csv", SPEC + "displacement_mm,force_N\n" + _body())
    with pytest.raises(SceneError, match="the same measured curve twice"):
        read_all([a, b])


def test_a_fitted_window_of_too_few_measured_points_or_past_yarn_locking_is_refused(tmp_path):
    c = read_measured(_csv(tmp_path / "a.csv", SPEC + "displacement_mm,force_N\n" + _body()))
    with pytest.raises(SceneError, match="holds 1 measured point"):
        c.check_window((0.0, 0.05))  # 2.0 to 3.9 mm: the row at 2 mm only
    assert "holds 10 measured points" in c.check_window((0.0, 0.5))  # the fit samples 16: said
    assert c.check_window((0.1, 0.9)) is None
    narrow = read_measured(
        _csv(
            tmp_path / "b.csv",
            "# specimen.width_mm = 100\n# specimen.length_mm = 150\ndisplacement_mm,force_N\n" + _body(),
        )
    )  # locks at 20.7 mm; data to 40 mm
    with pytest.raises(SceneError, match="beyond the ideal yarn locking"):
        narrow.check_window((0.1, 0.9))


def test_a_picture_frame_file_is_not_taken_for_a_bias_extension_curve():
    with pytest.raises(SceneError, match="picture-frame curve"):
        read_measured(DATA / "cao2008_pf" / "cao2008_pf_plain_UN_fig22_shear_force.csv")


def test_the_test_and_the_frame_are_read_from_the_header(tmp_path):
    t = read_table(DATA / "cao2008_pf" / "cao2008_pf_plain_UN_fig22_shear_force.csv")
    assert (t.test, t.x_quantity, t.y_quantity) == ("picture_frame", "shear_angle", "shear_force")
    assert t.frame == {"picture_frame.frame_mm": 145.0, "picture_frame.fabric_mm": 120.0}  # Table 3 (UN)
    p = _csv(
        tmp_path / "a.csv",
        "# test: picture_frame\n# picture_frame.frame_mm = 145\n"
        "# picture_frame.fabric_mm = 12 cm\ndisplacement_mm,force_N\n" + _body(),
    )
    assert read_table(p).frame == {"picture_frame.frame_mm": 145.0, "picture_frame.fabric_mm": 120.0}
    with pytest.raises(SceneError, match="header says test picture_frame, --test says bias_extension"):
        read_table(p, test="bias_extension")


def test_the_laboratory_and_the_fabric_are_read_from_the_header(tmp_path):
    """The laboratory from the most explicit line that names it, the fabric from a line of its own or
    after a semicolon; "" where the header says nothing (the reader never guesses from the file name)."""
    bet = read_table(DATA / "cao2008" / "cao2008_twill_unbalanced_100x250_UN.csv")
    assert bet.laboratory == "UN" and bet.fabric.startswith("Twintex TPECU53XXX 2/2 twill")
    pf = read_table(DATA / "cao2008_pf" / "cao2008_pf_plain_UML_fig22_shear_force.csv")  # legend label and Table 3
    assert pf.laboratory == "UML" and pf.fabric == "plain weave, Twintex TPEET22XXX (glass/PP commingled), Table 1"
    body = "displacement_mm,force_N\n" + _body()
    cases = {
        '# curve: legend label "KUL"\n# laboratory: TUD; 2 tests\n': "TUD",  # the explicit line wins
        "# Table 3 (KUL): frame 216 mm, fabric 140 mm\n# test: picture_frame\n": "KUL",
        '# legend label "Nottingham"\n': "Nottingham",
        "# fabric: a glass twill\n": "",
    }
    for k, (head, lab) in enumerate(cases.items()):
        t = read_table(_csv(tmp_path / f"h{k}.csv", head + body))
        assert t.laboratory == lab
    assert read_table(_csv(tmp_path / "h4.csv", "# fabric: a glass twill\n" + body)).fabric == "a glass twill"
    assert read_table(_csv(tmp_path / "h5.csv", body)).fabric == ""


# --- a machine export of every shipped Twintex curve ------------------------------------------------------------------


def _machine_export(src: Path, dst: Path) -> Path:
    """The curve as a testing machine's Excel export: semicolons, decimal commas, kN, the specimen with units."""
    c = read_measured(src)
    w, L = c.specimen["specimen.width_mm"], c.specimen["specimen.length_mm"]
    rows = "".join(
        f"{k * 0.1:.1f};{u:.6f};{f / 1000:.9f}\n".replace(".", ",")
        for k, (u, f) in enumerate(zip(c.u_mm, c.force_N, strict=True))
    )
    dst.write_text(
        f"# specimen.width_mm = {w:g} mm\n# specimen.length_mm = {L:g} mm\n"
        f'"Time (s)";"Displacement (mm)";"Standard force (kN)"\n{rows}',
        encoding="utf-8-sig",
    )
    return dst


@pytest.mark.parametrize("src", TWINTEX, ids=lambda p: p.stem)
def test_a_machine_export_of_each_shipped_twintex_curve_reads_back_to_the_same_numbers(tmp_path, src):
    ref = read_measured(src)
    c = read_measured(_machine_export(src, tmp_path / src.name))
    np.testing.assert_allclose(c.u_mm, ref.u_mm, rtol=0, atol=5e-7)  # written to 1e-6 mm
    np.testing.assert_allclose(c.force_N, ref.force_N, rtol=0, atol=5e-7)  # to 1e-9 kN
    assert c.label == ref.label


# --- ngbet normalise ---------------------------------------------------------------------------------------------


def test_eq18_and_the_energy_method_recover_a_known_normalised_shear_force():
    """A curve made from F_sh(γ) = a tan γ + b γ by Eq. 18 inverted: both methods give the law back.

    Eq. 18 inverts :func:`force_from_normalised` (the same interpolation of F_sh(γ/2)): measured
    4.5e-8 relative. The energy method integrates the force and differentiates the energy, a
    second-order route: measured 2.8e-4 with 2000 points to 50 mm (γ to 51°) on 100 x 250 mm.
    """
    H, W = 250.0, 100.0
    d = np.linspace(0.025, 50.0, 2000)
    g_table = np.linspace(1e-4, 1.3, 4000)
    law = 0.02 * np.tan(g_table) + 0.01 * g_table
    F_curve = force_from_normalised(g_table, law, d, H, W)
    from ngbet.kinematics import normalised_shear_force

    gamma, fsh = normalised_shear_force(d, F_curve, H, W)
    _, _, fsh_e = energy_method(d, F_curve, H, W)
    exact = 0.02 * np.tan(gamma) + 0.01 * gamma
    inside = gamma > np.radians(5)
    assert np.max(np.abs(fsh / exact - 1)[inside]) < 1e-6
    assert np.max(np.abs(fsh_e / exact - 1)[inside]) < 1e-3


def test_the_energy_method_is_the_work_of_the_clamp_force():
    """The zones' energy A_A w(γ) + A_B w(γ/2) equals ∫F dd at every point (the equation it solves)."""
    H, W = 200.0, 100.0
    d = np.linspace(0.5, 35.0, 300)
    force = 3.0 * d + 0.05 * d**2
    gamma, w, _ = energy_method(d, force, H, W)
    half = np.interp(gamma / 2, np.r_[0.0, gamma], np.r_[0.0, w])
    work = np.r_[0.0, np.cumsum(np.diff(d) * 0.5 * (force[1:] + force[:-1]))] + 0.5 * d[0] * force[0]
    np.testing.assert_allclose((2 * H * W - 3 * W * W) / 2 * w + W * W * half, work, rtol=1e-9)


def _table(path: Path) -> np.ndarray:
    """A table of ngbet normalise: '#' lines, the header, numbers."""
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    return np.genfromtxt(lines, delimiter=",", names=True)


def _normalise(*args: str) -> int:
    return main(["normalise", *args])


def test_normalise_picture_frame_eq10_of_the_shear_force_gives_the_papers_normalised_curve(tmp_path, capsys):
    """Cao et al. 2008: Fig. 22's F_s (UN, plain) through Eq. 10 is Fig. 28's F_norm, read from another plot.

    Measured over 10-47°: (max - min)/mean at most 4.5 % (at 11°, where the curves are steep), median 0.3 %
    (two digitised plots of one test; their reading error is 0.01 N and 2e-4 N/mm).
    """
    pf = DATA / "cao2008_pf"
    out = tmp_path / "pf"
    assert (
        _normalise(
            str(pf / "cao2008_pf_plain_UN_fig22_shear_force.csv"),
            str(pf / "cao2008_pf_plain_UN_fig28_normalized_energy.csv"),
            "--out",
            str(out),
        )
        == 0
    )
    summary = json.loads((out / "normalise.json").read_text())
    s = summary["spread"]["the picture frames"]
    assert s["max_percent"] < 5.0 and s["median_percent"] < 0.5
    assert "between the picture frames" in capsys.readouterr().out


def test_normalise_picture_frame_from_crosshead_displacement_and_force(tmp_path):
    """Eqs. 1-3 and 10 on a raw frame curve: F = 2 cos θ F_s for a known F_s(γ) comes back as F_s and F_norm."""
    L, Lf = 145.0, 120.0
    d = np.linspace(1.0, 60.0, 40)
    theta = np.arccos((math.sqrt(2) * L + d) / (2 * L))
    gamma = 90 - 2 * np.degrees(theta)
    fs = 5.0 * gamma + 0.02 * gamma**2
    p = _csv(
        tmp_path / "raw.csv",
        "# test: picture-frame\ncrosshead_mm;load_kN\n"
        + "".join(f"{a:.9g};{b / 1000:.12g}\n" for a, b in zip(d, 2 * np.cos(theta) * fs, strict=True))
        + "90;0,5\n",
    )  # beyond (2 - √2) L = 84.94 mm the frame is folded (Eq. 1): left out and said
    out = tmp_path / "o"
    assert _normalise(str(p), "--frame", "145x120", "--out", str(out)) == 0
    assert json.loads((out / "normalise.json").read_text())["curves"][0]["notes"][-1] == (
        "1 point outside the frame's displacements from 0 to 84.94 mm (Eq. 1) left out"
    )
    rows = _table(out / "raw_normalised.csv")
    np.testing.assert_allclose(rows["shear_angle_deg"], gamma, rtol=1e-5)
    np.testing.assert_allclose(rows["shear_force_N"], fs, rtol=1e-5)
    np.testing.assert_allclose(rows["fnorm_N_per_mm"], fs * L / Lf**2, rtol=1e-5)


def test_normalise_the_twintex_sizes_states_their_spread(tmp_path, capsys):
    """The unbalanced twill's two sizes (one laboratory): measured 70 % at most, 16 % median, over 10-70°."""
    files = [str(DATA / "cao2008" / f"cao2008_twill_unbalanced_100x{L}_UN.csv") for L in (200, 250)]
    out = tmp_path / "n"
    assert _normalise(*files, "--out", str(out)) == 0
    text = (out / "normalise.json").read_text()
    summary = json.loads(text, parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))
    s = summary["spread"]["the bias extension sizes"]
    assert s["max_percent"] == pytest.approx(70.1, abs=0.5) and s["median_percent"] == pytest.approx(15.6, abs=0.5)
    assert (s["from_deg"], s["to_deg"]) == (10.0, 70.0)
    assert "differs by up to 70 %" in capsys.readouterr().out
    assert sorted(summary["files"]) == sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    table = _table(out / "cao2008_twill_unbalanced_100x250_UN_normalised.csv")
    d = table["displacement_mm"]
    np.testing.assert_allclose(table["shear_angle_deg"], np.degrees(shear_angle_rad(d, 250.0, 100.0)), rtol=1e-5)


def test_normalise_a_machine_export_needs_no_more_than_the_file(tmp_path):
    src = DATA / "cao2008" / "cao2008_twill_unbalanced_100x200_UN.csv"
    p = _machine_export(src, tmp_path / "export.csv")
    assert _normalise(str(p), "--out", str(tmp_path / "o")) == 0
    a = _table(tmp_path / "o" / "export_normalised.csv")
    assert _normalise(str(src), "--out", str(tmp_path / "r")) == 0
    b = _table(tmp_path / "r" / f"{src.stem}_normalised.csv")
    np.testing.assert_allclose(a["fsh_eq18_N_per_mm"], b["fsh_eq18_N_per_mm"], rtol=1e-4, atol=1e-7)


def test_normalise_owns_its_folder(tmp_path, capsys):
    a = _csv(tmp_path / "a.csv", SPEC + "displacement_mm,force_N\n" + _body())
    b = _csv(
        tmp_path / "b.csv",
        "# specimen.width_mm = 100\n# specimen.length_mm = 300\ndisplacement_mm,force_N\n"
        + _body([(u, 1.1 * f) for u, f in ROWS]),
    )
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    assert _normalise(str(a), "--out", str(user)) == 3  # not an ngbet folder: refused, untouched
    assert [p.name for p in user.iterdir()] == ["notes.txt"]
    out = tmp_path / "o"
    assert _normalise(str(a), str(b), "--out", str(out)) == 0
    assert (out / "b_normalised.csv").exists()
    assert _normalise(str(a), "--out", str(out)) == 0  # the earlier set's tables do not stay beside the new one
    assert not (out / "b_normalised.csv").exists() and (out / "a_normalised.csv").exists()
    (out / "b_normalised.csv").write_text("the user's")
    assert _normalise(str(b), "--out", str(out)) == 3  # a file of its name that it did not write: refused
    assert (out / "b_normalised.csv").read_text() == "the user's"
    run = tmp_path / "run"
    run.mkdir()
    (run / ".ngbet.lock").write_text(json.dumps({"ngbet": "run folder", "pid": 1, "files": ["results.csv"]}))
    (run / "results.csv").write_text("u0_mm\n1\n")
    assert _normalise(str(a), "--out", str(run)) == 3  # a run's folder: refused, its files kept
    assert (run / "results.csv").read_text() == "u0_mm\n1\n"
    assert "an ngbet run folder" in capsys.readouterr().err


@pytest.mark.parametrize(
    "extra, files, match",
    [
        ([], ["a"], "which test"),  # neither a specimen nor a frame
        (["--specimen", "100x250", "--specimen", "100x300"], ["a"], "2 --specimen for 1 data files"),
        (["--specimen", "100x140"], ["a"], "Eq. 18 needs a clamp-to-clamp length above 1.5 times the width"),
        (["--test", "picture_frame"], ["a"], "needs the frame and the fabric square"),
        (["--specimen", "100x250"], ["a", "a"], "the same file twice"),
    ],
)
def test_normalise_refuses_what_it_cannot_normalise_before_writing(tmp_path, capsys, extra, files, match):
    _csv(tmp_path / "a.csv", "displacement_mm,force_N\n" + _body())
    out = tmp_path / "o"
    assert _normalise(*[str(tmp_path / f"{f}.csv") for f in files], *extra, "--out", str(out)) == 2
    assert match in capsys.readouterr().err
    assert not out.exists()


# --- the commands: refused before any model run ----------------------------------------------------------------------


def test_fit_refuses_an_incomplete_specimen_or_a_curve_twice_before_any_model_run(tmp_path, capsys):
    half = _csv(tmp_path / "half.csv", "# specimen.width_mm = 100\ndisplacement_mm,force_N\n" + _body())
    assert main(["fit", str(half), "--params", "material.K_sh", "--out", str(tmp_path / "f")]) == 2
    assert "incomplete specimen" in capsys.readouterr().err
    a = _csv(tmp_path / "a.csv", SPEC + "displacement_mm,force_N\n" + _body())
    assert main(["fit", str(a), str(a), "--params", "material.K_sh", "--out", str(tmp_path / "f")]) == 2
    assert "the same file twice" in capsys.readouterr().err
    assert main(["fit", str(a), "--range", "0:3", "--params", "material.K_sh", "--out", str(tmp_path / "f")]) == 2
    assert "holds 1 measured point" in capsys.readouterr().err
    b = _csv(tmp_path / "b.csv", "displacement_mm,force_N\n" + _body())  # no specimen: fitted on the scene's
    assert main(["fit", str(b), "--range", "0:3", "--params", "material.K_sh", "--out", str(tmp_path / "f")]) == 2
    assert "holds 1 measured point" in capsys.readouterr().err


def test_fit_reads_a_kn_export_with_the_specimen_from_the_command_line(tmp_path):
    from ngbet.calibration.command import Inputs
    from ngbet.cli import _parser

    p = _csv(
        tmp_path / "a.csv", "Displacement (mm);Force (kN)\n" + _body(sep=";", scale=(1, 1e-3), comma=True, fmt="{:.9g}")
    )
    inp = Inputs(
        _parser("fit").parse_args(
            ["fit", str(p), "--specimen", "100x250", "--params", "material.K_sh", "--out", str(tmp_path / "f")]
        )
    )  # everything read, no model run
    np.testing.assert_allclose(inp.curves[0].force_N, F, rtol=1e-9)
    assert inp.curves[0].label == "100 x 250 mm"
    notes = " ".join(inp.notes)
    assert "converted to N" in notes and "specimen.width_mm = 100 from --specimen" in notes


@pytest.mark.parametrize(
    "header, extra, match",
    [
        ("# specimen.width_mm = -100\n# specimen.length_mm = 250\n", [], "width_mm = -100 must be > 0"),
        ("", ["--specimen=-100x250"], "sizes must be > 0"),
        (SPEC, ["--set", "outputs.plot=false"], "outputs.plot = false draws none"),
    ],
)
def test_run_data_refuses_a_bad_specimen_or_figures_that_are_not_drawn(tmp_path, capsys, header, extra, match):
    p = _csv(tmp_path / "m.csv", header + "displacement_mm,force_N\n" + _body())
    out = tmp_path / "run"
    assert main(["run", "--data", str(p), *extra, "--out", str(out)]) == 2
    assert match in capsys.readouterr().err
    assert not out.exists()


def test_error_bar_files_given_with_their_curves_are_left_out_and_alone_are_refused(tmp_path, capsys):
    """``data/cao2008/*.csv`` names each curve and its NAME_errorbars.csv: the bars are no curve.

    Given with its curve, an error-bar file is left out (said); alone, it is refused naming the
    curve to give; a curve that only carries such a name is read as any curve.
    """
    from ngbet.calibration.command import Inputs
    from ngbet.cli import _parser

    files = sorted(str(p) for p in (DATA / "cao2008").glob("cao2008_twill_unbalanced_*.csv"))
    assert len(files) == 4 and sum(f.endswith("_errorbars.csv") for f in files) == 2
    out = tmp_path / "n"
    assert _normalise(*files, "--out", str(out)) == 0
    assert len(json.loads((out / "normalise.json").read_text())["curves"]) == 2
    assert capsys.readouterr().err.count("not a curve: left out") == 2
    inp = Inputs(_parser("fit").parse_args(["fit", *files, "--params", "material.K_sh", "--out", str(tmp_path / "f")]))
    assert [c.label for c in inp.curves] == ["100 x 200 mm", "100 x 250 mm"]
    assert all(c.bars is not None for c in inp.curves)  # the bars weight the points all the same
    assert sum("the error bars of" in n for n in inp.notes) == 2

    curve, bars = files[:2]
    assert bars == curve.removesuffix(".csv") + "_errorbars.csv"
    for cmd in (
        ["normalise", bars, "--out", str(tmp_path / "m")],
        ["run", "--data", bars, "--out", str(tmp_path / "r")],
    ):
        assert main(cmd) == 2
        assert f"not a curve: give {curve};" in capsys.readouterr().err
    assert not (tmp_path / "m").exists() and not (tmp_path / "r").exists()
    named = _csv(tmp_path / "own_errorbars.csv", SPEC + "displacement_mm,force_N\n" + _body())
    np.testing.assert_allclose(read_table(named).y, F)


def test_normalise_states_the_spread_of_each_fabric_and_draws_a_panel_each(tmp_path, capsys):
    """The three fabrics' curves (data/cao2008/*.csv and the frames): each fabric's spreads are its
    own curves' (the unbalanced twill's two sizes: 70 % at most, 16 % median, as alone), none across
    fabrics; a frame joins its fabric by the style code its header shares with the bias extension
    curves' ("TPEET22XXX"); the figure has one panel per fabric, inside its canvas."""
    from ngbet.figures.collapse import collapse_figure
    from ngbet.figures.style import texts_outside
    from ngbet.measured.header import fabric_names
    from ngbet.normalise import normalise_bet, normalise_pf, spread_text, spreads

    files = sorted((DATA / "cao2008").glob("*.csv")) + sorted((DATA / "cao2008_pf").glob("*.csv"))
    out = tmp_path / "n"
    assert _normalise(*map(str, files), "--out", str(out)) == 0
    groups = json.loads((out / "normalise.json").read_text())["spread"]
    twill = "Twintex TPECU53XXX 2/2 twill"
    assert sorted(groups) == sorted(
        f"the {what} of {fabric}"
        for fabric, whats in (
            ("Twintex TPEET22XXX plain weave", ("bias extension sizes", "picture frames", "tests")),
            ("Twintex TPEET44XXX 2/2 twill", ("bias extension sizes", "tests")),
            (twill, ("bias extension sizes", "tests")),
        )
        for what in whats
    )
    alone = groups[f"the bias extension sizes of {twill}"]
    assert alone["max_percent"] == pytest.approx(70.1, abs=0.5) and alone["median_percent"] == pytest.approx(
        15.6, abs=0.5
    )
    assert f"between the tests of {twill}" in capsys.readouterr().out

    curves = [normalise_bet(f) for f in files[:12] if not f.stem.endswith("_errorbars")]
    curves += [normalise_pf(read_table(f)) for f in files[12:]]
    names = fabric_names([c.fabric for c in curves])
    assert len(set(names)) == 3 and names.count("Twintex TPEET22XXX plain weave") == 6
    assert fabric_names([c.fabric for c in curves[:2]]) == ["", ""]  # one fabric: no names
    groups = {n: [c for c, m in zip(curves, names, strict=True) if m == n] for n in dict.fromkeys(names)}
    fig = collapse_figure([(n, mine, spread_text(spreads(mine))) for n, mine in groups.items()], "")
    assert len(fig.axes) == 3 and texts_outside(fig) == []
    assert len(collapse_figure([("", curves[:2], "one spread")], "one spread").axes) == 1
