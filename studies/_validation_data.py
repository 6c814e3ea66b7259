"""The measured curves of the validation study: the fabrics' own, and every other curve of them found.

Each Twintex fabric of Cao et al. (2008) has a scene and the curves its fits use (:data:`FABRICS`).
The study predicts every curve of a fabric that a fit does not use: the fabrics' own, every other
curve in ``data/cao2008/`` and ``data/cao2008_pf/``, and the curves in the folders or files given
with ``--data`` (:func:`find_curves`). A curve belongs to the fabric whose style code its header's
``fabric:`` line names (:data:`STYLES`, e.g. ``# fabric: Twintex TPEET22XXX plain weave``; without
a code, the weave in words: "unbalanced", "balanced ... twill", "plain"), and comes
from the laboratory its header names (``# laboratory: UN``, ``# Table 3 (UN): ...`` or ``legend label
"UN"``): both read by ngbet's one reader of measured curves (:mod:`ngbet.measured`), which also
gives the test, the specimen or the frame. A file the reader refuses, or whose fabric is none of
the study's, is not predicted, and the study says so (:attr:`Curves.skipped`); so is a ``--data``
curve that no fit of the study as run predicts (:attr:`Curves.given`, said by
:func:`ngbet.studies.validation.build`).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ngbet.measured.table import curve_files

__all__ = ["DATA_FOLDERS", "FABRICS", "STYLES", "Curves", "data_root", "find_curves"]

log = logging.getLogger(__name__)

#: fabric: (scene, the bias-extension curves its fits use (data/cao2008/), the picture-frame curves
#: (data/cao2008_pf/): each laboratory's frame is fitted alone, from its normalised-force figure)
FABRICS: dict[str, tuple[str, tuple[str, ...], tuple[str, ...]]] = {
    "plain": (
        "twintex_plain.toml",
        ("cao2008_plain_150x300_INSA-NU.csv", "cao2008_plain_150x450_INSA-NU.csv"),
        (
            "cao2008_pf_plain_UML_fig28_normalized_energy.csv",
            "cao2008_pf_plain_UN_fig28_normalized_energy.csv",
            "cao2008_pf_plain_UML_fig22_shear_force.csv",
            "cao2008_pf_plain_UN_fig22_shear_force.csv",
        ),
    ),
    "twill_balanced": (
        "twintex_twill_balanced.toml",
        ("cao2008_twill_balanced_150x300_INSA-NU.csv", "cao2008_twill_balanced_150x450_INSA-NU.csv"),
        ("cao2008_pf_twill_balanced_UML_fig29_normalized_energy.csv",),
    ),
    "twill_unbalanced": (
        "twintex_twill_unbalanced.toml",
        ("cao2008_twill_unbalanced_100x250_UN.csv", "cao2008_twill_unbalanced_100x200_UN.csv"),
        ("cao2008_pf_twill_unbalanced_UN_fig30_normalized_energy.csv",),
    ),
}
#: the style code of each fabric (paper, Table 1), as a data file's ``fabric:`` header line names it
STYLES = {"plain": "TPEET22", "twill_balanced": "TPEET44", "twill_unbalanced": "TPECU53"}
#: the folders of data/ the study reads
DATA_FOLDERS = ("cao2008", "cao2008_pf")


def data_root() -> Path:
    """The source tree holding the fabric scenes (geometry/) and their measured curves (data/).

    The clone this module is in (``studies/`` of the source tree, an editable install), else the
    copies installed with ngbet (``ngbet/geometry``, ``ngbet/data``), else the current directory.
    """
    import ngbet

    for root in (Path(__file__).resolve().parents[1], Path(ngbet.__file__).resolve().parent, Path.cwd()):
        if (root / "data" / "cao2008").is_dir() and (root / "geometry" / "twintex_plain.toml").is_file():
            return root
    from ngbet.scene.validate import SceneError

    raise SceneError(
        "study validation reads the fabric scenes geometry/twintex_*.toml and their measured curves "
        "data/cao2008/ and data/cao2008_pf/, installed with ngbet: not found beside the studies, in the "
        f"installed package {Path(ngbet.__file__).resolve().parent} nor in the current directory "
        f"{Path.cwd()} (reinstall ngbet)"
    )


@functools.cache
def _read(path: Path) -> Any:
    from ngbet.measured.curves import read_any

    return read_any(path)


@dataclass(frozen=True)
class Curves:
    """The study's curves: each file's name and path, each fabric's names, what was not taken and why.

    Names are file names (unique over the folders read); ``of[fabric]`` lists the fabric's own curves
    (:data:`FABRICS`) first, then the others in the order found (data/'s folders, then ``extra``,
    each folder's files sorted by name); ``given`` the names of those taken from ``extra`` (``--data``).
    """

    paths: dict[str, Path]
    of: dict[str, tuple[str, ...]]
    skipped: tuple[str, ...] = ()
    given: tuple[str, ...] = ()

    def read(self, name: str) -> Any:
        """The measured curve of ``name`` (:func:`ngbet.measured.curves.read_any`; read once per process)."""
        return _read(self.paths[name])

    def lab(self, name: str) -> str:
        """The laboratory the curve's header names ("?" where it names none)."""
        return str(self.read(name).laboratory) or "?"

    def is_frame(self, name: str) -> bool:
        """Whether the curve is of a picture-frame test (its header's test)."""
        return bool(self.read(name).test == "picture_frame")


#: where a fabric line names no style code: the weave in words (the first that matches)
WORDS = (("twill_unbalanced", ("unbalanced",)), ("twill_balanced", ("balanced", "twill")), ("plain", ("plain",)))


def _fabric(curve: Any) -> str | None:
    """The fabric a header's fabric line names: by style code, else by the weave in words; None if neither."""
    text = str(curve.fabric).lower()
    hits = [f for f, code in STYLES.items() if code.lower() in text]
    if hits:
        return hits[0] if len(hits) == 1 else None
    return next((f for f, words in WORDS if all(w in text for w in words)), None)


def _files(where: Path) -> list[Path]:
    if where.is_file():
        return [where]
    if not where.is_dir():
        from ngbet.scene.validate import SceneError

        raise SceneError(f"--data {where}: no such file or folder")
    return sorted(Path(p) for p in curve_files(list(where.glob("*.csv")))[0])


def find_curves(extra: Sequence[str | Path] = ()) -> Curves:
    """The fabrics' own curves, every other curve of them in data/ and in ``extra`` (folders or files).

    Refused (SceneError): a fabric's own curve that is missing or unreadable, an ``extra`` path
    that does not exist, two different files of one name. Not taken, with the reason in
    ``skipped`` and a warning: a file the reader refuses, or whose header names none of the
    fabrics of :data:`STYLES` (or more than one).
    """
    from ngbet.scene.validate import SceneError

    data = data_root() / "data"
    paths: dict[str, Path] = {}
    of: dict[str, list[str]] = {f: [] for f in FABRICS}
    for fabric, (_, bet, pf) in FABRICS.items():
        for name in (*bet, *pf):
            paths[name] = data / DATA_FOLDERS[name.startswith("cao2008_pf_")] / name
            of[fabric].append(name)
    skipped, given = [], []
    found = [(p, False) for f in DATA_FOLDERS for p in _files(data / f)]
    found += [(p, True) for e in extra for p in _files(Path(e))]
    for p, from_extra in found:
        if p.name in paths:
            if paths[p.name].resolve() != p.resolve():
                raise SceneError(f"two data files named {p.name}: {paths[p.name]} and {p}; rename one")
            continue
        try:
            which = _fabric(_read(p))
        except SceneError as exc:
            skipped.append(str(exc) if str(p) in str(exc) else f"{p}: {exc}")
            continue
        if which is None:
            skipped.append(
                f"{p}: its header's fabric line ('# fabric: ...') names none of the study's fabrics "
                f"({', '.join(f'{c}XXX' for c in STYLES.values())}, or plain weave, balanced or unbalanced "
                "twill) or more than one"
            )
            continue
        paths[p.name] = p
        of[which].append(p.name)
        given += [p.name] * from_extra
    for s in skipped:
        log.warning("study validation does not predict %s", s)
    return Curves(paths, {f: tuple(v) for f, v in of.items()}, tuple(skipped), tuple(given))
