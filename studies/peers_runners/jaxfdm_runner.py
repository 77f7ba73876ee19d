"""jax-fdm: constrained form finding, plan free.

The force density method with the force densities as the unknowns: for given q the free
vertices' x, y and z follow from one sparse linear solve (FDM), and L-BFGS-B moves q (bounded
to compression) so that the free vertices' heights match the target (``NodeZCoordinateGoal``,
squared error). x and y are not goals: the plan is whatever the force densities give.
"""
from __future__ import annotations

import sys
import time

import numpy as np
from runner_io import fail, installed_version, parse_args, read_problem, write_result

TOOL = "jax-fdm"


def uniform_start(xyz0: np.ndarray, target_z: np.ndarray, free: np.ndarray, fdm_z) -> float:
    """The uniform force density (negative) whose FDM heights best fit the target.

    With q = −s on every edge the plan does not depend on s and the free heights are
    z(s) = a + b/s (a: the supports' heights spread by the Laplacian, b: the load's share at
    s = 1), so 1/s has a closed-form least-squares fit. A jax-fdm user would tune this start by
    hand; doing it here keeps the optimiser's start comparable across scenes.
    """
    a = fdm_z(0.0)
    b = fdm_z(1.0) - a
    bb = float(b[free] @ b[free])
    inv_s = float(b[free] @ (target_z[free] - a[free])) / bb if bb > 0 else 1.0
    return -1.0 / inv_s if inv_s > 0 else -1.0


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    try:
        t_import = time.perf_counter()
        from jax_fdm.datastructures import FDNetwork
        from jax_fdm.equilibrium import constrained_fdm, fdm
        from jax_fdm.goals import NodeZCoordinateGoal
        from jax_fdm.losses import Loss, SquaredError
        from jax_fdm.optimization import LBFGSB
        from jax_fdm.parameters import EdgeForceDensityParameter
        print(f"{TOOL}: imported in {time.perf_counter() - t_import:.1f} s", file=sys.stderr)

        P = read_problem(args.problem)
        V, E, L = P["vertices"], P["edges"], P["loads"]
        n = len(V)
        sup = np.zeros(n, bool)
        sup[P["supports"]] = True
        free = ~sup
        t0 = time.perf_counter()
        deadline = t0 + args.time_limit

        def network(load_scale: float) -> FDNetwork:
            net = FDNetwork.from_nodes_and_edges({i: V[i].tolist() for i in range(n)},
                                                 [tuple(map(int, e)) for e in E])
            net.nodes_supports(np.flatnonzero(sup).tolist())
            for i in range(n):
                # jax-fdm's loads are force vectors, z up: the problem's signed loads as they are
                net.node_load(i, [0.0, 0.0, float(load_scale * L[i])])
            return net

        def fdm_z(load_scale: float) -> np.ndarray:
            net = network(load_scale)
            net.edges_forcedensities(-1.0)
            out = fdm(net)
            return np.array([out.node_coordinates(i)[2] for i in range(n)])

        q0 = uniform_start(V, V[:, 2], free, fdm_z)
        net = network(1.0)
        net.edges_forcedensities(q0)
        goals = [NodeZCoordinateGoal(int(i), float(V[i, 2])) for i in np.flatnonzero(free)]
        loss = Loss(SquaredError(goals))
        # jax-fdm's q < 0 is compression. Edges between two supports move nothing: no parameter.
        # The upper bound keeps every optimised edge in compression, 1e-6 of the start away from 0.
        carrying = [tuple(map(int, e)) for e in E if not (sup[e[0]] and sup[e[1]])]
        params = [EdgeForceDensityParameter(e, None, 1e-6 * q0) for e in carrying]

        def stop_at_deadline(_x) -> None:
            # SciPy's minimize ends cleanly when a callback raises StopIteration
            if time.perf_counter() > deadline:
                raise StopIteration

        opt = LBFGSB()
        out = constrained_fdm(net, optimizer=opt, loss=loss, parameters=params, maxiter=20000, tol=1e-14,
                              callback=stop_at_deadline)
        elapsed = time.perf_counter() - t0
        X = np.array([out.node_coordinates(i) for i in range(n)], float)
        q = np.array([out.edge_forcedensity(tuple(map(int, e))) for e in E], float)
        res = getattr(opt, "result", None)
        status = "time_limit" if time.perf_counter() > deadline else ("converged" if res is not None and res.success else "stopped")
        msg = str(getattr(res, "message", "")) + f"; {getattr(res, 'nit', '?')} L-BFGS-B iterations"
        # w = −q: jax-fdm's residual is Σ q_ij (x_j − x_i) + p_i = 0, ours Σ w_ij (v_j − v_i) = A_i F_i
        write_result(args.result, tool=TOOL, version=installed_version(TOOL),
                     status=status, message=msg, time_s=elapsed, vertices=X, edges=E, weights=-q,
                     q_start=q0)
    except Exception as exc:  # one failed row, not a crashed study
        fail(args.result, TOOL, exc)


if __name__ == "__main__":
    main()
