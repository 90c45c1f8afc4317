"""Window operators: assembly and factorisation, cached by the window's per-sleeper values.

An :class:`Operator` is everything position-independent about one window
configuration: its assembled matrices (:func:`clm_core.track.assemble` over
the window and its ghost bay, :func:`clamp_ghost_bay`), the CSR arrays of the
step's right-hand side and the LDL^T factor of the Newmark effective matrix
(paper Sec. 5; integrator in :mod:`clm_core.solver`)::

    K_eff = K + (2/dt) C + (4/dt^2) M      (symmetric positive definite)

factorised in envelope storage (:func:`clm_core.solver._kernels.ldlt_envelope`,
no fill outside the band profile). On demand it also holds the factor of the
static operator K (:meth:`Operator.static_factor`) and columns of K_eff^-1
(:meth:`Operator.columns`, the compiled vehicle coupling).

:class:`OperatorCache` keys operators by the window's orientation and the
per-sleeper values of the sleepers it assembles
(:meth:`clm_core.track.SleeperValues.key`): every window of a uniform track
shares one factorisation; a window over per-sleeper overrides gets its own,
kept in an LRU cache. Every window has the same DOF layout
(:class:`DofLayout`), which is what makes a window shift a copy.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from clm_core.arrays import Array, IntArray
from clm_core.checks import integer
from clm_core.errors import ParameterError, StabilityError
from clm_core.params import ModelParams
from clm_core.solver import _kernels as kern
from clm_core.solver.window import Orientation, Placement, Window
from clm_core.track import SleeperValues, TrackSystem, assemble


class Envelope(NamedTuple):
    """LDL^T factor of a symmetric positive definite matrix in envelope storage.

    Row ``i`` of the strict lower triangle of the unit factor is
    ``L[ptr[i]:ptr[i+1]]``, columns ``first[i] .. i - 1``; ``D`` holds the
    pivots (see :mod:`clm_core.solver._kernels`).
    """

    first: IntArray
    ptr: IntArray
    L: Array
    D: Array


def envelope(A: sp.spmatrix) -> Envelope:
    """Envelope storage of the lower triangle of a symmetric matrix (not yet factorised)."""
    A = sp.csr_matrix(A)
    A.eliminate_zeros()
    coo = sp.tril(A, k=-1).tocoo()
    n = A.shape[0]
    first = np.arange(n, dtype=np.int64)
    np.minimum.at(first, coo.row, coo.col.astype(np.int64))
    lengths = np.arange(n) - first
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(lengths, out=ptr[1:])
    L = np.zeros(int(ptr[-1]))
    L[ptr[coo.row] + coo.col - first[coo.row]] = coo.data
    D = np.ascontiguousarray(A.diagonal(), dtype=float)
    return Envelope(first, ptr, L, D)


def factorise(A: sp.spmatrix, what: str) -> Envelope:
    """LDL^T factor of a symmetric matrix in envelope storage.

    Raises
    ------
    StabilityError
        ``A`` (named ``what`` in the message) is not positive definite.
    """
    env = envelope(A)
    bad = int(kern.ldlt_envelope(*env))
    if bad >= 0:
        raise StabilityError(
            f"{what} is not positive definite (pivot <= 0 at DOF {bad}); the time integration "
            "would not be stable for this parameter set"
        )
    return env


def clamp_ghost_bay(full: TrackSystem, orient: Orientation) -> TrackSystem:
    """The window inside an assembly with one extra (ghost) bay, whose DOFs are clamped at zero.

    ``forward``: the ghost bay is the last one (ahead of the window), so the
    window's front is connected to fixed zero DOFs and its rear end is free;
    ``backward``: the mirror image; ``free``: returned as is (both ends free).
    A window shift towards the clamped end turns the clamped DOFs (zero) into
    free ones with their true value (zero) and drops elements at the free
    end: the discrete energy 1/2 v^T M v + 1/2 u^T K u cannot grow across a
    shift, so the Newmark scheme stays unconditionally stable through any
    number of shifts. (With a free front end, the elements added ahead of it
    inject energy at every shift; repeated shifts then amplify the weakly
    damped high-frequency rail modes, see docs/time-domain.md.)
    """
    if orient == "free":
        return full
    ne = full.elements_per_bay
    dpb = int(full.sleeper_dof[1] - full.sleeper_dof[0])
    n = full.n_dof - dpb
    nn = len(full.node_x) - ne
    N = full.n_sleepers - 1
    if orient == "forward":
        keep, nodes, sl, off, noff = slice(0, n), slice(0, nn), slice(0, N), 0, 0
    else:
        keep, nodes, sl, off, noff = slice(dpb, dpb + n), slice(ne, ne + nn), slice(1, N + 1), dpb, ne
    props = full.props
    new_props = type(props)(**{
        k: (getattr(props, k)[sl.start: sl.start + N - 1] if k in ("kc", "dc") else getattr(props, k)[sl]).copy()
        for k in ("kp", "dp", "ms", "kb", "db", "mf", "kf", "df", "kc", "dc")
    })
    M, C, K = (sp.csr_matrix(A)[keep][:, keep].tocsr() for A in (full.M, full.C, full.K))
    area = full.area_dof[sl]
    return replace(
        full, M=M, C=C, K=K, node_x=full.node_x[nodes].copy(),
        rail_w=full.rail_w[nodes] - off, rail_th=full.rail_th[nodes] - off,
        sleeper_index=full.sleeper_index[sl].copy(), sleeper_x=full.sleeper_x[sl].copy(),
        sleeper_node=full.sleeper_node[sl] - noff, sleeper_dof=full.sleeper_dof[sl] - off,
        area_dof=np.where(area >= 0, area - off, -1), props=new_props,
    )


@dataclass(frozen=True)
class DofLayout:
    """DOF maps shared by every window of a simulator (the same layout per bay).

    Attributes
    ----------
    rail_w, rail_th : (n_nodes,) int arrays
        Deflection and rotation DOF of each rail node.
    s_dof, a_dof, r_dof : (N,) int arrays
        Sleeper, contact-area (-1: rigid soil) and rail-above-sleeper DOFs.
    node_x_rel : (n_nodes,) array
        Rail node positions relative to the window's first sleeper [m].
    spacing : float
        Sleeper spacing [m].
    Le : float
        Rail element length [m].
    n_el : int
        Rail elements.
    dofs_per_bay : int
        DOFs per sleeper bay (the stride of a window shift).
    n_dof : int
        DOFs of the window.
    """

    rail_w: IntArray
    rail_th: IntArray
    s_dof: IntArray
    a_dof: IntArray
    r_dof: IntArray
    node_x_rel: Array
    spacing: float
    Le: float
    n_el: int
    dofs_per_bay: int
    n_dof: int

    @classmethod
    def of(cls, system: TrackSystem, first: int, periodic: bool) -> DofLayout:
        """The layout of a window's assembled ``system`` whose first sleeper is ``first``.

        Raises
        ------
        ParameterError
            Constrained rail DOFs, or (``periodic``: the window shifts) a DOF
            layout that is not the same for every bay.
        """
        d = float(system.params.track.spacing)
        rail_w = system.rail_w.astype(np.int64)
        rail_th = system.rail_th.astype(np.int64)
        s_dof = system.sleeper_dof.astype(np.int64)
        if np.any(rail_w < 0) or np.any(rail_th < 0):
            raise ParameterError("track window: constrained rail DOFs are not supported (free rail ends)")
        dpb = int(s_dof[1] - s_dof[0])
        a_dof = system.area_dof.astype(np.int64)
        kind = np.zeros(system.n_dof, dtype=np.int64)
        kind[rail_th] = 1
        kind[s_dof] = 2
        kind[a_dof[a_dof >= 0]] = 3
        if periodic and not np.array_equal(kind[dpb:], kind[:-dpb]):
            raise ParameterError(  # pragma: no cover - guarded by elements_per_bay >= 2
                "track window: the DOF layout is not periodic per bay; cannot shift the window by copying"
            )
        return cls(
            rail_w=rail_w, rail_th=rail_th, s_dof=s_dof, a_dof=a_dof,
            r_dof=system.rail_w[system.sleeper_node].astype(np.int64),
            node_x_rel=system.node_x - first * d, spacing=d, Le=d / system.elements_per_bay,
            n_el=len(system.node_x) - 1, dofs_per_bay=dpb, n_dof=system.n_dof,
        )

    def matches(self, system: TrackSystem) -> bool:
        """Whether ``system`` has this layout."""
        return bool(
            np.array_equal(system.rail_w, self.rail_w) and np.array_equal(system.sleeper_dof, self.s_dof)
            and np.array_equal(system.area_dof, self.a_dof)
        )


@dataclass
class Operator:
    """Matrices and factorisation of one window configuration (position independent).

    Attributes
    ----------
    system : TrackSystem
        The window's assembly (ghost bay clamped out; positions of the window
        it was first built for).
    kernel : StepOperator
        The arrays the compiled steps read (:class:`clm_core.solver._kernels.StepOperator`).
    orientation : {'forward', 'backward', 'free'}
        Side of the clamped ghost bay.
    """

    system: TrackSystem
    kernel: kern.StepOperator
    orientation: Orientation
    _static: Envelope | None = None
    # columns K_eff^-1 e_d of rail DOFs d that wheels have loaded (compiled coupling), filled on demand
    _cols: Array | None = None  # (capacity, n); row _slot[d] is the column of DOF d
    _slot: IntArray | None = None  # (n,) row of each DOF's column, -1: not computed
    _n_cols: int = 0

    @property
    def kernel_plain(self) -> tuple[object, ...]:
        """:attr:`kernel` as a plain tuple (what the per-frame kernel takes: cheap to type at a call)."""
        plain = self.__dict__.get("_plain")
        if plain is None:
            plain = self.__dict__["_plain"] = tuple(self.kernel)
        return plain

    @property
    def env(self) -> Envelope:
        """The LDL^T factor of K_eff."""
        k = self.kernel
        return Envelope(k.first, k.ptr, k.L, k.D)

    def static_factor(self) -> Envelope:
        """The LDL^T factor of the stiffness matrix K (computed on first use).

        Raises
        ------
        StabilityError
            K is not positive definite.
        """
        if self._static is None:
            self._static = factorise(self.system.K, "the stiffness matrix K")
        return self._static

    def columns(self, dofs: IntArray) -> tuple[Array, IntArray]:
        """Columns K_eff^-1 e_d for the DOFs ``dofs``, computed once per operator and DOF.

        Returns
        -------
        cols : (capacity, n) array
            Row ``slot[d]`` is the column of DOF ``d`` [m/N].
        slot : (n,) int array
            Row of each DOF's column (-1: not computed).
        """
        n = self.system.n_dof
        if self._cols is None or self._slot is None:
            self._cols = np.empty((min(n, 32), n))
            self._slot = np.full(n, -1, dtype=np.int64)
            self._n_cols = 0
        need = np.unique(dofs)
        need = np.ascontiguousarray(need[self._slot[need] < 0])
        if need.size:
            k = self._n_cols + need.size
            if k > self._cols.shape[0]:
                grown = np.empty((min(n, max(k, 2 * self._cols.shape[0])), n))
                grown[: self._n_cols] = self._cols[: self._n_cols]
                self._cols = grown
            rows = np.arange(self._n_cols, k, dtype=np.int64)
            kern.unit_columns(*self.env, need, self._cols, rows)
            self._slot[need] = rows
            self._n_cols = k
        return self._cols, self._slot


class OperatorCache:
    """Window operators built on demand and kept in an LRU cache keyed by the window's values.

    Parameters
    ----------
    params : ModelParams
        Rail, track and soil parameters with per-sleeper overrides.
    dt : float
        Time step [s].
    window : Window
        The window rules (sizes, ghost bay).
    elements_per_bay : int
        Rail elements per sleeper bay.
    sleeper_values : SleeperValues
        The per-sleeper values of ``params`` (the keys, and the assemblies).
    size : int
        Operators kept (least recently used dropped first).

    Attributes
    ----------
    n_factorisations : int
        Operators built so far (each one assembly and one factorisation).
    layout : DofLayout
        The DOF layout of every window (set by the first :meth:`get`).

    Raises
    ------
    ParameterError
        ``size < 1``.
    """

    def __init__(
        self,
        params: ModelParams,
        dt: float,
        window: Window,
        elements_per_bay: int,
        sleeper_values: SleeperValues,
        size: int = 64,
    ) -> None:
        integer("cache_size", size, 1)
        self.params = params
        self.dt = float(dt)
        self.window = window
        self.elements_per_bay = int(elements_per_bay)
        self.values = sleeper_values
        self.size = int(size)
        self.n_factorisations = 0
        self._layout: DofLayout | None = None
        self._lru: OrderedDict[tuple[str, bytes], Operator] = OrderedDict()
        N = window.n_sleepers
        self._uniform = {m: sleeper_values.key(None, m) for m in (N, N + 1)}

    @property
    def layout(self) -> DofLayout:
        """The DOF layout of every window (set by the first :meth:`get`)."""
        if self._layout is None:
            raise RuntimeError("OperatorCache.layout: no operator built yet")
        return self._layout

    def __len__(self) -> int:
        return len(self._lru)

    def key(self, p: Placement) -> tuple[str, bytes]:
        """Cache key of the operator of placement ``p``: orientation and per-sleeper values of its span."""
        a, m = self.window.span(p)
        if self.values.touches(a, m):
            return p.orientation, self.values.key(np.arange(a, a + m, dtype=np.int64))
        return p.orientation, self._uniform[m]

    def get(self, p: Placement) -> Operator:
        """The operator of placement ``p`` (built and factorised when first met).

        Raises
        ------
        ParameterError, StabilityError
            The window's assembly is refused (per-sleeper values, damping
            matrix not positive semi-definite, K_eff not positive definite).
        """
        key = self.key(p)
        op = self._lru.get(key)
        if op is None:
            op = self._build(p)
            self._lru[key] = op
            while len(self._lru) > self.size:
                self._lru.popitem(last=False)
        else:
            self._lru.move_to_end(key)
        return op

    def _build(self, p: Placement) -> Operator:
        a, m = self.window.span(p)
        full = assemble(self.params, m, elements_per_bay=self.elements_per_bay, first_sleeper=a,
                        check_stability=True, sleeper_values=self.values)
        sysm = clamp_ghost_bay(full, p.orientation)
        if self._layout is None:
            self._layout = DofLayout.of(sysm, p.first, periodic=self.window.follow)
        elif not self._layout.matches(sysm):  # pragma: no cover - a layout bug, not a user error
            raise RuntimeError(f"window DOF layout of the {p.orientation} operator differs from the first window's")
        lay = self._layout
        dt = self.dt
        K, C, M = sysm.K, sysm.C, sysm.M
        Keff = (K + (2.0 / dt) * C + (4.0 / dt**2) * M).tocsr()
        env = factorise(Keff, "the Newmark effective matrix K + 2/dt C + 4/dt^2 M")
        pat = (abs(K) + abs(M)).tocsr()
        pat.eliminate_zeros()
        pat.sort_indices()
        r = np.repeat(np.arange(pat.shape[0]), np.diff(pat.indptr))
        c = pat.indices
        Kv = np.asarray(sp.csr_matrix(K)[r, c]).ravel()
        Mv = np.asarray(sp.csr_matrix(M)[r, c]).ravel()
        self.n_factorisations += 1
        kernel = kern.StepOperator(
            indptr=pat.indptr.astype(np.int64), indices=c.astype(np.int64),
            Ka=np.ascontiguousarray(-2.0 * Kv), Mb=np.ascontiguousarray((4.0 / dt) * Mv),
            first=env.first, ptr=env.ptr, L=env.L, D=env.D, Dinv=1.0 / env.D, a1=2.0 / dt,
            s_dof=lay.s_dof, a_dof=lay.a_dof, r_dof=lay.r_dof,
            kb=np.ascontiguousarray(sysm.props.kb, dtype=float), db=np.ascontiguousarray(sysm.props.db, dtype=float),
        )
        return Operator(system=sysm, kernel=kernel, orientation=p.orientation)


__all__ = ["DofLayout", "Envelope", "Operator", "OperatorCache", "clamp_ghost_bay", "envelope", "factorise"]
