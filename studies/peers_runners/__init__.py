"""Runners of the peers study (:mod:`studies.peers`): one small script per tool.

Each script is run as ``PYTHON RUNNER.py PROBLEM.json RESULT.json --time-limit S`` by the
interpreter of the environment that holds its tool (the peers' own virtual environment for
jax-fdm, compas-tna and compas-tno; the project's for selfsupport). It reads the shared problem
(:func:`studies.peers.export_problem`) and writes::

    {"tool": ..., "version": ..., "status": ..., "message": ...,
     "time_s": wall time of the solve (imports and file I/O excluded),
     "vertices": [[x, y, z], ...], "edges": [[i, j], ...],
     "weights": [w, ...]}          # force densities, w > 0 = compression (docs/development/design.md)

Every runner converts its tool's own sign convention into ``weights`` and says how in a
comment; the study recomputes every metric from these three arrays and the problem's loads.
The runners import nothing from the project except the selfsupport runner, so the peers'
environment never needs the project installed; ``runner_io`` (arguments, problem and result
files) and ``compas_form`` (the compas form diagram of the problem and the force densities read
back, for compas-tna and compas-tno) are their shared plumbing.
"""
