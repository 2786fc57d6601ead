"""ArduPilot DataFlash logs: the writer's files read back, by pymavlink and by hand."""

from __future__ import annotations

import dataclasses
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.DFReader import DFReader_binary

from immukf_sitl.errors import UserError
from immukf_sitl.logs.dataflash import is_dataflash, read_dataflash, write_dataflash
from immukf_sitl.mavlink.flightlog import FaultRecord, FlightLog, read_flight_log
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample

FLIGHT = Path(__file__).parent / "data" / "q_gyro_zeroed.tlog"

# The test's own reading of the format (LogStructure.h), independent of the module's tables
_CODES = {"b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d",
          "q": "q", "Q": "Q", "n": "4s", "N": "16s", "Z": "64s", "c": "h", "C": "H", "e": "i",
          "E": "I", "L": "i", "M": "B"}  # fmt: skip
FMT_COLUMNS = "Type,Length,Name,Format,Columns"
#: ArduPilot's own formats (AP_InertialSensor, AP_GPS, AP_Logger LogStructure.h)
ARDUPILOT = {
    "IMU": ("QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    "GPS": ("QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U"),
    "GPA": ("QBCCCCfBIH", "TimeUS,I,VDop,HAcc,VAcc,SAcc,YAcc,VV,SMS,Delta"),
    "RCOU": ("QHHHHHHHHHHHHHH", "TimeUS," + ",".join(f"C{i}" for i in range(1, 15))),
    "PARM": ("QNff", "TimeUS,Name,Value,Default"),
    "MSG": ("QZ", "TimeUS,Message"),
}


def _struct(fmt: str) -> struct.Struct:
    return struct.Struct("<" + "".join(_CODES[c] for c in fmt))


def _text(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("ascii")


def parse_by_hand(data: bytes) -> tuple[dict[str, tuple[int, str, str]], list, int]:
    """Formats by name (type, format, columns), records (name, fields, offset), bytes read."""
    formats = {128: ("FMT", "BBnNZ", FMT_COLUMNS)}
    records, offset = [], 0
    while offset + 3 <= len(data):
        assert data[offset : offset + 2] == b"\xa3\x95", f"no record header at {offset}"
        name, fmt, columns = formats[data[offset + 2]]
        body = _struct(fmt)
        if offset + 3 + body.size > len(data):
            break
        fields = dict(zip(columns.split(","), body.unpack_from(data, offset + 3), strict=True))
        if name == "FMT":
            new = (_text(fields["Name"]), _text(fields["Format"]), _text(fields["Columns"]))
            assert fields["Length"] == 3 + _struct(new[1]).size
            formats[fields["Type"]] = new
        records.append((name, fields, offset))
        offset += 3 + body.size
    by_name = {name: (type_id, fmt, cols) for type_id, (name, fmt, cols) in formats.items()}
    return by_name, records, offset


def pack(type_id: int, fmt: str, *values: object) -> bytes:
    values = tuple(v.encode() if isinstance(v, str) else v for v in values)
    return b"\xa3\x95" + bytes((type_id,)) + _struct(fmt).pack(*values)


def fmt_record(type_id: int, name: str, fmt: str, columns: str) -> bytes:
    return pack(128, "BBnNZ", type_id, 3 + _struct(fmt).size, name, fmt, columns)


def f32(values) -> list[float]:
    return [float(np.float32(v)) for v in values]


def flat(sample: ImuSample | GpsSample | ActuatorSample) -> tuple:
    if isinstance(sample, ImuSample):
        return ("IMU", sample.time_s, *sample.as_array())
    return (type(sample).__name__, *dataclasses.astuple(sample))


def of_type(log: FlightLog, kind: type) -> list:
    return [s for s in log.stream if isinstance(s, kind)]


@pytest.fixture(scope="module")
def flight() -> FlightLog:
    return read_flight_log(FLIGHT)


@pytest.fixture(scope="module")
def written(flight, tmp_path_factory):
    path = tmp_path_factory.mktemp("df") / "flight.bin"
    size = write_dataflash(path, flight, params={"ARSPD_USE": 1.0, "SCALING_SPEED": 15.0})
    return path, size


@pytest.fixture(scope="module")
def back(written) -> FlightLog:
    return read_dataflash(written[0])


@pytest.fixture
def short(flight) -> FlightLog:
    return dataclasses.replace(flight, stream=flight.stream[:400])


def test_round_trip_keeps_the_stream_its_order_faults_and_vehicle(flight, written, back):
    path, size = written
    assert size == path.stat().st_size
    assert back.kind == "dataflash"
    assert back.bad_records == 0
    assert [type(s) for s in back.stream] == [type(s) for s in flight.stream]
    # TimeUS: whole microseconds (the sim's times are sums of steps, a hair off the grid)
    for old, new in zip(flight.stream, back.stream, strict=True):
        assert new.time_s == round(old.time_s * 1e6) / 1e6
        assert abs(new.time_s - old.time_s) <= 0.5e-6
    assert back.faults == flight.faults and back.faults
    assert back.scenario == flight.scenario == "q-gyro-zeroed"
    assert back.vehicle == "fixed-wing"
    assert back.vehicle_evidence == 'firmware "ArduPlane V4.5.7 (immukf-sitl writer)"'
    assert back.imu_source == "IMU[0]"
    assert back.imu_sources == {"IMU[0]": len(of_type(flight, ImuSample))}
    assert back.params == {"ARSPD_USE": 1.0, "SCALING_SPEED": 15.0}


def test_round_trip_imu_equals_the_original_to_float32(flight, back):
    for old, new in zip(of_type(flight, ImuSample), of_type(back, ImuSample), strict=True):
        assert list(new.gyro_radps) == f32(old.gyro_radps)
        assert list(new.accel_mps2) == f32(old.accel_mps2)


def test_round_trip_rcou_is_exact(flight, back):
    old, new = of_type(flight, ActuatorSample), of_type(back, ActuatorSample)
    assert [s.pwm_us for s in new] == [s.pwm_us[:14] + (0, 0) for s in old]
    assert [s.pwm_us for s in new] == [s.pwm_us for s in old]  # this flight uses channels 1..4


def test_round_trip_gps_within_the_format_quantisation(flight, back):
    # Lat/Lng int32 1e-7 deg: half a step; Alt int32 cm: half a step; Spd, GCrs float32 (deg
    # up to 360: half an ulp is 1.5e-5 deg, 2.7e-7 rad); plus 1e-9 for double rounding
    old, new = of_type(flight, GpsSample), of_type(back, GpsSample)
    assert len(new) == len(old) == 41
    for a, b in zip(old, new, strict=True):
        assert abs(b.lat_deg - a.lat_deg) <= 0.5e-7 + 1e-12
        assert abs(b.lon_deg - a.lon_deg) <= 0.5e-7 + 1e-12
        assert abs(b.alt_m - a.alt_m) <= 0.005 + 1e-9
        assert abs(b.ground_speed_mps - a.ground_speed_mps) <= 1e-6
        assert abs(math.remainder(b.course_rad - a.course_rad, 2 * math.pi)) <= 3e-7
        assert -math.pi <= b.course_rad < math.pi
        assert b.fix_type == a.fix_type == 3


def test_the_written_file_parses_by_hand_as_ardupilot_records(flight, written):
    path, _ = written
    data = path.read_bytes()
    assert data[:3] == b"\xa3\x95\x80"
    assert data[3] == 128 and data[4] == 89  # FMT defines itself first: type 128, 89 bytes
    assert _text(data[5:9]) == "FMT" and _text(data[9:25]) == "BBnNZ"
    formats, records, consumed = parse_by_hand(data)
    assert consumed == len(data)
    for name, (fmt, columns) in ARDUPILOT.items():
        assert formats[name][1:] == (fmt, columns)
    names = [name for name, _, _ in records]
    first_other = next(i for i, n in enumerate(names) if n != "FMT")
    assert "FMT" not in names[first_other:]  # FMT records first
    assert names.count("IMU") == names.count("RCOU") == 4001 and names.count("GPS") == 41
    timed = [f["TimeUS"] for n, f, _ in records if n in ("IMU", "GPS", "RCOU", "MSG", "PARM")]
    assert timed == sorted(timed)
    texts = [_text(f["Message"]) for n, f, _ in records if n == "MSG"]
    assert texts[0] == "ArduPlane V4.5.7 (immukf-sitl writer)"
    assert "SCENARIO q-gyro-zeroed" in texts and "FAULT zero q t=30.000" in texts
    imu = next(f for n, f, _ in records if n == "IMU")
    first = of_type(flight, ImuSample)[0]
    assert (imu["TimeUS"], imu["I"]) == (round(first.time_s * 1e6), 0)
    assert [imu[k] for k in ("GyrX", "GyrY", "GyrZ")] == f32(first.gyro_radps)
    assert [imu[k] for k in ("AccX", "AccY", "AccZ")] == f32(first.accel_mps2)
    gps = next(f for n, f, _ in records if n == "GPS")
    fix = of_type(flight, GpsSample)[0]
    assert gps["Lat"] == round(fix.lat_deg * 1e7) and gps["Lng"] == round(fix.lon_deg * 1e7)
    assert gps["Alt"] == round(fix.alt_m * 100) and gps["Status"] == 3
    assert 0.0 <= gps["GCrs"] < 360.0


def test_pymavlink_reads_it_as_an_arduplane_log(flight, written):
    reader = DFReader_binary(str(written[0]))
    try:
        assert reader.mav_type == mavutil.mavlink.MAV_TYPE_FIXED_WING  # from MSG and VER.BU
        assert reader.params == {"ARSPD_USE": 1.0, "SCALING_SPEED": 15.0}
        count = 0
        while reader.recv_match(type=["IMU"]) is not None:  # as mavlogdump iterates
            count += 1
        assert count == len(of_type(flight, ImuSample))
        imu_format = reader.messages["IMU"].fmt
        assert imu_format.instance_field == "I" and "IMU[0]" in reader.messages
        assert imu_format.get_unit("GyrX") == "rad/s"
        assert imu_format.get_unit("AccZ") == "m/s/s"
    finally:
        reader.close()


def test_a_copter_firmware_string_reads_as_a_multicopter(short, tmp_path):
    path = tmp_path / "copter.bin"
    write_dataflash(path, short, firmware="ArduCopter V4.5.1 (e4e2b7a5)")
    log = read_dataflash(path)
    assert log.vehicle == "multicopter"
    assert log.vehicle_evidence == 'firmware "ArduCopter V4.5.1 (e4e2b7a5)"'


def test_params_round_trip_as_float32(short, tmp_path):
    params = {"TRIM_ARSPD_CM": 2200.0, "INS_GYRO_FILTER": 20.1, "ARSPD_FBW_MIN": 9.0}
    path = tmp_path / "params.bin"
    write_dataflash(path, short, params=params)
    assert read_dataflash(path).params == {k: float(np.float32(v)) for k, v in params.items()}
    with pytest.raises(ValueError, match="16 characters"):
        write_dataflash(path, short, params={"A_NAME_OF_17_CHAR": 1.0})


def _with_second_imu(short, tmp_path):
    path = tmp_path / "two_imus.bin"
    write_dataflash(path, short)
    data = path.read_bytes()
    type_id, fmt, _ = parse_by_hand(data)[0]["IMU"]
    extra = [pack(type_id, fmt, 5000 * k, 1, 0.1 * k, 0, 0, 0, 0, -9.81, 0, 0, 30.0, 1, 1, 0, 0)
             for k in range(7)]  # fmt: skip
    path.write_bytes(data + b"".join(extra))
    return path


def test_a_second_imu_instance_is_read_when_asked(short, tmp_path):
    path = _with_second_imu(short, tmp_path)
    first = read_dataflash(path)
    n0 = len(of_type(short, ImuSample))
    assert first.imu_sources == {"IMU[0]": n0, "IMU[1]": 7}
    assert first.imu_source == "IMU[0]" and len(of_type(first, ImuSample)) == n0
    second = read_dataflash(path, imu=1)
    assert second.imu_source == "IMU[1]"
    imus = of_type(second, ImuSample)
    assert [s.time_s for s in imus] == [0.005 * k for k in range(7)]
    assert [s.gyro_radps[0] for s in imus] == f32([0.1 * k for k in range(7)])
    times = [s.time_s for s in second.stream]
    assert times == sorted(times)
    assert len(of_type(second, GpsSample)) == len(of_type(short, GpsSample))


def test_an_imu_not_in_the_log_names_the_instances_there(short, tmp_path):
    path = _with_second_imu(short, tmp_path)
    with pytest.raises(UserError, match=r"no IMU\[5\].*IMU\[0\], IMU\[1\]") as caught:
        read_dataflash(path, imu=5)
    assert "\n" not in str(caught.value)


def test_older_records_without_an_instance_field(tmp_path):
    # ArduPlane 3.x: IMU and IMU2 without ``I``, GPS without ``I`` and without Yaw
    imu_fmt, gps_fmt = "QffffffIIfBBHH", "QBIHBcLLefffB"
    imu_cols = "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"
    gps_cols = "TimeUS,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,U"
    data = [
        fmt_record(128, "FMT", "BBnNZ", FMT_COLUMNS),
        fmt_record(20, "IMU", imu_fmt, imu_cols),
        fmt_record(21, "IMU2", imu_fmt, imu_cols),
        fmt_record(22, "GPS", gps_fmt, gps_cols),
        fmt_record(23, "MSG", "QZ", "TimeUS,Message"),
        pack(23, "QZ", 1000, "ArduPlane V3.9.11 (b2dd5ecb)"),
    ]
    for k in range(5):
        data.append(pack(20, imu_fmt, 20000 * k, 0.5, 0, 0, 0, 0, -9.8, 0, 0, 40.0, 1, 1, 50, 50))
        data.append(pack(21, imu_fmt, 20000 * k, 0.25, 0, 0, 0, 0, -9.8, 0, 0, 40.0, 1, 1, 50, 50))
    data.append(pack(22, gps_fmt, 50000, 3, 0, 2000, 9, 90, 473977000, 85456000, 15012,
                     22.5, 270.0, 0.0, 1))  # fmt: skip
    path = tmp_path / "old.bin"
    path.write_bytes(b"".join(data))
    log = read_dataflash(path)
    assert log.imu_sources == {"IMU[0]": 5, "IMU[1]": 5}
    assert [s.gyro_radps[0] for s in of_type(log, ImuSample)] == [0.5] * 5
    assert [s.gyro_radps[0] for s in of_type(read_dataflash(path, imu=1), ImuSample)] == [0.25] * 5
    (fix,) = of_type(log, GpsSample)
    assert (fix.time_s, fix.lat_deg, fix.lon_deg, fix.alt_m) == (0.05, 47.3977, 8.5456, 150.12)
    assert fix.course_rad == pytest.approx(-math.pi / 2)
    assert log.vehicle == "fixed-wing"


def test_gps_without_a_3d_fix_is_left_out_and_courses_wrap(tmp_path):
    courses_fixes = [(3.14159, 3), (-math.pi, 3), (0.3, 2), (-0.5, 6)]
    fixes = [GpsSample(0.2 * k, 47.0, 8.0, 400.0, 20.0, c, f)
             for k, (c, f) in enumerate(courses_fixes)]  # fmt: skip
    path = tmp_path / "gps.bin"
    write_dataflash(path, FlightLog(stream=list(fixes)))
    log = read_dataflash(path)
    assert [s.fix_type for s in log.stream] == [3, 3, 6]
    for old, new in zip([fixes[0], fixes[1], fixes[3]], log.stream, strict=True):
        assert -math.pi <= new.course_rad < math.pi
        assert abs(math.remainder(new.course_rad - old.course_rad, 2 * math.pi)) <= 3e-7
    assert log.imu_source == "" and log.imu_sources == {}
    assert log.vehicle == "fixed-wing"


@pytest.mark.parametrize(("into_record", "bad"), [(0, 0), (1, 1), (5, 1), (40, 1)])
def test_a_truncated_file_keeps_its_whole_records(short, tmp_path, into_record, bad):
    path = tmp_path / "cut.bin"
    write_dataflash(path, short)
    full = read_dataflash(path)
    data = path.read_bytes()
    records = parse_by_hand(data)[1]
    cut_at = len(records) - 100  # a record of the stream, 100 before the end
    path.write_bytes(data[: records[cut_at][2] + into_record])
    log = read_dataflash(path)
    assert log.bad_records == bad
    whole = sum(name in ("IMU", "GPS", "RCOU") for name, _, _ in records[:cut_at])
    assert 0 < whole < len(short.stream)
    assert [flat(s) for s in log.stream] == [flat(s) for s in full.stream[:whole]]


def test_corrupt_bytes_between_records_are_skipped_and_counted(short, tmp_path):
    path = tmp_path / "corrupt.bin"
    write_dataflash(path, short)
    full = read_dataflash(path)
    data = path.read_bytes()
    records = parse_by_hand(data)[1]
    at = records[len(records) // 2][2]
    path.write_bytes(data[:at] + b"\x00\xa3\x17" * 3 + data[at:])
    log = read_dataflash(path)
    assert log.bad_records == 1
    assert [flat(s) for s in log.stream] == [flat(s) for s in full.stream]


def test_a_file_that_is_not_dataflash_is_one_line_of_user_error(tmp_path):
    for name, content in [("empty.bin", b""), ("text.bin", b"FMT, 128, 89\n"),
                          ("flight.tlog", FLIGHT.read_bytes()[:4096])]:  # fmt: skip
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(UserError, match="not an ArduPilot DataFlash log") as caught:
            read_dataflash(path)
        assert "\n" not in str(caught.value)


def test_a_missing_file_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match="no such log"):
        read_dataflash(tmp_path / "nothing.bin")


def test_is_dataflash_looks_for_a_header_and_an_fmt_record():
    assert is_dataflash(b"\xa3\x95\x80\x80\x59FMT\0")
    assert not is_dataflash(b"\xa3\x95\x40")
    assert not is_dataflash(b"\xa3")
    assert not is_dataflash(b"")


def test_the_writer_refuses_a_time_before_boot(tmp_path):
    log = FlightLog(stream=[ActuatorSample(0.0, (1500,) * 16)])
    log.faults = [FaultRecord("zero", ("q",), -0.5)]
    with pytest.raises(ValueError, match="unsigned"):
        write_dataflash(tmp_path / "neg.bin", log)


def test_a_fix_keeps_its_vertical_speed_where_its_gpa_says_the_receiver_has_one(tmp_path):
    """VZ is read where GPA.VV is 1 (the writer writes one per fix), and dropped where it is
    0, or where no GPA follows (ArduPilot logs VZ 0 for a receiver without it)."""
    fixes = [GpsSample(0.2 * k, 47.0, 8.0, 400.0, 20.0, 0.1, 3, vd)
             for k, vd in enumerate([-1.25, None, 0.5])]  # fmt: skip
    path = tmp_path / "vz.bin"
    write_dataflash(path, FlightLog(stream=list(fixes)))
    records = parse_by_hand(path.read_bytes())[1]
    gpa = [f for n, f, _ in records if n == "GPA"]
    assert [f["VV"] for f in gpa] == [1, 0, 1]
    assert [f["TimeUS"] for f in gpa] == [0, 200000, 400000]
    vz = [f["VZ"] for n, f, _ in records if n == "GPS"]
    assert vz == [-1.25, 0.0, 0.5]
    back = of_type(read_dataflash(path), GpsSample)
    assert [s.velocity_down_mps for s in back] == [-1.25, None, 0.5]
    without_gpa = tmp_path / "no-gpa.bin"
    data = path.read_bytes()
    starts = [offset for _, _, offset in records] + [len(data)]
    spans = zip(records, starts, starts[1:], strict=False)
    without_gpa.write_bytes(b"".join(data[a:b] for (n, _, _), a, b in spans if n != "GPA"))
    back = of_type(read_dataflash(without_gpa), GpsSample)
    assert len(back) == 3 and all(s.velocity_down_mps is None for s in back)
