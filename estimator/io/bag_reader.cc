#include "estimator/io/bag_reader.h"

#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <limits>
#include <initializer_list>
#include <set>
#include <tuple>
#include <sstream>
#include <utility>

#include <bzlib.h>
#include <roslz4/lz4s.h>
#include <rosbag/bag.h>
#include <rosbag/query.h>
#include <rosbag/view.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/JointState.h>
#include <sensor_msgs/NavSatFix.h>
#include <sensor_msgs/PointCloud2.h>

#include "estimator/io/livox_custom_msg.h"

namespace raillomer::io {
namespace {

constexpr int64_t kNsPerS = 1000000000;
constexpr char kBagMagic[] = "#ROSBAG V2.0\n";
constexpr size_t kBagMagicSize = sizeof(kBagMagic) - 1;
// A single message or chunk larger than this is taken as a corrupt length field.
constexpr uint64_t kMaxRecordBytes = uint64_t{1} << 31;

template <typename T>
const char* RosType() {
  return ros::message_traits::DataType<T>::value();
}
template <typename T>
const char* RosMd5() {
  return ros::message_traits::MD5Sum<T>::value();
}

int64_t ToNs(const ros::Time& t) { return int64_t{t.sec} * kNsPerS + t.nsec; }

// Seconds with all nine decimals (a double would round nanoseconds away at epoch times).
std::string FormatSeconds(int64_t ns) {
  const uint64_t magnitude = ns < 0 ? 0 - static_cast<uint64_t>(ns) : static_cast<uint64_t>(ns);
  char buffer[64];
  std::snprintf(buffer,
                sizeof(buffer),
                "%s%llu.%09llu",
                ns < 0 ? "-" : "",
                static_cast<unsigned long long>(magnitude / kNsPerS),
                static_cast<unsigned long long>(magnitude % kNsPerS));
  return buffer;
}

// --- Scanning a bag record by record (format 2.0), for bags without a usable index. -------------
// See http://wiki.ros.org/Bags/Format/2.0: every record is
//   uint32 header_len, header (fields: uint32 len, "name=value"), uint32 data_len, data.

enum Op : uint8_t {
  kOpMessageData = 0x02,
  kOpBagHeader = 0x03,
  kOpIndexData = 0x04,
  kOpChunk = 0x05,
  kOpChunkInfo = 0x06,
  kOpConnection = 0x07,
};

using Fields = std::map<std::string, std::string>;

struct Connection {
  std::string topic;
  std::string type;
  std::string md5sum;
};

struct RawMessage {
  uint32_t connection = 0;
  int64_t time_ns = 0;
  std::vector<uint8_t> data;
};

uint32_t ReadU32(const uint8_t* p) {
  return uint32_t{p[0]} | uint32_t{p[1]} << 8 | uint32_t{p[2]} << 16 | uint32_t{p[3]} << 24;
}

bool ParseFields(const uint8_t* p, size_t size, Fields* fields) {
  fields->clear();
  size_t i = 0;
  while (i < size) {
    if (size - i < 4) return false;
    const uint32_t len = ReadU32(p + i);
    i += 4;
    if (len > size - i) return false;
    const std::string field(reinterpret_cast<const char*>(p + i), len);
    i += len;
    const size_t eq = field.find('=');
    if (eq == std::string::npos) return false;
    (*fields)[field.substr(0, eq)] = field.substr(eq + 1);
  }
  return true;
}

bool FieldU32(const Fields& fields, const char* name, uint32_t* value) {
  auto it = fields.find(name);
  if (it == fields.end() || it->second.size() != 4) return false;
  *value = ReadU32(reinterpret_cast<const uint8_t*>(it->second.data()));
  return true;
}

bool FieldOp(const Fields& fields, uint8_t* op) {
  auto it = fields.find("op");
  if (it == fields.end() || it->second.size() != 1) return false;
  *op = static_cast<uint8_t>(it->second[0]);
  return true;
}

// Reads a bag sequentially. Messages inside one chunk come out sorted by time (stable); chunks
// come out in file order, which is recording order.
class BagScanner {
 public:
  ~BagScanner() {
    if (file_) std::fclose(file_);
  }

  // Checks the magic and reads the bag header record.
  bool Open(const std::string& path, std::string* error) {
    file_ = std::fopen(path.c_str(), "rb");
    if (!file_) {
      *error = "cannot open " + path + ": " + std::strerror(errno);
      return false;
    }
    struct stat st;
    if (::fstat(::fileno(file_), &st) != 0) {
      *error = "cannot stat " + path + ": " + std::strerror(errno);
      return false;
    }
    file_size_ = static_cast<uint64_t>(st.st_size);
    char magic[kBagMagicSize] = {};
    const size_t got = std::fread(magic, 1, kBagMagicSize, file_);
    if (got != kBagMagicSize || std::memcmp(magic, kBagMagic, kBagMagicSize) != 0) {
      if (got >= 9 && std::memcmp(magic, "#ROSBAG V", 9) == 0) {
        *error = path + " is a ROS bag of an unsupported format version (" +
                 std::string(magic, got - 1) + "); only V2.0 is supported";
      } else {
        *error = path + " is not a ROS1 bag (no '#ROSBAG V2.0' magic at its start)";
      }
      return false;
    }
    pos_ = kBagMagicSize;
    Fields header;
    std::vector<uint8_t> data;
    uint64_t record_pos = 0;
    if (!ReadRecord(&header, &data, &record_pos, /*allow_partial=*/false)) {
      *error = path + " is not a ROS1 bag: " + (damage_.empty() ? "it is empty" : damage_);
      return false;
    }
    uint8_t op = 0;
    auto index_it = header.find("index_pos");
    if (!FieldOp(header, &op) || op != kOpBagHeader || index_it == header.end() ||
        index_it->second.size() != 8) {
      *error = path + " is not a ROS1 bag: its first record is not a bag header";
      return false;
    }
    std::memcpy(&index_pos_, index_it->second.data(), 8);
    return true;
  }

  uint64_t file_size() const { return file_size_; }
  uint64_t index_pos() const { return index_pos_; }
  const std::string& damage() const { return damage_; }
  const std::map<uint32_t, Connection>& connections() const { return connections_; }

  // Next message in file order; false at the end of the file or at damage (damage() says which).
  // Messages recovered from before the damage are delivered first.
  bool Next(RawMessage* message) {
    while (pending_next_ >= pending_.size()) {
      pending_.clear();
      pending_next_ = 0;
      if (!damage_.empty() || pos_ >= file_size_) return false;
      Fields header;
      uint64_t record_pos = 0;
      if (!ReadRecord(&header, &record_data_, &record_pos, /*allow_partial=*/true)) return false;
      uint8_t op = 0;
      if (!FieldOp(header, &op)) {
        damage_ = "record at byte " + std::to_string(record_pos) + " has no op field";
        return false;
      }
      // Bag header, index data and chunk info records carry no messages.
      if (op == kOpChunk) {
        ReadChunk(header, record_pos);
      } else if (op == kOpConnection) {
        AddConnection(header, record_data_.data(), record_data_.size(), record_pos);
      } else if (op == kOpMessageData) {
        AddMessage(header, record_data_.data(), record_data_.size(), record_pos);
      }
      std::stable_sort(pending_.begin(), pending_.end(), ByTime);
    }
    *message = std::move(pending_[pending_next_++]);
    return true;
  }

 private:
  static bool ByTime(const RawMessage& a, const RawMessage& b) { return a.time_ns < b.time_ns; }

  // Reads the record at pos_. With allow_partial a record whose data is cut off by the end of the
  // file is returned with the bytes present and partial_ set (damage_ names the cut).
  bool ReadRecord(Fields* header, std::vector<uint8_t>* data, uint64_t* record_pos,
                  bool allow_partial) {
    *record_pos = pos_;
    const uint64_t remaining = file_size_ - pos_;
    uint8_t len_bytes[4];
    if (remaining < 4 || !ReadAt(pos_, len_bytes, 4)) {
      damage_ = "file ends at byte " + std::to_string(file_size_) + " inside the record at byte " +
                std::to_string(pos_) + " (no room for its header length)";
      return false;
    }
    const uint32_t header_len = ReadU32(len_bytes);
    if (header_len > remaining - 4) {
      damage_ = "file ends at byte " + std::to_string(file_size_) +
                " inside the header of the record at byte " + std::to_string(pos_) + " (needs " +
                std::to_string(header_len) + " bytes)";
      return false;
    }
    std::vector<uint8_t> header_bytes(header_len);
    if (!ReadAt(pos_ + 4, header_bytes.data(), header_len) ||
        !ParseFields(header_bytes.data(), header_len, header)) {
      damage_ = "corrupt record header at byte " + std::to_string(pos_);
      return false;
    }
    const uint64_t data_len_pos = pos_ + 4 + header_len;
    if (file_size_ - data_len_pos < 4 || !ReadAt(data_len_pos, len_bytes, 4)) {
      damage_ = "file ends at byte " + std::to_string(file_size_) +
                " inside the record at byte " + std::to_string(pos_) + " (no data length)";
      return false;
    }
    const uint32_t data_len = ReadU32(len_bytes);
    const uint64_t data_pos = data_len_pos + 4;
    const uint64_t present = std::min<uint64_t>(data_len, file_size_ - data_pos);
    partial_ = present < data_len;
    if (partial_) {
      damage_ = "file ends at byte " + std::to_string(file_size_) + " inside the record at byte " +
                std::to_string(pos_) + " (its data needs " + std::to_string(data_len) +
                " bytes, only " + std::to_string(present) + " are present)";
      if (!allow_partial) return false;
    }
    data->resize(present);
    if (present > 0 && !ReadAt(data_pos, data->data(), present)) {
      damage_ = "read error in the record at byte " + std::to_string(pos_);
      return false;
    }
    pos_ = data_pos + present;
    return true;
  }

  bool ReadAt(uint64_t pos, uint8_t* out, uint64_t size) {
    if (::fseeko(file_, static_cast<off_t>(pos), SEEK_SET) != 0) return false;
    return std::fread(out, 1, size, file_) == size;
  }

  // Decompresses a chunk and queues its messages; sets damage_ on failure.
  void ReadChunk(const Fields& header, uint64_t record_pos) {
    const std::string where = "chunk at byte " + std::to_string(record_pos);
    auto compression_it = header.find("compression");
    uint32_t size = 0;
    if (compression_it == header.end() || !FieldU32(header, "size", &size)) {
      if (damage_.empty()) damage_ = where + " lacks its compression or size field";
      return;
    }
    const std::string& compression = compression_it->second;
    if (compression == "none") {
      // A cut-off uncompressed chunk still yields its complete records.
      ParseChunkRecords(record_data_.data(), record_data_.size(), record_pos);
      if (partial_) damage_ += "; the complete messages before the cut were recovered";
      return;
    }
    if (partial_) {
      damage_ += "; that " + compression + "-compressed chunk is lost";
      return;
    }
    if (size > kMaxRecordBytes) {
      damage_ = where + " claims an implausible size of " + std::to_string(size) + " bytes";
      return;
    }
    chunk_.resize(size);
    unsigned int out_size = size;
    int rc = 0;
    if (compression == "lz4") {
      rc = roslz4_buffToBuffDecompress(reinterpret_cast<char*>(record_data_.data()),
                                       static_cast<unsigned int>(record_data_.size()),
                                       reinterpret_cast<char*>(chunk_.data()),
                                       &out_size);
      rc = rc == ROSLZ4_OK ? 0 : 1;
    } else if (compression == "bz2") {
      rc = BZ2_bzBuffToBuffDecompress(reinterpret_cast<char*>(chunk_.data()),
                                      &out_size,
                                      reinterpret_cast<char*>(record_data_.data()),
                                      static_cast<unsigned int>(record_data_.size()),
                                      /*small=*/0,
                                      /*verbosity=*/0);
      rc = rc == BZ_OK ? 0 : 1;
    } else {
      damage_ = where + " uses unknown compression '" + compression + "'";
      return;
    }
    if (rc != 0 || out_size != size) {
      damage_ = "cannot decompress the " + compression + " " + where + " (corrupt data)";
      return;
    }
    ParseChunkRecords(chunk_.data(), chunk_.size(), record_pos);
  }

  // Queues the connection and message records inside a (decompressed) chunk. Stops at the first
  // incomplete record, which is damage unless the chunk itself was cut off (partial_).
  void ParseChunkRecords(const uint8_t* p, size_t size, uint64_t chunk_pos) {
    size_t i = 0;
    const std::string where = " in the chunk at byte " + std::to_string(chunk_pos);
    while (i < size) {
      const size_t record_offset = i;
      if (size - i < 4) break;
      const uint32_t header_len = ReadU32(p + i);
      if (header_len > size - i - 4) break;
      Fields fields;
      uint8_t op = 0;
      if (!ParseFields(p + i + 4, header_len, &fields) || !FieldOp(fields, &op)) {
        SetDamage("corrupt record header at offset " + std::to_string(record_offset) + where);
        return;
      }
      i += 4 + header_len;
      if (size - i < 4) break;
      const uint32_t data_len = ReadU32(p + i);
      i += 4;
      if (data_len > size - i) break;
      bool ok = true;
      if (op == kOpConnection) {
        ok = AddConnection(fields, p + i, data_len, chunk_pos);
      } else if (op == kOpMessageData) {
        ok = AddMessage(fields, p + i, data_len, chunk_pos);
      }
      if (!ok) return;
      i += data_len;
    }
    if (i < size && !partial_) {
      SetDamage("truncated record at offset " + std::to_string(i) + where);
    }
  }

  void SetDamage(const std::string& what) {
    if (damage_.empty()) damage_ = what;
  }

  bool AddConnection(const Fields& header, const uint8_t* data, size_t size, uint64_t pos) {
    uint32_t id = 0;
    Fields conn_header;
    if (!FieldU32(header, "conn", &id) || !ParseFields(data, size, &conn_header)) {
      SetDamage("corrupt connection record near byte " + std::to_string(pos));
      return false;
    }
    Connection connection;
    auto topic_it = header.find("topic");
    if (topic_it != header.end()) connection.topic = topic_it->second;
    connection.type = conn_header["type"];
    connection.md5sum = conn_header["md5sum"];
    connections_[id] = connection;
    return true;
  }

  bool AddMessage(const Fields& header, const uint8_t* data, size_t size, uint64_t pos) {
    uint32_t id = 0;
    auto time_it = header.find("time");
    if (!FieldU32(header, "conn", &id) || time_it == header.end() || time_it->second.size() != 8) {
      SetDamage("corrupt message record near byte " + std::to_string(pos));
      return false;
    }
    if (connections_.count(id) == 0) {
      SetDamage("message near byte " + std::to_string(pos) + " refers to unknown connection " +
                std::to_string(id));
      return false;
    }
    const auto* t = reinterpret_cast<const uint8_t*>(time_it->second.data());
    RawMessage message;
    message.connection = id;
    message.time_ns = int64_t{ReadU32(t)} * kNsPerS + ReadU32(t + 4);
    message.data.assign(data, data + size);
    pending_.push_back(std::move(message));
    return true;
  }

  FILE* file_ = nullptr;
  uint64_t file_size_ = 0;
  uint64_t index_pos_ = 0;
  uint64_t pos_ = 0;
  bool partial_ = false;
  std::string damage_;
  std::map<uint32_t, Connection> connections_;
  std::vector<uint8_t> record_data_;
  std::vector<uint8_t> chunk_;
  std::vector<RawMessage> pending_;
  size_t pending_next_ = 0;
};

// --- Decoding message bytes into the sensor structs. ----------------------------------------------

template <typename T>
bool Deserialize(const std::vector<uint8_t>& bytes, T* message, std::string* error) {
  try {
    ros::serialization::IStream stream(const_cast<uint8_t*>(bytes.data()),
                                       static_cast<uint32_t>(bytes.size()));
    ros::serialization::deserialize(stream, *message);
    if (stream.getLength() != 0) {
      *error = std::to_string(stream.getLength()) + " bytes left over after a " + RosType<T>() +
               " (message does not match its type)";
      return false;
    }
  } catch (const std::exception& e) {
    *error = std::string("cannot deserialize ") + RosType<T>() + ": " + e.what();
    return false;
  }
  return true;
}

void ConvertCustomMsg(const livox_ros_driver::CustomMsg& in, LidarFrame* out) {
  out->stamp_ns = ToNs(in.header.stamp);
  out->frame_id = in.header.frame_id;
  out->timebase_ns = in.timebase;
  out->lidar_id = in.lidar_id;
  out->points.resize(in.points.size());
  for (size_t i = 0; i < in.points.size(); ++i) {
    const livox_ros_driver::CustomPoint& p = in.points[i];
    LivoxPoint& q = out->points[i];
    q.offset_time_ns = p.offset_time;
    q.x = p.x;
    q.y = p.y;
    q.z = p.z;
    q.reflectivity = p.reflectivity;
    q.tag = p.tag;
    q.line = p.line;
  }
}

// Reads one scalar of a PointCloud2 field as double (little-endian host assumed; big-endian clouds
// are rejected before).
double ReadScalar(const uint8_t* p, uint8_t datatype) {
  using sensor_msgs::PointField;
  switch (datatype) {
    case PointField::INT8: {
      int8_t v;
      std::memcpy(&v, p, 1);
      return v;
    }
    case PointField::UINT8:
      return *p;
    case PointField::INT16: {
      int16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case PointField::UINT16: {
      uint16_t v;
      std::memcpy(&v, p, 2);
      return v;
    }
    case PointField::INT32: {
      int32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PointField::UINT32: {
      uint32_t v;
      std::memcpy(&v, p, 4);
      return v;
    }
    case PointField::FLOAT32: {
      float v;
      std::memcpy(&v, p, 4);
      return v;
    }
    default: {
      double v;
      std::memcpy(&v, p, 8);
      return v;
    }
  }
}

size_t ScalarSize(uint8_t datatype) {
  using sensor_msgs::PointField;
  switch (datatype) {
    case PointField::INT8:
    case PointField::UINT8:
      return 1;
    case PointField::INT16:
    case PointField::UINT16:
      return 2;
    case PointField::INT32:
    case PointField::UINT32:
    case PointField::FLOAT32:
      return 4;
    case PointField::FLOAT64:
      return 8;
    default:
      return 0;
  }
}

const sensor_msgs::PointField* FindField(const sensor_msgs::PointCloud2& cloud,
                                         std::initializer_list<const char*> names) {
  for (const char* name : names) {
    for (const auto& field : cloud.fields) {
      if (field.name == name) return &field;
    }
  }
  return nullptr;
}

std::string FieldNames(const sensor_msgs::PointCloud2& cloud) {
  std::string names;
  for (const auto& field : cloud.fields) names += (names.empty() ? "" : ",") + field.name;
  return names.empty() ? "(none)" : names;
}

// Converts a sensor_msgs/PointCloud2 to a LidarFrame. Accepted layout (little-endian):
// - x, y, z: FLOAT32 or FLOAT64, metres. Points with a non-finite coordinate are dropped.
// - per-point time, the first present of the fields "time", "t", "timestamp", "offset_time":
//     FLOAT32/FLOAT64 = seconds relative to header.stamp (may be negative, as Velodyne stamps the
//     header at the end of the sweep); UINT32 = nanoseconds relative to header.stamp (Ouster "t",
//     Livox "offset_time"). Values above 1e6 s are absolute times (Hesai, livox_ros_driver2) and
//     are rejected with a message rather than guessed at. The time field is required.
// - optional "intensity" or "reflectivity" (any numeric type, rounded and clamped to 0..255),
//   optional "line" or "ring" (laser index, clamped to 0..255), optional "tag" (UINT8).
// The frame's timebase is the earliest point time, so offsets are non-negative; stamp_ns stays
// the header stamp. Offsets must span less than 2^32 ns.
bool ConvertPointCloud2(const sensor_msgs::PointCloud2& in,
                        uint8_t lidar_id,
                        LidarFrame* out,
                        std::string* error) {
  using sensor_msgs::PointField;
  if (in.is_bigendian) {
    *error = "big-endian PointCloud2 is not supported";
    return false;
  }
  const PointField* fx = FindField(in, {"x"});
  const PointField* fy = FindField(in, {"y"});
  const PointField* fz = FindField(in, {"z"});
  const PointField* ft = FindField(in, {"time", "t", "timestamp", "offset_time"});
  const PointField* fi = FindField(in, {"intensity", "reflectivity"});
  const PointField* fl = FindField(in, {"line", "ring"});
  const PointField* fg = FindField(in, {"tag"});
  if (!fx || !fy || !fz) {
    *error = "PointCloud2 lacks x, y or z (fields: " + FieldNames(in) + ")";
    return false;
  }
  if (!ft) {
    *error =
        "PointCloud2 has no per-point time field (looked for time, t, timestamp, offset_time; "
        "fields: " +
        FieldNames(in) + ")";
    return false;
  }
  for (const PointField* f : {fx, fy, fz}) {
    if (f->datatype != PointField::FLOAT32 && f->datatype != PointField::FLOAT64) {
      *error = "PointCloud2 field " + f->name + " must be FLOAT32 or FLOAT64";
      return false;
    }
  }
  const bool time_is_seconds =
      ft->datatype == PointField::FLOAT32 || ft->datatype == PointField::FLOAT64;
  if (!time_is_seconds && ft->datatype != PointField::UINT32) {
    *error = "PointCloud2 time field " + ft->name + " has datatype " +
             std::to_string(ft->datatype) +
             "; accepted: FLOAT32/FLOAT64 seconds or UINT32 nanoseconds relative to header.stamp";
    return false;
  }
  for (const PointField* f : {fx, fy, fz, ft, fi, fl, fg}) {
    if (!f) continue;
    const size_t size = ScalarSize(f->datatype);
    if (size == 0 || f->offset + size > in.point_step) {
      *error = "PointCloud2 field " + f->name + " has a bad datatype or lies outside point_step";
      return false;
    }
  }
  const uint64_t width = in.width, height = in.height;
  if (height > 0 &&
      (uint64_t{in.row_step} < width * in.point_step ||
       uint64_t{in.row_step} * (height - 1) + width * in.point_step > in.data.size())) {
    *error = "PointCloud2 data holds " + std::to_string(in.data.size()) + " bytes, too few for " +
             std::to_string(width) + "x" + std::to_string(height) + " points of " +
             std::to_string(in.point_step) + " bytes";
    return false;
  }
  const int64_t stamp_ns = ToNs(in.header.stamp);
  std::vector<int64_t> rel_ns;
  rel_ns.reserve(width * height);
  out->points.clear();
  out->points.reserve(width * height);
  for (uint64_t r = 0; r < height; ++r) {
    for (uint64_t c = 0; c < width; ++c) {
      const uint8_t* p = in.data.data() + r * in.row_step + c * in.point_step;
      const double x = ReadScalar(p + fx->offset, fx->datatype);
      const double y = ReadScalar(p + fy->offset, fy->datatype);
      const double z = ReadScalar(p + fz->offset, fz->datatype);
      if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) continue;
      const double t = ReadScalar(p + ft->offset, ft->datatype);
      if (time_is_seconds) {
        if (!std::isfinite(t) || std::fabs(t) > 1e6) {
          *error = "PointCloud2 time field " + ft->name + " holds " + std::to_string(t) +
                   ", not seconds relative to header.stamp (absolute times are not accepted)";
          return false;
        }
        rel_ns.push_back(std::llround(t * 1e9));
      } else {
        rel_ns.push_back(static_cast<int64_t>(t));
      }
      LivoxPoint q;
      q.x = static_cast<float>(x);
      q.y = static_cast<float>(y);
      q.z = static_cast<float>(z);
      if (fi) {
        const double v = ReadScalar(p + fi->offset, fi->datatype);
        q.reflectivity = static_cast<uint8_t>(std::isfinite(v) ? std::clamp(std::round(v), 0.0, 255.0)
                                                               : 0.0);
      }
      if (fl) {
        q.line = static_cast<uint8_t>(std::clamp(ReadScalar(p + fl->offset, fl->datatype), 0.0, 255.0));
      }
      if (fg) q.tag = static_cast<uint8_t>(ReadScalar(p + fg->offset, fg->datatype));
      out->points.push_back(q);
    }
  }
  const int64_t min_rel = rel_ns.empty() ? 0 : *std::min_element(rel_ns.begin(), rel_ns.end());
  const int64_t max_rel = rel_ns.empty() ? 0 : *std::max_element(rel_ns.begin(), rel_ns.end());
  if (max_rel - min_rel > int64_t{std::numeric_limits<uint32_t>::max()}) {
    *error = "PointCloud2 point times span " + FormatSeconds(max_rel - min_rel) +
             " s, more than fits uint32 nanosecond offsets";
    return false;
  }
  if (stamp_ns + min_rel < 0) {
    *error = "PointCloud2 point times lie before time 0";
    return false;
  }
  for (size_t i = 0; i < rel_ns.size(); ++i) {
    out->points[i].offset_time_ns = static_cast<uint32_t>(rel_ns[i] - min_rel);
  }
  out->stamp_ns = stamp_ns;
  out->frame_id = in.header.frame_id;
  out->timebase_ns = static_cast<uint64_t>(stamp_ns + min_rel);
  out->lidar_id = lidar_id;
  return true;
}

enum class Role { kLidar, kImu, kGnss, kOdometer };

struct TopicRole {
  Role role = Role::kLidar;
  uint8_t lidar_index = 0;
  const char* name = "";  // for messages: "lidar", "imu", ...
};

bool Decode(const TopicRole& role,
            const std::string& type,
            const std::vector<uint8_t>& bytes,
            SensorMessage* out,
            std::string* error) {
  switch (role.role) {
    case Role::kLidar: {
      LidarFrame frame;
      if (type == RosType<livox_ros_driver::CustomMsg>()) {
        livox_ros_driver::CustomMsg msg;
        if (!Deserialize(bytes, &msg, error)) return false;
        if (msg.point_num != msg.points.size()) {
          *error = "CustomMsg point_num " + std::to_string(msg.point_num) + " but " +
                   std::to_string(msg.points.size()) + " points";
          return false;
        }
        ConvertCustomMsg(msg, &frame);
      } else {
        sensor_msgs::PointCloud2 msg;
        if (!Deserialize(bytes, &msg, error)) return false;
        if (!ConvertPointCloud2(msg, role.lidar_index, &frame, error)) return false;
      }
      out->data = std::move(frame);
      return true;
    }
    case Role::kImu: {
      sensor_msgs::Imu msg;
      if (!Deserialize(bytes, &msg, error)) return false;
      ImuSample sample;
      sample.stamp_ns = ToNs(msg.header.stamp);
      sample.frame_id = msg.header.frame_id;
      sample.angular_velocity_radps = {
          msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z};
      sample.linear_acceleration_mps2 = {
          msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z};
      // -1 in element 0 means "unknown" (sensor_msgs/Imu); that becomes variance 0.
      sample.gyro_noise_var = std::max(0.0, msg.angular_velocity_covariance[0]);
      sample.accel_noise_var = std::max(0.0, msg.linear_acceleration_covariance[0]);
      out->data = std::move(sample);
      return true;
    }
    case Role::kGnss: {
      sensor_msgs::NavSatFix msg;
      if (!Deserialize(bytes, &msg, error)) return false;
      GnssFix fix;
      fix.stamp_ns = ToNs(msg.header.stamp);
      fix.frame_id = msg.header.frame_id;
      fix.status = msg.status.status;
      fix.service = msg.status.service;
      fix.latitude_deg = msg.latitude;
      fix.longitude_deg = msg.longitude;
      fix.altitude_m = msg.altitude;
      for (size_t i = 0; i < 9; ++i) fix.position_covariance[i] = msg.position_covariance[i];
      fix.position_covariance_type = msg.position_covariance_type;
      out->data = std::move(fix);
      return true;
    }
    case Role::kOdometer: {
      sensor_msgs::JointState msg;
      if (!Deserialize(bytes, &msg, error)) return false;
      auto it = std::find(msg.name.begin(), msg.name.end(), "wheel");
      if (it == msg.name.end()) {
        *error = "JointState has no joint named 'wheel'";
        return false;
      }
      const size_t i = static_cast<size_t>(it - msg.name.begin());
      if (i >= msg.position.size() || i >= msg.velocity.size()) {
        *error = "JointState lacks position or velocity for joint 'wheel'";
        return false;
      }
      WheelOdometry odometry;
      odometry.stamp_ns = ToNs(msg.header.stamp);
      odometry.frame_id = msg.header.frame_id;
      odometry.position_rad = msg.position[i];
      odometry.velocity_radps = msg.velocity[i];
      out->data = std::move(odometry);
      return true;
    }
  }
  return false;
}

struct ExpectedType {
  std::string type;
  std::string md5sum;
};

std::vector<ExpectedType> AcceptedTypes(Role role) {
  switch (role) {
    case Role::kLidar:
      return {{RosType<livox_ros_driver::CustomMsg>(), RosMd5<livox_ros_driver::CustomMsg>()},
              {RosType<sensor_msgs::PointCloud2>(), RosMd5<sensor_msgs::PointCloud2>()}};
    case Role::kImu:
      return {{RosType<sensor_msgs::Imu>(), RosMd5<sensor_msgs::Imu>()}};
    case Role::kGnss:
      return {{RosType<sensor_msgs::NavSatFix>(), RosMd5<sensor_msgs::NavSatFix>()}};
    case Role::kOdometer:
      return {{RosType<sensor_msgs::JointState>(), RosMd5<sensor_msgs::JointState>()}};
  }
  return {};
}

}  // namespace

// --- BagTopics, BagSummary ---------------------------------------------------------------------

BagTopics BagTopics::None() {
  BagTopics topics;
  topics.lidar.clear();
  topics.imu.clear();
  topics.gnss.clear();
  topics.odometer.clear();
  return topics;
}

bool BagTopics::IsValid(std::string* error) const {
  std::set<std::string> seen;
  std::vector<std::pair<std::string, std::string>> named;
  for (const std::string& topic : lidar) named.emplace_back("lidar", topic);
  named.emplace_back("imu", imu);
  named.emplace_back("gnss", gnss);
  named.emplace_back("odometer", odometer);
  for (const auto& [what, topic] : named) {
    if (topic.empty()) {
      if (what == "lidar") {
        if (error) *error = "a lidar topic name is empty";
        return false;
      }
      continue;
    }
    if (topic[0] != '/') {
      if (error) *error = what + " topic '" + topic + "' must start with '/'";
      return false;
    }
    if (!seen.insert(topic).second) {
      if (error) *error = "topic " + topic + " is configured twice";
      return false;
    }
  }
  return true;
}

std::string BagSummary::ToString() const {
  std::ostringstream out;
  out << "path:      " << path << "\n";
  out << "size:      " << file_size_bytes << " bytes\n";
  out << "indexed:   " << (indexed ? "yes" : "no (read by scanning records)") << "\n";
  out << "duration:  " << FormatSeconds(end_ns - start_ns) << " s\n";
  out << "start:     " << FormatSeconds(start_ns) << "\n";
  out << "end:       " << FormatSeconds(end_ns) << "\n";
  out << "messages:  " << message_count << "\n";
  size_t width = 0, count_width = 0;
  for (const auto& t : topics) {
    width = std::max(width, t.topic.size());
    count_width = std::max(count_width, std::to_string(t.message_count).size());
  }
  bool first = true;
  for (const auto& t : topics) {
    const std::string count = std::to_string(t.message_count);
    out << (first ? "topics:    " : "           ") << t.topic
        << std::string(width - t.topic.size() + 2 + count_width - count.size(), ' ') << count
        << " msgs : " << t.type << " [" << t.md5sum << "]\n";
    first = false;
  }
  if (topics.empty()) out << "topics:    (none)\n";
  if (!damage.empty()) out << "damage:    " << damage << "\n";
  return out.str();
}

// --- BagReader ----------------------------------------------------------------------------------

struct BagReader::Impl {
  BagSummary summary;
  std::map<std::string, TopicRole> roles;
  std::map<std::string, uint64_t> delivered;
  uint64_t delivered_total = 0;
  int64_t last_time_ns = 0;
  std::string error;
  bool finished = false;

  // Indexed bags: rosbag's View merges the topics in time order.
  std::unique_ptr<rosbag::Bag> bag;
  std::unique_ptr<rosbag::View> view;
  rosbag::View::iterator it;
  bool started = false;

  // Bags without a usable index: a sequential scan.
  std::unique_ptr<BagScanner> scanner;

  bool Fail(const std::string& what) {
    std::string text = what;
    if (delivered_total > 0) {
      text += " (after " + std::to_string(delivered_total) + " messages, the last at bag time " +
              FormatSeconds(last_time_ns) + " s)";
    } else {
      text += " (before any message was delivered)";
    }
    error = "bag " + summary.path + ": " + text;
    finished = true;
    return false;
  }

  bool Deliver(const std::string& topic,
               const std::string& type,
               int64_t time_ns,
               const std::vector<uint8_t>& bytes,
               SensorMessage* message) {
    const TopicRole& role = roles.at(topic);
    std::string why;
    SensorMessage out;
    out.topic = topic;
    out.receive_ns = time_ns;
    if (!Decode(role, type, bytes, &out, &why)) {
      return Fail("bad " + type + " on " + topic + " at bag time " + FormatSeconds(time_ns) +
                  " s: " + why);
    }
    *message = std::move(out);
    ++delivered[topic];
    ++delivered_total;
    last_time_ns = time_ns;
    return true;
  }

  bool NextIndexed(SensorMessage* message) {
    if (!view) {
      finished = true;
      return false;
    }
    std::vector<uint8_t> bytes;
    try {
      if (!started) {
        it = view->begin();
        started = true;
      } else {
        ++it;
      }
      if (it == view->end()) {
        finished = true;
        return false;
      }
      const rosbag::MessageInstance& m = *it;
      const uint32_t size = m.size();
      if (size > kMaxRecordBytes) {
        return Fail("message on " + m.getTopic() + " claims " + std::to_string(size) +
                    " bytes (corrupt record)");
      }
      bytes.resize(size);
      ros::serialization::OStream stream(bytes.data(), size);
      m.write(stream);
      return Deliver(m.getTopic(), m.getDataType(), ToNs(m.getTime()), bytes, message);
    } catch (const std::exception& e) {
      return Fail(std::string("read failed: ") + e.what());
    }
  }

  bool NextScanned(SensorMessage* message) {
    RawMessage raw;
    while (scanner->Next(&raw)) {
      const Connection& connection = scanner->connections().at(raw.connection);
      if (roles.count(connection.topic) == 0) continue;
      return Deliver(connection.topic, connection.type, raw.time_ns, raw.data, message);
    }
    // summary.damage holds why the index is unusable and where the scan stopped.
    if (!scanner->damage().empty()) return Fail("damaged: " + summary.damage);
    finished = true;
    return false;
  }
};

namespace {

// Summary of an indexed bag through rosbag's index.
void SummariseIndexed(rosbag::Bag& bag, BagSummary* summary) {
  rosbag::View all(bag);
  summary->message_count = all.size();
  if (summary->message_count > 0) {
    summary->start_ns = ToNs(all.getBeginTime());
    summary->end_ns = ToNs(all.getEndTime());
  }
  std::map<std::tuple<std::string, std::string, std::string>, BagTopicInfo> infos;
  for (const rosbag::ConnectionInfo* c : all.getConnections()) {
    BagTopicInfo& info = infos[{c->topic, c->datatype, c->md5sum}];
    info.topic = c->topic;
    info.type = c->datatype;
    info.md5sum = c->md5sum;
  }
  for (auto& [key, info] : infos) {
    // A topic may carry several connections; count those of this type only.
    const BagTopicInfo wanted = info;
    rosbag::View one(bag, [&wanted](const rosbag::ConnectionInfo* c) {
      return c->topic == wanted.topic && c->datatype == wanted.type && c->md5sum == wanted.md5sum;
    });
    info.message_count = one.size();
    summary->topics.push_back(info);
  }
}

// Summary of a bag without index: scan it completely (decompressing every chunk).
void SummariseScanned(const std::string& path, BagSummary* summary) {
  BagScanner scanner;
  std::string error;
  if (!scanner.Open(path, &error)) {
    summary->damage = error;
    return;
  }
  std::map<uint32_t, uint64_t> counts;
  RawMessage raw;
  bool any = false;
  while (scanner.Next(&raw)) {
    ++counts[raw.connection];
    ++summary->message_count;
    if (!any || raw.time_ns < summary->start_ns) summary->start_ns = raw.time_ns;
    if (!any || raw.time_ns > summary->end_ns) summary->end_ns = raw.time_ns;
    any = true;
  }
  summary->damage = scanner.damage();
  std::map<std::tuple<std::string, std::string, std::string>, BagTopicInfo> infos;
  for (const auto& [id, c] : scanner.connections()) {
    BagTopicInfo& info = infos[{c.topic, c.type, c.md5sum}];
    info.topic = c.topic;
    info.type = c.type;
    info.md5sum = c.md5sum;
    info.message_count += counts[id];
  }
  for (auto& [key, info] : infos) summary->topics.push_back(info);
}

std::string ListTopics(const BagSummary& summary) {
  if (summary.topics.empty()) return "none";
  std::string list;
  for (const auto& t : summary.topics) {
    list += (list.empty() ? "" : ", ") + t.topic + " (" + t.type + ")";
  }
  return list;
}

}  // namespace

BagReader::BagReader(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

BagReader::~BagReader() = default;

std::unique_ptr<BagReader> BagReader::Open(const std::string& path,
                                           const BagTopics& topics,
                                           std::string* error) {
  std::string ignored;
  if (!error) error = &ignored;
  if (!topics.IsValid(error)) return nullptr;
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) {
    *error = "bag " + path + " does not exist";
    if (errno != ENOENT) *error = "cannot access bag " + path + ": " + std::strerror(errno);
    return nullptr;
  }
  if (!S_ISREG(st.st_mode)) {
    *error = "bag " + path + " is not a regular file";
    return nullptr;
  }

  auto impl = std::make_unique<Impl>();
  BagSummary& summary = impl->summary;
  summary.path = path;
  summary.file_size_bytes = static_cast<uint64_t>(st.st_size);

  // Check the magic and the bag header ourselves: rosbag's error messages for a non-bag are
  // obscure, and a bag whose index position is 0 or past the end has no usable index.
  {
    BagScanner probe;
    if (!probe.Open(path, error)) return nullptr;
    summary.indexed = probe.index_pos() != 0 && probe.index_pos() < probe.file_size();
    if (!summary.indexed) {
      summary.damage = probe.index_pos() == 0
                           ? "the bag has no index (its recording was not closed)"
                           : "the index position " + std::to_string(probe.index_pos()) +
                                 " lies beyond the end of the file (" +
                                 std::to_string(probe.file_size()) + " bytes): truncated";
    }
  }
  if (summary.indexed) {
    try {
      impl->bag = std::make_unique<rosbag::Bag>();
      impl->bag->open(path, rosbag::bagmode::Read);
      SummariseIndexed(*impl->bag, &summary);
    } catch (const std::exception& e) {
      summary.indexed = false;
      summary.damage = std::string("its index cannot be read (") + e.what() + ")";
      summary.topics.clear();
      summary.message_count = 0;
      impl->bag.reset();
    }
  }
  if (!summary.indexed) {
    const std::string why = summary.damage;
    SummariseScanned(path, &summary);
    summary.damage = why + (summary.damage.empty() ? "" : "; " + summary.damage);
  }

  // Every configured topic must be present with an accepted type and md5.
  std::vector<std::pair<std::string, TopicRole>> wanted;
  for (size_t i = 0; i < topics.lidar.size(); ++i) {
    wanted.push_back({topics.lidar[i], {Role::kLidar, static_cast<uint8_t>(i), "lidar"}});
  }
  if (!topics.imu.empty()) wanted.push_back({topics.imu, {Role::kImu, 0, "imu"}});
  if (!topics.gnss.empty()) wanted.push_back({topics.gnss, {Role::kGnss, 0, "gnss"}});
  if (!topics.odometer.empty()) {
    wanted.push_back({topics.odometer, {Role::kOdometer, 0, "odometer"}});
  }
  const std::string damage_note =
      summary.damage.empty() ? "" : " (the bag is damaged: " + summary.damage + ")";
  for (const auto& [topic, role] : wanted) {
    bool found = false;
    for (const BagTopicInfo& info : summary.topics) {
      if (info.topic != topic) continue;
      found = true;
      const std::vector<ExpectedType> accepted = AcceptedTypes(role.role);
      std::string names;
      bool ok = false;
      for (const ExpectedType& e : accepted) {
        names += (names.empty() ? "" : " or ") + e.type;
        if (e.type != info.type) continue;
        if (e.md5sum != info.md5sum) {
          *error = "bag " + path + ": topic " + topic + " has type " + info.type + " with md5 " +
                   info.md5sum + ", expected md5 " + e.md5sum +
                   " (a different message definition)";
          return nullptr;
        }
        ok = true;
      }
      if (!ok) {
        *error = "bag " + path + ": " + role.name + " topic " + topic + " has type " + info.type +
                 ", expected " + names;
        return nullptr;
      }
    }
    if (!found) {
      *error = "bag " + path + " has no " + role.name + " topic " + topic +
               "; it has: " + ListTopics(summary) + damage_note;
      return nullptr;
    }
    impl->roles[topic] = role;
  }

  if (summary.indexed) {
    if (!impl->roles.empty()) {
      std::vector<std::string> names;
      for (const auto& [topic, role] : impl->roles) names.push_back(topic);
      try {
        impl->view = std::make_unique<rosbag::View>(*impl->bag, rosbag::TopicQuery(names));
      } catch (const std::exception& e) {
        *error = "bag " + path + ": cannot query its index: " + e.what();
        return nullptr;
      }
    }
  } else {
    impl->scanner = std::make_unique<BagScanner>();
    if (!impl->scanner->Open(path, error)) return nullptr;
  }
  return std::unique_ptr<BagReader>(new BagReader(std::move(impl)));
}

bool BagReader::Inspect(const std::string& path, BagSummary* summary, std::string* error) {
  std::unique_ptr<BagReader> reader = Open(path, BagTopics::None(), error);
  if (!reader) return false;
  *summary = reader->Summary();
  return true;
}

bool BagReader::Next(SensorMessage* message) {
  Impl& d = *impl_;
  if (d.finished) return false;
  if (d.roles.empty()) {
    d.finished = true;
    return false;
  }
  return d.summary.indexed ? d.NextIndexed(message) : d.NextScanned(message);
}

const std::string& BagReader::error() const { return impl_->error; }

const BagSummary& BagReader::Summary() const { return impl_->summary; }

const std::map<std::string, uint64_t>& BagReader::delivered_counts() const {
  return impl_->delivered;
}

}  // namespace raillomer::io
