"""Prototype: per-element orders rising with the distance from the clamp corners, default scene at 37 mm.

    python docs/research/hp_prototype.py CORNER_MM P_MIN P_MAX [SLOPE_DIST_MM] [--uniform]

The mesh is the 20 mm mesh graded by Netgen to CORNER_MM at the four clamp corners. The order of an
element is p_min + (p_max - p_min) * log2(d / c) / log2(D / c), rounded and clamped, where d is the
distance of its centroid from the nearest corner, c the corner size and D the distance at which p_max is
reached (default 5 mm). u and phi take the element order inside each element and the larger order of the two
neighbours on each edge (a conforming space holding P_p on every element); the multiplier is
Discontinuous(H1) of order p - 2 inside and the smaller neighbour's p - 2 on the edges (LAMEDGE=max: the
larger; measured: the force changes by 1e-6 N), so p_min >= 3. --uniform gives every element p_max (it
reproduces the uniform-order force: 61.252553 N at 0.125 mm, p = 4). EXTRA='{"loading.min_step_mm": ...}'
adds scene changes. Prints one JSON line: the last converged load, its force, the dofs.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import ngsolve as ngs

from ngbet.continuum import problem as P
from ngbet.run import run
from ngbet.studies import _common as C

ARGS = sys.argv[1:]
CORNER, PMIN, PMAX = float(ARGS[0]), int(ARGS[1]), int(ARGS[2])
DIST = float(ARGS[3]) if len(ARGS) > 3 and not ARGS[3].startswith("--") else 5.0
UNIFORM = "--uniform" in ARGS


def orders(mesh: ngs.Mesh, L: float, W: float) -> list[int]:
    out = []
    c, D = CORNER * 1e-3, DIST * 1e-3
    corners = ((0.0, 0.0), (L, 0.0), (0.0, W), (L, W))
    for el in mesh.Elements(ngs.VOL):
        pts = [mesh.vertices[v.nr].point for v in el.vertices]
        cx, cy = sum(p[0] for p in pts) / 3, sum(p[1] for p in pts) / 3
        d = min(math.hypot(cx - a, cy - b) for a, b in corners)
        t = math.log2(max(d, c) / c) / math.log2(D / c)
        if os.environ.get("MU"):  # a fixed rise of the order per halving of the distance
            t = float(os.environ["MU"]) * math.log2(max(d, c) / c) / (PMAX - PMIN)
        out.append(PMAX if UNIFORM else max(PMIN, min(PMAX, round(PMIN + (PMAX - PMIN) * t))))
    return out


def _spaces(self, scene, dirichlet):  # noqa: ANN001
    sp = scene.specimen
    po = orders(self.mesh, sp.L, sp.W)
    self.field_names = scene.effects.fields
    self.full_as_mixed = False
    self.p_lam = scene.discretization.p_lam
    pm = max(po)
    u = ngs.VectorH1(self.mesh, order=pm, dirichlet=dirichlet)
    phi = ngs.H1(self.mesh, order=pm, dirichlet=dirichlet)
    lam = ngs.H1(self.mesh, order=pm - 2)
    emax: dict[int, int] = {}
    emin: dict[int, int] = {}
    for i, p in enumerate(po):
        el = self.mesh[ngs.ElementId(ngs.VOL, i)]
        for e in el.edges:
            emax[e.nr] = max(emax.get(e.nr, 0), p)
            emin[e.nr] = min(emin.get(e.nr, 99), p)
        f = ngs.NodeId(ngs.FACE, el.faces[0].nr) if hasattr(el, "faces") and el.faces else None
        for s, q in ((u, p), (phi, p), (lam, p - 2)):
            s.SetOrder(f if f is not None else ngs.NodeId(ngs.FACE, i), q)
    for nr in emax:
        u.SetOrder(ngs.NodeId(ngs.EDGE, nr), emax[nr])
        phi.SetOrder(ngs.NodeId(ngs.EDGE, nr), emax[nr])
        lam.SetOrder(ngs.NodeId(ngs.EDGE, nr), (emax if os.environ.get("LAMEDGE") == "max" else emin)[nr] - 2)
    for s in (u, phi, lam):
        s.Update()
    self.X = ngs.FESpace([u, phi, ngs.Discontinuous(lam)])
    self.element_orders = po


P.ContinuumProblem._spaces = _spaces

scene = C.base_scene(
    False,
    **{
        **C.lagrange(20.0, PMAX, CORNER),
        "outputs.error_estimate": "off",
        "loading.u0_mm": 37.0,
        "loading.stops_mm": [],
        **json.loads(os.environ.get("EXTRA", "{}")),
    },
)
t0 = time.perf_counter()
with tempfile.TemporaryDirectory() as d:
    try:
        res = run(scene, Path(d))
        status = "ok"
    except Exception as e:  # noqa: BLE001
        res, status = {}, f"failed: {e}"[:300]
        print(status)
    rows = (Path(d) / "results.csv").read_text().splitlines()
    summ = json.loads((Path(d) / "summary.json").read_text()) if (Path(d) / "summary.json").exists() else {}
head = rows[0].split(",")
last = dict(zip(head, rows[-1].split(","), strict=False))
print(
    json.dumps(
        {
            "corner": CORNER,
            "pmin": PMIN,
            "pmax": PMAX,
            "D": DIST,
            "uniform": UNIFORM,
            "status": status,
            "u0": float(last["u0_mm"]),
            "F": float(last["force_N"]),
            "dofs": summ.get("dofs"),
            "wall": round(time.perf_counter() - t0, 1),
        }
    )
)
