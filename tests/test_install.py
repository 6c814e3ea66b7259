"""What an install gives: the version and git revision setuptools-scm records at build time, and
what every command still does when the plotting packages (matplotlib, pyvista) are missing."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import types
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _recorded(monkeypatch, version: str | None, commit: str | None) -> tuple[str, str]:
    """ngbet.revision's reading of a ``_version.py`` with these values (None for version: no file)."""
    from ngbet import revision

    fake = None
    if version is not None:
        fake = types.ModuleType("ngbet._version")
        fake.__version__, fake.__commit_id__ = version, commit  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "ngbet._version", fake)
    return revision._recorded()


@pytest.mark.parametrize(
    ("version", "commit", "expected"),
    [
        ("0.1.dev296+gbc21ef198", "gbc21ef198", ("0.1.dev296+gbc21ef198", "bc21ef198")),
        ("0.1.dev296+gbc21ef198.d20261125", "gbc21ef198", ("0.1.dev296+gbc21ef198.d20261125", "bc21ef198-dirty")),
        ("0.2.0", "g0123abcd", ("0.2.0", "0123abcd")),  # a tagged release: the commit still named
        ("0.1.dev0+gabc1234", None, ("0.1.dev0+gabc1234", "abc1234")),  # SETUPTOOLS_SCM_PRETEND_VERSION
        ("0.1.dev0", None, ("0.1.dev0", "unknown")),  # no git metadata: the fallback version
        (None, None, ("unknown", "unknown")),  # sources never built
    ],
)
def test_the_revision_is_read_from_what_setuptools_scm_wrote(monkeypatch, version, commit, expected):
    assert _recorded(monkeypatch, version, commit) == expected


def test_version_and_revision_on_the_command_line():
    import ngbet

    v = subprocess.run([sys.executable, "-m", "ngbet", "--version"], capture_output=True, text=True, check=True)
    assert v.stdout.strip() == f"ngbet {ngbet.__version__} (git revision {ngbet.__revision__})"


def _sources(tmp_path: Path) -> Path:
    """A copy of ngbet's sources without git metadata, as a container's build context holds them."""
    if not (ROOT / "ngbet" / "__init__.py").exists() or not (ROOT / "pyproject.toml").exists():
        pytest.skip("the sources are not beside the tests (tests run against an installed package)")
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, src / name)
    for pkg in ("ngbet", "studies", "data", "geometry"):  # installed as ngbet.studies, ngbet.data, ngbet.geometry
        shutil.copytree(ROOT / pkg, src / pkg, ignore=shutil.ignore_patterns("__pycache__", "_version.py"))
    return src


def _wheel(src: Path, out: Path, **env: str) -> tuple[str, dict[str, object]]:
    """Build a wheel of ``src`` (no isolation: setuptools-scm is in the test extra); its version and _version.py."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("SETUPTOOLS_SCM_")}
    env = {**clean, "SETUPTOOLS_SCM_WRITE_TO_SOURCE": "0", **env}
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(out), str(src)],
        check=True,
        capture_output=True,
        env=env,
    )
    (wheel,) = out.glob("ngbet-*.whl")
    ns: dict[str, object] = {}
    with zipfile.ZipFile(wheel) as z:
        exec(z.read("ngbet/_version.py").decode(), ns)
    return wheel.name.split("-")[1], ns


@pytest.mark.integration
def test_sources_without_git_build_with_the_fallback_version(tmp_path):
    version, ns = _wheel(_sources(tmp_path), tmp_path / "w1")
    assert version == ns["__version__"] == "0.1.dev0" and ns["__commit_id__"] is None


@pytest.mark.integration
def test_sources_without_git_take_the_version_they_are_given(tmp_path):
    version, ns = _wheel(_sources(tmp_path), tmp_path / "w2", SETUPTOOLS_SCM_PRETEND_VERSION="0.1.dev0+gabc1234")
    assert version == ns["__version__"] == "0.1.dev0+gabc1234"


@pytest.mark.integration
def test_a_clone_builds_with_its_commit(tmp_path):
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    if head.returncode != 0 or not (ROOT / "pyproject.toml").exists():
        pytest.skip("the tests do not run from a git checkout of ngbet")
    clone = tmp_path / "clone"  # a clone of the checkout's HEAD: the build writes into its tree, not ROOT's
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True, capture_output=True)
    version, ns = _wheel(clone, tmp_path / "w3")
    commit = str(ns["__commit_id__"]).removeprefix("g")
    assert len(commit) >= 7 and head.stdout.strip().startswith(commit) and f"+g{commit}" in version


# ------------------------------------------------------------------ without matplotlib and pyvista
@pytest.fixture
def bare_env(tmp_path):
    """An environment whose Python processes (workers and the plot process too) find neither matplotlib
    nor pyvista: a sitecustomize module blocks both imports, as if they were not installed."""
    site = tmp_path / "site"
    site.mkdir()
    block = "import sys\nfor _m in ('matplotlib', 'pyvista'):\n    sys.modules[_m] = None\n"
    (site / "sitecustomize.py").write_text(block)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), *filter(None, [os.environ.get("PYTHONPATH")])])}
    for m in ("matplotlib", "pyvista"):
        probe = subprocess.run([sys.executable, "-c", f"import {m}"], env=env, capture_output=True, text=True)
        assert probe.returncode == 1 and "ModuleNotFoundError" in probe.stderr
    return env


RUN_AND_API = """
import sys
import ngbet
from ngbet.cli import main
code = main(["run", "--quiet", "--out", sys.argv[1], "--set", "discretization.mesh_size_mm=20",
             "--set", "loading.u0_mm=10", "--set", "loading.stops_mm=[]"])
r = ngbet.load_result(sys.argv[1])
for call in (r.plot, r.fields):
    try:
        call()
    except ImportError as exc:
        print("ImportError:", exc)
sys.exit(code)
"""


@pytest.mark.integration
def test_a_run_without_matplotlib_and_pyvista_writes_its_data_and_says_what_it_skipped(tmp_path, bare_env):
    out = tmp_path / "run"
    p = subprocess.run([sys.executable, "-c", RUN_AND_API, str(out)], env=bare_env, capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert p.stderr.splitlines() == ["ngbet: no figures: matplotlib is not installed (pip install matplotlib)"]
    assert {"results.csv", "profile.csv", "summary.json", "fields.vtu", "scene.toml"} <= {f.name for f in out.iterdir()}
    assert not (out / "force.png").exists()
    assert p.stdout.splitlines() == [  # nothing from the quiet run; clear errors from the API
        "ImportError: Result.plot() draws with matplotlib, which is not installed: pip install matplotlib",
        "ImportError: Result.fields() reads the VTU file with pyvista, which is not installed: pip install pyvista",
    ]


@pytest.mark.integration
def test_a_study_without_matplotlib_and_pyvista_writes_its_tables_and_report(tmp_path, bare_env):
    out = tmp_path / "alpha1"
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "ngbet",
            "study",
            "alpha1",
            "--quick",
            "--quiet",
            "--out",
            str(out),
            "--cache",
            str(tmp_path / "cache"),
        ],
        env=bare_env,
        capture_output=True,
        text=True,
    )
    assert p.returncode == 0, p.stderr
    assert p.stderr.splitlines() == [
        "ngbet: study alpha1: figures skipped: matplotlib is not installed "
        "(pip install matplotlib); the tables and the report are written"
    ]
    assert p.stdout == ""  # --quiet
    assert {"results.csv", "report.md", "meta.json"} <= {f.name for f in out.iterdir()}
    assert not list(out.glob("*.png"))
