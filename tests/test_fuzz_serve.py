"""Property-based fuzzing of ``serve``'s packet handling, interleaved with a recorded flight.

The first 20 s of ``tests/data/fault_free.tlog`` go datagram by datagram into
:meth:`EstimatorService.on_datagram` (the path every UDP datagram takes), with hypothesis
choosing where to insert random bytes, truncated and bit-flipped copies of real frames, NaN and
Inf readings, duplicated and reordered samples and clock jumps. Whatever it inserts: no
exception, every bad input moves a counter, and the attitude at the end of the flight is within
1 deg of the undisturbed run's. Derandomized, so CI sees the same examples every time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from immukf_sitl.mavlink import codec
from immukf_sitl.mavlink.publish import OutputRates, Publisher
from immukf_sitl.mavlink.serve import EstimatorService
from immukf_sitl.mavlink.wire import SIM_COMPONENT_ID, mavlink, open_tlog_reader
from immukf_sitl.options import FilterOptions
from immukf_sitl.samples import ImuSample

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

FLIGHT = Path(__file__).resolve().parent / "data" / "fault_free.tlog"
FLIGHT_S = 20.0
#: disturbances go into the first 14 s: a clock jump makes the service start over, and it
#: re-aligns on the next fix and settles before the end
DISTURBED_UNTIL_S = 14.0
KINDS = ("random_bytes", "truncated", "bit_flip", "non_finite", "duplicate", "reorder", "jump")


class _Link:
    """A connection that swallows what the service sends (acknowledgements, publications)."""

    def write(self, buf: bytes) -> None:
        pass


@dataclass(frozen=True)
class Recorded:
    """The flight's frames from the sim's component, in order, and the IMU ones' indices."""

    frames: tuple[bytes, ...]
    imu_positions: tuple[int, ...]


def _recorded() -> Recorded:
    reader = open_tlog_reader(str(FLIGHT))
    frames: list[bytes] = []
    imu: list[int] = []
    while (msg := reader.recv_msg()) is not None:
        if msg.get_srcComponent() != SIM_COMPONENT_ID:
            continue  # the truth and the annotations never go on the wire
        t = getattr(msg, "time_usec", 0) * 1e-6
        if msg.get_type() != "HEARTBEAT" and t > FLIGHT_S:
            break
        if msg.get_type() == "HIGHRES_IMU":
            imu.append(len(frames))
        frames.append(bytes(msg.get_msgbuf()))
    return Recorded(tuple(frames), tuple(imu))


RECORDED = _recorded()
N_DISTURBED = int(DISTURBED_UNTIL_S * 100)


def _service() -> EstimatorService:
    return EstimatorService(
        FilterOptions().pipeline(), _Link(), [_Link()], Publisher(OutputRates()), stats_interval_s=0
    )


def _counted(service: EstimatorService) -> int:
    c = service.pipeline.counters
    s = service.stats
    return (
        s.bad_packets
        + s.decode_errors
        + s.ignored
        + c.out_of_order
        + c.restarts
        + c.realignments
        + c.bad_samples
    )


def _imu_message(frame: bytes):
    (msg,) = mavlink.MAVLink(None).parse_buffer(frame)
    return msg


def _repacked(frame: bytes, t_s: float | None = None, values=None) -> bytes:
    """The IMU frame again (a new sequence number), at another time or with other readings."""
    msg = _imu_message(frame)
    sample = ImuSample(
        msg.time_usec * 1e-6 if t_s is None else t_s,
        [msg.xacc, msg.yacc, msg.zacc] if values is None else values[:3],
        [msg.xgyro, msg.ygyro, msg.zgyro] if values is None else values[3:],
    )
    return codec.highres_imu_message(sample).pack(mavlink.MAVLink(None, 1, 1))


def _disturbance(kind: str, seed: int, imu_frames: list[bytes]) -> bytes:
    """One bad datagram of ``kind`` made from the flight so far (``imu_frames``, in order)."""
    rng = np.random.default_rng(seed)
    last = imu_frames[-1]
    t_s = _imu_message(last).time_usec * 1e-6
    if kind == "random_bytes":
        return bytes(rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8))
    if kind == "truncated":
        return last[: int(rng.integers(1, len(last)))]
    if kind == "bit_flip":
        flipped = bytearray(last)
        bit = int(rng.integers(0, 8 * len(flipped)))
        flipped[bit // 8] ^= 1 << (bit % 8)
        return bytes(flipped)
    if kind == "non_finite":
        msg = _imu_message(last)
        values = [msg.xacc, msg.yacc, msg.zacc, msg.xgyro, msg.ygyro, msg.zgyro]
        values[int(rng.integers(0, 6))] = [math.nan, math.inf, -math.inf][int(rng.integers(0, 3))]
        return _repacked(last, values=values)
    if kind == "duplicate":
        return last
    if kind == "reorder":
        back = int(rng.integers(1, min(50, len(imu_frames) - 1) + 1))
        return imu_frames[-1 - back]
    if kind == "jump":  # back by more than the 1 s gap limit, or forward
        if t_s > 2.0 and rng.random() < 0.5:
            return _repacked(last, t_s=float(rng.uniform(0.0, t_s - 1.5)))
        return _repacked(last, t_s=t_s + float(rng.uniform(2.0, 3600.0)))
    raise ValueError(kind)


def _fly(plan: dict[int, list[tuple[str, int]]]) -> EstimatorService:
    """Feed the flight, inserting ``plan[k]`` right after the k-th IMU frame; check counting."""
    service = _service()
    imu_frames: list[bytes] = []
    imu_index = 0
    pending_jump: int | None = None
    imu_set = set(RECORDED.imu_positions)
    for position, frame in enumerate(RECORDED.frames):
        service.on_datagram(frame, 0)
        if position not in imu_set:
            continue
        imu_frames.append(frame)
        if pending_jump is not None:  # a jump is counted once the real stream goes on
            assert _counted(service) > pending_jump, "a clock jump was not counted"
            pending_jump = None
        for kind, seed in plan.get(imu_index, ()):
            before = _counted(service)
            service.on_datagram(_disturbance(kind, seed, imu_frames), 0)
            if kind == "jump":
                pending_jump = before
            else:
                assert _counted(service) > before, f"{kind} was not counted"
        imu_index += 1
    return service


@pytest.fixture(scope="module")
def undisturbed():
    return _fly({})


disturbances = st.lists(
    st.tuples(
        st.integers(1, N_DISTURBED - 1),
        st.sampled_from(KINDS),
        st.integers(0, 2**32 - 1),
    ),
    min_size=1,
    max_size=25,
)


def _plan(items: list[tuple[int, str, int]]) -> dict[int, list[tuple[str, int]]]:
    """Insertions by IMU index; a clock jump last at its index, at most two, 3 s apart."""
    plan: dict[int, list[tuple[str, int]]] = {}
    jumps: list[int] = []
    for index, kind, seed in sorted(items, key=lambda i: (i[0], i[1] == "jump")):
        if kind == "jump":
            if len(jumps) == 2 or any(abs(index - j) < 300 for j in jumps):
                continue
            jumps.append(index)
        plan.setdefault(index, []).append((kind, seed))
    return plan


def _attitude_error_deg(a: EstimatorService, b: EstimatorService) -> float:
    assert a._last_output is not None and b._last_output is not None
    diff = np.asarray(a._last_output.nav.euler_rad) - np.asarray(b._last_output.nav.euler_rad)
    diff = (diff + np.pi) % (2 * np.pi) - np.pi
    return float(np.degrees(np.linalg.norm(diff)))


@settings(
    max_examples=12,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(items=disturbances)
def test_bad_input_is_counted_and_leaves_the_estimate_within_a_degree(undisturbed, items) -> None:
    service = _fly(_plan(items))
    assert service._last_output is not None
    assert service._last_output.t_s == undisturbed._last_output.t_s
    assert _attitude_error_deg(service, undisturbed) < 1.0


def test_the_undisturbed_flight_is_clean_and_aligned(undisturbed) -> None:
    c = undisturbed.pipeline.counters
    assert c.imu_samples == len(RECORDED.imu_positions) == 2001
    assert c.out_of_order == c.restarts == c.realignments == c.gap_steps == 0
    assert undisturbed.stats.bad_packets == undisturbed.stats.decode_errors == 0
    assert c.steps > 1800


def test_every_kind_of_disturbance_is_counted_on_its_own() -> None:
    plan = {400 + 100 * i: [(kind, 7)] for i, kind in enumerate(KINDS)}
    service = _fly(plan)
    c, s = service.pipeline.counters, service.stats
    assert s.bad_packets >= 3 and s.decode_errors == 1
    assert c.out_of_order == 2 and c.restarts == 1
