"""compas-tno: thrust network optimisation, best fit with the plan fixed.

``Analysis.create_bestfit_analysis``: variables the force densities of the independent edges
(the rest follow from horizontal equilibrium of the fixed plan, QR) and the support heights;
objective Σ (z − z_target)² (``bestfit``); constraints ``funicular`` (q ≤ 0, compression in TNO's
sign) and ``envelope`` (lb ≤ z ≤ ub). Start: TNO's load-path optimum (a convex SDP through CVXPY
and Clarabel); solver: SciPy's SLSQP (IPOPT needs cyipopt, which compas-tno does not install).
The envelope is set ±half the bounding-box diagonal around the target, so that it does not bind
and the problem is the others' (no masonry hull). TNO's examples run on loads normalised to a
total of 1: the loads are divided by their total here and the force densities multiplied back.
"""
from __future__ import annotations

import time

import numpy as np
from runner_io import fail, installed_version, parse_args, read_problem, write_result

TOOL = "compas-tno"


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    try:
        from compas_form import form_diagram, read_back
        from compas_tna.envelope import MeshEnvelope
        from compas_tno.analysis import Analysis

        P = read_problem(args.problem)
        V, E, L = P["vertices"], P["edges"], P["loads"]
        scale = float(np.abs(L).sum())
        t0 = time.perf_counter()
        # TNO's pz is signed, negative down (its apply_hor_multiplier: "swt (pz) is negative")
        form, mesh = form_diagram(P, L / scale)
        half = 0.5 * float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
        for i in form.vertices():
            # what Envelope.apply_bounds/apply_target compute by vertical projection onto the
            # reference, written directly: the plan is the reference's, so the projection is z
            z = float(V[i, 2])
            form.vertex_attributes(i, ["ub", "lb", "target"], [z + half, z - half, z])
        envelope = MeshEnvelope.from_middle_mesh(mesh.copy(), thickness=P["thickness"])
        analysis = Analysis.create_bestfit_analysis(form, envelope, printout=False, max_iter=500, solver="SLSQP",
                                                    starting_point="loadpath")
        # TNO's default q range [-1e4, 1e-8] in normalised units; compression strictly (q < 0)
        analysis.optimiser.set_optimiser_options(qmin=-1e7, qmax=-1e-9)
        analysis.create_base_problem()
        analysis.compute_starting_point()
        analysis.setup_optimization()
        analysis.solve()
        elapsed = time.perf_counter() - t0
        res = analysis.result
        ok = bool(getattr(res, "success", False))
        msg = f"{getattr(res, 'message', '')}; {getattr(res, 'niter', '?')} SLSQP iterations"
        if not ok:
            write_result(args.result, tool=TOOL, version=installed_version(TOOL), status="failed", message=msg, time_s=elapsed,
                         vertices=[], edges=[], weights=[])
            return
        X, q = read_back(form, P)
        # TNO's q < 0 is compression (Σ q (v_j − v_i) + p = 0): w = −q, times the load scale
        w = -scale * q
        write_result(args.result, tool=TOOL, version=installed_version(TOOL), status="converged", message=msg, time_s=elapsed,
                     vertices=X, edges=E, weights=w)
    except Exception as exc:  # one failed row, not a crashed study
        fail(args.result, TOOL, exc)


if __name__ == "__main__":
    main()
