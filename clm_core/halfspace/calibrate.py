"""CLM soil parameters straight from a soil profile (Kouroussis et al. 2011, Sec. 4.1).

Steps:

1. rigorous flexibility of a row of 2n + 1 rigid massless rectangular areas
   (the sleeper–ballast contact areas, 2.5 m x 0.285 m, long side across
   the track, spacing d along it) on the layered viscoelastic half-space
   (:mod:`clm_core.halfspace.bem`);
2. unit force on the centre area: displacements X_j, j = -n..n;
3. the two sums S = F / sum_j X_j (Eq. 16) and A = F / sum_j (-1)^j X_j (Eq. 18);
4. band- and norm-explicit least squares for m_f, k_f, d_f, k_c, d_c from
   both sums at once (default route ``"joint"``), or m_f, k_f, d_f from S
   and then k_c, d_c from A (route ``"total-first"``)
   (:func:`clm_core.soil.fit.fit_clm_sums`); the fit quality of both sums is
   reported, and the other route is fitted too for comparison.

The impedance of one isolated area is computed as well, with its Lysmer fit
(Eq. 3) and its static stiffness next to the estimate of Eq. (6).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from clm_core.errors import ParameterError, StabilityError
from clm_core.halfspace.bem import RowGeometry, RowModel, RowResult
from clm_core.profile import SoilProfile
from clm_core.soil.chain import chain_frequency_response
from clm_core.soil.fit import ROUTES, ClmSumFit, LysmerFit, Norm, Route, fit_clm_sums, fit_lysmer
from clm_core.soil.formulas import static_stiffness_rectangle

__all__ = ["SoilCalibration", "auto_geometry", "calibrate_profile"]

#: Default frequency grid of the rigorous sweep [Hz].
DEFAULT_FREQS = np.arange(0.0, 151.0, 1.0)


def auto_geometry(
    profile: SoilProfile,
    f_max: float,
    *,
    n_areas: int = 41,
    spacing: float = 0.6,
    width: float = 0.285,
    length: float = 2.5,
    nx: int = 6,
    cells_per_wavelength: float = 3.0,
) -> RowGeometry:
    """Default mesh: cosine-graded cells, nx = 6 along the track, ny from the wavelength.

    ny is the smallest even number >= 12 whose largest (middle) cell,
    about pi L / (2 ny), is at most lambda_R / ``cells_per_wavelength`` at
    ``f_max`` (lambda_R ~ 0.87 c_s,min / f). The convergence study in
    ``docs/halfspace.md`` shows this mesh within ~2 % of the extrapolated
    sums for the Mevergnies profile up to 150 Hz.
    """
    lam = 0.87 * profile.min_cs / f_max if f_max > 0 else math.inf
    ny = 12
    if math.isfinite(lam):
        need = math.pi * length / 2.0 * cells_per_wavelength / lam
        ny = max(ny, int(2 * math.ceil(need / 2.0)))
    return RowGeometry(
        n_areas=n_areas, spacing=spacing, width=width, length=length, nx=nx, ny=ny, grading=1.0, n_gauss=2
    )


@dataclass(frozen=True)
class SoilCalibration:
    """Result of :func:`calibrate_profile`.

    Attributes
    ----------
    profile : SoilProfile
        The soil.
    row : RowResult
        Rigorous flexibility of the row (centre column at least).
    fit : ClmSumFit
        Fitted CLM parameters, band, norm and residuals.
    single_freqs : ndarray
        Frequencies of the single-area impedance [Hz].
    single_impedance : ndarray of complex
        Impedance F / X of one isolated area [N/m].
    lysmer : LysmerFit
        Lysmer fit of the single-area impedance (same band and norm).
    eq6_static : float
        Eq. (6) with the top-layer E, nu [N/m].
    other_route : ClmSumFit or str
        The same fit by the other route (``"total-first"`` for a joint fit
        and vice versa), or why it failed (e.g. a non-admissible set).
    """

    profile: SoilProfile
    row: RowResult
    fit: ClmSumFit
    single_freqs: NDArray[np.float64]
    single_impedance: NDArray[np.complex128]
    lysmer: LysmerFit
    eq6_static: float
    other_route: ClmSumFit | str = ""

    @property
    def freqs(self) -> NDArray[np.float64]:
        """Frequencies of the row sweep [Hz]."""
        return self.row.freqs

    @property
    def total_sum(self) -> NDArray[np.complex128]:
        """Rigorous F / sum_j X_j [N/m]."""
        return self.row.total_sum()

    @property
    def alternating_sum(self) -> NDArray[np.complex128]:
        """Rigorous F / sum_j (-1)^j X_j [N/m]."""
        return self.row.alternating_sum()

    @property
    def single_static(self) -> float:
        """Static stiffness of one isolated area from the BEM [N/m] (NaN without f = 0)."""
        i = np.nonzero(self.single_freqs == 0.0)[0]
        return float(self.single_impedance[i[0]].real) if i.size else math.nan

    def clm_response(self) -> NDArray[np.complex128]:
        """Displacements of the fitted CLM chain (same length) per unit centre force [m/N], (nf, N)."""
        return chain_frequency_response(self.fit.params, self.row.geometry.n_areas, self.freqs)

    def fit_quality(self) -> dict[str, Any]:
        """Quality of the fit of both sums (relative RMS residual, largest relative error) [-].

        With the route, band, norm and active constraints, and the same
        figures for the other route (or why it failed).
        """
        fit, other = self.fit, self.other_route
        out: dict[str, Any] = {
            "route": fit.route,
            "band_hz": list(fit.band),
            "norm": fit.norm,
            **fit.quality(),
            "constrained": list(fit.constrained),
            "mf_unconstrained": fit.mf_unconstrained,
        }
        if isinstance(other, ClmSumFit):
            out["other_route"] = {
                "route": other.route,
                **other.params,
                **other.quality(),
                "constrained": list(other.constrained),
                "mf_unconstrained": other.mf_unconstrained,
            }
        elif other:
            out["other_route"] = {"error": other}
        return out

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary: fitted values, residuals, band, norm, static stiffness vs Eq. (6)."""
        f = self.freqs
        g = self.row.geometry
        picks = {}
        for fv in (0.0, 10.0, 50.0, 100.0):
            i = np.nonzero(np.isclose(f, fv))[0]
            if i.size:
                s = self.total_sum[i[0]]
                a = self.alternating_sum[i[0]]
                picks[f"{fv:g}"] = {
                    "total": [float(s.real), float(s.imag)],
                    "alternating": [float(a.real), float(a.imag)],
                }
        return {
            "profile": {
                "name": self.profile.name,
                "source": self.profile.source,
                "notes": list(self.profile.notes),
                "layers": self.profile.to_dict()["layers"],
            },
            "geometry": {
                "n_areas": g.n_areas,
                "spacing": g.spacing,
                "width": g.width,
                "length": g.length,
                "nx": g.nx,
                "ny": g.ny,
                "grading": g.grading,
                "n_gauss": g.n_gauss,
            },
            "conventions": {
                "time": "exp(+i w t)",
                "units": "SI (N, m, s, kg)",
                "damping": "E* = E (1 + i w beta + 2 i xi)",
                "sign": "force and displacement positive downwards",
            },
            "fit": self.fit.to_dict(),
            "fit_quality": self.fit_quality(),
            "sums_at": picks,
            "single_area": {
                "static_bem": self.single_static,
                "static_eq6": self.eq6_static,
                "ratio_bem_eq6": self.single_static / self.eq6_static,
                "lysmer_fit": self.lysmer.to_dict(),
            },
            "row_info": dict(self.row.info),
        }


def calibrate_profile(
    profile: SoilProfile,
    *,
    freqs: Sequence[float] | NDArray[np.float64] | None = None,
    fmin: float = 0.0,
    fmax: float = 80.0,
    norm: Norm = "ls",
    n_areas: int = 41,
    spacing: float = 0.6,
    geometry: RowGeometry | None = None,
    mass: Literal["nonnegative", "free"] = "nonnegative",
    on_unstable: Literal["raise", "clip"] = "raise",
    full: bool = False,
    progress: Callable[[str, float], None] | None = None,
    route: Route = "joint",
) -> SoilCalibration:
    """Fit CLM parameters to the rigorous response of a row of contact areas.

    Parameters
    ----------
    profile : SoilProfile
        The soil.
    freqs : array_like, optional
        Frequencies of the sweep [Hz] (default 0..150 Hz step 1 Hz; must
        contain the band, and 0 Hz for the static values).
    fmin, fmax : float
        Fit band [Hz].
    norm : {"ls", "relative"}
        Fit norm (:mod:`clm_core.soil.fit`).
    n_areas : int
        Number of areas 2n + 1 (41: n = 20, as in the paper).
    spacing : float
        Sleeper spacing d [m].
    geometry : RowGeometry, optional
        Explicit row and mesh (overrides ``n_areas`` and ``spacing``);
        default :func:`auto_geometry`.
    mass, on_unstable
        Constraints, see :func:`clm_core.soil.fit.fit_clm_sums`.
    full : bool
        Keep the full N x N flexibility (else the centre column only).
    progress : callable, optional
        Called with (stage, fraction of the work done in [0, 1]) during the sweeps.
    route : {"joint", "total-first"}
        Both sums at once (default: the CLM is defined by both), or m_f,
        k_f, d_f from the total sum alone and then k_c, d_c from the
        alternating sum (:mod:`clm_core.soil.fit`). The other route is
        fitted as well and kept in ``other_route``.

    Returns
    -------
    SoilCalibration
    """
    f = DEFAULT_FREQS if freqs is None else np.asarray(freqs, dtype=float)
    if f.ndim != 1 or f.size < 3 or np.any(f < 0) or np.any(np.diff(f) <= 0):
        raise ParameterError("freqs: need an increasing 1-D array of >= 3 frequencies >= 0 [Hz]")
    f_top = float(f.max())
    geo = geometry or auto_geometry(profile, f_top, n_areas=n_areas, spacing=spacing)
    if route not in ROUTES:
        raise ParameterError(f"route = {route!r}: must be one of {ROUTES}")

    def report(stage: str, lo: float, hi: float) -> Callable[[int, int], None] | None:
        if progress is None:
            return None
        return lambda i, n: progress(stage, lo + (hi - lo) * i / n)

    row = RowModel(profile, geo, f_max=f_top).sweep(f, full=full, progress=report("row sweep", 0.0, 0.9))
    fits: dict[str, ClmSumFit | str] = {}
    for r in (route, *(x for x in ROUTES if x != route)):
        try:
            fits[r] = fit_clm_sums(
                f,
                row.total_sum(),
                row.alternating_sum(),
                fmin=fmin,
                fmax=fmax,
                norm=norm,
                mass=mass,
                on_unstable=on_unstable,
                n_areas=geo.n_areas,
                route=r,
            )
        except StabilityError as exc:
            if r == route:
                raise
            fits[r] = str(exc)
    fit = fits.pop(route)
    assert isinstance(fit, ClmSumFit)
    other = next(iter(fits.values()))
    single_geo = replace(geo, n_areas=1)
    single = RowModel(profile, single_geo, f_max=f_top).sweep(f, full=False, progress=report("single area", 0.9, 1.0))
    Ksingle = 1.0 / single.centre_column[:, 0]
    lys = fit_lysmer(f, Ksingle, fmin=fmin, fmax=fmax, norm=norm, mass=mass)
    top = profile.top
    eq6 = static_stiffness_rectangle(geo.length, geo.width, top.E, top.nu)
    return SoilCalibration(
        profile=profile,
        row=row,
        fit=fit,
        single_freqs=f,
        single_impedance=np.asarray(Ksingle),
        lysmer=lys,
        eq6_static=eq6,
        other_route=other,
    )
