"""compas-tna: thrust network analysis, plan fixed.

TNA in its two steps. Horizontal: the force diagram (the form diagram's dual) is made parallel to
the form diagram by ``horizontal_nodal`` with ``alpha=100``, i.e. the form's own edges are the
targets and the plan stays put; the horizontal force densities are q = l_force / l_form. Vertical:
``vertical_from_zmax`` scales them so that the highest free vertex is as high as the target's,
solving the heights under the fixed loads (``density=0``: no self-weight of its own).
"""
from __future__ import annotations

import time

import numpy as np
from runner_io import fail, installed_version, parse_args, read_problem, write_result

TOOL = "compas-tna"
#: parallelisation sweeps of the horizontal step (compas-tna's default is 100)
KMAX = 100


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    try:
        from compas_form import form_diagram, read_back
        from compas_tna.diagrams import ForceDiagram
        from compas_tna.equilibrium import horizontal_nodal, vertical_from_zmax

        P = read_problem(args.problem)
        V, E, L = P["vertices"], P["edges"], P["loads"]
        sup = np.zeros(len(V), bool)
        sup[P["supports"]] = True
        t0 = time.perf_counter()
        # compas-tna's pz is the load's magnitude, positive down (its self-weight adds
        # +area·t·density): minus the problem's signed load
        form, _ = form_diagram(P, -L)
        force = ForceDiagram.from_formdiagram(form)
        horizontal_nodal(form, force, alpha=100, kmax=KMAX)
        zmax = float(V[~sup, 2].max())
        form, scale = vertical_from_zmax(form, zmax, density=0.0)
        elapsed = time.perf_counter() - t0
        # compas-tna's q > 0 is compression with pz > 0 down: the same as our w. Edges it dropped
        # (between supports) carry 0.
        X, w = read_back(form, P)
        write_result(args.result, tool=TOOL, version=installed_version(TOOL), status="done",
                     message=f"horizontal_nodal alpha=100 kmax={KMAX}; vertical_from_zmax zmax={zmax:.4g}, scale {scale:.4g}",
                     time_s=elapsed, vertices=X, edges=E, weights=w)
    except Exception as exc:  # one failed row, not a crashed study
        fail(args.result, TOOL, exc)


if __name__ == "__main__":
    main()
