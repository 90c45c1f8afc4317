"""Rail irregularities: random profiles from standard PSDs, isolated defects, wheel flats.

Sign convention
---------------
Every irregularity here is a vertical offset ``r`` [m] of the running
surface measured DOWNWARDS, like every displacement of the suite: a dip of
the rail surface (dipped joint, the lower rail after a step-down) is r > 0,
a raised spot r < 0. The contact compression is
``delta = z_wheel - w_rail - r`` (:mod:`clm_core.vehicle.contact`). Measured
profiles are usually given as *elevations* (positive up): files read with
:func:`load_profile_csv` hold ``position [m], elevation [m]`` and are
converted with r = -elevation. A wheel flat lowers the axle centre while it
is under the wheel, which acts like a dip under that wheel only: r_flat > 0.

Random profiles
---------------
One-sided power spectral densities S(Omega) [m^2/(rad/m)] of the vertical
profile, Omega = 2 pi / lambda the angular wavenumber [rad/m], with
variance = integral of S over Omega > 0:

- FRA classes 1–6 (US Federal Railroad Administration; Hamid & Yang 1981;
  as used by Fries & Coffey 1990 and Lei & Noda 2002, J. Sound Vib.
  258(1):147–165):
  S(Omega) = k A_v Omega_c^2 / (Omega^2 (Omega^2 + Omega_c^2)), k = 0.25,
  Omega_c = 0.8245 rad/m and A_v [cm^2 rad/m] = 1.2107, 1.0181, 0.6816,
  0.5376, 0.2095, 0.0339 for classes 1 to 6 (class 6 is the best track).
- German spectra (ORE B176 / DB; as tabulated by Zhai, Wang & Cai 2009,
  Vehicle Syst. Dyn. 47(11):1349–1376):
  S(Omega) = A_v Omega_c^2 / ((Omega^2 + Omega_r^2)(Omega^2 + Omega_c^2)),
  Omega_c = 0.8246 rad/m, Omega_r = 0.0206 rad/m, A_v = 4.032e-7 m rad (low
  disturbance, high-speed lines) and 1.080e-6 m rad (high disturbance).

Normalisations of these spectra differ between authors (one- or two-sided,
per Hz or per rad/m, the factor k); the forms above are the ones coded.
A profile is synthesised by an inverse FFT: cosines at Omega_k = 2 pi k / L
inside the wavelength band, amplitudes sqrt(2 S(Omega_k) dOmega), uniform
random phases from ``numpy.random.default_rng(seed)``. Its variance equals
sum S(Omega_k) dOmega exactly (only the phases are random).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from clm_core.arrays import Array
from clm_core.checks import finite as _fin
from clm_core.checks import positive as _posv
from clm_core.errors import InputError, ParameterError
from clm_core.params import PER_SLEEPER_NAMES, ModelParams, SleeperOverride

#: FRA vertical-profile parameters: class -> (A_v [m^2 rad/m], Omega_c [rad/m]).
FRA_CLASSES: Mapping[int, tuple[float, float]] = {
    1: (1.2107e-4, 0.8245),
    2: (1.0181e-4, 0.8245),
    3: (0.6816e-4, 0.8245),
    4: (0.5376e-4, 0.8245),
    5: (0.2095e-4, 0.8245),
    6: (0.0339e-4, 0.8245),
}
#: FRA scale factor k (Lei & Noda 2002 use 0.25).
FRA_K = 0.25
#: German spectra: level -> (A_v [m rad], Omega_c [rad/m], Omega_r [rad/m]).
GERMAN_LEVELS: Mapping[str, tuple[float, float, float]] = {
    "low": (4.032e-7, 0.8246, 0.0206),
    "high": (1.080e-6, 0.8246, 0.0206),
}
#: Names accepted by :func:`psd` and :func:`random_profile`.
SPECTRA: tuple[str, ...] = (*(f"fra{i}" for i in range(1, 7)), "german-low", "german-high")


def psd(spectrum: str, omega: ArrayLike) -> Array:
    """One-sided vertical-profile PSD S(Omega) [m^2/(rad/m)] of a named spectrum.

    Parameters
    ----------
    spectrum : str
        ``fra1`` .. ``fra6``, ``german-low``, ``german-high``.
    omega : array_like
        Angular wavenumbers Omega = 2 pi / lambda [rad/m], > 0.
    """
    om = np.asarray(omega, dtype=float)
    if np.any(~np.isfinite(om)) or np.any(om <= 0):
        raise InputError("psd: wavenumbers must be finite and > 0 rad/m")
    s = spectrum.lower()
    if s.startswith("fra") and s[3:].isdigit() and int(s[3:]) in FRA_CLASSES:
        Av, Oc = FRA_CLASSES[int(s[3:])]
        return np.asarray(FRA_K * Av * Oc**2 / (om**2 * (om**2 + Oc**2)), dtype=float)
    if s.startswith("german-") and s[7:] in GERMAN_LEVELS:
        Av, Oc, Or = GERMAN_LEVELS[s[7:]]
        return np.asarray(Av * Oc**2 / ((om**2 + Or**2) * (om**2 + Oc**2)), dtype=float)
    raise ParameterError(f"irregularity spectrum {spectrum!r}: unknown; known: {', '.join(SPECTRA)}")


def band_variance(spectrum: str, band: tuple[float, float]) -> float:
    """Variance [m^2] of a spectrum over a wavelength band (lambda_min, lambda_max) [m] (quadrature)."""
    from scipy.integrate import quad

    lo, hi = _check_band(band)
    val, _ = quad(lambda o: float(psd(spectrum, np.array([o]))[0]), 2 * math.pi / hi, 2 * math.pi / lo, limit=200)
    return float(val)


def _check_band(band: Sequence[float]) -> tuple[float, float]:
    if len(band) != 2:
        raise ParameterError(f"wavelength band {band!r}: need (lambda_min, lambda_max) in m")
    lo, hi = float(band[0]), float(band[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise ParameterError(f"wavelength band ({lo:g}, {hi:g}) m: need 0 < lambda_min < lambda_max, finite")
    return lo, hi


@dataclass(frozen=True)
class Profile:
    """A sampled rail irregularity r(x) [m] (positive downwards), linearly interpolated.

    Attributes
    ----------
    x : (n,) array
        Strictly increasing positions along the track [m].
    r : (n,) array
        Irregularity [m], positive = rail surface below nominal.
    name : str
        Description (spectrum and seed, or file name).
    """

    x: Array
    r: Array
    name: str = ""

    def __post_init__(self) -> None:
        x = np.asarray(self.x, dtype=float)
        r = np.asarray(self.r, dtype=float)
        if x.ndim != 1 or x.shape != r.shape or x.size < 2:
            raise InputError(f"profile {self.name!r}: need x and r of equal length >= 2 (got {x.shape}, {r.shape})")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(r))):
            bad = int(np.argmax(~(np.isfinite(x) & np.isfinite(r))))
            raise InputError(f"profile {self.name!r}: non-finite value at row {bad} (x = {x[bad]}, r = {r[bad]})")
        if np.any(np.diff(x) <= 0):
            bad = int(np.argmax(np.diff(x) <= 0))
            raise InputError(
                f"profile {self.name!r}: positions must increase strictly (row {bad + 1}: "
                f"x = {x[bad + 1]:g} m after {x[bad]:g} m)"
            )
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "r", r)

    def __call__(self, x: ArrayLike) -> Array:
        """r at positions ``x`` [m]; positions outside the profile raise InputError."""
        xx = np.asarray(x, dtype=float)
        if xx.size and (np.min(xx) < self.x[0] - 1e-9 or np.max(xx) > self.x[-1] + 1e-9):
            raise InputError(
                f"profile {self.name!r} covers [{self.x[0]:g}, {self.x[-1]:g}] m; the wheels run over "
                f"[{np.min(xx):g}, {np.max(xx):g}] m: extend the profile or shorten the run"
            )
        return np.asarray(np.interp(xx, self.x, self.r), dtype=float)

    def rms(self) -> float:
        """Root mean square of r about its mean [m]."""
        return float(np.std(self.r))


def random_profile(
    spectrum: str,
    x_start: float,
    length: float,
    seed: int | None = None,
    band: tuple[float, float] = (1.0, 50.0),
    dx: float | None = None,
) -> Profile:
    """Random vertical profile of a standard PSD over [x_start, x_start + length] [m].

    Parameters
    ----------
    spectrum : str
        ``fra1`` .. ``fra6``, ``german-low``, ``german-high`` (module docstring).
    x_start, length : float
        Start position and length of track to cover [m].
    seed : int or None
        Seed of ``numpy.random.default_rng``: the same seed gives the same profile.
    band : (float, float)
        Wavelength band (lambda_min, lambda_max) [m]; components outside are zero.
    dx : float, optional
        Sampling step [m]; default lambda_min / 20.

    Returns
    -------
    Profile
        Zero-mean profile; r = sum_k a_k cos(Omega_k (x - x_start) + phi_k),
        a_k = sqrt(2 S(Omega_k) dOmega), Omega_k = 2 pi k / L_p, dOmega = 2 pi / L_p.
        The synthesis period L_p >= max(length, 8 lambda_max) (a power of two
        times dx), so the longest band wavelength is sampled by >= 8
        wavenumber components below 2 pi / lambda_max and the profile does not
        repeat over the run.
    """
    lo, hi = _check_band(band)
    _posv("profile length", length, unit="m")
    _fin("profile x_start", x_start)
    h = lo / 20.0 if dx is None else float(dx)
    if not (math.isfinite(h) and 0 < h <= lo / 4):
        raise ParameterError(f"dx = {h:g} m: must be in (0, lambda_min / 4 = {lo / 4:g}] m")
    psd(spectrum, np.array([1.0]))  # validates the name
    Lp = max(length + h, 8.0 * hi)
    N = 1 << int(math.ceil(math.log2(Lp / h)))
    Lp = N * h
    k = np.arange(N // 2 + 1)
    omega = 2 * math.pi * k / Lp
    inband = (omega >= 2 * math.pi / hi) & (omega <= 2 * math.pi / lo) & (k > 0) & (k < N // 2)
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0.0, 2 * math.pi, size=k.size)
    amp = np.zeros(k.size)
    domega = 2 * math.pi / Lp
    amp[inband] = np.sqrt(2.0 * psd(spectrum, omega[inband]) * domega)
    c = amp * np.exp(1j * phase)
    r = np.fft.irfft(c, n=N) * (N / 2.0)
    n_keep = int(math.ceil(length / h)) + 2
    x = np.asarray(x_start + h * np.arange(n_keep), dtype=float)
    name = f"{spectrum} seed={seed} band=[{lo:g}, {hi:g}] m"
    return Profile(x=x, r=r[:n_keep].copy(), name=name)


def load_profile_csv(path: str | Path) -> Profile:
    """Read a measured profile: CSV rows ``position [m], elevation [m]`` (elevation positive UP).

    Lines starting with ``#`` and a non-numeric header row are skipped.
    The result holds r = -elevation (positive downwards, the suite's
    convention).

    Raises
    ------
    InputError
        Missing file, fewer than two rows, a non-numeric or non-finite value,
        positions not strictly increasing.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"irregularity file {str(p)!r} not found")
    xs: list[float] = []
    zs: list[float] = []
    with p.open(newline="") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue
            if len(row) < 2:
                raise InputError(f"{p}: line {lineno}: need two columns (position [m], elevation [m]), got {row!r}")
            try:
                xv, zv = float(row[0]), float(row[1])
            except ValueError:
                if not xs:  # header
                    continue
                raise InputError(f"{p}: line {lineno}: not a number: {row[:2]!r}") from None
            if not (math.isfinite(xv) and math.isfinite(zv)):
                raise InputError(f"{p}: line {lineno}: non-finite value ({xv}, {zv}); NaN/inf are not allowed")
            xs.append(xv)
            zs.append(zv)
    if len(xs) < 2:
        raise InputError(f"{p}: need at least two data rows (position [m], elevation [m])")
    try:
        return Profile(x=np.array(xs), r=-np.array(zs), name=p.name)
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None


# ------------------------------------------------------------------ isolated defects


@dataclass(frozen=True)
class DippedJoint:
    """A dipped rail joint: two straight ramps down to the joint (Jenkins et al. 1974).

    r(x) = depth (1 - |x - x0| / half_length) for |x - x0| < half_length, else 0.
    The total dip angle is 2 alpha = 2 depth / half_length [rad]: the wheel's
    vertical velocity changes by 2 alpha V at the joint, which excites the
    P1 (high-frequency, Hertz spring against rail mass) and P2 (unsprung mass
    on the track stiffness) force peaks.

    Parameters
    ----------
    x : float
        Joint position [m].
    depth : float
        Dip depth at the joint [m], > 0 (positive downwards).
    half_length : float
        Length of each ramp [m].
    """

    x: float
    depth: float
    half_length: float = 1.0

    def __post_init__(self) -> None:
        _fin("dipped-joint x", self.x)
        _posv("dipped-joint depth", self.depth)
        _posv("dipped-joint half_length", self.half_length)

    @property
    def total_angle(self) -> float:
        """Total joint angle 2 alpha [rad]."""
        return 2.0 * self.depth / self.half_length

    def __call__(self, x: Array, wheel_radius: Array | float = 0.0) -> Array:
        """r at positions x [m] (the wheel radius does not matter for small angles)."""
        return np.asarray(self.depth * np.maximum(0.0, 1.0 - np.abs(x - self.x) / self.half_length), dtype=float)


@dataclass(frozen=True)
class JointStep:
    """A height step at a rail joint, as the wheel centre sees it.

    The rail surface elevation changes by ``height`` at ``x`` (height > 0:
    the rail after the joint is higher, a step-up; < 0 a step-down). The
    wheel centre follows the envelope of the wheel circle (radius R) rolling
    over the corner: a step-up is met over u0 = sqrt(2 R h - h^2) before the
    joint, a step-down is left over sqrt(2 R |h| - h^2) after it.
    In the downward convention r = -elevation of the wheel-centre path.

    Parameters
    ----------
    x : float
        Joint position [m].
    height : float
        Elevation change [m] (positive = step up), non-zero.
    """

    x: float
    height: float

    def __post_init__(self) -> None:
        _fin("joint-step x", self.x)
        h = _fin("joint-step height", self.height)
        if h == 0.0:
            raise ParameterError("joint-step height = 0: must be non-zero (positive = step up) [m]")

    def __call__(self, x: Array, wheel_radius: Array | float = 0.46) -> Array:
        """r at wheel-centre positions x [m] for wheels of radius ``wheel_radius`` [m]."""
        R = np.broadcast_to(np.asarray(wheel_radius, dtype=float), np.shape(x))
        u = np.asarray(x, dtype=float) - self.x
        h = self.height
        if h > 0:  # step up: climb the corner before the joint
            rise = h - (R - np.sqrt(np.maximum(R**2 - u**2, 0.0)))
            elev = np.where(u >= 0, h, np.where(-u < np.sqrt(2 * R * h), np.maximum(rise, 0.0), 0.0))
        else:  # step down: roll off the corner after the joint
            drop = -(R - np.sqrt(np.maximum(R**2 - u**2, 0.0)))
            elev = np.where(u <= 0, 0.0, np.maximum(drop, h))
        return np.asarray(-elev, dtype=float)


@dataclass(frozen=True)
class WheelFlat:
    """A flat on one wheel, periodic with the wheel circumference 2 pi R.

    Parameters
    ----------
    wheel : int
        Wheel index (front to rear, from 0) carrying the flat.
    x : float
        A track position [m] where the flat's centre is under the wheel; the
        impacts recur every 2 pi R before and after.
    length : float
        Flat length L [m].
    depth : float or None
        Depth of the wheel-centre drop [m]. ``None``: the geometric value of
        the shape (rounded: L^2 / (16 R); fresh: R - sqrt(R^2 - L^2/4)).
    shape : {'rounded', 'fresh'}
        ``rounded``: the worn flat of Newton & Clark (1979, J. Mech. Eng.
        Sci. 21(4)), drop (d/2)(1 + cos(2 pi u / L)) for |u| < L/2 (u from
        the flat's centre), with L = sqrt(16 R d). ``fresh``: a newly formed
        flat (chord of the tread), the wheel pivoting on its edges: drop
        R - sqrt(R^2 - (L/2 - |u|)^2).
    """

    wheel: int
    x: float
    length: float
    depth: float | None = None
    shape: Literal["rounded", "fresh"] = "rounded"

    def __post_init__(self) -> None:
        if int(self.wheel) != self.wheel or self.wheel < 0:
            raise ParameterError(f"wheel-flat wheel = {self.wheel!r}: must be a wheel index >= 0")
        _fin("wheel-flat x", self.x)
        _posv("wheel-flat length", self.length)
        if self.depth is not None:
            _posv("wheel-flat depth", self.depth)
        if self.shape not in ("rounded", "fresh"):
            raise ParameterError(f"wheel-flat shape = {self.shape!r}: one of 'rounded', 'fresh'")
        if self.shape == "fresh" and self.depth is not None:
            raise ParameterError("wheel-flat: a 'fresh' flat's depth follows from its length; give length only")

    def drop(self, x: Array, wheel_radius: float) -> Array:
        """Wheel-centre drop r [m] (>= 0) at wheel positions x [m]."""
        R = float(wheel_radius)
        if self.length >= 2 * R:
            raise ParameterError(f"wheel-flat length = {self.length:g} m: must be < the wheel diameter {2 * R:g} m")
        circ = 2 * math.pi * R
        u = np.mod(np.asarray(x, dtype=float) - self.x + 0.5 * circ, circ) - 0.5 * circ
        inside = np.abs(u) < 0.5 * self.length
        if self.shape == "rounded":
            d = self.length**2 / (16 * R) if self.depth is None else float(self.depth)
            out = 0.5 * d * (1.0 + np.cos(2 * math.pi * u / self.length))
        else:
            a = 0.5 * self.length - np.abs(u)
            out = R - np.sqrt(np.maximum(R**2 - a**2, 0.0))
        return np.asarray(np.where(inside, out, 0.0), dtype=float)


RailDefect = DippedJoint | JointStep


@dataclass(frozen=True)
class Irregularity:
    """Everything that excites the wheels geometrically.

    Attributes
    ----------
    profile : Profile or None
        Random or measured rail profile (r, positive downwards).
    defects : tuple
        Isolated rail defects (:class:`DippedJoint`, :class:`JointStep`).
    flats : tuple of WheelFlat
        Wheel flats.
    lead_in : float
        Distance [m] each wheel travels before the rail profile (not the
        isolated defects) reaches full amplitude: a raised-cosine ramp that
        avoids the start transient of a wheel released at rest on a sloping
        profile. 0 disables it.
    """

    profile: Profile | None = None
    defects: tuple[RailDefect, ...] = ()
    flats: tuple[WheelFlat, ...] = ()
    lead_in: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "lead_in", _fin("lead_in", self.lead_in))
        if self.lead_in < 0:
            raise ParameterError(f"lead_in = {self.lead_in:g} m: must be >= 0")

    def wheel_irregularity(self, x: Array, x0: Array, wheel_radius: Array) -> Array:
        """r [m] under each wheel at positions ``x`` (n_t, n_w), wheels started at ``x0`` (n_w,).

        Sum of the (ramped) rail profile, the rail defects and the flats of
        each wheel.
        """
        x = np.atleast_2d(np.asarray(x, dtype=float))
        R = np.broadcast_to(np.asarray(wheel_radius, dtype=float), x.shape[1:])
        out = np.zeros_like(x)
        if self.profile is not None:
            rp = self.profile(x)
            if self.lead_in > 0:
                s = np.clip((x - np.asarray(x0)[None, :]) / self.lead_in, 0.0, 1.0)
                rp = rp * 0.5 * (1.0 - np.cos(math.pi * s))
            out += rp
        for d in self.defects:
            out += d(x, R[None, :])
        for f in self.flats:
            if f.wheel >= x.shape[1]:
                raise ParameterError(
                    f"wheel-flat wheel = {f.wheel}: the train has only {x.shape[1]} wheels (0..{x.shape[1] - 1})"
                )
            out[:, f.wheel] += f.drop(x[:, f.wheel], float(R[f.wheel]))
        return out


# ------------------------------------------------------------------ parsing and helpers


def parse_defect(text: str) -> DippedJoint | JointStep | WheelFlat | dict[str, float]:
    """Parse a ``--defect`` specification.

    Forms (lengths in m, angles in rad)::

        dipped-joint:x=50,depth=0.002[,half_length=1.0]
        dipped-joint:x=50,angle=0.01[,half_length=1.0]   (angle = total 2 alpha)
        joint-step:x=50,height=0.001                     (positive = step up)
        wheel-flat:wheel=0,x=20,length=0.05[,depth=...][,shape=rounded|fresh]
        stiffness:from=30,to=36,kb=20e6[,kp=...]         (per-sleeper override, see
                                                         :func:`local_stiffness_change`)

    Returns the defect, or for ``stiffness`` a mapping with ``from``, ``to``
    and the parameter values.
    """
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower()
    vals: dict[str, str] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        if "=" not in item:
            raise ParameterError(f"--defect {text!r}: expected KEY=VALUE items after the kind, got {item!r}")
        k, _, v = item.partition("=")
        vals[k.strip().lower()] = v.strip()

    def num(key: str, default: float | None = None) -> float:
        """The value of ``key`` as a finite float."""
        if key not in vals:
            if default is None:
                raise ParameterError(f"--defect {text!r}: missing {key}=...")
            return default
        return _fin(f"--defect {kind} {key}", vals[key])

    def only(allowed: Iterable[str]) -> None:
        extra = set(vals) - set(allowed)
        if extra:
            raise ParameterError(f"--defect {text!r}: unknown key(s) {sorted(extra)}; allowed {sorted(allowed)}")

    if kind == "dipped-joint":
        only(("x", "depth", "angle", "half_length"))
        hl = num("half_length", 1.0)
        if "angle" in vals and "depth" in vals:
            raise ParameterError(f"--defect {text!r}: give depth or angle, not both")
        depth = num("angle") * hl / 2.0 if "angle" in vals else num("depth")
        return DippedJoint(x=num("x"), depth=depth, half_length=hl)
    if kind == "joint-step":
        only(("x", "height"))
        return JointStep(x=num("x"), height=num("height"))
    if kind == "wheel-flat":
        only(("wheel", "x", "length", "depth", "shape"))
        shape = vals.get("shape", "rounded")
        if shape not in ("rounded", "fresh"):
            raise ParameterError(f"--defect {text!r}: shape = {shape!r}: one of rounded, fresh")
        w = num("wheel", 0.0)
        if w != int(w):
            raise ParameterError(f"--defect {text!r}: wheel = {w}: must be an integer index")
        return WheelFlat(
            wheel=int(w),
            x=num("x"),
            length=num("length"),
            depth=num("depth") if "depth" in vals else None,
            shape=shape,  # type: ignore[arg-type]
        )
    if kind == "stiffness":
        only(("from", "to", *PER_SLEEPER_NAMES))
        out = {k: num(k) for k in vals}
        if "from" not in out or "to" not in out:
            raise ParameterError(f"--defect {text!r}: needs from=X0,to=X1 [m]")
        if len(out) == 2:
            raise ParameterError(f"--defect {text!r}: name at least one of {', '.join(PER_SLEEPER_NAMES)}")
        return out
    raise ParameterError(f"--defect kind {kind!r}: unknown; one of dipped-joint, joint-step, wheel-flat, stiffness")


def local_stiffness_change(
    params: ModelParams,
    x_from: float,
    x_to: float,
    values: Mapping[str, float] | None = None,
    factors: Mapping[str, float] | None = None,
) -> ModelParams:
    """Add a per-sleeper override for the sleepers between two positions (a local track change).

    Parameters
    ----------
    params : ModelParams
        The track model.
    x_from, x_to : float
        Positions [m]; the sleepers at x = i * spacing with x_from <= x <= x_to
        are changed.
    values : mapping, optional
        New values by name (``kp dp ms kb db mf kf df kc dc``), e.g. ``{'kb': 20e6}``.
    factors : mapping, optional
        Multipliers of the uniform values by name, e.g. ``{'kb': 0.5}``.

    Returns
    -------
    ModelParams
        A copy with one more :class:`clm_core.params.SleeperOverride`.
    """
    a, b = _fin("x_from", x_from), _fin("x_to", x_to)
    if b < a:
        raise ParameterError(f"local stiffness change: x_to = {b:g} m < x_from = {a:g} m")
    d = params.track.spacing
    i0, i1 = int(math.ceil(a / d - 1e-9)), int(math.floor(b / d + 1e-9))
    if i1 < i0:
        raise ParameterError(f"local stiffness change [{a:g}, {b:g}] m: contains no sleeper (spacing {d:g} m)")
    new: dict[str, float] = {}
    base = {
        **{n: getattr(params.track, n) for n in ("kp", "dp", "ms", "kb", "db")},
        **{n: getattr(params.soil, n) for n in ("mf", "kf", "df", "kc", "dc")},
    }
    for name, v in (values or {}).items():
        if name not in PER_SLEEPER_NAMES:
            raise ParameterError(
                f"local stiffness change: unknown parameter {name!r}; allowed {', '.join(PER_SLEEPER_NAMES)}"
            )
        new[name] = _fin(name, v)
    for name, f in (factors or {}).items():
        if name not in PER_SLEEPER_NAMES:
            raise ParameterError(
                f"local stiffness change: unknown parameter {name!r}; allowed {', '.join(PER_SLEEPER_NAMES)}"
            )
        new[name] = base[name] * _fin(f"factor {name}", f)
    if not new:
        raise ParameterError("local stiffness change: give at least one value or factor")
    ov = SleeperOverride(sleepers=tuple(range(i0, i1 + 1)), values=new)
    return replace(params, overrides=(*params.overrides, ov))


__all__ = [
    "FRA_CLASSES",
    "GERMAN_LEVELS",
    "SPECTRA",
    "DippedJoint",
    "Irregularity",
    "JointStep",
    "Profile",
    "WheelFlat",
    "band_variance",
    "load_profile_csv",
    "local_stiffness_change",
    "parse_defect",
    "psd",
    "random_profile",
]
