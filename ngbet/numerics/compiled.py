"""Compiling the energy integrand: interpreted, or native C++ reused across runs and processes.

``CoefficientFunction.Compile()`` flattens the expression tree into a program that NGSolve
interprets; ``Compile(realcompile=True)`` generates C++ for it and its first and second
derivatives, compiles it with NGSolve's ``ngscxx`` into a temporary folder, links it with
``ngsld`` and loads it. NGSolve keeps no such library after the process ends and caches nothing:
each process would pay the C++ compilation again. The generated code keeps the addresses of live
objects apart, in a small second source file, so the large file depends on the expression alone.

This module puts a caching ``ngscxx`` and ``ngsld`` in front of NGSolve's (on ``PATH`` while
compiling): the object file of a source is kept under :func:`cache_dir`, named by a SHA-256 of
the source (the expression, with its constants as literals) and what else determines the code
(:func:`code_key`: NGSolve's version and compiler flags, the compiler; not the cache's path), and
copied back when the same source comes again; its shared library (linked against NGSolve's
libraries) is kept beside it. Each kept file has a checksum file beside it (the SHA-256 of what
was built and the key it was built for), checked on the copy that is used: a file that does not
match (changed bytes, or another source's file under this key) is removed with an ``ngbet:`` line
on stderr and built again (``"auto"``: interpreted, as for a missing file). The address table is
compiled directly (no NGSolve headers) and linked alone, by ``ld`` without the C++ driver,
against a private copy of the cached library, whose address symbols bind to that table when
NGSolve loads it (two compiles of one source in a process keep apart).

``solver.compile``:

* ``"interpret"``: ``Compile()``.
* ``"native"``: ``Compile(realcompile=True, wait=True)`` through the cache (cold: the full C++
  compilation, once per integrand and NGSolve version); without a C++ compiler, or when it fails,
  the interpreted form with a warning.
* ``"auto"`` (default): by the size of the problem, since native code saves a time per dof in each
  linearization and residual and costs a setup (warm: code generation, loading, a link per
  library; cold: the compilation): interpreted below :data:`NATIVE_IF_CACHED` dofs; native from
  the cache (nothing compiled) up to :data:`NATIVE_COLD`; native, compiling if needed, above. Run
  once with ``"native"`` to fill the cache for a family of scenes. The measurements behind the two
  thresholds are in docs/numerics.md.

The constants of the energy (K_aug, the penalty K, the tabulated law's rises) are literals in the
generated code, so each set of them is its own source; the material values of
:mod:`ngbet.continuum.parameters` are Parameters, read at run time (a run with other K_el and α1
reuses the cached code). The tangent and the residual are the same either way to round-off (after
the element-wise condensation of the exact Lagrangian's Newton matrix, whose local blocks carry
K_aug, to the round-off that elimination amplifies).

Linearization (:func:`add_energy`). By default NGSolve's energy integrator gets the Hessian by
evaluating the integrand in second-order automatic differentiation, pair of trial components by
pair; with ``ngsglobals.symbolic_integrator_uses_diff`` it differentiates the expression once
per trial function, symbolically, when the integrator is built (read then only), and gets the
Hessian from first-order automatic differentiation of those derivatives: a faster assembly with
the same Hessian to round-off. Native, the derivatives of a compiled integrand are compiled too
(one more object per trial function: u's gradient, φ, ∇φ, Λ), through the same cache while the
integrator is built; cold, each derivative is a C++ compilation of its own.

The energy may come in parts, one integrator each (:func:`add_energy`). NGSolve's integrator
computes a block of the element matrix for every pair of trial functions its nonzero pattern
marks as coupled, and that pattern, propagated in a single direction, marks a pair as soon as
the integrand has a second derivative in either function: with all terms in one integrand
every pair was computed, zero blocks included. A part in fewer trial functions has fewer
pairs, at the price of one more pass over the element's integration points.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import ngsolve as ngs

__all__ = ["COMPILE_MODES", "NATIVE_COLD", "NATIVE_IF_CACHED", "add_energy", "cache_dir", "compile_energy"]

log = logging.getLogger(__name__)

COMPILE_MODES = ("auto", "interpret", "native")
#: "auto" uses cached native code from this many dofs on (a warm compile pays for itself)
NATIVE_IF_CACHED = 30_000
#: "auto" compiles native code from this many dofs on (a cold compile pays for itself in one run)
NATIVE_COLD = 500_000

_NGSCXX = """#!/bin/sh
# ngbet: object cache in front of NGSolve's ngscxx (called as: ngscxx -c SOURCE -o OBJECT). KEY hashes
# this wrapper's key and the source (the expression, its constants as literals); the object is kept as
# KEY.o beside KEY.o.sum ("<sha256 of the object> KEY"). A kept object is used only when its copy
# matches both; else the entry (and its library) is removed, and built again unless only cached code
# is asked for.
src="$2"; obj="$4"
if ! grep -q '#include' "$src"; then exec {cxx} -c -fPIC -x c++ "$src" -o "$obj"; fi
key=$(cat "$0.key" "$src" | sha256sum | cut -c1-40)
hit="{objects}/$key.o"
echo "$key" > "$obj.key"
if [ -f "$hit" ] && cp "$hit" "$obj"; then
  [ "$(sha256sum < "$obj" | cut -c1-64) $key" = "$(cat "$hit.sum" 2>/dev/null)" ] && exit 0
  echo "ngbet: native-code cache: $hit does not match its checksum; removed" >&2
  rm -f "$hit" "$hit.sum" "{objects}/$key.so" "{objects}/$key.so.sum" "$obj"
fi
if [ -n "$NGBET_CACHED_ONLY" ]; then exit 1; fi
{real} "$@" || exit $?
echo "$(sha256sum < "$obj" | cut -c1-64) $key" > "$hit.sum.$$" && cp "$obj" "$hit.$$" \\
  && mv "$hit.sum.$$" "$hit.sum" && mv "$hit.$$" "$hit"
"""

_NGSLD = """#!/bin/sh
# ngbet: NGSolve's ngsld (called as: ngsld -shared CODE.o TABLE.o -o LIBRARY -l...). The code's
# shared library is cached by the code object's key as KEY.so beside KEY.so.sum (as the objects) and
# copied beside LIBRARY; a copy that does not match is linked again. LIBRARY is the address table
# alone, linked without the C++ driver, with the copy as its dependency (the copy's address symbols
# bind to this table when LIBRARY is loaded). Any other call: the plain link.
if [ "$1" = -shared ] && [ "$4" = -o ] && [ -f "$2.key" ] && [ -n "{ld}" ]; then
  code="$2"; table="$3"; lib="$5"; shift 5
  key=$(cat "$code.key")
  so="{objects}/$key.so"
  dir=$(cd "$(dirname "$lib")" && pwd) || exit 1
  if [ -f "$so" ] && cp "$so" "$dir/code.so" \\
     && [ "$(sha256sum < "$dir/code.so" | cut -c1-64) $key" = "$(cat "$so.sum" 2>/dev/null)" ]; then
    exec {ld} -shared "$table" "$dir/code.so" -o "$lib"
  fi
  if [ -f "$so" ]; then
    echo "ngbet: native-code cache: $so does not match its checksum; linked again" >&2
    rm -f "$so" "$so.sum"
  fi
  {cxx} {args} -shared "$code" -o "$dir/code.so" "$@" || exit 1
  echo "$(sha256sum < "$dir/code.so" | cut -c1-64) $key" > "$so.sum.$$" && cp "$dir/code.so" "$so.$$" \\
    && mv "$so.sum.$$" "$so.sum" && mv "$so.$$" "$so"
  exec {ld} -shared "$table" "$dir/code.so" -o "$lib"
fi
exec {cxx} {args} "$@"
"""


def cache_dir() -> Path:
    """Where compiled objects are kept: ``$NGBET_CACHE_DIR`` or ``$XDG_CACHE_HOME/ngbet`` (~/.cache/ngbet)."""
    env = os.environ.get("NGBET_CACHE_DIR")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ngbet"


def _compiler() -> tuple[str, str] | None:
    """NGSolve's ngscxx and a C++ compiler, or None when either is missing."""
    real = shutil.which("ngscxx") or _beside_python("ngscxx")
    cxx = shutil.which("c++") or shutil.which("g++")
    return (real, cxx) if real and cxx else None


def _beside_python(name: str) -> str | None:
    p = Path(sys.executable).parent / name
    return str(p) if p.exists() else None


def _write(path: Path, text: str) -> None:
    if path.exists() and path.read_text() == text:
        return
    tmp = path.with_suffix(f".{os.getpid()}")
    tmp.write_text(text)
    tmp.chmod(tmp.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    tmp.replace(path)


def code_key(real: str, cxx: str) -> str:
    """What determines the code built from a source, as a SHA-256: the key of every cache entry.

    The NGSolve version (its headers and ABI), the text of its ``ngscxx`` (the compiler flags),
    the bytes of the C++ driver (one per compiler release) and the caching protocol (the wrappers'
    templates). Not where the cache or the installation lives, nor ngbet's version: a cache
    copied elsewhere, or used by another environment or a reinstall with the same NGSolve and
    compiler, hands out the same code.
    """
    h = hashlib.sha256()
    h.update(ngs.__version__.encode())
    h.update(Path(real).read_bytes())
    h.update(Path(cxx).resolve().read_bytes())
    h.update((_NGSCXX + _NGSLD).encode())
    return h.hexdigest()


def _wrappers(real: str, cxx: str) -> Path:
    """The folder with the caching ngscxx and the direct ngsld (created on first use).

    One folder per installation (named by a hash of the wrappers' text, which holds its paths):
    processes of different environments sharing a cache never rewrite each other's wrappers. The
    objects they keep are named by :func:`code_key` and the source alone.
    """
    import ngsolve.config as cfg

    root = cache_dir() / "native"
    objects = root / "objects"
    wrapper = _NGSCXX.format(cxx=cxx, objects=objects, real=real)
    ngsld = _NGSLD.format(cxx=cxx, args=cfg.get_link_lib_args(), objects=objects, ld=shutil.which("ld") or "")
    key = code_key(real, cxx)
    bins = root / "bin" / hashlib.sha256((key + wrapper + ngsld).encode()).hexdigest()[:16]
    bins.mkdir(parents=True, exist_ok=True)
    objects.mkdir(parents=True, exist_ok=True)
    _write(bins / "ngscxx.key", key + "\n")
    _write(bins / "ngscxx", wrapper)
    _write(bins / "ngsld", ngsld)
    return bins


@contextlib.contextmanager
def _on_path(bins: Path, cached_only: bool) -> Iterator[None]:
    """The environment of NGSolve's compile: the caching wrappers first, and a temporary directory of its own.

    NGSolve compiles each expression in a folder of its own under the temporary directory and
    removes it only in the interpreter's teardown, never after a failed compilation (an expression
    that "auto" does not find in the cache); a run's process ends without that teardown
    (:func:`ngbet.watch.end_run_process`). Here every compilation of the block goes into one
    folder (``TMPDIR``), removed when the block ends however it ends: the libraries are loaded by
    then (``wait=True``), and a loaded library stays mapped after its file is gone.
    """
    from .._env import environ

    # NGSolve's ngscxx asks `python3` for its include flags: this interpreter's first
    path = os.pathsep.join([str(bins), str(Path(sys.executable).parent), os.environ.get("PATH", "")])
    scratch = tempfile.mkdtemp(prefix="ngbet-compile-")
    try:
        with environ({"PATH": path, "TMPDIR": scratch, **({"NGBET_CACHED_ONLY": "1"} if cached_only else {})}):
            yield
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _add_variation(form: ngs.BilinearForm, compiled: ngs.CoefficientFunction, dx: Any, symbolic: bool) -> None:
    """``form += Variation(compiled * dx)``; ``symbolic``: the integrator differentiates symbolically."""
    before = ngs.ngsglobals.symbolic_integrator_uses_diff
    ngs.ngsglobals.symbolic_integrator_uses_diff = symbolic
    try:
        form += ngs.Variation(compiled * dx)
    finally:
        ngs.ngsglobals.symbolic_integrator_uses_diff = before


def add_energy(
    form: ngs.BilinearForm,
    parts: ngs.CoefficientFunction | Sequence[ngs.CoefficientFunction],
    dx: Any,
    mode: str,
    ndof: int = 0,
    linearized: bool = True,
) -> str:
    """Compile the energy as ``solver.compile`` asks (:func:`compile_energy`) and add it to ``form``.

    ``parts`` (one integrand, or several that sum to the energy) become one ``Variation`` each.
    Returns the mode used ("interpret" or "native"; the parts are all native or all interpreted).
    A form that is ``linearized`` gets symbolic derivatives: interpreted, the integrator
    differentiates the expression when it is built; native, it also compiles the first
    derivatives (one object per trial function, through the cache, while the integrator is
    built). A form used only for residuals and energies keeps the integrands' own compiled
    derivatives (``Apply`` does not use the symbolic ones).
    """
    parts = [parts] if isinstance(parts, ngs.CoefficientFunction) else list(parts)
    compiled = [compile_energy(cf, mode, ndof) for cf in parts]
    if any(used == "interpret" for _, used in compiled):  # not native throughout: none native
        for (c, used), cf in zip(compiled, parts, strict=True):
            _add_variation(form, c if used == "interpret" else cf.Compile(), dx, symbolic=linearized)
        return "interpret"
    tools = _compiler()
    assert tools is not None  # compile_energy found them
    # a derivative that cannot be compiled (or, for "auto", is not in the cache) leaves the
    # integrator with automatic differentiation of the compiled integrand: the same tangent
    with _on_path(_wrappers(*tools), cached_only=mode == "auto"):
        for cf, _ in compiled:
            _add_variation(form, cf, dx, symbolic=linearized)
    return "native"


def compile_energy(cf: ngs.CoefficientFunction, mode: str, ndof: int = 0) -> tuple[ngs.CoefficientFunction, str]:
    """``cf`` compiled as ``solver.compile`` asks; returns it and the mode used ("interpret" or "native").

    ``ndof`` (the problem's size) decides for "auto". Native compilation that cannot be done (no
    compiler; for "auto" below :data:`NATIVE_COLD` dofs: an object not in the cache; a failed
    compilation) falls back to the interpreted form with a log line.
    """
    if mode == "auto" and ndof >= NATIVE_COLD:
        mode = "native"
    if mode == "interpret" or (mode == "auto" and ndof < NATIVE_IF_CACHED):
        return cf.Compile(), "interpret"
    tools = _compiler()
    if tools is None:
        if mode == "native":
            log.warning("solver.compile = 'native': no C++ compiler or ngscxx found; the energy is interpreted")
        return cf.Compile(), "interpret"
    try:
        with _on_path(_wrappers(*tools), cached_only=mode == "auto"):
            return cf.Compile(realcompile=True, wait=True), "native"
    except Exception as err:  # NGSolve raises on a failed compile or link (or an uncached one for "auto")
        level = logging.WARNING if mode == "native" else logging.INFO
        log.log(
            level,
            "native compilation %s (%s); the energy is interpreted",
            "not in the cache" if mode == "auto" else "failed",
            err,
        )
        return cf.Compile(), "interpret"
