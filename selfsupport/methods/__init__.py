"""The solution methods: what each declares it can do, and the registry by name.

Every method class carries a ``name`` (its key in :data:`METHODS`, ``--method NAME``) and its
:class:`Capabilities`; callers ask for a capability (:func:`capabilities`), never for a name.
A method's module is imported only when it is asked for (the IPOPT method pulls in CasADi; a
method whose module is missing raises :class:`~selfsupport.core.errors.BackendUnavailable` with the
reason instead of breaking the import).

>>> capabilities("ipopt").hull_as_rows, capabilities("staggered").hull_as_rows
(True, False)
>>> find_method(planar_rows=True, warm_start=True)
'ipopt'
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, fields
from typing import Any

from selfsupport.core.errors import BackendUnavailable, InputError

__all__ = ["Capabilities", "MethodSpec", "METHODS", "method_class", "make_method", "capabilities", "find_method"]


@dataclass(frozen=True)
class Capabilities:
    """What a method can do, as the code around it needs to know.

    Attributes
    ----------
    warm_start
        ``solve(..., warm_start=NETWORK)`` starts from a previous network on the same mesh.
    hull_as_rows
        The masonry hull is a set of hard inequality rows: one solve decides whether a network
        inside it exists (and a warm start is kept); otherwise the hull search climbs its
        penalties (:func:`selfsupport.methods.hull_search.solve_in_hull`).
    load_cases
        Several load cases in one solve.
    planar_rows
        Planar faces are equations, not a penalty.
    options_type
        ``"module:Class"`` of the dataclass whose fields are the method's per-solve ``options``
        (checked before the work; :meth:`options_class` imports it), or ``None``: the method
        takes only the stopping rules.
    simultaneous
        Positions and weights at once: the result is a KKT point of the simultaneous NLP
        (:meth:`~selfsupport.methods.simultaneous.Simultaneous.formulation`), so it has
        sensitivities.
    levels
        The method solves coarsened levels first (for big meshes).
    bytes_per_vertex
        Peak memory per vertex of a one-case solve (measured rates rounded up; see
        :mod:`selfsupport.methods.memory`).
    """

    warm_start: bool = False
    hull_as_rows: bool = False
    load_cases: bool = True
    planar_rows: bool = False
    options_type: str | None = None
    simultaneous: bool = False
    levels: bool = False
    bytes_per_vertex: float = 100e3

    def options_class(self) -> type | None:
        """The options dataclass named by :attr:`options_type` (imported now), or ``None``."""
        if self.options_type is None:
            return None
        module, _, attr = self.options_type.partition(":")
        return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True)
class MethodSpec:
    """Where a method class lives, so that it is imported only when asked for.

    Attributes
    ----------
    module, attr
        ``importlib.import_module(module).<attr>`` is the method class; its instances have
        ``solve(problem, options, *, progress, warm_start?, deadline) -> SolveResult``.
    summary
        One line for ``--help``.
    capabilities
        What the method can do, declared here so that asking costs no import (the class's
        ``capabilities`` attribute is this one).
    backend_module, backends
        Name of a module-level dict of backend names in ``backend_module`` (the method's
        constructor then takes ``backend=NAME``); empty when the method has no backend choice.
    """

    module: str
    attr: str
    summary: str
    capabilities: Capabilities = Capabilities()
    backend_module: str = ""
    backends: str = ""

    def load(self) -> type:
        """Import and return the method class; :class:`BackendUnavailable` if it is not there."""
        try:
            mod = importlib.import_module(self.module)
        except ModuleNotFoundError as e:
            # a missing dependency inside an existing module is reported the same way, with its name
            raise BackendUnavailable(f"method module {self.module} cannot be imported ({e}); "
                                     f"choose another --method (one of {', '.join(METHODS)})") from None
        try:
            return getattr(mod, self.attr)
        except AttributeError:
            raise BackendUnavailable(f"{self.module} has no {self.attr} yet; choose another --method "
                                     f"(one of {', '.join(METHODS)})") from None

    def backend_names(self) -> tuple[str, ...]:
        """Backend names the method accepts (empty: no choice)."""
        if not self.backends:
            return ()
        return tuple(getattr(importlib.import_module(self.backend_module), self.backends))


_STAGGERED_OPTIONS = "selfsupport.methods.staggered.options:StaggeredOptions"

#: Method name (``--method``) -> where its class lives; the order is the order of preference
#: of :func:`find_method`.
METHODS: dict[str, MethodSpec] = {
    "staggered": MethodSpec("selfsupport.methods.staggered", "StaggeredLinearization",
                            "the paper's staggered linearization (§3): weights and positions in turn",
                            Capabilities(warm_start=True, options_type=_STAGGERED_OPTIONS, bytes_per_vertex=16e3),
                            backend_module="selfsupport.methods.weightfit_backends", backends="WEIGHT_FIT_BACKENDS"),
    "multilevel": MethodSpec("selfsupport.methods.multilevel", "Multilevel",
                             "the staggered method on coarsened top views first, each level warm-starting "
                             "the next (big meshes)",
                             Capabilities(warm_start=True, options_type=_STAGGERED_OPTIONS, levels=True,
                                          bytes_per_vertex=16e3),
                             backend_module="selfsupport.methods.weightfit_backends", backends="WEIGHT_FIT_BACKENDS"),
    "ipopt": MethodSpec("selfsupport.methods.simultaneous", "Simultaneous",
                        "all positions and weights at once with IPOPT (CasADi, MUMPS)",
                        Capabilities(warm_start=True, hull_as_rows=True, planar_rows=True, simultaneous=True,
                                     bytes_per_vertex=100e3)),
    "nlopt": MethodSpec("selfsupport.methods.nlopt_methods", "NloptSimultaneous",
                        "all positions and weights at once with nlopt SLSQP (small problems only)",
                        Capabilities(load_cases=False, simultaneous=True, bytes_per_vertex=100e3)),
}


def method_class(name: str) -> type:
    """The method class registered as ``name`` in :data:`METHODS` (imported now)."""
    try:
        spec = METHODS[name]
    except KeyError:
        raise InputError(f"unknown method {name!r}; choose one of {', '.join(METHODS)}") from None
    return spec.load()


def make_method(name: str = "staggered", backend: str | None = None, **settings: Any) -> Any:
    """An instance of method ``name``; ``backend`` picks its inner solver where it has a choice
    (the staggered method's Step 2: see ``selfsupport.methods.weightfit_backends.WEIGHT_FIT_BACKENDS``);
    ``settings`` are further keywords of its constructor."""
    cls = method_class(name)
    if backend is None:
        return cls(**settings)
    names = METHODS[name].backend_names()
    if not names:
        raise InputError(f"method {name!r} has no backend choice; leave --backend out")
    if backend not in names:
        raise InputError(f"unknown backend {backend!r} for method {name!r}; choose one of {', '.join(names)}")
    return cls(backend=backend, **settings)


def capabilities(method: Any) -> Capabilities:
    """The capabilities of a method given by its registered name, its class or an instance; an
    object that declares none has the defaults of :class:`Capabilities` (no warm start, ...)."""
    if isinstance(method, str):
        if method not in METHODS:
            raise InputError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
        return METHODS[method].capabilities
    caps = getattr(method, "capabilities", None)
    return caps if isinstance(caps, Capabilities) else Capabilities()


def find_method(**required: Any) -> str:
    """The first registered method whose capabilities have the ``required`` values (e.g.
    ``planar_rows=True``); :class:`InputError` when none has."""
    unknown = set(required) - {f.name for f in fields(Capabilities)}
    if unknown:
        raise InputError(f"unknown capabilities {sorted(unknown)}")
    for name in METHODS:
        caps = capabilities(name)
        if all(getattr(caps, k) == v for k, v in required.items()):
            return name
    raise InputError(f"no registered method has {required}")
