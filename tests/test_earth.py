"""WGS-84 earth: geodesy round trip, normal gravity, ISA density."""

import numpy as np
import pytest

from immukf_sitl.models.earth import (
    NedOrigin,
    geodetic_to_ned,
    isa_density_kgpm3,
    ned_to_geodetic,
    normal_gravity_mps2,
)


@pytest.mark.parametrize("lat0_deg", [-80.0, -45.0, 0.0, 33.3, 80.0])
def test_ned_geodetic_round_trip_to_a_millimetre(lat0_deg: float) -> None:
    origin = NedOrigin(lat0_deg, 151.2, 250.0)
    n, e, d = np.meshgrid(
        np.linspace(-5000.0, 5000.0, 7), np.linspace(-5000.0, 5000.0, 7), [-2000.0, 0.0, 300.0]
    )
    ned = np.stack([n, e, d])
    geo = ned_to_geodetic(ned, origin)
    assert geo.shape == ned.shape
    back = geodetic_to_ned(geo[0], geo[1], geo[2], origin)
    np.testing.assert_allclose(back, ned, rtol=0.0, atol=1e-3)
    # and the other way round, on a geodetic grid around the origin
    lat, lon = np.meshgrid(
        lat0_deg + np.linspace(-0.03, 0.03, 5), 151.2 + np.linspace(-0.1, 0.1, 5)
    )
    ned2 = origin.to_ned(lat, lon, 400.0)
    geo2 = origin.to_geodetic(ned2)
    np.testing.assert_allclose(geo2[0], lat, rtol=0.0, atol=1e-8)  # 1e-8 deg ~ 1 mm
    np.testing.assert_allclose(geo2[1], lon, rtol=0.0, atol=1e-7)
    np.testing.assert_allclose(geo2[2], 400.0, rtol=0.0, atol=1e-3)


def test_ned_axes_point_north_east_down() -> None:
    origin = NedOrigin(10.0, 20.0, 0.0)
    north = origin.to_ned(10.001, 20.0, 0.0)
    east = origin.to_ned(10.0, 20.001, 0.0)
    up = origin.to_ned(10.0, 20.0, 100.0)
    assert north[0] > 100.0 and abs(north[1]) < 1e-6
    assert east[1] > 100.0 and abs(east[0]) < 1e-3
    np.testing.assert_allclose(up, [0.0, 0.0, -100.0], atol=1e-6)


def test_origin_validation() -> None:
    with pytest.raises(ValueError, match="lat_deg"):
        NedOrigin(91.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="alt_m: expected a finite"):
        NedOrigin(0.0, 0.0, float("nan"))
    with pytest.raises(ValueError, match=r"expected shape \(3, \.\.\.\)"):
        ned_to_geodetic(np.zeros((2, 4)), NedOrigin(0.0, 0.0, 0.0))


def test_normal_gravity_matches_published_wgs84_values() -> None:
    # NIMA TR8350.2 table 3.4: gamma_e and gamma_p
    assert normal_gravity_mps2(0.0) == pytest.approx(9.7803253359, abs=1e-9)
    assert normal_gravity_mps2(90.0) == pytest.approx(9.8321849378, abs=1e-9)
    assert normal_gravity_mps2(-90.0) == pytest.approx(9.8321849378, abs=1e-9)
    # TR8350.2 table 3.4: mean value of normal gravity 9.7976432222 lies between
    g45 = normal_gravity_mps2(45.0)
    assert 9.80 < g45 < 9.81
    # height: the free-air gradient is 0.3086 mGal/m = 3.086e-6 s^-2 at mid latitudes
    drop = normal_gravity_mps2(45.0, 0.0) - normal_gravity_mps2(45.0, 1000.0)
    assert drop == pytest.approx(3.086e-3, rel=2e-3)
    # vectorised with broadcasting
    g = normal_gravity_mps2(np.array([[0.0], [90.0]]), np.array([0.0, 1000.0, 2000.0]))
    assert g.shape == (2, 3)
    assert np.all(np.diff(g, axis=1) < 0.0)


def test_isa_density() -> None:
    assert isa_density_kgpm3(0.0) == pytest.approx(1.225, abs=1e-12)
    # U.S. Standard Atmosphere 1976 table: 1000 m 1.1117, 5000 m 0.73643 kg/m^3
    np.testing.assert_allclose(isa_density_kgpm3([1000.0, 5000.0]), [1.1117, 0.73643], rtol=2e-4)
    # JSBSim's standard atmosphere gives 1.213 at 100 m
    assert isa_density_kgpm3(100.0) == pytest.approx(1.213, abs=1e-3)
    with pytest.raises(ValueError, match="troposphere"):
        isa_density_kgpm3(12000.0)
