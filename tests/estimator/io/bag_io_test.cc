// Tests of BagWriter and BagReader: round trips, the independent python checker
// (tests/tools/check_bag.py), reader errors on bad and damaged bags, and the writer's atomic close.

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <type_traits>
#include <vector>

#include <gtest/gtest.h>

#include <rosbag/bag.h>
#include <sensor_msgs/PointCloud2.h>

#include "estimator/io/bag_reader.h"
#include "estimator/io/bag_writer.h"
#include "tests/support/process.h"

namespace raillomer::io {
namespace {

namespace fs = std::filesystem;

constexpr int64_t kT0Ns = int64_t{1700000000} * 1000000000;
constexpr int64_t kMsNs = 1000000;

// A fresh directory per test, removed afterwards.
class RosbagIoTest : public ::testing::Test {
 protected:
  void SetUp() override { ASSERT_FALSE(scratch_.path().empty()); }
  std::string Path(const std::string& name) const { return (scratch_.path() / name).string(); }

  test::ScratchDir scratch_{"raillomer_bag_io_"};
  const fs::path& dir_ = scratch_.path();
};

struct StreamSpec {
  double duration_s = 2.0;
  size_t points_per_frame = 24000;
  double imu_rate_hz = 200.0;
  double lidar_rate_hz = 10.0;
  double gnss_rate_hz = 1.0;
  double odometer_rate_hz = 50.0;
  int short_frame_index = -1;  ///< this frame of /livox/lidar_up gets one point fewer
};

LidarFrame MakeFrame(int64_t stamp_ns, uint8_t lidar_id, size_t num_points, uint32_t seed) {
  LidarFrame frame;
  frame.stamp_ns = stamp_ns;
  frame.timebase_ns = static_cast<uint64_t>(stamp_ns);
  frame.frame_id = lidar_id == 0 ? "livox_up" : "livox_down";
  frame.lidar_id = lidar_id;
  frame.points.resize(num_points);
  for (size_t i = 0; i < num_points; ++i) {
    LivoxPoint& p = frame.points[i];
    p.offset_time_ns = static_cast<uint32_t>(i * 4166);  // 240 kHz: 24000 points in 100 ms
    const double a = 0.001 * static_cast<double>(i + seed);
    p.x = static_cast<float>(20.0 + 10.0 * std::sin(a));
    p.y = static_cast<float>(5.0 * std::cos(3.0 * a));
    p.z = static_cast<float>(-1.0 + 0.5 * std::sin(7.0 * a));
    p.reflectivity = static_cast<uint8_t>((i * 7 + seed) % 256);
    p.tag = 0x10;
    p.line = static_cast<uint8_t>(i % 6);
  }
  return frame;
}

// A time-ordered stream with two lidars, IMU, GNSS and odometer at the given rates.
std::vector<SensorMessage> MakeStream(const StreamSpec& spec) {
  std::vector<SensorMessage> messages;
  const int64_t duration_ns = static_cast<int64_t>(spec.duration_s * 1e9);
  const auto period = [](double rate_hz) {
    return static_cast<int64_t>(std::llround(1e9 / rate_hz));
  };
  int frame_index = 0;
  for (int64_t t = 0; t < duration_ns; t += period(spec.lidar_rate_hz), ++frame_index) {
    for (uint8_t id = 0; id < 2; ++id) {
      size_t n = spec.points_per_frame;
      if (id == 0 && frame_index == spec.short_frame_index) n -= 1;
      SensorMessage m;
      m.topic = id == 0 ? "/livox/lidar_up" : "/livox/lidar_down";
      m.receive_ns = kT0Ns + t + 100 * kMsNs + (id == 0 ? 300000 : 700000);
      m.data = MakeFrame(kT0Ns + t, id, n, static_cast<uint32_t>(frame_index * 2 + id));
      messages.push_back(std::move(m));
    }
  }
  int k = 0;
  for (int64_t t = 0; t < duration_ns; t += period(spec.imu_rate_hz), ++k) {
    ImuSample s;
    s.stamp_ns = kT0Ns + t;
    s.angular_velocity_radps = {0.001 * std::sin(0.1 * k), -0.002, 0.01 * std::cos(0.05 * k)};
    s.linear_acceleration_mps2 = {0.2 * std::sin(0.02 * k), -0.05, 9.81 + 0.01 * std::cos(0.3 * k)};
    s.gyro_noise_var = 1.5e-8;
    s.accel_noise_var = 3.5e-7;
    messages.push_back({"/imu/data", kT0Ns + t + kMsNs, s});
  }
  k = 0;
  for (int64_t t = 0; t < duration_ns; t += period(spec.gnss_rate_hz), ++k) {
    GnssFix f;
    f.stamp_ns = kT0Ns + t;
    f.status = 0;
    f.service = 1 | 4;
    f.latitude_deg = 32.4567891 + 1e-6 * k;
    f.longitude_deg = 116.2345678 - 2e-6 * k;
    f.altitude_m = 27.25 + 0.01 * k;
    f.position_covariance = {1.44, 0.01, 0, 0.01, 1.44, 0, 0, 0, 6.25};
    f.position_covariance_type = 3;
    messages.push_back({"/gnss/fix", kT0Ns + t + 50 * kMsNs + 500000, f});
  }
  k = 0;
  for (int64_t t = 0; t < duration_ns; t += period(spec.odometer_rate_hz), ++k) {
    WheelOdometry o;
    o.stamp_ns = kT0Ns + t;
    o.position_rad = 2.0 * M_PI / 100.0 * (3 * k);  // whole pulses of a 100-pulse wheel
    o.velocity_radps = 2.0 * M_PI / 100.0 * 3 * spec.odometer_rate_hz;
    messages.push_back({"/odometer", kT0Ns + t + 2 * kMsNs, o});
  }
  std::stable_sort(messages.begin(), messages.end(), [](const auto& a, const auto& b) {
    return a.receive_ns < b.receive_ns;
  });
  return messages;
}

bool WriteBag(const std::string& path,
              const std::vector<SensorMessage>& messages,
              const BagWriterOptions& options = {}) {
  std::string error;
  auto writer = BagWriter::Open(path, options, &error);
  EXPECT_TRUE(writer) << error;
  if (!writer) return false;
  for (const SensorMessage& m : messages) {
    if (!writer->Write(m, &error)) {
      ADD_FAILURE() << error;
      return false;
    }
  }
  const bool ok = writer->Close(&error);
  EXPECT_TRUE(ok) << error;
  return ok;
}

std::vector<SensorMessage> ReadAll(BagReader* reader) {
  std::vector<SensorMessage> out;
  SensorMessage m;
  while (reader->Next(&m)) out.push_back(m);
  return out;
}

// Every field must match exactly.
void ExpectSame(const SensorMessage& a, const SensorMessage& b, size_t index) {
  SCOPED_TRACE("message " + std::to_string(index) + " on " + a.topic);
  ASSERT_EQ(a.topic, b.topic);
  ASSERT_EQ(a.receive_ns, b.receive_ns);
  ASSERT_EQ(a.data.index(), b.data.index());
  std::visit(
      [&](const auto& x) {
        using T = std::decay_t<decltype(x)>;
        const T& y = std::get<T>(b.data);
        EXPECT_EQ(x.stamp_ns, y.stamp_ns);
        EXPECT_EQ(x.frame_id, y.frame_id);
        if constexpr (std::is_same_v<T, LidarFrame>) {
          EXPECT_EQ(x.timebase_ns, y.timebase_ns);
          EXPECT_EQ(x.lidar_id, y.lidar_id);
          ASSERT_EQ(x.points.size(), y.points.size());
          for (size_t i = 0; i < x.points.size(); ++i) {
            const LivoxPoint& p = x.points[i];
            const LivoxPoint& q = y.points[i];
            ASSERT_TRUE(p.offset_time_ns == q.offset_time_ns && p.x == q.x && p.y == q.y &&
                        p.z == q.z && p.reflectivity == q.reflectivity && p.tag == q.tag &&
                        p.line == q.line)
                << "point " << i;
          }
        } else if constexpr (std::is_same_v<T, ImuSample>) {
          EXPECT_EQ(x.angular_velocity_radps, y.angular_velocity_radps);
          EXPECT_EQ(x.linear_acceleration_mps2, y.linear_acceleration_mps2);
          EXPECT_EQ(x.gyro_noise_var, y.gyro_noise_var);
          EXPECT_EQ(x.accel_noise_var, y.accel_noise_var);
        } else if constexpr (std::is_same_v<T, GnssFix>) {
          EXPECT_EQ(x.status, y.status);
          EXPECT_EQ(x.service, y.service);
          EXPECT_EQ(x.latitude_deg, y.latitude_deg);
          EXPECT_EQ(x.longitude_deg, y.longitude_deg);
          EXPECT_EQ(x.altitude_m, y.altitude_m);
          EXPECT_EQ(x.position_covariance, y.position_covariance);
          EXPECT_EQ(x.position_covariance_type, y.position_covariance_type);
        } else {
          EXPECT_EQ(x.position_rad, y.position_rad);
          EXPECT_EQ(x.velocity_radps, y.velocity_radps);
        }
      },
      a.data);
}

void ExpectSameStreams(const std::vector<SensorMessage>& expected,
                       const std::vector<SensorMessage>& actual) {
  ASSERT_EQ(expected.size(), actual.size());
  for (size_t i = 0; i < expected.size(); ++i) {
    ExpectSame(expected[i], actual[i], i);
    if (::testing::Test::HasFatalFailure()) return;
  }
}

// Runs tests/tools/check_bag.py with /usr/bin/python3; returns its exit code.
int RunChecker(const std::string& bag, const std::string& args, std::string* output) {
  const test::CommandResult run = test::RunCommand(
      "/usr/bin/python3 " + (test::SourceDir() / "tests/tools/check_bag.py").string() + " " + bag +
          " " + args,
      fs::path(bag).parent_path());
  *output = run.out + run.err;
  return run.exit_code;
}

std::vector<SensorMessage> SmallStream() {
  StreamSpec spec;
  spec.duration_s = 0.3;
  spec.points_per_frame = 50;
  spec.imu_rate_hz = 40;
  spec.odometer_rate_hz = 20;
  return MakeStream(spec);
}

// --- Round trips ---------------------------------------------------------------------------------

TEST_F(RosbagIoTest, EveryFieldRoundTrips) {
  std::vector<SensorMessage> messages = SmallStream();
  // Out-of-order writes come back in bag-time order.
  std::swap(messages[1], messages[4]);
  ASSERT_TRUE(WriteBag(Path("a.bag"), messages));
  std::stable_sort(messages.begin(), messages.end(), [](const auto& a, const auto& b) {
    return a.receive_ns < b.receive_ns;
  });

  std::string error;
  auto reader = BagReader::Open(Path("a.bag"), BagTopics{}, &error);
  ASSERT_TRUE(reader) << error;
  ExpectSameStreams(messages, ReadAll(reader.get()));
  EXPECT_EQ(reader->error(), "");
  const BagSummary& summary = reader->Summary();
  EXPECT_TRUE(summary.indexed);
  EXPECT_EQ(summary.damage, "");
  EXPECT_EQ(summary.message_count, messages.size());
  EXPECT_EQ(summary.start_ns, messages.front().receive_ns);
  EXPECT_EQ(summary.end_ns, messages.back().receive_ns);
  ASSERT_EQ(summary.topics.size(), 5u);
  EXPECT_EQ(summary.topics[0].topic, "/gnss/fix");
  EXPECT_EQ(summary.topics[0].type, "sensor_msgs/NavSatFix");
  EXPECT_EQ(summary.topics[0].md5sum, "2d3a8cd499b9b4a0249fb98fd05cfa48");
  EXPECT_EQ(summary.topics[2].topic, "/livox/lidar_down");
  EXPECT_EQ(summary.topics[2].md5sum, "e4d6829bdfe657cb6c21a746c86b21a6");
  EXPECT_EQ(summary.topics[2].message_count, 3u);
  EXPECT_NE(summary.ToString().find("/imu/data"), std::string::npos);
  EXPECT_EQ(reader->delivered_counts().at("/imu/data"), 12u);
}

TEST_F(RosbagIoTest, Lz4BagRoundTripsAndCountsPerTopic) {
  const std::vector<SensorMessage> messages = SmallStream();
  BagWriterOptions options;
  options.lz4_compression = true;
  options.chunk_threshold_bytes = 4096;
  std::string error;
  auto writer = BagWriter::Open(Path("lz4.bag"), options, &error);
  ASSERT_TRUE(writer) << error;
  for (const auto& m : messages) ASSERT_TRUE(writer->Write(m, &error)) << error;
  EXPECT_EQ(writer->total_messages(), messages.size());
  EXPECT_EQ(writer->message_counts().at("/livox/lidar_up"), 3u);
  EXPECT_EQ(writer->message_counts().at("/odometer"), 6u);
  ASSERT_TRUE(writer->Close(&error)) << error;

  auto reader = BagReader::Open(Path("lz4.bag"), BagTopics{}, &error);
  ASSERT_TRUE(reader) << error;
  ExpectSameStreams(messages, ReadAll(reader.get()));
  EXPECT_EQ(reader->error(), "");
}

TEST_F(RosbagIoTest, ReaderSkipsTopicsNotConfigured) {
  ASSERT_TRUE(WriteBag(Path("a.bag"), SmallStream()));
  BagTopics topics = BagTopics::None();
  topics.imu = "/imu/data";
  std::string error;
  auto reader = BagReader::Open(Path("a.bag"), topics, &error);
  ASSERT_TRUE(reader) << error;
  const auto read = ReadAll(reader.get());
  ASSERT_EQ(read.size(), 12u);
  for (const auto& m : read) EXPECT_EQ(m.topic, "/imu/data");

  BagSummary summary;
  ASSERT_TRUE(BagReader::Inspect(Path("a.bag"), &summary, &error)) << error;
  EXPECT_EQ(summary.topics.size(), 5u);
}

// A sensor_msgs/PointCloud2 with a per-point time field becomes a LidarFrame.
void WriteCloudBag(const std::string& path, const std::string& time_field, uint8_t time_type) {
  sensor_msgs::PointCloud2 cloud;
  cloud.header.stamp = ros::Time(1700000000, 500000000);
  cloud.header.frame_id = "velodyne";
  cloud.height = 1;
  cloud.width = 3;
  const std::vector<std::pair<std::string, uint8_t>> fields = {
      {"x", sensor_msgs::PointField::FLOAT32},
      {"y", sensor_msgs::PointField::FLOAT32},
      {"z", sensor_msgs::PointField::FLOAT32},
      {"intensity", sensor_msgs::PointField::FLOAT32},
      {"ring", sensor_msgs::PointField::UINT16},
      {time_field, time_type}};
  uint32_t offset = 0;
  for (const auto& [name, type] : fields) {
    sensor_msgs::PointField f;
    f.name = name;
    f.offset = offset;
    f.datatype = type;
    f.count = 1;
    cloud.fields.push_back(f);
    offset += type == sensor_msgs::PointField::UINT16 ? 2 : 4;
  }
  cloud.point_step = 24;  // 22 bytes of fields plus padding
  cloud.row_step = cloud.point_step * cloud.width;
  cloud.is_dense = false;
  cloud.data.assign(cloud.row_step, 0);
  const float xyz[3][3] = {{1.f, 2.f, 3.f}, {NAN, 0.f, 0.f}, {4.f, 5.f, 6.f}};
  const float intensity[3] = {12.4f, 0.f, 300.f};
  const uint16_t ring[3] = {3, 0, 15};
  const float time_s[3] = {-0.05f, 0.f, 0.f};  // Velodyne: header at the end of the sweep
  const uint32_t time_ns[3] = {1000, 0, 51000};
  for (int i = 0; i < 3; ++i) {
    uint8_t* p = cloud.data.data() + i * cloud.point_step;
    std::memcpy(p, xyz[i], 12);
    std::memcpy(p + 12, &intensity[i], 4);
    std::memcpy(p + 16, &ring[i], 2);
    if (time_type == sensor_msgs::PointField::UINT32) {
      std::memcpy(p + 18, &time_ns[i], 4);
    } else {
      std::memcpy(p + 18, &time_s[i], 4);
    }
  }
  rosbag::Bag bag(path, rosbag::bagmode::Write);
  bag.write("/livox/lidar_up", ros::Time(1700000000, 600000000), cloud);
}

TEST_F(RosbagIoTest, ReadsPointCloud2WithRelativeSecondsTime) {
  WriteCloudBag(Path("cloud.bag"), "time", sensor_msgs::PointField::FLOAT32);
  BagTopics topics = BagTopics::None();
  topics.lidar = {"/livox/lidar_up"};
  std::string error;
  auto reader = BagReader::Open(Path("cloud.bag"), topics, &error);
  ASSERT_TRUE(reader) << error;
  SensorMessage m;
  ASSERT_TRUE(reader->Next(&m)) << reader->error();
  const LidarFrame& frame = std::get<LidarFrame>(m.data);
  EXPECT_EQ(frame.stamp_ns, 1700000000500000000);
  EXPECT_EQ(frame.frame_id, "velodyne");
  // float32 -0.05 s is -50000000.7 ns; the earliest point defines the timebase.
  EXPECT_EQ(frame.timebase_ns,
            static_cast<uint64_t>(1700000000500000000 + std::llround(double{-0.05f} * 1e9)));
  ASSERT_EQ(frame.points.size(), 2u);  // the NaN point is dropped
  EXPECT_EQ(frame.points[0].offset_time_ns, 0u);
  EXPECT_EQ(frame.points[1].offset_time_ns,
            static_cast<uint32_t>(-std::llround(double{-0.05f} * 1e9)));
  EXPECT_EQ(frame.points[0].x, 1.f);
  EXPECT_EQ(frame.points[1].z, 6.f);
  EXPECT_EQ(frame.points[0].reflectivity, 12);
  EXPECT_EQ(frame.points[1].reflectivity, 255);
  EXPECT_EQ(frame.points[0].line, 3);
  EXPECT_EQ(frame.points[1].line, 15);
  EXPECT_EQ(frame.lidar_id, 0);
  EXPECT_FALSE(reader->Next(&m));
  EXPECT_EQ(reader->error(), "");
}

TEST_F(RosbagIoTest, ReadsPointCloud2WithUint32NanosecondTime) {
  WriteCloudBag(Path("cloud.bag"), "t", sensor_msgs::PointField::UINT32);
  BagTopics topics = BagTopics::None();
  topics.lidar = {"/livox/lidar_up"};
  std::string error;
  auto reader = BagReader::Open(Path("cloud.bag"), topics, &error);
  ASSERT_TRUE(reader) << error;
  SensorMessage m;
  ASSERT_TRUE(reader->Next(&m)) << reader->error();
  const LidarFrame& frame = std::get<LidarFrame>(m.data);
  EXPECT_EQ(frame.timebase_ns, 1700000000500001000u);
  ASSERT_EQ(frame.points.size(), 2u);
  EXPECT_EQ(frame.points[0].offset_time_ns, 0u);
  EXPECT_EQ(frame.points[1].offset_time_ns, 50000u);
}

TEST_F(RosbagIoTest, PointCloud2WithoutTimeFieldIsAClearError) {
  WriteCloudBag(Path("cloud.bag"), "label", sensor_msgs::PointField::UINT32);
  BagTopics topics = BagTopics::None();
  topics.lidar = {"/livox/lidar_up"};
  std::string error;
  auto reader = BagReader::Open(Path("cloud.bag"), topics, &error);
  ASSERT_TRUE(reader) << error;
  SensorMessage m;
  EXPECT_FALSE(reader->Next(&m));
  EXPECT_NE(reader->error().find("no per-point time field"), std::string::npos) << reader->error();
  EXPECT_NE(reader->error().find("x,y,z,intensity,ring,label"), std::string::npos)
      << reader->error();
}

// --- The independent checker ---------------------------------------------------------------------

TEST_F(RosbagIoTest, GeneratedStreamPassesTheIndependentChecker) {
  ASSERT_TRUE(WriteBag(Path("good.bag"), MakeStream(StreamSpec{})));
  std::string output;
  const int code =
      RunChecker(Path("good.bag"), "--duration-s 2 --json " + Path("good.json"), &output);
  EXPECT_EQ(code, 0) << output;
  // The checker deserialised CustomMsg from the definition text stored in the bag.
  EXPECT_NE(output.find("PASS dynamic deserialization /livox/lidar_up"), std::string::npos)
      << output;
  std::ifstream json(Path("good.json"));
  const std::string text((std::istreambuf_iterator<char>(json)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("\"passed\": true"), std::string::npos) << text;
}

TEST_F(RosbagIoTest, CheckerRejectsAFrameWithOnePointMissing) {
  StreamSpec spec;
  spec.short_frame_index = 7;
  ASSERT_TRUE(WriteBag(Path("short.bag"), MakeStream(spec)));
  std::string output;
  EXPECT_EQ(RunChecker(Path("short.bag"), "--duration-s 2", &output), 1) << output;
  EXPECT_NE(output.find("23999"), std::string::npos) << output;
}

TEST_F(RosbagIoTest, CheckerRejectsAWrongImuRate) {
  StreamSpec spec;
  spec.points_per_frame = 24000;
  spec.imu_rate_hz = 100;
  ASSERT_TRUE(WriteBag(Path("imu.bag"), MakeStream(spec)));
  std::string output;
  EXPECT_EQ(RunChecker(Path("imu.bag"), "--duration-s 2", &output), 1) << output;
  EXPECT_NE(output.find("FAIL imu rate"), std::string::npos) << output;
}

TEST_F(RosbagIoTest, CheckerUsageErrorsExitTwo) {
  std::string output;
  EXPECT_EQ(RunChecker(Path("missing.bag"), "", &output), 2) << output;
  EXPECT_EQ(RunChecker(Path("x.bag"), "--points-per-frame", &output), 2) << output;
}

// --- Reader errors -------------------------------------------------------------------------------

TEST_F(RosbagIoTest, MissingFileIsAClearError) {
  std::string error;
  EXPECT_FALSE(BagReader::Open(Path("nothing.bag"), BagTopics{}, &error));
  EXPECT_NE(error.find("does not exist"), std::string::npos) << error;
  EXPECT_NE(error.find("nothing.bag"), std::string::npos) << error;
}

TEST_F(RosbagIoTest, FileThatIsNotABagIsAClearError) {
  std::ofstream(Path("text.bag")) << "hello, I am not a bag\n";
  std::string error;
  EXPECT_FALSE(BagReader::Open(Path("text.bag"), BagTopics{}, &error));
  EXPECT_NE(error.find("not a ROS1 bag"), std::string::npos) << error;
  std::ofstream(Path("empty.bag")).flush();
  EXPECT_FALSE(BagReader::Open(Path("empty.bag"), BagTopics{}, &error));
  EXPECT_NE(error.find("not a ROS1 bag"), std::string::npos) << error;
}

TEST_F(RosbagIoTest, MissingTopicListsTheTopicsTheBagHas) {
  ASSERT_TRUE(WriteBag(Path("a.bag"), SmallStream()));
  BagTopics topics;
  topics.lidar = {"/livox/lidar_up", "/velodyne_points"};
  std::string error;
  EXPECT_FALSE(BagReader::Open(Path("a.bag"), topics, &error));
  EXPECT_NE(error.find("has no lidar topic /velodyne_points"), std::string::npos) << error;
  EXPECT_NE(error.find("/livox/lidar_down (livox_ros_driver/CustomMsg)"), std::string::npos)
      << error;
  EXPECT_NE(error.find("/odometer (sensor_msgs/JointState)"), std::string::npos) << error;
}

TEST_F(RosbagIoTest, WrongTypeOnATopicNamesExpectedAndFound) {
  std::vector<SensorMessage> messages;
  for (SensorMessage m : SmallStream()) {
    if (m.topic == "/gnss/fix") continue;
    messages.push_back(m);
    if (m.topic == "/imu/data") {  // IMU samples on the GNSS topic as well
      m.topic = "/gnss/fix";
      m.receive_ns += 1000;
      messages.push_back(m);
    }
  }
  ASSERT_TRUE(WriteBag(Path("a.bag"), messages));
  std::string error;
  EXPECT_FALSE(BagReader::Open(Path("a.bag"), BagTopics{}, &error));
  EXPECT_NE(error.find("topic /gnss/fix has type sensor_msgs/Imu, expected sensor_msgs/NavSatFix"),
            std::string::npos)
      << error;
}

TEST_F(RosbagIoTest, InvalidTopicConfigurationIsRejected) {
  BagTopics topics;
  topics.gnss = topics.imu;
  std::string error;
  EXPECT_FALSE(topics.IsValid(&error));
  EXPECT_NE(error.find("configured twice"), std::string::npos) << error;
  EXPECT_FALSE(BagReader::Open(Path("a.bag"), topics, &error));
  topics = BagTopics{};
  topics.imu = "imu";
  EXPECT_FALSE(topics.IsValid(&error));
}

void CutFile(const std::string& from, const std::string& to, uint64_t size) {
  std::ifstream in(from, std::ios::binary);
  std::vector<char> bytes(size);
  in.read(bytes.data(), static_cast<std::streamsize>(size));
  ASSERT_EQ(static_cast<uint64_t>(in.gcount()), size);
  std::ofstream out(to, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(size));
}

// Reads a damaged copy; the messages it yields must be a prefix of the intact stream.
void ExpectPrefixThenError(const std::string& path,
                           const std::vector<SensorMessage>& full,
                           size_t* delivered,
                           std::string* error_text) {
  std::string error;
  auto reader = BagReader::Open(path, BagTopics{}, &error);
  ASSERT_TRUE(reader) << error;
  EXPECT_FALSE(reader->Summary().indexed);
  EXPECT_FALSE(reader->Summary().damage.empty());
  const std::vector<SensorMessage> read = ReadAll(reader.get());
  ASSERT_LE(read.size(), full.size());
  for (size_t i = 0; i < read.size(); ++i) {
    ExpectSame(full[i], read[i], i);
    if (::testing::Test::HasFatalFailure()) return;
  }
  *delivered = read.size();
  *error_text = reader->error();
}

TEST_F(RosbagIoTest, TruncatedBagYieldsTheMessagesBeforeTheCut) {
  StreamSpec spec;
  spec.points_per_frame = 2000;
  const std::vector<SensorMessage> full = MakeStream(spec);
  BagWriterOptions options;
  options.chunk_threshold_bytes = 64 * 1024;
  ASSERT_TRUE(WriteBag(Path("full.bag"), full, options));
  const uint64_t size = fs::file_size(Path("full.bag"));
  CutFile(Path("full.bag"), Path("half.bag"), size / 2);

  size_t delivered = 0;
  std::string error;
  ExpectPrefixThenError(Path("half.bag"), full, &delivered, &error);
  EXPECT_GT(delivered, full.size() / 4);
  EXPECT_LT(delivered, full.size());
  EXPECT_NE(error.find("truncated"), std::string::npos) << error;
  EXPECT_NE(error.find("file ends at byte " + std::to_string(size / 2)), std::string::npos)
      << error;
  EXPECT_NE(error.find("after " + std::to_string(delivered) + " messages"), std::string::npos)
      << error;
}

TEST_F(RosbagIoTest, TruncatedLz4BagYieldsTheCompleteChunks) {
  StreamSpec spec;
  spec.points_per_frame = 2000;
  const std::vector<SensorMessage> full = MakeStream(spec);
  BagWriterOptions options;
  options.lz4_compression = true;
  options.chunk_threshold_bytes = 64 * 1024;
  ASSERT_TRUE(WriteBag(Path("full.bag"), full, options));
  const uint64_t size = fs::file_size(Path("full.bag"));
  CutFile(Path("full.bag"), Path("half.bag"), size / 2);
  size_t delivered = 0;
  std::string error;
  ExpectPrefixThenError(Path("half.bag"), full, &delivered, &error);
  EXPECT_GT(delivered, 0u);
  EXPECT_LT(delivered, full.size());
  EXPECT_NE(error.find("lz4-compressed chunk is lost"), std::string::npos) << error;
}

TEST_F(RosbagIoTest, CutsAnywhereNeverCrash) {
  const std::vector<SensorMessage> full = SmallStream();
  BagWriterOptions options;
  options.chunk_threshold_bytes = 2048;
  ASSERT_TRUE(WriteBag(Path("full.bag"), full, options));
  const uint64_t size = fs::file_size(Path("full.bag"));
  for (uint64_t cut = 0; cut < size; cut += 997) {
    SCOPED_TRACE("cut at " + std::to_string(cut));
    CutFile(Path("full.bag"), Path("cut.bag"), cut);
    std::string error;
    auto reader = BagReader::Open(Path("cut.bag"), BagTopics{}, &error);
    if (!reader) {
      EXPECT_FALSE(error.empty());
      continue;
    }
    const std::vector<SensorMessage> read = ReadAll(reader.get());
    ASSERT_LE(read.size(), full.size());
    for (size_t i = 0; i < read.size(); ++i) ExpectSame(full[i], read[i], i);
    EXPECT_FALSE(reader->error().empty());
  }
}

// Random byte corruption (in records, index, compressed data) gives messages or an error, never a
// crash. rosbag's own reader overruns buffers on some of these files.
TEST_F(RosbagIoTest, CorruptBytesNeverCrash) {
  for (bool lz4 : {false, true}) {
    BagWriterOptions options;
    options.lz4_compression = lz4;
    options.chunk_threshold_bytes = 3000;
    ASSERT_TRUE(WriteBag(Path("full.bag"), SmallStream(), options));
    std::ifstream in(Path("full.bag"), std::ios::binary);
    const std::vector<char> original((std::istreambuf_iterator<char>(in)),
                                     std::istreambuf_iterator<char>());
    std::mt19937 rng(lz4 ? 7 : 11);
    for (int iteration = 0; iteration < 300; ++iteration) {
      std::vector<char> bytes = original;
      const int flips = 1 + static_cast<int>(rng() % 8);
      for (int k = 0; k < flips; ++k) {
        bytes[rng() % bytes.size()] ^= static_cast<char>(1 + rng() % 255);
      }
      std::ofstream(Path("bad.bag"), std::ios::binary)
          .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
      std::string error;
      auto reader = BagReader::Open(Path("bad.bag"), BagTopics{}, &error);
      if (!reader) {
        EXPECT_FALSE(error.empty());
        continue;
      }
      SensorMessage m;
      size_t count = 0;
      while (reader->Next(&m)) ++count;
      EXPECT_LE(count, reader->Summary().message_count);
    }
  }
}

TEST_F(RosbagIoTest, BagWithoutIndexIsReadCompletelyByScanning) {
  const std::vector<SensorMessage> full = SmallStream();
  ASSERT_TRUE(WriteBag(Path("full.bag"), full));
  // Zero the bag header's index_pos, as in a recording that was never closed.
  std::fstream f(Path("full.bag"), std::ios::in | std::ios::out | std::ios::binary);
  std::vector<char> head(256);
  f.read(head.data(), static_cast<std::streamsize>(head.size()));
  const std::string text(head.begin(), head.end());
  const size_t field = text.find("index_pos=");
  ASSERT_NE(field, std::string::npos);
  f.seekp(static_cast<std::streamoff>(field + 10));
  const char zeros[8] = {};
  f.write(zeros, 8);
  f.close();

  std::string error;
  auto reader = BagReader::Open(Path("full.bag"), BagTopics{}, &error);
  ASSERT_TRUE(reader) << error;
  EXPECT_FALSE(reader->Summary().indexed);
  EXPECT_NE(reader->Summary().damage.find("no index"), std::string::npos);
  EXPECT_EQ(reader->Summary().message_count, full.size());
  ExpectSameStreams(full, ReadAll(reader.get()));
  EXPECT_EQ(reader->error(), "");
}

// --- Writer --------------------------------------------------------------------------------------

TEST_F(RosbagIoTest, WriterLeavesNoFinalFileWhenNotClosed) {
  {
    std::string error;
    auto writer = BagWriter::Open(Path("open.bag"), BagWriterOptions{}, &error);
    ASSERT_TRUE(writer) << error;
    for (const auto& m : SmallStream()) ASSERT_TRUE(writer->Write(m, &error)) << error;
    EXPECT_FALSE(fs::exists(Path("open.bag")));
  }
  EXPECT_FALSE(fs::exists(Path("open.bag")));
  EXPECT_TRUE(fs::is_empty(dir_)) << "the temporary file must be removed too";
}

TEST_F(RosbagIoTest, WriterRejectsBadInputWithoutThrowing) {
  std::string error;
  auto writer = BagWriter::Open(Path("a.bag"), BagWriterOptions{}, &error);
  ASSERT_TRUE(writer) << error;
  ImuSample imu;
  imu.stamp_ns = kT0Ns;
  EXPECT_FALSE(writer->Write({"/imu/data", 0, imu}, &error));
  EXPECT_NE(error.find("at least 1 ns"), std::string::npos) << error;
  EXPECT_FALSE(writer->Write({"imu", kT0Ns, imu}, &error));
  imu.stamp_ns = -5;
  EXPECT_FALSE(writer->Write({"/imu/data", kT0Ns, imu}, &error));
  EXPECT_NE(error.find("header stamp"), std::string::npos) << error;
  imu.stamp_ns = kT0Ns;
  ASSERT_TRUE(writer->Write({"/imu/data", kT0Ns, imu}, &error)) << error;
  EXPECT_FALSE(writer->Write({"/imu/data", kT0Ns + 1, GnssFix{}}, &error));
  EXPECT_NE(error.find("already carries sensor_msgs/Imu"), std::string::npos) << error;
  EXPECT_EQ(writer->total_messages(), 1u);
  ASSERT_TRUE(writer->Close(&error)) << error;
  EXPECT_TRUE(fs::exists(Path("a.bag")));
  EXPECT_FALSE(writer->Write({"/imu/data", kT0Ns, imu}, &error));
  EXPECT_FALSE(writer->Close(&error));

  EXPECT_FALSE(BagWriter::Open(Path("no/such/dir/a.bag"), BagWriterOptions{}, &error));
  EXPECT_NE(error.find("cannot open bag"), std::string::npos) << error;
}

}  // namespace
}  // namespace raillomer::io
