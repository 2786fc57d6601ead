"""The WGS-84 earth: geodetic <-> local NED, normal gravity, ISA air density.

Geodesy is pymap3d's (WGS-84 ellipsoid); gravity is the WGS-84 normal gravity of NIMA TR8350.2
(3rd ed., 2000, ch. 4); density is the ISA troposphere (ICAO Doc 7488 / U.S. Standard
Atmosphere 1976), which JSBSim's standard atmosphere also follows, so the filter should use it
at its altitude rather than a constant sea-level value.

Conventions (NED axes, units, component axis first): ``docs/conventions.md``.
"""

import math
from dataclasses import dataclass

import numpy as np
import pymap3d
from numpy.typing import ArrayLike

__all__ = [
    "EULER_LABELS",
    "POSITION_NED_LABELS",
    "LocalGeodetic",
    "body_to_ned",
    "WGS84",
    "NedOrigin",
    "geodetic_to_ned",
    "isa_density_kgpm3",
    "ned_to_geodetic",
    "normal_gravity_mps2",
]

#: State labels of a NED position about the origin (m) and of the ZYX Euler attitude (rad), the
#: first and third blocks of every filter state (docs/conventions.md).
POSITION_NED_LABELS = ("pN_m", "pE_m", "pD_m")
EULER_LABELS = ("phi_rad", "theta_rad", "psi_rad")

#: The WGS-84 ellipsoid as pymap3d knows it.
WGS84 = pymap3d.Ellipsoid.from_name("wgs84")

# WGS-84 defining and derived constants, NIMA TR8350.2 tables 3.1, 3.3 and 3.4.
_A_M = 6378137.0  # semi-major axis a
_F = 1.0 / 298.257223563  # flattening f
_GAMMA_E_MPS2 = 9.7803253359  # normal gravity at the equator
_K_SOMIGLIANA = 0.00193185265241  # k = (b gamma_p) / (a gamma_e) - 1
_E2 = 0.00669437999014  # first eccentricity squared e^2
_M_RATIO = 0.00344978650684  # m = omega^2 a^2 b / GM

# ISA troposphere (ICAO Doc 7488; U.S. Standard Atmosphere 1976).
_T0_K = 288.15  # sea-level temperature
_RHO0_KGPM3 = 1.225  # sea-level density
_LAPSE_KPM = 0.0065  # temperature lapse rate
_G0_MPS2 = 9.80665  # standard gravity
_R_AIR_JPKGK = 287.05287  # specific gas constant of dry air
_R_EARTH_GEOPOTENTIAL_M = 6356766.0  # earth radius of the geopotential conversion (USSA 1976)
_TROPOPAUSE_M = 11000.0  # geopotential
_TROPOPAUSE_GEOMETRIC_M = (
    _R_EARTH_GEOPOTENTIAL_M * _TROPOPAUSE_M / (_R_EARTH_GEOPOTENTIAL_M - _TROPOPAUSE_M)
)
#: ISA troposphere: L / T0 (1/m) and the density exponent g0 / (R L) - 1 (about 4.2559).
ISA_LAPSE_OVER_T0_PM = _LAPSE_KPM / _T0_K
ISA_DENSITY_EXPONENT = _G0_MPS2 / (_R_AIR_JPKGK * _LAPSE_KPM) - 1.0
ISA_RHO0_KGPM3 = _RHO0_KGPM3
ISA_EARTH_RADIUS_M = _R_EARTH_GEOPOTENTIAL_M


@dataclass(frozen=True)
class NedOrigin:
    """Geodetic origin of the local NED frame (WGS-84).

    Parameters
    ----------
    lat_deg, lon_deg : float
        Geodetic latitude and longitude of the origin (deg).
    alt_m : float
        Height of the origin above the ellipsoid (m).
    """

    lat_deg: float
    lon_deg: float
    alt_m: float

    def __post_init__(self) -> None:
        for name in ("lat_deg", "lon_deg", "alt_m"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"NedOrigin.{name}: expected a finite number")
        if abs(self.lat_deg) > 90.0:
            raise ValueError(f"NedOrigin.lat_deg: expected |lat| <= 90, got {self.lat_deg}")

    def to_ned(self, lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike) -> np.ndarray:
        """Geodetic -> NED about this origin; see :func:`geodetic_to_ned`."""
        return geodetic_to_ned(lat_deg, lon_deg, alt_m, self)

    def to_geodetic(self, ned_m: ArrayLike) -> np.ndarray:
        """NED about this origin -> geodetic; see :func:`ned_to_geodetic`."""
        return ned_to_geodetic(ned_m, self)


def body_to_ned(euler_rad: np.ndarray) -> np.ndarray:
    """``R_nb = Rz(psi) Ry(theta) Rx(phi)`` for ZYX Euler angles (B&M eq. 3.14).

    Written out: it runs on every published estimate, where scipy's ``Rotation`` cost ten
    times as much (170-200 us against 17-25 us on the loaded CI machine); the tests hold the
    two to 1e-15.
    """
    phi, theta, psi = (float(a) for a in euler_rad)
    sph, cph = math.sin(phi), math.cos(phi)
    sth, cth = math.sin(theta), math.cos(theta)
    sps, cps = math.sin(psi), math.cos(psi)
    return np.array(
        [
            [cth * cps, sph * sth * cps - cph * sps, cph * sth * cps + sph * sps],
            [cth * sps, sph * sth * sps + cph * cps, cph * sth * sps - sph * cps],
            [-sth, sph * cth, cph * cth],
        ]
    )


def geodetic_to_ned(
    lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike, origin: NedOrigin
) -> np.ndarray:
    """WGS-84 geodetic coordinates to local NED about an origin (pymap3d).

    Parameters
    ----------
    lat_deg, lon_deg : array_like
        Geodetic latitude and longitude (deg), broadcastable shapes.
    alt_m : array_like
        Height above the ellipsoid (m).
    origin : NedOrigin
        Origin of the NED frame.

    Returns
    -------
    numpy.ndarray
        ``(3, *batch)`` array ``[north, east, down]`` (m).
    """
    n, e, d = pymap3d.geodetic2ned(
        np.asarray(lat_deg, dtype=float),
        np.asarray(lon_deg, dtype=float),
        np.asarray(alt_m, dtype=float),
        origin.lat_deg,
        origin.lon_deg,
        origin.alt_m,
        ell=WGS84,
        deg=True,
    )
    return np.stack(np.broadcast_arrays(n, e, d))


def ned_to_geodetic(ned_m: ArrayLike, origin: NedOrigin) -> np.ndarray:
    """Local NED about an origin to WGS-84 geodetic coordinates (pymap3d).

    Parameters
    ----------
    ned_m : array_like
        ``(3, *batch)`` positions ``[north, east, down]`` (m).
    origin : NedOrigin
        Origin of the NED frame.

    Returns
    -------
    numpy.ndarray
        ``(3, *batch)`` array ``[lat_deg, lon_deg, alt_m]`` (height above the ellipsoid).
    """
    ned = np.asarray(ned_m, dtype=float)
    if ned.shape[:1] != (3,):
        raise ValueError(f"ned_m: expected shape (3, ...), got {ned.shape}")
    lat, lon, alt = pymap3d.ned2geodetic(
        ned[0],
        ned[1],
        ned[2],
        origin.lat_deg,
        origin.lon_deg,
        origin.alt_m,
        ell=WGS84,
        deg=True,
    )
    return np.stack(np.broadcast_arrays(lat, lon, alt))


def normal_gravity_mps2(lat_deg: ArrayLike, alt_m: ArrayLike = 0.0) -> np.ndarray:
    """WGS-84 normal gravity magnitude at a geodetic latitude and height.

    Somigliana's closed formula on the ellipsoid (NIMA TR8350.2 eq. 4-1) with the
    second-order free-air height correction (TR8350.2 eq. 4-3), valid for small heights
    (aircraft altitudes) above the ellipsoid.

    Parameters
    ----------
    lat_deg : array_like
        Geodetic latitude (deg).
    alt_m : array_like, optional
        Height above the ellipsoid (m), default 0.

    Returns
    -------
    numpy.ndarray
        Normal gravity (m/s^2), the broadcast shape of the inputs; it points along the
        ellipsoid normal (NED "down").
    """
    sin2 = np.sin(np.radians(np.asarray(lat_deg, dtype=float))) ** 2
    h = np.asarray(alt_m, dtype=float)
    # TR8350.2 eq. (4-1): Somigliana
    gamma = _GAMMA_E_MPS2 * (1.0 + _K_SOMIGLIANA * sin2) / np.sqrt(1.0 - _E2 * sin2)
    # TR8350.2 eq. (4-3): free-air correction to second order in h / a
    scale = 1.0 - 2.0 / _A_M * (1.0 + _F + _M_RATIO - 2.0 * _F * sin2) * h + 3.0 / _A_M**2 * h**2
    return gamma * scale


def isa_density_kgpm3(alt_m: ArrayLike) -> np.ndarray:
    """ISA troposphere air density at a geometric altitude.

    ``rho = rho0 (T / T0)^(g0 / (R L) - 1)`` with ``T = T0 - L H``, where ``H`` is the
    geopotential altitude ``r0 h / (r0 + h)`` (U.S. Standard Atmosphere 1976, eq. 18 and 42).

    Parameters
    ----------
    alt_m : array_like
        Geometric altitude above mean sea level (m), within the troposphere (below 11 km).

    Returns
    -------
    numpy.ndarray
        Density (kg/m^3), the shape of ``alt_m``.

    Raises
    ------
    ValueError
        If an altitude lies at or above the tropopause (11 km), where the formula is wrong.
    """
    h = np.asarray(alt_m, dtype=float)
    if np.any(h >= _TROPOPAUSE_GEOMETRIC_M):
        raise ValueError("isa_density_kgpm3: altitude beyond the troposphere (11 km)")
    return isa_density_unchecked(h)


def isa_density_unchecked(alt_m: np.ndarray | float) -> np.ndarray | float:
    """:func:`isa_density_kgpm3` without the range check, for hot loops (same formula)."""
    # USSA 1976 eq. (18): geopotential altitude; eq. (42): troposphere density
    geopotential_m = _R_EARTH_GEOPOTENTIAL_M * alt_m / (_R_EARTH_GEOPOTENTIAL_M + alt_m)
    return _RHO0_KGPM3 * (1.0 - ISA_LAPSE_OVER_T0_PM * geopotential_m) ** ISA_DENSITY_EXPONENT


# the ellipsoid pymap3d's conversions use (WGS84 above)
_WGS84_A_M = WGS84.semimajor_axis
_WGS84_F = WGS84.flattening
_WGS84_B_M = WGS84.semiminor_axis
_WGS84_E2 = _WGS84_F * (2.0 - _WGS84_F)
_WGS84_EP2 = _WGS84_E2 / (1.0 - _WGS84_E2)


class LocalGeodetic:
    """Geodetic <-> NED about one origin, in scalar arithmetic with the origin's frame cached.

    The same transforms as :func:`ned_to_geodetic` and :func:`geodetic_to_ned` (pymap3d, WGS-84),
    for one point at a time: the origin's ECEF position and NED axes are computed once, geodetic ->
    ECEF is closed form, and ECEF -> geodetic is Bowring's (1976) formula iterated twice. Within 10
    km of the origin and from -400 m to 10 km of height the two agree to well under a millimetre
    (the tests hold them to 1 mm); pymap3d's array code costs several hundred microseconds a call,
    this costs a few, and it runs on every filter step.

    Parameters
    ----------
    origin : NedOrigin
    """

    def __init__(self, origin: NedOrigin) -> None:
        self.origin = origin
        lat = math.radians(origin.lat_deg)
        lon = math.radians(origin.lon_deg)
        self._origin_ecef = self._ecef(lat, lon, origin.alt_m)
        sl, cl = math.sin(lat), math.cos(lat)
        so, co = math.sin(lon), math.cos(lon)
        # rows: north, east, down axes in ECEF
        self._axes = (
            (-sl * co, -sl * so, cl),
            (-so, co, 0.0),
            (-cl * co, -cl * so, -sl),
        )

    @staticmethod
    def _ecef(lat_rad: float, lon_rad: float, alt_m: float) -> tuple[float, float, float]:
        sl, cl = math.sin(lat_rad), math.cos(lat_rad)
        n = _WGS84_A_M / math.sqrt(1.0 - _WGS84_E2 * sl * sl)
        r = (n + alt_m) * cl
        return r * math.cos(lon_rad), r * math.sin(lon_rad), (n * (1.0 - _WGS84_E2) + alt_m) * sl

    def to_geodetic(
        self, north_m: float, east_m: float, down_m: float
    ) -> tuple[float, float, float]:
        """``(lat_deg, lon_deg, alt_m)`` of a NED position (height above the ellipsoid)."""
        (n0, n1, n2), (e0, e1, _), (d0, d1, d2) = self._axes
        ox, oy, oz = self._origin_ecef
        x = ox + n0 * north_m + e0 * east_m + d0 * down_m
        y = oy + n1 * north_m + e1 * east_m + d1 * down_m
        z = oz + n2 * north_m + d2 * down_m
        p = math.hypot(x, y)
        a, b = _WGS84_A_M, _WGS84_B_M
        beta = math.atan2(a * z, b * p)  # reduced latitude, first guess
        for _ in range(2):
            sb, cb = math.sin(beta), math.cos(beta)
            lat = math.atan2(z + _WGS84_EP2 * b * sb**3, p - _WGS84_E2 * a * cb**3)
            beta = math.atan2((1.0 - _WGS84_F) * math.sin(lat), math.cos(lat))
        sl = math.sin(lat)
        n = a / math.sqrt(1.0 - _WGS84_E2 * sl * sl)
        alt = p * math.cos(lat) + (z + _WGS84_E2 * n * sl) * sl - n
        return math.degrees(lat), math.degrees(math.atan2(y, x)), alt

    def to_ned(self, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
        """``(north, east, down)`` (m) of a geodetic position."""
        x, y, z = self._ecef(math.radians(lat_deg), math.radians(lon_deg), alt_m)
        ox, oy, oz = self._origin_ecef
        dx, dy, dz = x - ox, y - oy, z - oz
        (n0, n1, n2), (e0, e1, _), (d0, d1, d2) = self._axes
        return (
            n0 * dx + n1 * dy + n2 * dz,
            e0 * dx + e1 * dy,
            d0 * dx + d1 * dy + d2 * dz,
        )
