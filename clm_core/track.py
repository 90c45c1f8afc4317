"""Assembly of the track–soil model: sparse M, C, K (paper Sec. 5, Fig. 6).

The model is one rail line:

- the rail, Euler–Bernoulli beam finite elements (cubic Hermite, consistent
  mass), ``elements_per_bay`` elements per sleeper bay (2 by default, as the
  paper's ref. [23]), overhanging the end sleepers by half a bay;
- under each sleeper node: a railpad (k_p, d_p), the sleeper mass m, the
  ballast (k_b, d_b) down to the soil contact area;
- the soil under each contact area: rigid, Winkler (k_f, d_f), Lysmer's
  analogue (m_f, k_f, d_f) or the CLM chain (plus k_c, d_c between
  neighbouring areas, Eq. 7–8).

Degrees of freedom are ordered by position along the track, so the matrices
are banded (half bandwidth 2 * elements_per_bay + 2). Displacements positive
downwards. Sleeper ``i`` of the assembly has the global index
``first_sleeper + i`` and lies at ``x = (first_sleeper + i) * spacing`` [m].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from numpy.typing import NDArray

from clm_core.arrays import Array, IntArray
from clm_core.checks import finite, integer, positive
from clm_core.errors import InputError, ParameterError, StabilityError
from clm_core.params import PER_SLEEPER_NAMES, ModelParams

RailEnds = Literal["free", "pinned", "clamped"]
#: Most degrees of freedom of one assembled model (:func:`assemble`): about 330 000 sleepers, 200 km of line at
#: 0.6 m; a larger model is an input mistake and would not fit in memory.
MAX_DOFS = 2_000_000


def beam_element(EI: float, m: float, L: float) -> tuple[Array, Array]:
    """Stiffness and consistent mass of an Euler–Bernoulli element, DOFs (w1, th1, w2, th2).

    Parameters
    ----------
    EI : float
        Bending stiffness [N m^2].
    m : float
        Mass per unit length [kg/m].
    L : float
        Element length [m].

    Raises
    ------
    ParameterError
        ``EI``, ``m`` or ``L`` not finite and > 0.
    """
    EI = positive("EI", EI, unit="N m^2")
    m = positive("m", m, unit="kg/m")
    L = positive("L", L, unit="m")
    k = (
        EI
        / L**3
        * np.array(
            [
                [12, 6 * L, -12, 6 * L],
                [6 * L, 4 * L**2, -6 * L, 2 * L**2],
                [-12, -6 * L, 12, -6 * L],
                [6 * L, 2 * L**2, -6 * L, 4 * L**2],
            ]
        )
    )
    mm = (
        m
        * L
        / 420.0
        * np.array(
            [
                [156, 22 * L, 54, -13 * L],
                [22 * L, 4 * L**2, 13 * L, -3 * L**2],
                [54, 13 * L, 156, -22 * L],
                [-13 * L, -3 * L**2, -22 * L, 4 * L**2],
            ]
        )
    )
    return k, mm


def hermite(xi: Array, L: float) -> Array:
    """Cubic Hermite shape functions at local coordinates ``xi`` in [0, 1] of an element of length ``L`` [m] > 0;
    shape (len(xi), 4)."""
    L = positive("element length L", L, unit="m")
    xi = np.asarray(xi, dtype=float)
    return np.stack(
        [1 - 3 * xi**2 + 2 * xi**3, L * (xi - 2 * xi**2 + xi**3), 3 * xi**2 - 2 * xi**3, L * (-(xi**2) + xi**3)],
        axis=-1,
    )


@dataclass(frozen=True)
class SleeperProperties:
    """Per-sleeper parameter arrays after overrides (length n, or n - 1 for links)."""

    kp: Array
    dp: Array
    ms: Array
    kb: Array
    db: Array
    mf: Array
    kf: Array
    df: Array
    kc: Array  # link i -> i + 1, length n - 1
    dc: Array


class SleeperValues:
    """Per-sleeper parameter values along the line: base values with the overrides applied.

    The one place where the per-sleeper overrides of a :class:`ModelParams`
    (:class:`~clm_core.params.SleeperOverride`, global sleeper indices) are
    applied: :func:`sleeper_properties` (hence :func:`assemble`), the
    operator cache of the streaming solver (its keys) and the stability check
    of overridden stretches (:func:`check_overridden_stretches`) all read
    them from here. Overrides apply in their order (a later one wins where
    two overlap); ``kc`` and ``dc`` of sleeper ``g`` belong to the link
    ``g -> g + 1``. Values are raw: the soil-model rules (e.g. no ``kc`` off
    the CLM model) are applied by :func:`sleeper_properties`.

    Parameters
    ----------
    params : ModelParams
        Base values (track and soil sections) and overrides.

    Notes
    -----
    Indexing costs O(total overridden sleepers) once; :meth:`values` costs
    O(n log m) per override for n sleepers, independent of the length of
    line the overrides cover.
    """

    def __init__(self, params: ModelParams) -> None:
        t, s = params.track, params.soil
        self.base: dict[str, float] = {
            "kp": t.kp, "dp": t.dp, "ms": t.ms, "kb": t.kb, "db": t.db,
            "mf": s.mf, "kf": s.kf, "df": s.df, "kc": s.kc, "dc": s.dc,
        }
        self._ov = [(np.unique(np.asarray(o.sleepers, dtype=np.int64)), dict(o.values)) for o in params.overrides]
        touched = [g for g, _ in self._ov]
        #: Sorted global indices of every overridden sleeper.
        self.touched: IntArray = np.unique(np.concatenate(touched)) if touched else np.zeros(0, dtype=np.int64)

    def values(self, global_index: IntArray | None, n: int = 0) -> dict[str, Array]:
        """Raw per-sleeper values {name: (n,) array} of sleepers ``global_index`` (None: ``n`` base ones)."""
        m = n if global_index is None else len(global_index)
        vals = {k: np.full(m, float(v)) for k, v in self.base.items()}
        if global_index is not None:
            for g, changes in self._ov:
                mask = _member(np.asarray(global_index, dtype=np.int64), g)
                if mask.any():
                    for name, v in changes.items():
                        vals[name][mask] = v
        return vals

    def key(self, global_index: IntArray | None, n: int = 0) -> bytes:
        """The values of :meth:`values` (and the count) as bytes: equal keys, identical stretches."""
        vals = self.values(global_index, n)
        m = n if global_index is None else len(global_index)
        return np.concatenate([vals[k] for k in PER_SLEEPER_NAMES]).tobytes() + int(m).to_bytes(8, "little")

    def touches(self, first: int, count: int) -> bool:
        """Whether any of the sleepers ``first .. first + count - 1`` is overridden."""
        if not self.touched.size:
            return False
        i = int(np.searchsorted(self.touched, first))
        return i < self.touched.size and int(self.touched[i]) < first + count


def _member(gidx: IntArray, sorted_unique: IntArray) -> NDArray[np.bool_]:
    """Which of ``gidx`` are in the sorted unique array (O(len(gidx) log m))."""
    if sorted_unique.size == 0:
        return np.zeros(gidx.shape, dtype=bool)
    i = np.clip(np.searchsorted(sorted_unique, gidx), 0, sorted_unique.size - 1)
    return np.asarray(sorted_unique[i] == gidx)


def sleeper_properties(
    params: ModelParams, global_index: IntArray, values: SleeperValues | None = None
) -> SleeperProperties:
    """Per-sleeper values for the sleepers with the given global indices (overrides applied).

    Parameters
    ----------
    params : ModelParams
        Parameters (the soil model decides which values are used).
    global_index : (n,) int array
        Global sleeper indices.
    values : SleeperValues, optional
        The per-sleeper values of ``params``, when the caller keeps them
        (indexed once for many windows); built from ``params`` otherwise.

    Raises
    ------
    ParameterError
        A per-sleeper value outside its range (names the sleeper).
    """
    s = params.soil
    vals = (values if values is not None else SleeperValues(params)).values(global_index)
    for name in PER_SLEEPER_NAMES:
        a = vals[name]
        if name in ("kp", "ms", "kb") and np.any(a <= 0):
            i = int(np.argmin(a))
            raise ParameterError(f"{name} = {a[i]:g} at sleeper {int(global_index[i])}: must be > 0")
        if name in ("dp", "db", "df", "kc") and np.any(a < 0):
            i = int(np.argmin(a))
            raise ParameterError(f"{name} = {a[i]:g} at sleeper {int(global_index[i])}: must be >= 0")
    if s.model != "rigid" and np.any(vals["kf"] <= 0):
        i = int(np.argmin(vals["kf"]))
        raise ParameterError(f"kf = {vals['kf'][i]:g} at sleeper {int(global_index[i])}: must be > 0")
    if s.model in ("lysmer", "clm") and np.any(vals["mf"] <= 0):
        i = int(np.argmin(vals["mf"]))
        raise ParameterError(f"mf = {vals['mf'][i]:g} at sleeper {int(global_index[i])}: must be > 0")
    if s.model != "clm":
        vals["kc"][:] = 0.0
        vals["dc"][:] = 0.0
    if s.model in ("rigid", "winkler"):
        vals["mf"][:] = 0.0
    if s.model == "rigid":
        vals["kf"][:] = 0.0
        vals["df"][:] = 0.0
    return SleeperProperties(**{k: (v[:-1].copy() if k in ("kc", "dc") else v) for k, v in vals.items()})


@dataclass(frozen=True)
class TrackSystem:
    """An assembled track–soil model.

    Attributes
    ----------
    M, C, K : scipy.sparse.csr_matrix, shape (n_dof, n_dof)
        Mass [kg], damping [N s/m], stiffness [N/m].
    node_x : (n_nodes,) array
        Rail node positions [m].
    rail_w, rail_th : (n_nodes,) int arrays
        DOF of the deflection / rotation of each rail node (-1 where constrained).
    sleeper_index : (n_sleepers,) int array
        Global sleeper indices.
    sleeper_x : (n_sleepers,) array
        Sleeper positions [m].
    sleeper_node : (n_sleepers,) int array
        Rail node above each sleeper.
    sleeper_dof, area_dof : (n_sleepers,) int arrays
        DOF of each sleeper and of each soil contact area (-1 for a rigid soil).
    props : SleeperProperties
        Per-sleeper values used.
    """

    params: ModelParams
    M: sp.csr_matrix
    C: sp.csr_matrix
    K: sp.csr_matrix
    node_x: Array
    rail_w: IntArray
    rail_th: IntArray
    sleeper_index: IntArray
    sleeper_x: Array
    sleeper_node: IntArray
    sleeper_dof: IntArray
    area_dof: IntArray
    props: SleeperProperties
    elements_per_bay: int
    half_bandwidth: int = field(default=0)

    @property
    def n_dof(self) -> int:
        """Number of degrees of freedom."""
        return int(self.K.shape[0])

    @property
    def n_sleepers(self) -> int:
        """Number of sleepers."""
        return len(self.sleeper_index)

    def ballast_force(self, u: Array, v: Array) -> Array:
        """Soil reaction force under every sleeper [N], positive = compression.

        k_b (z_s - x_f) + d_b (v_s - v_f): the ballast force on the contact
        area (the paper's "forces acting on the soil surface"). ``u``, ``v``
        have the DOFs on the last axis.
        """
        zs, vs = u[..., self.sleeper_dof], v[..., self.sleeper_dof]
        if self.params.soil.model == "rigid":
            xf, vf = 0.0 * zs, 0.0 * vs
        else:
            xf, vf = u[..., self.area_dof], v[..., self.area_dof]
        return self.props.kb * (zs - xf) + self.props.db * (vs - vf)

    def rail_above_sleepers(self, u: Array) -> Array:
        """Rail deflection above every sleeper [m] (DOFs on the last axis)."""
        return u[..., self.rail_w[self.sleeper_node]]

    def point_load(self, x: float) -> tuple[IntArray, Array]:
        """DOFs and weights that distribute a unit force at rail position ``x`` [m].

        The force goes to the element's four DOFs with the Hermite shape
        functions (consistent nodal loads); the same weights interpolate the
        rail deflection under the load. Constrained DOFs get weight 0.
        """
        xs = self.node_x
        x = finite("load position x", x, InputError)
        if not xs[0] <= x <= xs[-1]:
            raise InputError(f"load position x = {x:g} m: outside the rail [{xs[0]:g}, {xs[-1]:g}] m")
        e = int(np.clip(np.searchsorted(xs, x, side="right") - 1, 0, len(xs) - 2))
        L = xs[e + 1] - xs[e]
        N = hermite(np.array([(x - xs[e]) / L]), L)[0]
        dofs = np.array([self.rail_w[e], self.rail_th[e], self.rail_w[e + 1], self.rail_th[e + 1]], dtype=np.int64)
        w = np.where(dofs >= 0, N, 0.0)
        return np.where(dofs >= 0, dofs, 0), w

    def banded(self, A: sp.spmatrix) -> NDArray[np.generic]:
        """Matrix ``A`` in LAPACK general band storage (``solve_banded`` layout)."""
        b = self.half_bandwidth
        n = self.n_dof
        coo = sp.coo_matrix(A)
        ab = np.zeros((2 * b + 1, n), dtype=coo.dtype)
        ab[b + coo.row - coo.col, coo.col] = coo.data
        return ab


def _overhang(elements_per_bay: int, overhang_elements: int | None) -> int:
    """Rail elements beyond each end sleeper: ``overhang_elements``, by default ``max(1, elements_per_bay // 2)``."""
    return max(1, elements_per_bay // 2) if overhang_elements is None else int(overhang_elements)


def check_size(n_sleepers: int, elements_per_bay: int, overhang_elements: int | None = None) -> None:
    """Refuse a model of more than :data:`MAX_DOFS` degrees of freedom before anything is allocated.

    Raises
    ------
    ParameterError
        The rail, sleepers and areas of ``n_sleepers`` sleepers with
        ``elements_per_bay`` rail elements per bay and ``overhang_elements`` at
        each end (default as in :func:`assemble`) have more than
        :data:`MAX_DOFS` degrees of freedom.
    """
    oh = _overhang(elements_per_bay, overhang_elements)
    n_dof = 2 * (2 * oh + (n_sleepers - 1) * elements_per_bay + 1) + 2 * n_sleepers
    if n_dof > MAX_DOFS:
        raise ParameterError(
            f"n_sleepers = {n_sleepers}, elements_per_bay = {elements_per_bay}: about {n_dof} degrees of freedom, "
            f"more than {MAX_DOFS} (such a model does not fit in memory; a moving-load window needs a few hundred "
            "sleepers)"
        )


def assemble(
    params: ModelParams,
    n_sleepers: int,
    elements_per_bay: int = 2,
    first_sleeper: int = 0,
    rail_ends: RailEnds = "free",
    overhang_elements: int | None = None,
    check_stability: bool = True,
    sleeper_values: SleeperValues | None = None,
) -> TrackSystem:
    """Assemble M, C, K of a track of ``n_sleepers`` on the chosen soil model.

    Parameters
    ----------
    params : ModelParams
        Rail, track and soil parameters (+ per-sleeper overrides by global index).
    n_sleepers : int
        Number of sleepers (>= 2).
    elements_per_bay : int
        Rail elements between two sleepers (>= 1; 2 is the paper's choice).
    first_sleeper : int
        Global index of the first sleeper.
    rail_ends : {'free', 'pinned', 'clamped'}
        Boundary condition at both rail ends.
    overhang_elements : int, optional
        Rail elements beyond each end sleeper; default ``max(1, elements_per_bay // 2)``
        (half a bay).
    check_stability : bool
        Refuse a damping matrix with a negative-dissipation direction (Sec. 4.2).
    sleeper_values : SleeperValues, optional
        The per-sleeper values of ``params`` indexed once (a caller that
        assembles many windows of one line passes them); built from
        ``params`` otherwise.

    Raises
    ------
    ParameterError
        Bad sizes (a count or index that is not an integer, or out of range)
        or per-sleeper values.
    StabilityError
        The assembled damping matrix is not positive semi-definite.
    """
    counts = {"n_sleepers": n_sleepers, "elements_per_bay": elements_per_bay, "first_sleeper": first_sleeper}
    if overhang_elements is not None:
        counts["overhang_elements"] = overhang_elements
    for name, value in counts.items():
        integer(name, value)
    if n_sleepers < 2:
        raise ParameterError(f"n_sleepers = {n_sleepers}: need at least 2")
    if elements_per_bay < 1:
        raise ParameterError(f"elements_per_bay = {elements_per_bay}: need at least 1")
    if rail_ends not in ("free", "pinned", "clamped"):
        raise ParameterError(f"rail_ends = {rail_ends!r}: one of free, pinned, clamped")
    ne = elements_per_bay
    oh = _overhang(ne, overhang_elements)
    if oh < 0:
        raise ParameterError(f"overhang_elements = {oh}: must be >= 0")
    check_size(n_sleepers, ne, oh)
    n_el = 2 * oh + (n_sleepers - 1) * ne  # rail elements: overhang, bays, overhang
    d = params.track.spacing
    gidx = np.arange(first_sleeper, first_sleeper + n_sleepers, dtype=np.int64)
    sx = gidx * d
    props = sleeper_properties(params, gidx, sleeper_values)
    model = params.soil.model
    has_area = model != "rigid"

    # rail nodes: overhang, bays, overhang
    Le = d / ne
    node_x = sx[0] - oh * Le + Le * np.arange(n_el + 1)
    sleeper_node = (oh + ne * np.arange(n_sleepers)).astype(np.int64)

    # DOF numbering in position order
    n_nodes = n_el + 1
    rail_w = np.empty(n_nodes, dtype=np.int64)
    rail_th = np.empty(n_nodes, dtype=np.int64)
    sleeper_dof = np.empty(n_sleepers, dtype=np.int64)
    area_dof = np.full(n_sleepers, -1, dtype=np.int64)
    is_sleeper = np.full(n_nodes, -1, dtype=np.int64)
    is_sleeper[sleeper_node] = np.arange(n_sleepers)
    k = 0
    for j in range(n_nodes):
        rail_w[j], rail_th[j] = k, k + 1
        k += 2
        i = is_sleeper[j]
        if i >= 0:
            sleeper_dof[i] = k
            k += 1
            if has_area:
                area_dof[i] = k
                k += 1
    n_dof = k

    rows: list[NDArray[np.int64]] = []
    cols: list[NDArray[np.int64]] = []
    kv: list[Array] = []
    mv: list[Array] = []
    cv: list[Array] = []

    def add(r: NDArray[np.int64], c: NDArray[np.int64], kk: Array, mm: Array, cc: Array) -> None:
        rows.append(r.ravel())
        cols.append(c.ravel())
        kv.append(np.broadcast_to(kk, r.shape).ravel())
        mv.append(np.broadcast_to(mm, r.shape).ravel())
        cv.append(np.broadcast_to(cc, r.shape).ravel())

    # rail elements (vectorised over elements)
    ke, me = beam_element(params.rail.EI, params.rail.mass_per_length, Le)
    edofs = np.stack([rail_w[:-1], rail_th[:-1], rail_w[1:], rail_th[1:]], axis=1)  # (n_el, 4)
    R = np.repeat(edofs[:, :, None], 4, axis=2)
    Cc = np.repeat(edofs[:, None, :], 4, axis=1)
    add(R, Cc, np.broadcast_to(ke, R.shape), np.broadcast_to(me, R.shape), np.zeros(R.shape))

    def spring(a: NDArray[np.int64], b: NDArray[np.int64], kk: Array, cc: Array) -> None:
        """Spring-dashpot between DOFs a and b (b = -1: to ground)."""
        ground = b < 0
        bb = np.where(ground, a, b)
        z = np.zeros_like(kk)
        add(a, a, kk, z, cc)
        g = ~ground
        add(bb[g], bb[g], kk[g], z[g], cc[g])
        add(a[g], bb[g], -kk[g], z[g], -cc[g])
        add(bb[g], a[g], -kk[g], z[g], -cc[g])

    rw = rail_w[sleeper_node]
    spring(rw, sleeper_dof, props.kp, props.dp)
    spring(sleeper_dof, area_dof if has_area else np.full(n_sleepers, -1, dtype=np.int64), props.kb, props.db)
    add(sleeper_dof, sleeper_dof, np.zeros(n_sleepers), props.ms, np.zeros(n_sleepers))
    if has_area:
        spring(area_dof, np.full(n_sleepers, -1, dtype=np.int64), props.kf, props.df)
        add(area_dof, area_dof, np.zeros(n_sleepers), props.mf, np.zeros(n_sleepers))
        if model == "clm":
            spring(area_dof[:-1], area_dof[1:], props.kc, props.dc)

    r = np.concatenate(rows)
    c = np.concatenate(cols)
    shape = (n_dof, n_dof)
    K = sp.coo_matrix((np.concatenate(kv), (r, c)), shape=shape).tocsr()
    M = sp.coo_matrix((np.concatenate(mv), (r, c)), shape=shape).tocsr()
    C = sp.coo_matrix((np.concatenate(cv), (r, c)), shape=shape).tocsr()

    # rail end conditions: remove constrained DOFs
    removed: list[int] = []
    if rail_ends in ("pinned", "clamped"):
        removed += [int(rail_w[0]), int(rail_w[-1])]
    if rail_ends == "clamped":
        removed += [int(rail_th[0]), int(rail_th[-1])]
    if removed:
        keep = np.setdiff1d(np.arange(n_dof), removed)
        new = np.full(n_dof, -1, dtype=np.int64)
        new[keep] = np.arange(len(keep))
        K, M, C = (A[keep][:, keep].tocsr() for A in (K, M, C))
        rail_w, rail_th = new[rail_w], new[rail_th]
        sleeper_dof = new[sleeper_dof]
        area_dof = np.where(area_dof >= 0, new[np.maximum(area_dof, 0)], -1)

    coo = K.tocoo()
    bw = int(np.max(np.abs(coo.row - coo.col)))
    coo = C.tocoo()
    bw = max(bw, int(np.max(np.abs(coo.row - coo.col))) if coo.nnz else 0)
    system = TrackSystem(
        params=params,
        M=M,
        C=C,
        K=K,
        node_x=node_x,
        rail_w=rail_w,
        rail_th=rail_th,
        sleeper_index=gidx,
        sleeper_x=np.asarray(sx, dtype=np.float64),
        sleeper_node=sleeper_node,
        sleeper_dof=sleeper_dof,
        area_dof=area_dof,
        props=props,
        elements_per_bay=ne,
        half_bandwidth=bw,
    )
    if check_stability:
        check_damping(system)
    return system


def min_damping_eigenvalue(system: TrackSystem) -> float:
    """Smallest eigenvalue of the assembled damping matrix C [N s/m] (banded solver)."""
    b = system.half_bandwidth
    n = system.n_dof
    coo = sp.tril(system.C).tocoo()
    ab = np.zeros((b + 1, n))
    ab[coo.row - coo.col, coo.col] = coo.data
    ev = sla.eig_banded(ab, lower=True, eigvals_only=True, select="i", select_range=(0, 0))
    return float(ev[0])


def check_damping(system: TrackSystem) -> None:
    """Refuse a damping matrix with a negative-dissipation direction (Sec. 4.2).

    The rail DOFs carry no damping, so C is at best positive semi-definite;
    the rule is lambda_min(C) >= -1e-9 max|C_ii|. A negative eigenvalue means
    a velocity pattern that feeds energy into the system (negative d_c larger
    than the damping around it): the time response can diverge.
    """
    lam = min_damping_eigenvalue(system)
    scale = float(np.max(np.abs(system.C.diagonal()))) or 1.0
    if lam < -1e-9 * scale:
        s = system.params.soil
        raise StabilityError(
            f"damping matrix not positive semi-definite: smallest eigenvalue {lam:.4g} N s/m "
            f"(soil d_f = {s.df:g}, d_c = {s.dc:g} N s/m, ballast d_b = {system.params.track.db:g} N s/m); "
            "the negative coupling damping outweighs the damping around it (Kouroussis et al. 2011, Sec. 4.2)"
        )


def check_overridden_stretches(
    params: ModelParams, elements_per_bay: int = 2, sleeper_values: SleeperValues | None = None
) -> None:
    """Refuse a line whose overridden stretches are unstable (Sec. 4.2), however far along the line.

    Every cluster of overridden sleepers (gaps of at most 4 sleepers) is
    assembled with two neighbours on either side, in pieces of at most 400
    sleepers overlapping by 20, and its damping matrix checked
    (:func:`check_damping`); identical pieces are checked once.

    Parameters
    ----------
    params : ModelParams
        Parameters with per-sleeper overrides (nothing to check without).
    elements_per_bay : int
        Rail elements per sleeper bay of the assemblies.
    sleeper_values : SleeperValues, optional
        The per-sleeper values of ``params``, if already indexed.

    Raises
    ------
    ParameterError
        A per-sleeper value outside its range.
    StabilityError
        A damping matrix that is not positive semi-definite.
    """
    values = sleeper_values if sleeper_values is not None else SleeperValues(params)
    g = values.touched
    if not g.size:
        return
    breaks = np.nonzero(np.diff(g) > 4)[0]
    starts = np.concatenate([[g[0]], g[breaks + 1]])
    ends = np.concatenate([g[breaks], [g[-1]]])
    seen: set[bytes] = set()
    piece, overlap = 400, 20
    for a, b in zip(starts, ends):
        lo, hi = int(a) - 2, int(b) + 3
        s = lo
        while True:
            e = min(hi, s + piece)
            n = max(e - s, 2)
            key = values.key(np.arange(s, s + n, dtype=np.int64))
            if key not in seen:
                seen.add(key)
                assemble(params, n, elements_per_bay=elements_per_bay, first_sleeper=s, check_stability=True,
                         sleeper_values=values)
            if e >= hi:
                break
            s = e - overlap
