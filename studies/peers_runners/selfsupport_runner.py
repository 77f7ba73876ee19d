"""selfsupport: the staggered method, plan free or fixed (``--fixed-top-view``).

The project's default method (paper §3) on the shared problem: its loads held as they are
(a ``PointLoad`` of the problem's loads, no self-weight re-estimated from the moving geometry,
so that every tool balances the same forces), its default objective (``reference``: squared
distance to the reference surface) and default weight bounds (w ≥ ε > 0: compression).
Run by the project's interpreter with the repository on ``PYTHONPATH``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from runner_io import fail, read_problem, write_result


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("problem")
    p.add_argument("result")
    p.add_argument("--time-limit", type=float, default=300.0)
    p.add_argument("--fixed-top-view", action="store_true")
    args = p.parse_args()
    tool = "selfsupport (plan fixed)" if args.fixed_top_view else "selfsupport (plan free)"
    try:
        import selfsupport
        from formulations import Problem
        from selfsupport.core.loads import PointLoad
        from selfsupport.core.mesh import PolyMesh
        from selfsupport.core.scene import Scene
        from selfsupport.methods.staggered import StaggeredLinearization

        P = read_problem(args.problem)
        t0 = time.perf_counter()
        mesh = PolyMesh.from_faces(P["vertices"], P["faces"])
        if not np.array_equal(np.sort(mesh.edges, axis=1), np.sort(P["edges"], axis=1)):
            raise ValueError("the mesh's edges are not the problem's edges")  # the study built them from this mesh
        scene = Scene(mesh=mesh, supports=P["supports"], name=P["name"])
        cons = ("fixed_top_view",) if args.fixed_top_view else ()
        problem = Problem.build(scene, PointLoad(P["loads"]), constraints=cons)
        res = StaggeredLinearization().solve(problem, {"time_limit": args.time_limit})
        elapsed = time.perf_counter() - t0
        net = res.network
        write_result(args.result, tool=tool, version=getattr(selfsupport, "__version__", "dev"), status=res.status,
                     message=f"{res.iterations} outer iterations; {res.message}", time_s=elapsed,
                     vertices=net.vertices, edges=net.mesh.edges, weights=net.weights)
    except Exception as exc:  # one failed row, not a crashed study
        fail(args.result, tool, exc)


if __name__ == "__main__":
    main()
