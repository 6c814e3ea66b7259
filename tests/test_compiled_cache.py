"""The native-code cache checks what it hands out: each kept object and library is used only when
its copy matches the checksum recorded beside it when it was built, for the key it is kept under;
anything else (changed bytes, another source's code under this key) is removed and built again.

The wrappers are run with stand-ins for NGSolve's compiler, the C++ driver and ``ld`` (shell
scripts that write what they were given and count their calls), so that every path through the
cache is exercised in milliseconds; ``test_native_code_from_a_tampered_cache_is_rebuilt`` does the
same with NGSolve's real compiler."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from ngbet.numerics import compiled

FAKE_NGSCXX = """#!/bin/sh
# stand-in for NGSolve's ngscxx -c SOURCE -o OBJECT: the object names its source's text
echo x >> "$(dirname "$0")/compiles"
{ echo "object of:"; cat "$2"; } > "$4"
"""
FAKE_CXX = """#!/bin/sh
# stand-in for the C++ driver's -shared CODE -o LIBRARY: the library names its code
echo x >> "$(dirname "$0")/links"
while [ "$#" -gt 0 ]; do case "$1" in -o) out="$2"; shift;; *.o) code="$1";; esac; shift; done
{ echo "library of:"; cat "$code"; } > "$out"
"""
FAKE_LD = """#!/bin/sh
# stand-in for ld -shared TABLE CODE.so -o LIBRARY: the library holds the code library it binds to
{ echo "table library over:"; cat "$3"; } > "$5"
"""


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """The caching wrappers over the stand-ins, in a fresh cache; returns (bins, objects, tools)."""
    tools = tmp_path / "tools"
    tools.mkdir()
    for name, text in (("ngscxx", FAKE_NGSCXX), ("c++", FAKE_CXX), ("ld", FAKE_LD)):
        (tools / name).write_text(text)
        (tools / name).chmod(0o755)
    monkeypatch.setenv("NGBET_CACHE_DIR", str(tmp_path / "cache"))
    which = compiled.shutil.which
    monkeypatch.setattr(compiled.shutil, "which", lambda n: str(tools / "ld") if n == "ld" else which(n))
    bins = compiled._wrappers(str(tools / "ngscxx"), str(tools / "c++"))
    return bins, tmp_path / "cache" / "native" / "objects", tools


def _count(tools: Path, what: str) -> int:
    f = tools / what
    return len(f.read_text().splitlines()) if f.exists() else 0


def _compile(bins: Path, source: Path, obj: Path, cached_only: bool = False) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "NGBET_CACHED_ONLY"}
    if cached_only:
        env["NGBET_CACHED_ONLY"] = "1"
    return subprocess.run(
        ["sh", str(bins / "ngscxx"), "-c", str(source), "-o", str(obj)], env=env, capture_output=True, text=True
    )


def _source(tmp_path: Path, name: str, constant: float) -> Path:
    src = tmp_path / f"{name}.cpp"
    src.write_text(f"#include <comp.hpp>\ndouble K = {constant};\n")
    return src


def _entry(objects: Path, obj: Path) -> Path:
    """The cache's object for the object file ``obj`` just compiled (named by its key)."""
    return objects / (obj.with_name(obj.name + ".key").read_text().strip() + ".o")


def test_a_kept_object_is_used_while_it_matches_its_checksum(tmp_path, cache):
    bins, objects, tools = cache
    src = _source(tmp_path, "a", 1.0)
    first = _compile(bins, src, tmp_path / "1.o")
    assert first.returncode == 0 and first.stderr == ""
    assert _count(tools, "compiles") == 1
    again = _compile(bins, src, tmp_path / "2.o", cached_only=True)  # "auto": from the cache only
    assert again.returncode == 0 and again.stderr == ""
    assert _count(tools, "compiles") == 1  # not compiled again
    assert (tmp_path / "2.o").read_bytes() == (tmp_path / "1.o").read_bytes()
    entry = _entry(objects, tmp_path / "1.o")
    digest, key = entry.with_name(entry.name + ".sum").read_text().split()
    assert key == entry.stem and len(digest) == 64


@pytest.mark.parametrize("cached_only", [False, True])
def test_an_object_with_changed_bytes_is_removed_and_built_again(tmp_path, cache, cached_only):
    bins, objects, tools = cache
    src = _source(tmp_path, "a", 1.0)
    _compile(bins, src, tmp_path / "1.o")
    entry = _entry(objects, tmp_path / "1.o")
    data = bytearray(entry.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte
    entry.write_bytes(bytes(data))
    p = _compile(bins, src, tmp_path / "2.o", cached_only=cached_only)
    assert p.stderr.splitlines() == [f"ngbet: native-code cache: {entry} does not match its checksum; removed"]
    if cached_only:  # "auto" interprets: nothing compiled, nothing handed out, the entry gone
        assert p.returncode == 1 and not (tmp_path / "2.o").exists() and not entry.exists()
    else:
        assert p.returncode == 0 and _count(tools, "compiles") == 2
        assert (tmp_path / "2.o").read_bytes() == entry.read_bytes() == (tmp_path / "1.o").read_bytes()
    assert _count(tools, "compiles") == (1 if cached_only else 2)


def test_another_sources_object_under_this_key_is_not_used(tmp_path, cache):
    """Two entries renamed into each other's keys, checksum files and all: both are valid objects,
    built from other constants; each is refused for the key it now has, and built again."""
    bins, objects, tools = cache
    a, b = _source(tmp_path, "a", 1.0), _source(tmp_path, "b", 2.0)
    _compile(bins, a, tmp_path / "a.o")
    _compile(bins, b, tmp_path / "b.o")
    ea, eb = _entry(objects, tmp_path / "a.o"), _entry(objects, tmp_path / "b.o")
    for suffix in ("", ".sum"):
        fa, fb = Path(f"{ea}{suffix}"), Path(f"{eb}{suffix}")
        tmp = fa.with_name("swap")
        fa.rename(tmp)
        fb.rename(fa)
        tmp.rename(fb)
    p = _compile(bins, a, tmp_path / "a2.o")
    assert p.returncode == 0 and "does not match its checksum" in p.stderr
    assert (tmp_path / "a2.o").read_text() == "object of:\n" + a.read_text()  # K = 1.0, not 2.0
    assert _count(tools, "compiles") == 3


def _link(bins: Path, code: Path, tmp_path: Path, name: str) -> subprocess.CompletedProcess:
    out = tmp_path / name
    out.mkdir()
    table = tmp_path / "table.o"
    table.write_text("addresses\n")
    return subprocess.run(
        ["sh", str(bins / "ngsld"), "-shared", str(code), str(table), "-o", str(out / "lib.so"), "-lngsolve"],
        capture_output=True,
        text=True,
    )


def test_a_kept_library_with_changed_bytes_is_linked_again(tmp_path, cache):
    bins, objects, tools = cache
    src = _source(tmp_path, "a", 1.0)
    _compile(bins, src, tmp_path / "1.o")
    assert _link(bins, tmp_path / "1.o", tmp_path, "l1").returncode == 0
    kept = _entry(objects, tmp_path / "1.o").with_suffix(".so")
    assert _count(tools, "links") == 1 and kept.exists()
    assert _link(bins, tmp_path / "1.o", tmp_path, "l2").returncode == 0
    assert _count(tools, "links") == 1  # the kept library, copied beside the second
    kept.write_bytes(kept.read_bytes().replace(b"K = 1.0", b"K = 7.0"))
    p = _link(bins, tmp_path / "1.o", tmp_path, "l3")
    assert p.returncode == 0
    assert p.stderr.splitlines() == [f"ngbet: native-code cache: {kept} does not match its checksum; linked again"]
    assert _count(tools, "links") == 2
    expected = "library of:\nobject of:\n" + src.read_text()
    assert (tmp_path / "l3" / "code.so").read_text() == kept.read_text() == expected
    assert (tmp_path / "l3" / "lib.so").read_text() == "table library over:\n" + expected


# ------------------------------------------------------------------------ with NGSolve's compiler
ENERGY = """
import sys
import ngsolve as ngs
from ngbet.numerics import compiled
k = float(sys.argv[1])
fes = ngs.H1(ngs.Mesh(ngs.unit_square.GenerateMesh(maxh=0.5)), order=1)
u = fes.TrialFunction()
g = ngs.GridFunction(fes)
g.Set(ngs.x * ngs.y)
cf = k * u * u + ngs.sqrt(1 + ngs.Grad(u) * ngs.Grad(u))
native, mode = compiled.compile_energy(cf, "native", 10)
energies = []
for c in (native, cf.Compile()):
    form = ngs.BilinearForm(fes)
    form += ngs.Variation(c * ngs.dx)
    energies.append(form.Energy(g.vec))
print(mode, *energies)
"""


def _native_energy(k: float, env: dict[str, str]) -> tuple[str, float, float, str]:
    """In a new process: the mode, the native and the interpreted energy of k u² + sqrt(1 + |∇u|²), stderr."""
    p = subprocess.run([sys.executable, "-c", ENERGY, str(k)], env=env, capture_output=True, text=True, check=True)
    mode, native, interpreted = p.stdout.split()
    return mode, float(native), float(interpreted), p.stderr


@pytest.mark.slow
@pytest.mark.skipif(compiled._compiler() is None, reason="needs a C++ compiler and NGSolve's ngscxx")
def test_native_code_from_a_tampered_cache_is_rebuilt(tmp_path):
    """Two integrands that differ in a constant, compiled natively in one cache; their objects and
    libraries renamed into each other's keys with their checksum files: a new process compiles
    each again (with a line saying so) and gets its own energy, not the other's."""
    env = {**os.environ, "NGBET_CACHE_DIR": str(tmp_path)}
    objects = tmp_path / "native" / "objects"
    keys = []
    for k in (1.0, 3.0):
        before = set(objects.glob("*.o")) if objects.exists() else set()
        mode, native, interpreted, _ = _native_energy(k, env)
        assert mode == "native" and native == pytest.approx(interpreted, rel=1e-14)
        (new,) = set(objects.glob("*.o")) - before  # one object per integrand
        keys.append(new.stem)
    for ext in (".o", ".o.sum", ".so", ".so.sum"):
        a, b = objects / f"{keys[0]}{ext}", objects / f"{keys[1]}{ext}"
        a.rename(tmp_path / "swap")
        b.rename(a)
        (tmp_path / "swap").rename(b)
    for k, key in zip((1.0, 3.0), keys, strict=True):
        mode, native, interpreted, err = _native_energy(k, env)
        assert mode == "native" and native == pytest.approx(interpreted, rel=1e-14)
        assert f"ngbet: native-code cache: {objects / key}.o does not match its checksum; removed" in err


def test_a_copied_cache_is_used_where_it_is_copied_to(tmp_path, cache, monkeypatch):
    """The key is what determines the code (source, NGSolve, compiler), not the cache's path nor the
    installation's: a cache copied elsewhere, read through wrappers of another installation of the
    same compiler, hands out its object without compiling."""
    bins, objects, tools = cache
    src = _source(tmp_path, "a", 1.0)
    assert _compile(bins, src, tmp_path / "1.o").returncode == 0
    import shutil

    shutil.copytree(tmp_path / "cache", tmp_path / "copied")
    shutil.rmtree(tmp_path / "cache")
    other = tmp_path / "other-installation"
    shutil.copytree(tools, other)
    monkeypatch.setenv("NGBET_CACHE_DIR", str(tmp_path / "copied"))
    bins2 = compiled._wrappers(str(other / "ngscxx"), str(other / "c++"))
    assert bins2 != bins
    p = _compile(bins2, src, tmp_path / "2.o", cached_only=True)
    assert p.returncode == 0 and p.stderr == ""
    assert (tmp_path / "2.o").read_bytes() == (tmp_path / "1.o").read_bytes()
    assert _count(tools, "compiles") == 1 and _count(other, "compiles") == 1  # the copy of the count: none new


def test_another_compiler_or_ngsolve_is_another_key(tmp_path, cache, monkeypatch):
    """Code built by one compiler, or for one NGSolve version, is not handed to another."""
    _, _, tools = cache
    real, cxx = str(tools / "ngscxx"), str(tools / "c++")
    key = compiled.code_key(real, cxx)
    assert compiled.code_key(real, cxx) == key
    newer = tmp_path / "c++-newer"
    newer.write_text((tools / "c++").read_text() + "# another release\n")
    assert compiled.code_key(real, str(newer)) != key
    flags = tmp_path / "ngscxx-flags"
    flags.write_text((tools / "ngscxx").read_text().replace("#!/bin/sh", "#!/bin/sh\n# -O2"))
    assert compiled.code_key(str(flags), cxx) != key
    monkeypatch.setattr(compiled.ngs, "__version__", "0.0.0")
    assert compiled.code_key(real, cxx) != key
