"""Fault modes are generated, named and ordered as in the paper's Table 2."""

import itertools

import numpy as np
import pytest

from immukf_sitl.estimation import (
    FaultMode,
    all_fault_modes,
    fault_mode_output,
    single_fault_modes,
)


def test_sixty_four_distinct_modes_in_paper_order():
    modes = all_fault_modes()
    assert len(modes) == 64 and len(set(modes)) == 64
    counts = [len(m.channels) for m in modes]
    assert counts == sorted(counts)
    # paper's Table 2 examples: I=11 is C=1,5 (x, q); I=18 is C=3,5; I=34 is C=2-3,5; I=64 all
    assert FaultMode.from_name("x+q").paper_index == 11
    assert FaultMode.from_name("z+q").paper_index == 18
    assert FaultMode.from_name("y+z+q").paper_index == 34
    assert modes[-1].channels == ("x", "y", "z", "p", "q", "r")
    assert [len(list(g)) for _, g in itertools.groupby(counts)] == [1, 6, 15, 20, 15, 6, 1]


def test_single_modes_are_none_then_each_channel():
    assert [m.name for m in single_fault_modes()] == ["none", "x", "y", "z", "p", "q", "r"]
    assert FaultMode.from_name("q").description == "q gyro"
    assert FaultMode(0).description == "fault-free"
    np.testing.assert_array_equal(FaultMode.from_name("y+r").healthy_mask, [1, 0, 1, 1, 1, 0])


def test_bits_match_highres_imu_fields_updated_order():
    # HIGHRES_IMU: XACC 1, YACC 2, ZACC 4, XGYRO 8, YGYRO 16, ZGYRO 32
    assert [FaultMode.from_name(c).bits for c in "xyzpqr"] == [1, 2, 4, 8, 16, 32]


def test_bad_names_and_bits_are_rejected():
    with pytest.raises(ValueError, match="unknown IMU channel 'w'"):
        FaultMode.from_name("x+w")
    with pytest.raises(ValueError, match="\\[0, 63\\]"):
        FaultMode(64)


def test_masked_output_predicts_zero_on_failed_channels_and_leaves_gps_alone():
    modes = [FaultMode(0), FaultMode.from_name("q"), FaultMode.from_name("x+r")]

    def healthy(t, x, u, w):
        return np.concatenate([x[:6], x[:2] * 10.0])  # six IMU channels + two extra

    g = fault_mode_output(healthy, modes, "zero", n_extra=2)
    x = np.arange(1.0, 7.0)[:, None, None] * np.ones((6, 3, 5))
    w = np.full((8, 3, 5), 0.5)
    z = g(0.0, x, None, w)
    assert z.shape == (8, 3, 5)
    np.testing.assert_array_equal(z[:, 0, 0], [1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 10.5, 20.5])
    np.testing.assert_array_equal(z[:, 1, 0], [1.5, 2.5, 3.5, 4.5, 0.5, 6.5, 10.5, 20.5])
    np.testing.assert_array_equal(z[:, 2, 0], [0.5, 2.5, 3.5, 4.5, 5.5, 0.5, 10.5, 20.5])
