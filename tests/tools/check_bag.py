#!/usr/bin/python3
"""Independent checker of a sensor-data-contract bag (see shared ARCHITECTURE.md).

Uses Debian's python3-rosbag and python3-genmsg only, never RailLoMer's C++ code, so it can catch
mistakes that a C++ writer and a C++ reader would share. Run it with /usr/bin/python3.

Checks: topics present; message types; md5 sums against the real ROS constants; the stored message
definitions re-hash (genmsg) to those md5 sums; python rosbag deserialises the first message of
every topic from the definition stored in the bag; frame rates by median interval (dropouts are
reported as gaps, not failures); points per frame (exact); per-point offset_time non-decreasing and
within [0, 100 ms]; line in 0..5; header stamp == timebase; IMU rate and gravity; GNSS rate and
plausible lat/lon; IMU samples without spikes; odometer JointState name == ["wheel"].

Speed: CustomMsg and Imu are read raw and parsed with struct; point columns are cut out of the
point array with strided byte slices, so every point is checked without a Python-level loop.

Exit codes: 0 all checks pass, 1 a check fails (or the bag cannot be read), 2 usage error.
"""

import argparse
import array
import json
import math
import os
import statistics
import struct
import sys

import genmsg
import genmsg.gentools
import genmsg.msg_loader
import rosbag

# md5 sums of the real ROS message definitions. The sensor_msgs ones equal what genmsg computes
# from the definitions in Debian's libsensor-msgs-dev headers; CustomMsg/CustomPoint are the
# livox_ros_driver v2.x values.
MD5 = {
    "livox_ros_driver/CustomMsg": "e4d6829bdfe657cb6c21a746c86b21a6",
    "livox_ros_driver/CustomPoint": "109a3cc548bb1f96626be89a5008bd6d",
    "sensor_msgs/Imu": "6a62c6daae103f4ff57a132d6f95cec2",
    "sensor_msgs/NavSatFix": "2d3a8cd499b9b4a0249fb98fd05cfa48",
    "sensor_msgs/JointState": "3066dcd76a6cfaef579bd0f34173e9fd",
}

POINT_SIZE = 19  # uint32 offset_time, 3 x float32, 3 x uint8
MAX_OFFSET_NS = 100_000_000
RATE_TOLERANCE = 0.03  # median interval within 3 % of the nominal period
GAP_FACTOR = 1.5  # an interval longer than 1.5 nominal periods is a gap (dropout)


class Report:
    def __init__(self):
        self.checks = []
        self.stats = {}

    def check(self, name, passed, detail=""):
        self.checks.append({"name": name, "passed": bool(passed), "detail": detail})
        print("%s %s%s" % ("PASS" if passed else "FAIL", name, (": " + detail) if detail else ""))
        return passed

    def info(self, text):
        print("INFO " + text)

    @property
    def passed(self):
        return all(c["passed"] for c in self.checks)


def md5_of_definition(core_type, full_text):
    """Re-hashes a gendeps full text (as stored in a bag connection header) with genmsg."""
    context = genmsg.MsgContext.create_default()
    sections = full_text.split("\n" + "=" * 80 + "\n")
    specs = {core_type: genmsg.msg_loader.load_msg_from_string(context, sections[0], core_type)}
    for section in sections[1:]:
        first_line, _, text = section.partition("\n")
        if not first_line.startswith("MSG: "):
            raise ValueError("dependency section without 'MSG:' line")
        dep_type = first_line[5:].strip()
        specs[dep_type] = genmsg.msg_loader.load_msg_from_string(context, text, dep_type)
    context = genmsg.MsgContext.create_default()
    for name, spec in specs.items():
        context.register(name, spec)
    return genmsg.gentools.compute_md5(context, specs[core_type])


def parse_header(data):
    """std_msgs/Header at the start of a serialised message: (stamp_ns, frame_id, end offset)."""
    _seq, sec, nsec, frame_len = struct.unpack_from("<IIII", data, 0)
    frame_id = bytes(data[16:16 + frame_len]).decode("utf-8", "replace")
    return sec * 1_000_000_000 + nsec, frame_id, 16 + frame_len


def column(points, count, offset, width):
    """Bytes of one field of every point, cut out with strided slices (fast, no Python loop)."""
    out = bytearray(count * width)
    for k in range(width):
        out[k::width] = points[offset + k::POINT_SIZE]
    return out


def interval_stats(stamps_ns, rate_hz):
    """Median interval, gaps (intervals > GAP_FACTOR periods), non-increasing steps."""
    period_ns = 1e9 / rate_hz
    intervals = [b - a for a, b in zip(stamps_ns, stamps_ns[1:])]
    if not intervals:
        return None, [], 0
    gaps = [(i, d) for i, d in enumerate(intervals) if d > GAP_FACTOR * period_ns]
    backwards = sum(1 for d in intervals if d <= 0)
    return statistics.median(intervals), gaps, backwards


def check_rate(report, name, stamps_ns, rate_hz):
    median, gaps, backwards = interval_stats(stamps_ns, rate_hz)
    if median is None:
        return report.check(name + " rate", False, "fewer than two messages")
    measured_hz = 1e9 / median if median > 0 else float("inf")
    ok = abs(median - 1e9 / rate_hz) <= RATE_TOLERANCE * 1e9 / rate_hz and backwards == 0
    detail = "median interval %.3f ms = %.3f Hz (expected %g Hz)" % (median / 1e6, measured_hz,
                                                                     rate_hz)
    if backwards:
        detail += ", %d stamps not increasing" % backwards
    report.check(name + " rate", ok, detail)
    if gaps:
        longest = max(d for _, d in gaps)
        report.info("%s: %d gap(s), longest %.3f s (dropouts)" % (name, len(gaps), longest / 1e9))
    return ok


def parse_livox_frame(raw):
    """A CustomMsg's header stamp, timebase, point_num, array length and point bytes."""
    data = memoryview(raw[1])
    stamp_ns, _frame_id, pos = parse_header(data)
    timebase, point_num, _lidar_id = struct.unpack_from("<QIB", data, pos)
    pos += 8 + 4 + 1 + 3
    (array_len,) = struct.unpack_from("<I", data, pos)
    pos += 4
    return stamp_ns, timebase, point_num, array_len, data[pos:]


def check_frame_points(index, points, array_len, problems):
    """Offsets non-decreasing within a frame, lines 0..5, a strided subset of coordinates finite
    and within 1 km; what is wrong goes into problems."""
    offsets = array.array("I", bytes(column(points, array_len, 0, 4)))
    if sys.byteorder != "little":
        offsets.byteswap()
    if offsets.tolist() != sorted(offsets) or max(offsets) > MAX_OFFSET_NS:
        problems["offsets"].append("frame %d: offset_time range %d..%d ns%s" % (
            index, min(offsets), max(offsets),
            "" if offsets.tolist() == sorted(offsets) else ", not non-decreasing"))
    lines = column(points, array_len, 18, 1)
    if max(lines) > 5:
        problems["lines"].append("frame %d: line up to %d" % (index, max(lines)))
    stride = max(1, array_len // 500)
    for i in range(0, array_len, stride):
        x, y, z = struct.unpack_from("<fff", points, i * POINT_SIZE + 4)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)) or max(
                abs(x), abs(y), abs(z)) > 1000.0:
            problems["values"].append("frame %d point %d: (%g, %g, %g)" % (index, i, x, y, z))
            break


def report_lidar(report, topic, frames, problems, args):
    """One check per property of the topic's frames."""
    count, offsets, lines = problems["count"], problems["offsets"], problems["lines"]
    timebase, values = problems["timebase"], problems["values"]
    report.check("lidar %s points per frame" % topic, not count,
                 "all %d frames have %d points" % (frames, args.points_per_frame) if not count
                 else "; ".join(count[:5]) + (" ..." if len(count) > 5 else ""))
    report.check("lidar %s offset_time" % topic, not offsets,
                 "non-decreasing within [0, 100 ms]" if not offsets else "; ".join(offsets[:5]))
    report.check("lidar %s line" % topic, not lines,
                 "within 0..5" if not lines else "; ".join(lines[:5]))
    report.check("lidar %s stamp == timebase" % topic, not timebase,
                 "" if not timebase else "frames %s" % timebase[:10])
    report.check("lidar %s coordinates" % topic, not values,
                 "finite, within 1 km (sampled)" if not values else "; ".join(values[:5]))


def check_lidar(report, bag, topic, args):
    stamps = []
    problems = {"count": [], "offsets": [], "lines": [], "timebase": [], "values": []}
    frames = 0
    for _, raw, _t in bag.read_messages(topics=[topic], raw=True):
        stamp_ns, timebase, point_num, array_len, points = parse_livox_frame(raw)
        frames += 1
        stamps.append(stamp_ns)
        if len(points) != array_len * POINT_SIZE:
            problems["count"].append("frame %d: %d bytes of points for %d points" % (
                frames - 1, len(points), array_len))
            continue
        if point_num != array_len or array_len != args.points_per_frame:
            problems["count"].append("frame %d: point_num %d, %d points" % (
                frames - 1, point_num, array_len))
        if timebase != stamp_ns:
            problems["timebase"].append(frames - 1)
        if array_len:
            check_frame_points(frames - 1, points, array_len, problems)

    report.stats[topic] = {"frames": frames}
    report.check("lidar %s frames" % topic, frames > 0, "%d frames" % frames)
    if frames == 0:
        return
    check_rate(report, "lidar %s" % topic, stamps, args.lidar_rate)
    report_lidar(report, topic, frames, problems, args)


MAX_ACCEL_MPS2 = 100.0  # ~10 g: beyond this a sample is a glitch, not a rail vehicle
MAX_GYRO_RADPS = 10.0


def check_imu(report, bag, topic, args):
    stamps = []
    sum_accel = [0.0, 0.0, 0.0]
    finite = 0
    bad = 0
    spikes = []
    for _, raw, _t in bag.read_messages(topics=[topic], raw=True):
        data = raw[1]
        stamp_ns, _frame_id, pos = parse_header(data)
        values = struct.unpack_from("<4d9d3d9d3d9d", data, pos)
        gyro = values[13:16]
        accel = values[25:28]
        stamps.append(stamp_ns)
        if not all(math.isfinite(v) for v in gyro + accel):
            bad += 1
            continue
        finite += 1
        for k in range(3):
            sum_accel[k] += accel[k]
        accel_norm = math.sqrt(sum(a * a for a in accel))
        gyro_norm = math.sqrt(sum(w * w for w in gyro))
        if accel_norm > MAX_ACCEL_MPS2 or gyro_norm > MAX_GYRO_RADPS:
            spikes.append("sample %d at %.3f s: |accel| %.1f m/s^2, |gyro| %.2f rad/s" % (
                len(stamps) - 1, (stamp_ns - stamps[0]) / 1e9, accel_norm, gyro_norm))
    report.stats[topic] = {"messages": len(stamps)}
    if not report.check("imu %s messages" % topic, stamps, "%d samples" % len(stamps)):
        return
    check_rate(report, "imu", stamps, args.imu_rate)
    report.check("imu finite values", bad == 0, "%d samples with NaN/inf" % bad if bad else "")
    report.check("imu no spikes", not spikes,
                 "all |accel| <= %g m/s^2, |gyro| <= %g rad/s" % (MAX_ACCEL_MPS2, MAX_GYRO_RADPS)
                 if not spikes else "%d: %s" % (len(spikes), "; ".join(spikes[:3])))
    if finite:
        mean = [v / finite for v in sum_accel]
        norm = math.sqrt(sum(v * v for v in mean))
        report.stats[topic]["mean_accel_mps2"] = mean
        report.check("imu gravity", abs(norm - 9.8) <= 0.5,
                     "|mean accel| %.3f m/s^2 (expected 9.8 +- 0.5), mean (%.3f, %.3f, %.3f)" %
                     (norm, mean[0], mean[1], mean[2]))


def check_gnss(report, bag, topic, args):
    stamps = []
    bad = []
    for _, msg, _t in bag.read_messages(topics=[topic]):
        stamps.append(msg.header.stamp.to_nsec())
        lat, lon, alt = msg.latitude, msg.longitude, msg.altitude
        plausible = (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and
                     -180 <= lon <= 180 and not (lat == 0 and lon == 0) and
                     (math.isnan(alt) or -500 <= alt <= 9000))
        if not plausible and msg.status.status >= 0:
            bad.append("(%g, %g, %g)" % (lat, lon, alt))
    report.stats[topic] = {"messages": len(stamps)}
    if not report.check("gnss %s messages" % topic, stamps, "%d fixes" % len(stamps)):
        return
    if len(stamps) >= 2:
        check_rate(report, "gnss", stamps, args.gnss_rate)
    else:
        report.info("gnss: one fix only, rate not checked")
    report.check("gnss lat/lon plausible", not bad, "; ".join(bad[:5]))


def check_odometer(report, bag, topic, args):
    stamps = []
    bad = []
    for _, msg, _t in bag.read_messages(topics=[topic]):
        stamps.append(msg.header.stamp.to_nsec())
        if list(msg.name) != ["wheel"] or len(msg.position) != 1 or len(msg.velocity) != 1:
            bad.append("name %s, %d positions, %d velocities" % (list(msg.name), len(msg.position),
                                                                len(msg.velocity)))
        elif not (math.isfinite(msg.position[0]) and math.isfinite(msg.velocity[0])):
            bad.append("non-finite position/velocity")
    report.stats[topic] = {"messages": len(stamps)}
    if not report.check("odometer %s messages" % topic, stamps, "%d readings" % len(stamps)):
        return
    check_rate(report, "odometer", stamps, args.odom_rate)
    report.check("odometer name == [wheel]", not bad, "; ".join(bad[:3]))


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bag")
    parser.add_argument("--duration-s", type=float, help="expected time span of the bag")
    parser.add_argument("--points-per-frame", type=int, default=24000)
    parser.add_argument("--lidar-topics", default="/livox/lidar_up,/livox/lidar_down")
    parser.add_argument("--imu-topic", default="/imu/data", help="empty: no IMU expected")
    parser.add_argument("--gnss-topic", default="/gnss/fix", help="empty: no GNSS expected")
    parser.add_argument("--odom-topic", default="/odometer", help="empty: no odometer expected")
    parser.add_argument("--lidar-rate", type=float, default=10.0)
    parser.add_argument("--imu-rate", type=float, default=200.0)
    parser.add_argument("--gnss-rate", type=float, default=1.0)
    parser.add_argument("--odom-rate", type=float, default=50.0)
    parser.add_argument("--json", help="write the report as JSON to this file")
    args = parser.parse_args(argv)  # exits 2 on usage errors
    if not os.path.isfile(args.bag):
        parser.error("no such bag file: %s" % args.bag)
    for name in ("points_per_frame", "lidar_rate", "imu_rate", "gnss_rate", "odom_rate"):
        if getattr(args, name) <= 0:
            parser.error("--%s must be positive" % name.replace("_", "-"))
    return args


def expected_topics(args):
    """{topic: message type} of the sensors the bag should hold (an empty name skips one)."""
    expected = {t: "livox_ros_driver/CustomMsg" for t in args.lidar_topics.split(",") if t}
    for topic, type_name in ((args.imu_topic, "sensor_msgs/Imu"),
                             (args.gnss_topic, "sensor_msgs/NavSatFix"),
                             (args.odom_topic, "sensor_msgs/JointState")):
        if topic:
            expected[topic] = type_name
    return expected


def check_connection(report, topic, type_name, c):
    """A connection's type, MD5 and stored definition against the contract."""
    report.check("type %s" % topic, c.datatype == type_name,
                 "%s (expected %s)" % (c.datatype, type_name))
    report.check("md5 %s" % topic, c.md5sum == MD5.get(type_name),
                 "%s (expected %s)" % (c.md5sum, MD5.get(type_name)))
    try:
        rehash = md5_of_definition(c.datatype, c.msg_def)
    except Exception as e:
        rehash = "error: %s" % e
    report.check("definition %s" % topic, rehash == c.md5sum,
                 "genmsg re-hashes the stored definition to %s" % rehash)


def check_first_message(report, bag, topic, type_name):
    """One message deserialised with the class genpy builds from the stored definition."""
    try:
        msg = next(bag.read_messages(topics=[topic])).message
        detail = msg._type
        if msg._type == "livox_ros_driver/CustomMsg":
            ok = len(msg.points) == msg.point_num and msg.header.stamp.to_nsec() == msg.timebase
            detail += ", %d points" % len(msg.points)
        else:
            ok = msg._type == type_name
        report.check("dynamic deserialization %s" % topic, ok, detail)
    except Exception as e:
        report.check("dynamic deserialization %s" % topic, False, "%s: %s" % (type(e).__name__, e))


def check_topics(report, bag, expected):
    """Every expected topic present, typed and readable; {topic: [connection]}."""
    connections = {}
    for c in bag._get_connections():
        connections.setdefault(c.topic, []).append(c)
    for topic, type_name in expected.items():
        conns = connections.get(topic)
        if not report.check("topic %s present" % topic, conns,
                            "" if conns else "bag has: %s" % ", ".join(sorted(connections))):
            continue
        for c in conns:
            check_connection(report, topic, type_name, c)
        check_first_message(report, bag, topic, type_name)
    return connections


def check_streams(report, bag, expected, connections, args):
    """Each correctly typed sensor's stream (rates, gaps, contents) and the bag's span."""
    def typed(topic):
        return topic in expected and any(c.datatype == expected[topic]
                                         for c in connections.get(topic, []))

    for topic in (t for t in args.lidar_topics.split(",") if t):
        if typed(topic):
            check_lidar(report, bag, topic, args)
    for topic, check in ((args.imu_topic, check_imu), (args.gnss_topic, check_gnss),
                         (args.odom_topic, check_odometer)):
        if typed(topic):
            check(report, bag, topic, args)
    if args.duration_s is not None:
        span = bag.get_end_time() - bag.get_start_time()
        tolerance = 0.05 * args.duration_s + 0.15
        report.check("duration", abs(span - args.duration_s) <= tolerance,
                     "bag spans %.3f s (expected %.3f +- %.3f s)" % (span, args.duration_s,
                                                                     tolerance))


def main(argv):
    args = parse_args(argv)
    expected = expected_topics(args)
    report = Report()
    print("bag %s (%d bytes)" % (args.bag, os.path.getsize(args.bag)))
    try:
        bag = rosbag.Bag(args.bag)
    except Exception as e:  # unindexed, truncated or not a bag at all
        report.check("bag readable", False, "%s: %s" % (type(e).__name__, e))
        return finish(report, args)
    with bag:
        report.check("bag readable", True, "%d messages" % bag.get_message_count())
        connections = check_topics(report, bag, expected)
        check_streams(report, bag, expected, connections, args)
    return finish(report, args)


def finish(report, args):
    print("%s: %d checks, %d failed" % ("PASSED" if report.passed else "FAILED",
                                        len(report.checks),
                                        sum(not c["passed"] for c in report.checks)))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"bag": args.bag, "passed": report.passed, "checks": report.checks,
                       "stats": report.stats}, f, indent=2)
    return 0 if report.passed else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
