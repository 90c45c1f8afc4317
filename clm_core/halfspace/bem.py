"""Boundary elements for rigid massless surface areas on a layered half-space.

The row problem
---------------
N = 2n + 1 identical rigid, massless rectangles (the sleeper–ballast contact
areas) lie on the surface in a row: area a (a = -n..n) has its centre at
x = a d (x along the track, d the spacing) and covers
[a d - w/2, a d + w/2] x [-L/2, L/2] (w = 0.285 m along the track,
L = 2.5 m across it). Each area moves in vertical translation only (rigid,
no rocking, relaxed contact: no shear tractions). For every frequency the
N x N vertical impedance K (forces [N] from displacements [m]) and
flexibility H = K^{-1} [m/N] are computed.

Discretisation: every area is cut into nx x ny rectangular cells (edges
graded towards the area boundary, where the contact pressure of a rigid
punch is singular as 1/sqrt(distance)); the pressure is constant on a cell
and the displacement is collocated at the cell centres. The influence of a
cell of uniform unit pressure on a point is

    int_cell [c0 / rho + g_s(rho)] dA,

the Boussinesq part integrated in closed form (:func:`rect_inverse_distance`),
the smooth remainder g_s (:mod:`clm_core.halfspace.green`) by Gauss points
per cell and 4-point interpolation on a radial grid.

Structure used (this is what makes a 41-area sweep cheap):

- translation invariance: the influence between cells of areas a and b only
  depends on b - a; one table T(o) of nx ny/2 x nx ny/2 cell influences per
  offset o (with the two y-images of every source folded in, since every
  area is loaded symmetrically about the track axis y = 0) replaces the
  (N nx ny)^2 matrix;
- the sparse interpolation matrix from the radial grid to all needed
  Gauss-point distances is frequency independent (computed once), so each
  frequency costs one radial Green's function, one sparse product and the
  solves;
- mirror symmetry of the row about the centre area (x -> -x): the problem
  splits into a symmetric and an antisymmetric one of half size each (the
  centre-loaded case only needs the symmetric one).

Mesh convergence: the error of the stiffness of a rigid punch with constant
cells and centre collocation is O(h) on a uniform mesh; grading reduces the
constant. :func:`richardson` extrapolates two meshes (h and h/2,
order p = 1 by default); :func:`convergence_study` reports the sequence. See
``docs/halfspace.md`` for the numbers.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse, special

from clm_core.arrays import Array, CArray
from clm_core.checks import nonnegative, odd_count, positive
from clm_core.errors import ParameterError
from clm_core.halfspace.green import KernelEngine, RadialKernel, lagrange_weights
from clm_core.profile import SoilProfile
from clm_core.soil.chain import chain_sums

__all__ = [
    "RowGeometry",
    "RowModel",
    "RowResult",
    "disk_impedance",
    "graded_edges",
    "rect_inverse_distance",
    "richardson",
]


#: Radial grid points per Rayleigh wavelength at f_max (4-point interpolation error ~1e-4).
DR_PER_WAVELENGTH = 16.0


def graded_edges(length: float, n: int, grading: float = 0.5) -> Array:
    """Cell edges over [-length/2, length/2], graded towards both ends.

    edges = length/2 [(1 - g) u + g sin(pi u / 2)],  u = linspace(-1, 1, n + 1).
    ``grading`` g = 0: uniform; g = 1: cosine (Chebyshev) spacing.
    """
    if n < 1:
        raise ParameterError(f"n = {n}: need at least one cell")
    if not 0.0 <= grading <= 1.0:
        raise ParameterError(f"grading = {grading}: must be in [0, 1]")
    u = np.linspace(-1.0, 1.0, n + 1)
    return 0.5 * length * ((1.0 - grading) * u + grading * np.sin(0.5 * math.pi * u))


def _q(x: Array, y: Array) -> Array:
    """Signed quadrant integral int_0^x int_0^y dx dy / sqrt(x^2 + y^2)."""
    ax = np.abs(x)
    ay = np.abs(y)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = ax * np.arcsinh(np.where(ax > 0, ay / np.where(ax > 0, ax, 1.0), 0.0)) + ay * np.arcsinh(
            np.where(ay > 0, ax / np.where(ay > 0, ay, 1.0), 0.0)
        )
    return np.asarray(np.sign(x) * np.sign(y) * v, dtype=np.float64)


def rect_inverse_distance(
    x0: Array, y0: Array, x1: Array, x2: Array, y1: Array, y2: Array
) -> Array:
    """Closed form of int_{x1}^{x2} int_{y1}^{y2} dx dy / sqrt((x - x0)^2 + (y - y0)^2) [m].

    Valid for any position of the point (x0, y0), inside the rectangle
    included (the weak singularity is integrable). Arrays broadcast.
    """
    return _q(x2 - x0, y2 - y0) - _q(x1 - x0, y2 - y0) - _q(x2 - x0, y1 - y0) + _q(x1 - x0, y1 - y0)


def richardson(
    coarse: CArray | float, fine: CArray | float, ratio: float = 2.0, order: float = 1.0
) -> CArray:
    """Richardson extrapolation fine + (fine - coarse) / (ratio^order - 1)."""
    c = np.asarray(coarse)
    f = np.asarray(fine)
    return np.asarray(f + (f - c) / (ratio**order - 1.0))


@dataclass(frozen=True)
class RowGeometry:
    """A row of 2n + 1 identical rectangular areas and their mesh.

    Parameters
    ----------
    n_areas : int
        Number of areas N = 2n + 1 (odd, >= 1).
    spacing : float
        Centre-to-centre distance d along the track [m] (0.6 m default).
    width : float
        Side along the track [m] (0.285 m).
    length : float
        Side across the track [m] (2.5 m).
    nx, ny : int
        Cells per area along and across the track (both even).
    grading : float
        Edge grading of the cells, see :func:`graded_edges`.
    n_gauss : int
        Gauss points per cell direction for the smooth part of the kernel.
    """

    n_areas: int = 41
    spacing: float = 0.6
    width: float = 0.285
    length: float = 2.5
    nx: int = 4
    ny: int = 16
    grading: float = 0.5
    n_gauss: int = 2

    def __post_init__(self) -> None:
        odd_count("n_areas", self.n_areas)
        for name in ("spacing", "width", "length"):
            positive(name, getattr(self, name), unit="m")
        if self.n_areas > 1 and self.spacing < self.width:
            raise ParameterError(
                f"spacing = {self.spacing} m: must be >= width = {self.width} m (areas may not overlap)"
            )
        for name in ("nx", "ny"):
            v = getattr(self, name)
            if v < 2 or v % 2:
                raise ParameterError(f"{name} = {v}: must be even and >= 2")
        if not 1 <= self.n_gauss <= 8:
            raise ParameterError(f"n_gauss = {self.n_gauss}: must be in 1..8")

    @property
    def n(self) -> int:
        """Half-number n of the row (N = 2n + 1)."""
        return self.n_areas // 2

    @property
    def positions(self) -> Array:
        """Area centres along the track, x_a = a d, a = -n..n [m]."""
        return np.arange(-self.n, self.n + 1, dtype=np.float64) * self.spacing

    def refined(self, factor: int = 2) -> RowGeometry:
        """The same row with ``factor`` times more cells in each direction."""
        from dataclasses import replace

        return replace(self, nx=self.nx * factor, ny=self.ny * factor)


@dataclass(frozen=True)
class RowResult:
    """Rigorous impedance of a row of rigid areas over frequency.

    Attributes
    ----------
    freqs : ndarray, shape (nf,)
        Frequencies [Hz].
    positions : ndarray, shape (N,)
        Area centres [m] (index n is the centre area).
    flexibility : ndarray of complex, shape (nf, N, N) or None
        H[f, a, b]: displacement of area a per unit force on area b [m/N]
        (None when only the centre column was computed).
    centre_column : ndarray of complex, shape (nf, N)
        H[f, :, n]: displacements of all areas for a unit force on the centre area [m/N].
    geometry : RowGeometry
        Row and mesh.
    """

    freqs: Array
    positions: Array
    flexibility: CArray | None
    centre_column: CArray
    geometry: RowGeometry
    info: dict[str, float] = field(default_factory=dict)

    @property
    def impedance(self) -> CArray:
        """K = H^{-1} [N/m], shape (nf, N, N) (needs the full flexibility)."""
        if self.flexibility is None:
            raise ParameterError("impedance: this result holds the centre column only (full=False)")
        return np.asarray(np.linalg.inv(self.flexibility))

    def total_sum(self) -> CArray:
        """F / sum_j X_j for a unit force on the centre area, Eq. (16) [N/m] (``soil.chain.chain_sums``)."""
        return chain_sums(self.freqs, self.centre_column).total

    def alternating_sum(self) -> CArray:
        """F / sum_j (-1)^j X_j, centre area j = 0, Eq. (18) [N/m] (``soil.chain.chain_sums``)."""
        return chain_sums(self.freqs, self.centre_column).alternating


class RowModel:
    """Precomputed boundary-element model of a row of rigid areas on a soil profile.

    Parameters
    ----------
    profile : SoilProfile
        The soil.
    geometry : RowGeometry
        Areas and mesh.
    f_max : float
        Highest frequency the model will be evaluated at [Hz]; sets the
        radial grid of the kernel (step <= lambda_R / 24 at f_max).
    dr : float, optional
        Override of the radial grid step [m].

    Notes
    -----
    The mesh should have cells no larger than about lambda_R / 6 at f_max
    (lambda_R the Rayleigh wavelength of the softest layer); the model
    warns through ``mesh_wavelength_ratio`` (reported, not enforced).
    """

    def __init__(
        self, profile: SoilProfile, geometry: RowGeometry, f_max: float = 150.0, dr: float | None = None
    ) -> None:
        nonnegative("f_max", f_max, unit="Hz")
        self.profile = profile
        self.geometry = geometry
        self.f_max = f_max
        g = geometry
        ex = graded_edges(g.width, g.nx, g.grading)
        ey = graded_edges(g.length, g.ny, g.grading)
        # representative half in y (y > 0): cell (ix, iy), iy in ny/2..ny-1
        iyh = np.arange(g.ny // 2, g.ny)
        ix = np.repeat(np.arange(g.nx), iyh.size)
        iy = np.tile(iyh, g.nx)
        self.cx = 0.5 * (ex[ix] + ex[ix + 1])
        self.cy = 0.5 * (ey[iy] + ey[iy + 1])
        self.x1, self.x2 = ex[ix], ex[ix + 1]
        self.y1, self.y2 = ey[iy], ey[iy + 1]
        self.cell_area = (self.x2 - self.x1) * (self.y2 - self.y1)
        self.mh = self.cx.size
        # x-mirror of each cell within an area
        self.sigma = (g.nx - 1 - ix) * iyh.size + (iy - g.ny // 2)
        n = g.n
        self.offsets = np.arange(-2 * n, n + 1)
        h_max = max(float(np.diff(ex).max()), float(np.diff(ey).max()))
        cs_min = profile.min_cs
        lam_r = 2.0 * math.pi * 0.87 * cs_min / (2.0 * math.pi * f_max) if f_max > 0 else math.inf
        self.mesh_wavelength_ratio = h_max / lam_r if math.isfinite(lam_r) else 0.0
        # Gauss points of the sources (both y images)
        gx, gw = np.polynomial.legendre.leggauss(g.n_gauss)
        sx = 0.5 * (self.x1 + self.x2)[:, None] + 0.5 * (self.x2 - self.x1)[:, None] * gx[None, :]
        sy = 0.5 * (self.y1 + self.y2)[:, None] + 0.5 * (self.y2 - self.y1)[:, None] * gx[None, :]
        wx = 0.5 * (self.x2 - self.x1)[:, None] * gw[None, :]
        wy = 0.5 * (self.y2 - self.y1)[:, None] * gw[None, :]
        gpx = np.repeat(sx, g.n_gauss, axis=1)  # (mh, G*G)
        gpy = np.tile(sy, (1, g.n_gauss))
        gpw = np.repeat(wx, g.n_gauss, axis=1) * np.tile(wy, (1, g.n_gauss))
        no = self.offsets.size
        mh = self.mh
        # distances: (no, mh_target, mh_source, image, gp)
        dx = self.offsets[:, None, None, None] * g.spacing + gpx[None, None, :, :] - self.cx[None, :, None, None]
        dy_p = gpy[None, None, :, :] - self.cy[None, :, None, None]
        dy_m = -gpy[None, None, :, :] - self.cy[None, :, None, None]
        dist = np.stack(
            [
                np.sqrt(dx**2 + np.broadcast_to(dy_p, dx.shape) ** 2),
                np.sqrt(dx**2 + np.broadcast_to(dy_m, dx.shape) ** 2),
            ],
            axis=3,
        )  # (no, mh, mh, 2, G*G)
        weights = np.broadcast_to(gpw[None, None, :, None, :], dist.shape)
        self.r_max = float(dist.max())
        if dr is None:
            dr = min(lam_r / DR_PER_WAVELENGTH, self.r_max / 200.0) if math.isfinite(lam_r) else self.r_max / 200.0
            h1 = profile.first_interface_depth
            if h1 is not None:
                dr = min(dr, h1 / 8.0)
        self.dr = float(dr)
        self.engine = KernelEngine(profile, self.r_max, self.dr, f_max)
        self.n_grid = self.engine.r.size
        grid = self.engine.r
        W = lagrange_weights(grid, dist.ravel())
        # sum over images and Gauss points with their weights
        npts = dist.shape[3] * dist.shape[4]
        rows = np.repeat(np.arange(no * mh * mh), npts)
        S = sparse.csr_matrix((weights.ravel(), (rows, np.arange(rows.size))), shape=(no * mh * mh, rows.size))
        self._W = (S @ W).tocsr()
        # static (Boussinesq) geometric part: int 1/rho over both y images
        X0 = self.cx[None, :, None]
        Y0 = self.cy[None, :, None]
        off = self.offsets[:, None, None] * g.spacing
        st = rect_inverse_distance(
            X0,
            Y0,
            off + self.x1[None, None, :],
            off + self.x2[None, None, :],
            self.y1[None, None, :],
            self.y2[None, None, :],
        ) + rect_inverse_distance(
            X0,
            Y0,
            off + self.x1[None, None, :],
            off + self.x2[None, None, :],
            -self.y2[None, None, :],
            -self.y1[None, None, :],
        )
        self._static = np.asarray(st, dtype=np.float64)  # (no, mh, mh)
        # representative cells: areas 1..n all cells, area 0 cells with x > 0
        rep_area: list[int] = []
        rep_cell: list[int] = []
        half0 = np.nonzero(self.cx > 0)[0]
        rep_area += [0] * half0.size
        rep_cell += [int(i) for i in half0]
        for a in range(1, n + 1):
            rep_area += [a] * mh
            rep_cell += list(range(mh))
        self.rep_area = np.asarray(rep_area)
        self.rep_cell = np.asarray(rep_cell)
        A = self.rep_area
        C = self.rep_cell
        o_direct = A[None, :] - A[:, None]  # b - a
        o_mirror = -A[None, :] - A[:, None]  # -b - a
        self._idx_direct = (o_direct - self.offsets[0], C[:, None], C[None, :])
        self._idx_mirror = (o_mirror - self.offsets[0], C[:, None], self.sigma[C][None, :])
        # force multiplicities: y image x 2; centre area x-mirror x 2 in the symmetric problem
        self._mult_sym = 2.0 * self.cell_area[C] * np.where(A == 0, 2.0, 1.0)
        self._mult_anti = 2.0 * self.cell_area[C] * np.where(A == 0, 0.0, 1.0)

    # ------------------------------------------------------------------
    def kernel(self, omega: float) -> RadialKernel:
        """The radial Green's function on this model's grid at ``omega`` [rad/s]."""
        return self.engine(omega)

    def cell_tables(self, omega: float) -> CArray:
        """T(o)[i, j]: displacement at cell centre i per unit pressure on cell j (+ its y image)
        of the area at offset o [m / (N/m^2)], shape (n_offsets, mh, mh)."""
        ker = self.kernel(omega)
        if ker.gs.size != self.n_grid:
            raise RuntimeError("radial grid mismatch")  # pragma: no cover
        smooth = (self._W @ ker.gs).reshape(self._static.shape)
        return np.asarray(ker.c0 * self._static + smooth)

    def solve(self, omega: float, full: bool = True) -> tuple[CArray | None, CArray]:
        """Flexibility at one circular frequency ``omega`` [rad/s].

        Returns
        -------
        H : ndarray (N, N) of complex or None
            Full flexibility [m/N] (None if ``full`` is False).
        col : ndarray (N,) of complex
            Displacements for a unit force on the centre area [m/N].
        """
        g = self.geometry
        n = g.n
        T = self.cell_tables(omega)
        Td = T[self._idx_direct]
        Tm = T[self._idx_mirror]
        A = self.rep_area
        # symmetric problem: modes a' = 0..n
        Es = (A[:, None] == np.arange(n + 1)[None, :]).astype(np.complex128)
        Ps = np.linalg.solve(Td + Tm, Es)
        Ks = np.zeros((n + 1, n + 1), dtype=np.complex128)
        np.add.at(Ks, A, self._mult_sym[:, None] * Ps)
        col_half = np.linalg.solve(Ks, np.eye(n + 1, dtype=np.complex128)[:, 0])
        col = np.concatenate([col_half[:0:-1], col_half])
        if not full:
            return None, col
        N = g.n_areas
        K = np.zeros((N, N), dtype=np.complex128)
        if n > 0:
            Ea = (A[:, None] == np.arange(1, n + 1)[None, :]).astype(np.complex128)
            Pa = np.linalg.solve(Td - Tm, Ea)
            Ka = np.zeros((n + 1, n), dtype=np.complex128)
            np.add.at(Ka, A, self._mult_anti[:, None] * Pa)
            Ka = Ka[1:, :]
        else:
            Ka = np.zeros((0, 0), dtype=np.complex128)
        c = n  # index of the centre area
        K[c + np.arange(-n, n + 1), c] = Ks[np.abs(np.arange(-n, n + 1)), 0]
        for b in range(1, n + 1):
            K[c, c + b] = 0.5 * Ks[0, b]
            for a in range(1, n + 1):
                K[c + a, c + b] = 0.5 * (Ks[a, b] + Ka[a - 1, b - 1])
                K[c - a, c + b] = 0.5 * (Ks[a, b] - Ka[a - 1, b - 1])
        # mirror: K[a, b] = K[-a, -b]
        for b in range(1, n + 1):
            K[:, c - b] = K[::-1, c + b]
        H: CArray = np.asarray(np.linalg.inv(K), dtype=np.complex128)
        return H, np.asarray(col, dtype=np.complex128)

    def sweep(
        self, freqs: Sequence[float] | Array, full: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> RowResult:
        """Flexibility of the row at the frequencies ``freqs`` [Hz] (each <= f_max).

        ``progress``, if given, is called with (frequencies done, total) after each one.
        """
        f = np.asarray(freqs, dtype=float)
        if f.ndim != 1 or f.size == 0:
            raise ParameterError("freqs: need a non-empty 1-D array of frequencies [Hz]")
        if np.any(f < 0) or np.any(f > self.f_max * (1 + 1e-9)):
            raise ParameterError(
                f"freqs in [{f.min():g}, {f.max():g}] Hz: must lie in [0, f_max = {self.f_max:g}] Hz of the model"
            )
        N = self.geometry.n_areas
        cols = np.zeros((f.size, N), dtype=np.complex128)
        Hs = np.zeros((f.size, N, N), dtype=np.complex128) if full else None
        for i, fi in enumerate(f):
            H, col = self.solve(2.0 * math.pi * fi, full=full)
            cols[i] = col
            if Hs is not None and H is not None:
                Hs[i] = H
            if progress is not None:
                progress(i + 1, f.size)
        info = {"mesh_wavelength_ratio": self.mesh_wavelength_ratio, "dr": self.dr, "r_max": self.r_max}
        return RowResult(
            freqs=f,
            positions=self.geometry.positions,
            flexibility=Hs,
            centre_column=cols,
            geometry=self.geometry,
            info=info,
        )


def row_sweep(
    profile: SoilProfile,
    freqs: Sequence[float] | Array,
    geometry: RowGeometry | None = None,
    *,
    full: bool = True,
    extrapolate: bool = False,
) -> RowResult:
    """Rigorous flexibility of a row of rigid areas (convenience wrapper).

    Parameters
    ----------
    profile : SoilProfile
        Soil.
    freqs : array_like
        Frequencies [Hz], >= 0.
    geometry : RowGeometry, optional
        Row and mesh (default: 41 areas, 0.6 m, 2.5 m x 0.285 m, 4 x 16 cells).
    full : bool
        Compute the whole N x N flexibility (else the centre column only).
    extrapolate : bool
        Also solve on the mesh refined twice in each direction and return the
        Richardson extrapolation (order 1) of the two flexibilities.
    """
    geometry = geometry or RowGeometry()
    f = np.asarray(freqs, dtype=float)
    fmax = float(f.max())
    res = RowModel(profile, geometry, f_max=fmax).sweep(f, full=full)
    if not extrapolate:
        return res
    fine = RowModel(profile, geometry.refined(2), f_max=fmax).sweep(f, full=full)
    Hx = None
    if res.flexibility is not None and fine.flexibility is not None:
        Hx = richardson(res.flexibility, fine.flexibility)
    col = richardson(res.centre_column, fine.centre_column)
    info = dict(fine.info)
    info["extrapolated"] = 1.0
    return RowResult(
        freqs=f, positions=res.positions, flexibility=Hx, centre_column=col, geometry=fine.geometry, info=info
    )


# ----------------------------------------------------------------------------
# rigid disk (axisymmetric rings) -- validation against Veletsos & Verbic
# ----------------------------------------------------------------------------


def _disk_static_inverse_distance(rho: Array, a: Array) -> Array:
    """int over the disk of radius a of 1/|x - x0| dA at distance rho from the centre [m].

    4 a E(rho/a) for rho <= a and 4 rho [E(a/rho) - (1 - a^2/rho^2) K(a/rho)] for rho > a
    (E, K complete elliptic integrals of modulus k; scipy takes m = k^2).
    """
    rho = np.asarray(rho, dtype=float)
    a = np.asarray(a, dtype=float)
    inside = rho <= a
    with np.errstate(divide="ignore", invalid="ignore"):
        m_in = np.where(inside, (rho / np.where(a > 0, a, 1.0)) ** 2, 0.0)
        m_out = np.where(inside, 0.0, (a / np.where(rho > 0, rho, 1.0)) ** 2)
        v_in = 4.0 * a * special.ellipe(m_in)
        v_out = 4.0 * rho * (special.ellipe(m_out) - (1.0 - m_out) * special.ellipk(m_out))
    return np.asarray(np.where(a <= 0, 0.0, np.where(inside, v_in, v_out)), dtype=np.float64)


def disk_impedance(
    profile: SoilProfile,
    radius: float,
    freqs: Sequence[float] | Array,
    n_rings: int = 16,
    grading: float = 0.7,
    n_theta: int = 64,
) -> CArray:
    """Vertical impedance of a rigid massless disk on the surface (relaxed contact) [N/m].

    Ring elements of uniform pressure (edges graded towards the rim),
    collocation at mid-radius; the Boussinesq part in closed form (complete
    elliptic integrals), the smooth remainder by Gauss points in r and the
    trapezoidal rule in the angle.

    Parameters
    ----------
    profile : SoilProfile
        Soil.
    radius : float
        Disk radius R [m].
    freqs : array_like
        Frequencies [Hz].
    n_rings : int
        Number of rings.
    grading : float
        Rim grading (0 uniform, 1 fully clustered).
    n_theta : int
        Angular points of the smooth-part quadrature.
    """
    if radius <= 0:
        raise ParameterError(f"radius = {radius}: must be > 0 [m]")
    u = np.linspace(0.0, 1.0, n_rings + 1)
    edges = radius * ((1.0 - grading) * u + grading * np.sin(0.5 * math.pi * u))
    rc = 0.5 * (edges[1:] + edges[:-1])
    ring_area = math.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    st = _disk_static_inverse_distance(rc[:, None], edges[None, 1:]) - _disk_static_inverse_distance(
        rc[:, None], edges[None, :-1]
    )
    gx, gw = np.polynomial.legendre.leggauss(4)
    rs = 0.5 * (edges[1:] + edges[:-1])[:, None] + 0.5 * np.diff(edges)[:, None] * gx[None, :]
    ws = 0.5 * np.diff(edges)[:, None] * gw[None, :] * rs
    th = (np.arange(n_theta) + 0.5) * math.pi / n_theta  # half circle, symmetric
    wth = 2.0 * math.pi / n_theta
    d = np.sqrt(
        rc[:, None, None, None] ** 2
        + rs[None, :, :, None] ** 2
        - 2.0 * rc[:, None, None, None] * rs[None, :, :, None] * np.cos(th)
    )
    wts = np.broadcast_to(ws[None, :, :, None] * wth, d.shape)
    r_max = 2.0 * radius
    fr = np.asarray(freqs, dtype=float)
    f_top = float(fr.max())
    lam = 0.87 * profile.min_cs / f_top if f_top > 0 else math.inf
    engine = KernelEngine(profile, r_max, min(r_max / 400.0, lam / 30.0), f_top)
    out = []
    for f in fr:
        ker = engine(2.0 * math.pi * f)
        sm = (ker.smooth(d.ravel()).reshape(d.shape) * wts).sum(axis=(2, 3))
        F = ker.c0 * st + sm
        p = np.linalg.solve(F, np.ones(n_rings, dtype=np.complex128))
        out.append(np.sum(p * ring_area))
    return np.asarray(out, dtype=np.complex128)
