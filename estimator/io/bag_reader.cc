#include "estimator/io/bag_reader.h"

#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <initializer_list>
#include <limits>
#include <list>
#include <set>
#include <sstream>
#include <tuple>
#include <utility>

#include <bzlib.h>
#include <roslz4/lz4s.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/JointState.h>
#include <sensor_msgs/NavSatFix.h>
#include <sensor_msgs/PointCloud2.h>

#include "estimator/io/livox_custom_msg.h"

// The reader parses the bag format itself (http://wiki.ros.org/Bags/Format/2.0) instead of using
// rosbag::View: rosbag's parser overruns buffers on corrupt records, and ROS deserialisers resize
// vectors to any length a corrupt message claims. Here every length is checked against the bytes
// present, so a damaged bag gives a message, never a crash or a huge allocation. The message
// types' names and md5 sums still come from the ROS headers (and livox_custom_msg.h).

namespace raillomer::io {
namespace {

constexpr int64_t kNsPerS = 1000000000;
constexpr char kBagMagic[] = "#ROSBAG V2.0\n";
constexpr size_t kBagMagicSize = sizeof(kBagMagic) - 1;
// A chunk larger than this (uncompressed) is taken as a corrupt size field.
constexpr uint64_t kMaxChunkBytes = uint64_t{1} << 31;
// Decompressed chunks kept while reading in time order (messages of neighbouring chunks interleave
// in time when receive times lag).
constexpr size_t kChunkCacheSize = 4;

template <typename T>
const char* RosType() {
  return ros::message_traits::DataType<T>::value();
}
template <typename T>
const char* RosMd5() {
  return ros::message_traits::MD5Sum<T>::value();
}

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

std::string At(uint64_t pos) { return "byte " + std::to_string(pos); }

// --- Records -------------------------------------------------------------------------------------
// Every record is: uint32 header_len, header (fields: uint32 len, "name=value"), uint32 data_len,
// data. All integers little-endian.

enum Op : uint8_t {
  kOpMessageData = 0x02,
  kOpBagHeader = 0x03,
  kOpIndexData = 0x04,
  kOpChunk = 0x05,
  kOpChunkInfo = 0x06,
  kOpConnection = 0x07,
};

using Fields = std::map<std::string, std::string>;

uint32_t ReadU32(const uint8_t* p) {
  return uint32_t{p[0]} | uint32_t{p[1]} << 8 | uint32_t{p[2]} << 16 | uint32_t{p[3]} << 24;
}

uint64_t ReadU64(const uint8_t* p) { return ReadU32(p) | uint64_t{ReadU32(p + 4)} << 32; }

int64_t ReadTime(const uint8_t* p) { return int64_t{ReadU32(p)} * kNsPerS + ReadU32(p + 4); }

bool ParseFields(const uint8_t* p, size_t size, Fields* fields) {
  fields->clear();
  size_t i = 0;
  while (i < size) {
    if (size - i < 4) return false;
    const uint32_t len = ReadU32(p + i);
    i += 4;
    if (len > size - i) return false;
    const char* field = reinterpret_cast<const char*>(p + i);
    const char* eq = static_cast<const char*>(std::memchr(field, '=', len));
    if (!eq) return false;
    (*fields)[std::string(field, eq)] = std::string(eq + 1, field + len);
    i += len;
  }
  return true;
}

bool FieldU32(const Fields& fields, const char* name, uint32_t* value) {
  auto it = fields.find(name);
  if (it == fields.end() || it->second.size() != 4) return false;
  *value = ReadU32(reinterpret_cast<const uint8_t*>(it->second.data()));
  return true;
}

bool FieldU64(const Fields& fields, const char* name, uint64_t* value) {
  auto it = fields.find(name);
  if (it == fields.end() || it->second.size() != 8) return false;
  *value = ReadU64(reinterpret_cast<const uint8_t*>(it->second.data()));
  return true;
}

bool FieldTime(const Fields& fields, const char* name, int64_t* time_ns) {
  auto it = fields.find(name);
  if (it == fields.end() || it->second.size() != 8) return false;
  *time_ns = ReadTime(reinterpret_cast<const uint8_t*>(it->second.data()));
  return true;
}

bool FieldOp(const Fields& fields, uint8_t* op) {
  auto it = fields.find("op");
  if (it == fields.end() || it->second.size() != 1) return false;
  *op = static_cast<uint8_t>(it->second[0]);
  return true;
}

struct Connection {
  std::string topic;
  std::string type;
  std::string md5sum;
};

// Parses a connection record (header: conn, topic; data: the connection header fields).
bool ParseConnection(
    const Fields& header, const uint8_t* data, size_t size, uint32_t* id, Connection* connection) {
  Fields fields;
  auto topic_it = header.find("topic");
  if (!FieldU32(header, "conn", id) || topic_it == header.end() ||
      !ParseFields(data, size, &fields)) {
    return false;
  }
  connection->topic = topic_it->second;
  connection->type = fields["type"];
  connection->md5sum = fields["md5sum"];
  return !connection->type.empty();
}

// The header of a record in the file, its data not yet read.
struct RecordHeader {
  uint64_t pos = 0;  // of the record
  Fields fields;
  uint8_t op = 0;
  uint64_t data_pos = 0;
  uint32_t data_len = 0;
  uint64_t data_present = 0;  // < data_len when the file ends inside the data
};

// A bag file opened for random access.
class BagFile {
 public:
  ~BagFile() {
    if (file_) std::fclose(file_);
  }

  // Opens the file, checks the magic and reads the bag header record.
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
    size_ = static_cast<uint64_t>(st.st_size);
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
    RecordHeader header;
    std::string why;
    if (!ReadHeader(kBagMagicSize, &header, &why) || header.data_present < header.data_len ||
        header.op != kOpBagHeader || !FieldU64(header.fields, "index_pos", &index_pos_)) {
      *error = path + " is not a ROS1 bag: no valid bag header record after the magic" +
               (why.empty() ? "" : " (" + why + ")");
      return false;
    }
    FieldU32(header.fields, "conn_count", &conn_count_);
    FieldU32(header.fields, "chunk_count", &chunk_count_);
    first_record_pos_ = header.data_pos + header.data_len;
    return true;
  }

  uint64_t size() const { return size_; }
  uint64_t index_pos() const { return index_pos_; }
  uint32_t conn_count() const { return conn_count_; }
  uint32_t chunk_count() const { return chunk_count_; }
  uint64_t first_record_pos() const { return first_record_pos_; }

  bool ReadAt(uint64_t pos, void* out, uint64_t size) {
    if (pos > size_ || size > size_ - pos) return false;
    if (::fseeko(file_, static_cast<off_t>(pos), SEEK_SET) != 0) return false;
    return std::fread(out, 1, size, file_) == size;
  }

  // Reads the header of the record at `pos`. False with `why` when the header itself is cut off
  // or corrupt; a record whose data is cut off is returned with data_present < data_len.
  bool ReadHeader(uint64_t pos, RecordHeader* header, std::string* why) {
    header->pos = pos;
    uint8_t len_bytes[4];
    if (!ReadAt(pos, len_bytes, 4)) {
      *why = "file ends at " + At(size_) + " inside the record at " + At(pos);
      return false;
    }
    const uint32_t header_len = ReadU32(len_bytes);
    if (header_len > size_ - pos - 4) {
      *why = "file ends at " + At(size_) + " inside the header of the record at " + At(pos) +
             " (or its length field is corrupt)";
      return false;
    }
    std::vector<uint8_t> bytes(header_len);
    if (!ReadAt(pos + 4, bytes.data(), header_len) ||
        !ParseFields(bytes.data(), header_len, &header->fields) ||
        !FieldOp(header->fields, &header->op)) {
      *why = "corrupt record header at " + At(pos);
      return false;
    }
    const uint64_t data_len_pos = pos + 4 + header_len;
    if (!ReadAt(data_len_pos, len_bytes, 4)) {
      *why = "file ends at " + At(size_) + " inside the record at " + At(pos);
      return false;
    }
    header->data_len = ReadU32(len_bytes);
    header->data_pos = data_len_pos + 4;
    header->data_present = std::min<uint64_t>(header->data_len, size_ - header->data_pos);
    return true;
  }

  bool ReadData(const RecordHeader& header, std::vector<uint8_t>* data) {
    data->resize(header.data_present);
    return header.data_present == 0 || ReadAt(header.data_pos, data->data(), header.data_present);
  }

 private:
  FILE* file_ = nullptr;
  uint64_t size_ = 0;
  uint64_t index_pos_ = 0;
  uint32_t conn_count_ = 0;
  uint32_t chunk_count_ = 0;
  uint64_t first_record_pos_ = 0;
};

// Decompresses a chunk's data into `out` (`size` bytes uncompressed).
bool Decompress(const std::string& compression,
                std::vector<uint8_t>& in,
                uint32_t size,
                std::vector<uint8_t>* out,
                std::string* why) {
  if (size > kMaxChunkBytes) {
    *why = "implausible uncompressed size " + std::to_string(size);
    return false;
  }
  if (compression == "none") {
    if (in.size() != size) {
      *why = "uncompressed chunk of " + std::to_string(in.size()) + " bytes claims size " +
             std::to_string(size);
      return false;
    }
    *out = in;
    return true;
  }
  out->resize(size);
  unsigned int out_size = size;
  bool ok = false;
  if (compression == "lz4") {
    ok = roslz4_buffToBuffDecompress(reinterpret_cast<char*>(in.data()),
                                     static_cast<unsigned int>(in.size()),
                                     reinterpret_cast<char*>(out->data()),
                                     &out_size) == ROSLZ4_OK;
  } else if (compression == "bz2") {
    ok = BZ2_bzBuffToBuffDecompress(reinterpret_cast<char*>(out->data()),
                                    &out_size,
                                    reinterpret_cast<char*>(in.data()),
                                    static_cast<unsigned int>(in.size()),
                                    /*small=*/0,
                                    /*verbosity=*/0) == BZ_OK;
  } else {
    *why = "unknown compression '" + compression + "'";
    return false;
  }
  if (!ok || out_size != size) {
    *why = "cannot decompress its " + compression + " data (corrupt)";
    return false;
  }
  return true;
}

// One record inside a (decompressed) chunk.
struct InnerRecord {
  Fields fields;
  uint8_t op = 0;
  const uint8_t* data = nullptr;
  uint32_t data_len = 0;
  size_t end = 0;  // offset after the record
};

enum class InnerResult { kOk, kIncomplete, kCorrupt };

InnerResult ParseInnerRecord(const uint8_t* p, size_t size, size_t offset, InnerRecord* record) {
  if (offset > size || size - offset < 4) return InnerResult::kIncomplete;
  const uint32_t header_len = ReadU32(p + offset);
  if (header_len > size - offset - 4) return InnerResult::kIncomplete;
  if (!ParseFields(p + offset + 4, header_len, &record->fields) ||
      !FieldOp(record->fields, &record->op)) {
    return InnerResult::kCorrupt;
  }
  const size_t data_len_pos = offset + 4 + header_len;
  if (size - data_len_pos < 4) return InnerResult::kIncomplete;
  record->data_len = ReadU32(p + data_len_pos);
  if (record->data_len > size - data_len_pos - 4) return InnerResult::kIncomplete;
  record->data = p + data_len_pos + 4;
  record->end = data_len_pos + 4 + record->data_len;
  return InnerResult::kOk;
}

// --- The bag's index -----------------------------------------------------------------------------

struct Chunk {
  RecordHeader record;
  std::string compression;
  uint32_t size = 0;  // uncompressed
};

struct IndexEntry {
  int64_t time_ns = 0;
  uint32_t chunk = 0;
  uint32_t offset = 0;  // of the message record in the uncompressed chunk
  uint32_t connection = 0;
};

// The index of a finished bag: chunks, their index data records, and the connection records at
// the end. Loaded by walking the top-level records (skipping chunk data), and checked for
// consistency, so that reading by it cannot go astray.
struct BagIndex {
  std::map<uint32_t, Connection> connections;
  std::vector<Chunk> chunks;
  std::vector<IndexEntry> entries;  // sorted by time, then file order

  bool Load(BagFile& file, std::string* why) {
    if (file.index_pos() == 0) {
      *why = "the bag has no index (its recording was not closed)";
      return false;
    }
    if (file.index_pos() >= file.size()) {
      *why = "the index position " + std::to_string(file.index_pos()) +
             " lies beyond the end of the file (" + std::to_string(file.size()) +
             " bytes): the file is truncated";
      return false;
    }
    uint64_t pos = file.first_record_pos();
    std::vector<uint8_t> data;
    while (pos < file.size()) {
      RecordHeader header;
      if (!file.ReadHeader(pos, &header, why)) return false;
      if (header.data_present < header.data_len) {
        *why = "file ends at " + At(file.size()) + " inside the record at " + At(pos);
        return false;
      }
      if (!AddRecord(file, header, pos, &data, why)) return false;
      pos = header.data_pos + header.data_len;
    }
    if (!Consistent(file, why)) return false;
    std::stable_sort(entries.begin(), entries.end(), [](const IndexEntry& a, const IndexEntry& b) {
      return a.time_ns < b.time_ns;
    });
    return true;
  }

 private:
  /// Takes one top-level record at `pos`: a chunk, its index data or a connection.
  bool AddRecord(BagFile& file,
                 const RecordHeader& header,
                 uint64_t pos,
                 std::vector<uint8_t>* data,
                 std::string* why) {
    if (header.op == kOpChunk) {
      Chunk chunk;
      chunk.record = header;
      auto compression = header.fields.find("compression");
      if (compression == header.fields.end() || !FieldU32(header.fields, "size", &chunk.size)) {
        *why = "chunk at " + At(pos) + " lacks its compression or size";
        return false;
      }
      chunk.compression = compression->second;
      chunks.push_back(std::move(chunk));
    } else if (header.op == kOpIndexData) {
      return AddIndexData(file, header, pos, data, why);
    } else if (header.op == kOpConnection) {
      uint32_t id = 0;
      Connection connection;
      if (!file.ReadData(header, data) ||
          !ParseConnection(header.fields, data->data(), data->size(), &id, &connection)) {
        *why = "corrupt connection record at " + At(pos);
        return false;
      }
      connections[id] = connection;
    } else if (header.op != kOpChunkInfo) {
      *why = "unexpected record (op " + std::to_string(header.op) + ") at " + At(pos);
      return false;
    }
    return true;
  }

  /// The entries of an index data record, which follows its chunk.
  bool AddIndexData(BagFile& file,
                    const RecordHeader& header,
                    uint64_t pos,
                    std::vector<uint8_t>* data,
                    std::string* why) {
    uint32_t version = 0, connection = 0, count = 0;
    if (chunks.empty() || !FieldU32(header.fields, "ver", &version) || version != 1 ||
        !FieldU32(header.fields, "conn", &connection) ||
        !FieldU32(header.fields, "count", &count) || uint64_t{count} * 12 != header.data_len ||
        !file.ReadData(header, data)) {
      *why = "corrupt index data record at " + At(pos);
      return false;
    }
    for (uint32_t i = 0; i < count; ++i) {
      IndexEntry entry;
      entry.time_ns = ReadTime(data->data() + 12 * i);
      entry.offset = ReadU32(data->data() + 12 * i + 8);
      entry.chunk = static_cast<uint32_t>(chunks.size() - 1);
      entry.connection = connection;
      entries.push_back(entry);
    }
    return true;
  }

  /// The index agrees with the bag header's counts, and every entry with its chunk.
  bool Consistent(const BagFile& file, std::string* why) const {
    if (chunks.size() != file.chunk_count() || connections.size() != file.conn_count()) {
      *why = "the index lists " + std::to_string(chunks.size()) + " chunks and " +
             std::to_string(connections.size()) + " connections, the bag header " +
             std::to_string(file.chunk_count()) + " and " + std::to_string(file.conn_count());
      return false;
    }
    for (const IndexEntry& entry : entries) {
      if (connections.count(entry.connection) == 0 || entry.offset >= chunks[entry.chunk].size) {
        *why = "the index of the chunk at " + At(chunks[entry.chunk].record.pos) + " is corrupt";
        return false;
      }
    }
    return true;
  }
};

// --- Scanning a bag without a usable index
// --------------------------------------------------------

struct RawMessage {
  uint32_t connection = 0;
  int64_t time_ns = 0;
  std::vector<uint8_t> data;
};

// Reads a bag record by record. Messages inside one chunk come out sorted by time (stable); chunks
// come out in file order, which is recording order.
class BagScanner {
 public:
  bool Open(const std::string& path, std::string* error) {
    if (!file_.Open(path, error)) return false;
    pos_ = file_.first_record_pos();
    return true;
  }

  const std::string& damage() const { return damage_; }
  const std::map<uint32_t, Connection>& connections() const { return connections_; }

  // Next message; false at the end of the file or at damage (damage() says what and where).
  // Messages recovered from before the damage are delivered first.
  bool Next(RawMessage* message) {
    while (pending_next_ >= pending_.size()) {
      pending_.clear();
      pending_next_ = 0;
      if (!damage_.empty() || pos_ >= file_.size()) return false;
      RecordHeader header;
      if (!file_.ReadHeader(pos_, &header, &damage_)) return false;
      const bool cut = header.data_present < header.data_len;
      if (cut) {
        damage_ = "file ends at " + At(file_.size()) + " inside the record at " + At(pos_) +
                  " (its data needs " + std::to_string(header.data_len) + " bytes, only " +
                  std::to_string(header.data_present) + " are present)";
      }
      pos_ = header.data_pos + header.data_present;
      if (header.op != kOpChunk && header.op != kOpConnection && header.op != kOpMessageData) {
        continue;  // bag header, index data and chunk info records carry no messages
      }
      if (!file_.ReadData(header, &data_)) {
        damage_ = "read error in the record at " + At(header.pos);
        return false;
      }
      if (header.op == kOpChunk) {
        ReadChunk(header, cut);
      } else if (!cut && header.op == kOpConnection) {
        AddConnection(header.fields, data_.data(), data_.size(), header.pos);
      } else if (!cut) {
        AddMessage(header.fields, data_.data(), data_.size(), header.pos);
      }
      std::stable_sort(pending_.begin(), pending_.end(), [](const auto& a, const auto& b) {
        return a.time_ns < b.time_ns;
      });
    }
    *message = std::move(pending_[pending_next_++]);
    return true;
  }

 private:
  void SetDamage(const std::string& what) {
    if (damage_.empty()) damage_ = what;
  }

  void ReadChunk(const RecordHeader& header, bool cut) {
    const std::string where = "the chunk at " + At(header.pos);
    auto compression = header.fields.find("compression");
    uint32_t size = 0;
    if (compression == header.fields.end() || !FieldU32(header.fields, "size", &size)) {
      SetDamage(where + " lacks its compression or size");
      return;
    }
    if (cut) {
      if (compression->second == "none") {
        // A cut-off uncompressed chunk still yields its complete records.
        ParseChunk(data_.data(), data_.size(), where, /*cut=*/true);
        damage_ += "; the complete messages before the cut were recovered";
      } else {
        damage_ += "; that " + compression->second + "-compressed chunk is lost";
      }
      return;
    }
    std::string why;
    if (!Decompress(compression->second, data_, size, &chunk_, &why)) {
      SetDamage(where + ": " + why);
      return;
    }
    ParseChunk(chunk_.data(), chunk_.size(), where, /*cut=*/false);
  }

  void ParseChunk(const uint8_t* p, size_t size, const std::string& where, bool cut) {
    size_t offset = 0;
    while (offset < size) {
      InnerRecord record;
      const InnerResult result = ParseInnerRecord(p, size, offset, &record);
      if (result == InnerResult::kIncomplete) {
        if (!cut)
          SetDamage("truncated record at offset " + std::to_string(offset) + " in " + where);
        return;
      }
      if (result == InnerResult::kCorrupt) {
        SetDamage("corrupt record header at offset " + std::to_string(offset) + " in " + where);
        return;
      }
      bool ok = true;
      if (record.op == kOpConnection) {
        ok = AddConnection(record.fields, record.data, record.data_len, 0, where);
      } else if (record.op == kOpMessageData) {
        ok = AddMessage(record.fields, record.data, record.data_len, 0, where);
      }
      if (!ok) return;
      offset = record.end;
    }
  }

  bool AddConnection(const Fields& header,
                     const uint8_t* data,
                     size_t size,
                     uint64_t pos,
                     const std::string& where = "") {
    uint32_t id = 0;
    Connection connection;
    if (!ParseConnection(header, data, size, &id, &connection)) {
      SetDamage("corrupt connection record " + (where.empty() ? "at " + At(pos) : "in " + where));
      return false;
    }
    connections_[id] = connection;
    return true;
  }

  bool AddMessage(const Fields& header,
                  const uint8_t* data,
                  size_t size,
                  uint64_t pos,
                  const std::string& where = "") {
    RawMessage message;
    const std::string place = where.empty() ? "at " + At(pos) : "in " + where;
    if (!FieldU32(header, "conn", &message.connection) ||
        !FieldTime(header, "time", &message.time_ns)) {
      SetDamage("corrupt message record " + place);
      return false;
    }
    if (connections_.count(message.connection) == 0) {
      SetDamage("a message " + place + " refers to unknown connection " +
                std::to_string(message.connection));
      return false;
    }
    message.data.assign(data, data + size);
    pending_.push_back(std::move(message));
    return true;
  }

  BagFile file_;
  uint64_t pos_ = 0;
  std::string damage_;
  std::map<uint32_t, Connection> connections_;
  std::vector<uint8_t> data_;
  std::vector<uint8_t> chunk_;
  std::vector<RawMessage> pending_;
  size_t pending_next_ = 0;
};

// --- Decoding serialised messages ----------------------------------------------------------------

// Reads ROS1 serialisation (little-endian, uint32 lengths) with every length checked against the
// bytes left, so a corrupt message can neither overrun nor allocate more than its own size.
class Wire {
 public:
  Wire(const uint8_t* p, size_t size) : p_(p), left_(size) {}

  template <typename T>
  bool Get(T* value) {
    static_assert(std::is_arithmetic_v<T>);
    if (left_ < sizeof(T)) return Overrun();
    std::memcpy(value, p_, sizeof(T));
    p_ += sizeof(T);
    left_ -= sizeof(T);
    return true;
  }
  template <typename T, size_t N>
  bool Get(boost::array<T, N>* values) {
    for (T& v : *values) {
      if (!Get(&v)) return false;
    }
    return true;
  }
  bool Get(std::string* s) {
    uint32_t n = 0;
    if (!Get(&n)) return false;
    if (n > left_) return Overrun();
    s->assign(reinterpret_cast<const char*>(p_), n);
    p_ += n;
    left_ -= n;
    return true;
  }
  // The length of an array whose elements take at least `min_element_bytes` each.
  bool Count(size_t min_element_bytes, uint32_t* n) {
    if (!Get(n)) return false;
    if (uint64_t{*n} * min_element_bytes > left_) return Overrun();
    return true;
  }
  template <typename T>
  bool Get(std::vector<T>* values) {
    uint32_t n = 0;
    if (!Count(std::is_arithmetic_v<T> ? sizeof(T) : 4, &n)) return false;
    values->resize(n);
    if constexpr (std::is_arithmetic_v<T>) {
      if (n > 0) std::memcpy(values->data(), p_, n * sizeof(T));
      p_ += n * sizeof(T);
      left_ -= n * sizeof(T);
      return true;
    } else {
      for (T& v : *values) {
        if (!Get(&v)) return false;
      }
      return true;
    }
  }
  bool Get(ros::Time* t) { return Get(&t->sec) && Get(&t->nsec); }
  bool Get(std_msgs::Header* h) { return Get(&h->seq) && Get(&h->stamp) && Get(&h->frame_id); }
  bool Get(geometry_msgs::Vector3* v) { return Get(&v->x) && Get(&v->y) && Get(&v->z); }
  bool Get(geometry_msgs::Quaternion* q) {
    return Get(&q->x) && Get(&q->y) && Get(&q->z) && Get(&q->w);
  }
  bool Get(sensor_msgs::PointField* f) {
    return Get(&f->name) && Get(&f->offset) && Get(&f->datatype) && Get(&f->count);
  }
  bool Get(livox_ros_driver::CustomPoint* p) {
    return Get(&p->offset_time) && Get(&p->x) && Get(&p->y) && Get(&p->z) &&
           Get(&p->reflectivity) && Get(&p->tag) && Get(&p->line);
  }

  bool Get(sensor_msgs::Imu* m) {
    return Get(&m->header) && Get(&m->orientation) && Get(&m->orientation_covariance) &&
           Get(&m->angular_velocity) && Get(&m->angular_velocity_covariance) &&
           Get(&m->linear_acceleration) && Get(&m->linear_acceleration_covariance);
  }
  bool Get(sensor_msgs::NavSatFix* m) {
    return Get(&m->header) && Get(&m->status.status) && Get(&m->status.service) &&
           Get(&m->latitude) && Get(&m->longitude) && Get(&m->altitude) &&
           Get(&m->position_covariance) && Get(&m->position_covariance_type);
  }
  bool Get(sensor_msgs::JointState* m) {
    return Get(&m->header) && Get(&m->name) && Get(&m->position) && Get(&m->velocity) &&
           Get(&m->effort);
  }
  bool Get(sensor_msgs::PointCloud2* m) {
    uint32_t num_fields = 0;
    if (!Get(&m->header) || !Get(&m->height) || !Get(&m->width) || !Count(13, &num_fields)) {
      return false;
    }
    m->fields.resize(num_fields);
    for (auto& f : m->fields) {
      if (!Get(&f)) return false;
    }
    return Get(&m->is_bigendian) && Get(&m->point_step) && Get(&m->row_step) && Get(&m->data) &&
           Get(&m->is_dense);
  }
  bool Get(livox_ros_driver::CustomMsg* m) {
    uint32_t n = 0;
    if (!Get(&m->header) || !Get(&m->timebase) || !Get(&m->point_num) || !Get(&m->lidar_id) ||
        !Get(&m->rsvd) || !Count(19, &n)) {
      return false;
    }
    m->points.resize(n);
    for (auto& p : m->points) {
      if (!Get(&p)) return false;
    }
    return true;
  }

  size_t left() const { return left_; }

 private:
  bool Overrun() {
    left_ = 0;
    return false;
  }
  const uint8_t* p_;
  size_t left_;
};

template <typename T>
bool Deserialize(const uint8_t* data, size_t size, T* message, std::string* error) {
  Wire wire(data, size);
  if (!wire.Get(message)) {
    *error = std::string("message too short for a ") + RosType<T>() + " (" + std::to_string(size) +
             " bytes; corrupt or a different definition)";
    return false;
  }
  if (wire.left() != 0) {
    *error = std::to_string(wire.left()) + " bytes left over after a " + RosType<T>() +
             " (corrupt or a different definition)";
    return false;
  }
  return true;
}

int64_t ToNs(const ros::Time& t) { return int64_t{t.sec} * kNsPerS + t.nsec; }

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

/// The fields of a PointCloud2 that a LiDAR frame reads; i, l and g are optional.
struct CloudFields {
  const sensor_msgs::PointField *x, *y, *z, *t, *i, *l, *g;
  bool time_is_seconds;  ///< FLOAT32/FLOAT64 seconds, else UINT32 nanoseconds
};

/// Finds and checks the fields (see ConvertPointCloud2); false with the error.
bool FindCloudFields(const sensor_msgs::PointCloud2& in, CloudFields* f, std::string* error) {
  using sensor_msgs::PointField;
  *f = {FindField(in, {"x"}),
        FindField(in, {"y"}),
        FindField(in, {"z"}),
        FindField(in, {"time", "t", "timestamp", "offset_time"}),
        FindField(in, {"intensity", "reflectivity"}),
        FindField(in, {"line", "ring"}),
        FindField(in, {"tag"}),
        false};
  if (!f->x || !f->y || !f->z) {
    *error = "PointCloud2 lacks x, y or z (fields: " + FieldNames(in) + ")";
    return false;
  }
  if (!f->t) {
    *error =
        "PointCloud2 has no per-point time field (looked for time, t, timestamp, offset_time; "
        "fields: " +
        FieldNames(in) + ")";
    return false;
  }
  for (const PointField* xyz : {f->x, f->y, f->z}) {
    if (xyz->datatype != PointField::FLOAT32 && xyz->datatype != PointField::FLOAT64) {
      *error = "PointCloud2 field " + xyz->name + " must be FLOAT32 or FLOAT64";
      return false;
    }
  }
  f->time_is_seconds =
      f->t->datatype == PointField::FLOAT32 || f->t->datatype == PointField::FLOAT64;
  if (!f->time_is_seconds && f->t->datatype != PointField::UINT32) {
    *error = "PointCloud2 time field " + f->t->name + " has datatype " +
             std::to_string(f->t->datatype) +
             "; accepted: FLOAT32/FLOAT64 seconds or UINT32 nanoseconds relative to header.stamp";
    return false;
  }
  for (const PointField* field : {f->x, f->y, f->z, f->t, f->i, f->l, f->g}) {
    if (!field) continue;
    const size_t size = ScalarSize(field->datatype);
    if (size == 0 || field->offset + size > in.point_step) {
      *error =
          "PointCloud2 field " + field->name + " has a bad datatype or lies outside point_step";
      return false;
    }
  }
  return true;
}

/// Reads the point at `p`: false with the error for a time that is not relative seconds; a point
/// with a non-finite coordinate is skipped (nothing appended).
bool ReadCloudPoint(const uint8_t* p,
                    const CloudFields& f,
                    std::vector<int64_t>* rel_ns,
                    std::vector<LivoxPoint>* points,
                    std::string* error) {
  const double x = ReadScalar(p + f.x->offset, f.x->datatype);
  const double y = ReadScalar(p + f.y->offset, f.y->datatype);
  const double z = ReadScalar(p + f.z->offset, f.z->datatype);
  if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) return true;
  const double t = ReadScalar(p + f.t->offset, f.t->datatype);
  if (f.time_is_seconds) {
    if (!std::isfinite(t) || std::fabs(t) > 1e6) {
      *error = "PointCloud2 time field " + f.t->name + " holds " + std::to_string(t) +
               ", not seconds relative to header.stamp (absolute times are not accepted)";
      return false;
    }
    rel_ns->push_back(std::llround(t * 1e9));
  } else {
    rel_ns->push_back(static_cast<int64_t>(t));
  }
  LivoxPoint q;
  q.x = static_cast<float>(x);
  q.y = static_cast<float>(y);
  q.z = static_cast<float>(z);
  if (f.i) {
    const double v = ReadScalar(p + f.i->offset, f.i->datatype);
    q.reflectivity =
        static_cast<uint8_t>(std::isfinite(v) ? std::clamp(std::round(v), 0.0, 255.0) : 0.0);
  }
  if (f.l) {
    q.line =
        static_cast<uint8_t>(std::clamp(ReadScalar(p + f.l->offset, f.l->datatype), 0.0, 255.0));
  }
  if (f.g) q.tag = static_cast<uint8_t>(ReadScalar(p + f.g->offset, f.g->datatype));
  points->push_back(q);
  return true;
}

/// Makes the points' times offsets from the earliest, which becomes the frame's timebase.
bool SetFrameTimes(const std::vector<int64_t>& rel_ns,
                   int64_t stamp_ns,
                   LidarFrame* out,
                   std::string* error) {
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
  out->timebase_ns = static_cast<uint64_t>(stamp_ns + min_rel);
  return true;
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
  if (in.is_bigendian) {
    *error = "big-endian PointCloud2 is not supported";
    return false;
  }
  CloudFields fields;
  if (!FindCloudFields(in, &fields, error)) return false;
  const uint64_t width = in.width, height = in.height;
  if (height > 0 &&
      (uint64_t{in.row_step} < width * in.point_step ||
       uint64_t{in.row_step} * (height - 1) + width * in.point_step > in.data.size())) {
    *error = "PointCloud2 data holds " + std::to_string(in.data.size()) + " bytes, too few for " +
             std::to_string(width) + "x" + std::to_string(height) + " points of " +
             std::to_string(in.point_step) + " bytes";
    return false;
  }
  std::vector<int64_t> rel_ns;
  rel_ns.reserve(width * height);
  out->points.clear();
  out->points.reserve(width * height);
  for (uint64_t r = 0; r < height; ++r) {
    for (uint64_t c = 0; c < width; ++c) {
      const uint8_t* p = in.data.data() + r * in.row_step + c * in.point_step;
      if (!ReadCloudPoint(p, fields, &rel_ns, &out->points, error)) return false;
    }
  }
  if (!SetFrameTimes(rel_ns, ToNs(in.header.stamp), out, error)) return false;
  out->frame_id = in.header.frame_id;
  out->lidar_id = lidar_id;
  return true;
}

enum class Role { kLidar, kImu, kGnss, kOdometer };

struct TopicRole {
  Role role = Role::kLidar;
  uint8_t lidar_index = 0;
  const char* name = "";  // "lidar", "imu", ... for messages
};

/// A LiDAR frame from a Livox CustomMsg or a PointCloud2.
bool DecodeLidar(const TopicRole& role,
                 const std::string& type,
                 const uint8_t* data,
                 size_t size,
                 SensorMessage* out,
                 std::string* error) {
  LidarFrame frame;
  if (type == RosType<livox_ros_driver::CustomMsg>()) {
    livox_ros_driver::CustomMsg msg;
    if (!Deserialize(data, size, &msg, error)) return false;
    if (msg.point_num != msg.points.size()) {
      *error = "CustomMsg point_num " + std::to_string(msg.point_num) + " but " +
               std::to_string(msg.points.size()) + " points";
      return false;
    }
    ConvertCustomMsg(msg, &frame);
  } else {
    sensor_msgs::PointCloud2 msg;
    if (!Deserialize(data, size, &msg, error)) return false;
    if (!ConvertPointCloud2(msg, role.lidar_index, &frame, error)) return false;
  }
  out->data = std::move(frame);
  return true;
}

/// An IMU sample from a sensor_msgs/Imu.
bool DecodeImu(const uint8_t* data, size_t size, SensorMessage* out, std::string* error) {
  sensor_msgs::Imu msg;
  if (!Deserialize(data, size, &msg, error)) return false;
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

/// A GNSS fix from a sensor_msgs/NavSatFix.
bool DecodeGnss(const uint8_t* data, size_t size, SensorMessage* out, std::string* error) {
  sensor_msgs::NavSatFix msg;
  if (!Deserialize(data, size, &msg, error)) return false;
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

/// The odometer is the JointState's joint named "wheel".
bool DecodeOdometer(const uint8_t* data, size_t size, SensorMessage* out, std::string* error) {
  sensor_msgs::JointState msg;
  if (!Deserialize(data, size, &msg, error)) return false;
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

/// Decodes a message of the topic's role into `out`.
bool Decode(const TopicRole& role,
            const std::string& type,
            const uint8_t* data,
            size_t size,
            SensorMessage* out,
            std::string* error) {
  switch (role.role) {
    case Role::kLidar:
      return DecodeLidar(role, type, data, size, out, error);
    case Role::kImu:
      return DecodeImu(data, size, out, error);
    case Role::kGnss:
      return DecodeGnss(data, size, out, error);
    case Role::kOdometer:
      return DecodeOdometer(data, size, out, error);
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

// Topics of a set of connections, with message counts, for the summary.
std::vector<BagTopicInfo> TopicInfos(const std::map<uint32_t, Connection>& connections,
                                     const std::map<uint32_t, uint64_t>& counts) {
  std::map<std::tuple<std::string, std::string, std::string>, BagTopicInfo> infos;
  for (const auto& [id, c] : connections) {
    BagTopicInfo& info = infos[{c.topic, c.type, c.md5sum}];
    info.topic = c.topic;
    info.type = c.type;
    info.md5sum = c.md5sum;
    auto count = counts.find(id);
    if (count != counts.end()) info.message_count += count->second;
  }
  std::vector<BagTopicInfo> topics;
  for (auto& [key, info] : infos) topics.push_back(info);
  return topics;
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

  // A bag with a sound index: its entries of the configured topics in time order.
  BagFile file;
  BagIndex index;
  std::vector<IndexEntry> entries;
  size_t next_entry = 0;
  std::list<std::pair<uint32_t, std::vector<uint8_t>>> chunk_cache;  // most recent first
  std::vector<uint8_t> chunk_data;

  // A bag without a usable index: a sequential scan.
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

  bool Deliver(const Connection& connection,
               int64_t time_ns,
               const uint8_t* data,
               size_t size,
               SensorMessage* message) {
    std::string why;
    SensorMessage out;
    out.topic = connection.topic;
    out.receive_ns = time_ns;
    if (!Decode(roles.at(connection.topic), connection.type, data, size, &out, &why)) {
      return Fail("bad " + connection.type + " on " + connection.topic + " at bag time " +
                  FormatSeconds(time_ns) + " s: " + why);
    }
    *message = std::move(out);
    ++delivered[connection.topic];
    ++delivered_total;
    last_time_ns = time_ns;
    return true;
  }

  // The decompressed data of a chunk, through a small cache.
  const std::vector<uint8_t>* ChunkData(uint32_t id, std::string* why) {
    for (auto it = chunk_cache.begin(); it != chunk_cache.end(); ++it) {
      if (it->first == id) {
        chunk_cache.splice(chunk_cache.begin(), chunk_cache, it);
        return &chunk_cache.front().second;
      }
    }
    const Chunk& chunk = index.chunks[id];
    std::vector<uint8_t> decompressed;
    if (!file.ReadData(chunk.record, &chunk_data)) {
      *why = "read error";
      return nullptr;
    }
    if (!Decompress(chunk.compression, chunk_data, chunk.size, &decompressed, why)) {
      return nullptr;
    }
    chunk_cache.emplace_front(id, std::move(decompressed));
    if (chunk_cache.size() > kChunkCacheSize) chunk_cache.pop_back();
    return &chunk_cache.front().second;
  }

  bool NextIndexed(SensorMessage* message) {
    if (next_entry >= entries.size()) {
      finished = true;
      return false;
    }
    const IndexEntry& entry = entries[next_entry++];
    const std::string where = "the chunk at " + At(index.chunks[entry.chunk].record.pos) +
                              ", offset " + std::to_string(entry.offset);
    std::string why;
    const std::vector<uint8_t>* chunk = ChunkData(entry.chunk, &why);
    if (!chunk) return Fail("damaged: " + where + ": " + why);
    InnerRecord record;
    uint32_t connection = 0;
    int64_t time_ns = 0;
    if (ParseInnerRecord(chunk->data(), chunk->size(), entry.offset, &record) != InnerResult::kOk ||
        record.op != kOpMessageData || !FieldU32(record.fields, "conn", &connection) ||
        !FieldTime(record.fields, "time", &time_ns) || connection != entry.connection ||
        time_ns != entry.time_ns) {
      return Fail("damaged: the index points to no matching message record in " + where);
    }
    return Deliver(
        index.connections.at(connection), time_ns, record.data, record.data_len, message);
  }

  bool NextScanned(SensorMessage* message) {
    RawMessage raw;
    while (scanner->Next(&raw)) {
      const Connection& connection = scanner->connections().at(raw.connection);
      if (roles.count(connection.topic) == 0) continue;
      return Deliver(connection, raw.time_ns, raw.data.data(), raw.data.size(), message);
    }
    // summary.damage holds why the index is unusable and where the scan stopped.
    if (!scanner->damage().empty()) return Fail("damaged: " + summary.damage);
    finished = true;
    return false;
  }
};

BagReader::BagReader(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

BagReader::~BagReader() = default;

namespace {

/// Checks that `path` is a regular file; its size goes to `size`.
bool StatBag(const std::string& path, uint64_t* size, std::string* error) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) {
    *error = errno == ENOENT ? "bag " + path + " does not exist"
                             : "cannot access bag " + path + ": " + std::strerror(errno);
    return false;
  }
  if (!S_ISREG(st.st_mode)) {
    *error = "bag " + path + " is not a regular file";
    return false;
  }
  *size = static_cast<uint64_t>(st.st_size);
  return true;
}

/// The bag's topics, counts and time span from its index; without a usable index, from one scan
/// of the whole bag, which also reports the damage (and leaves `index` empty).
bool SummarizeBag(const std::string& path,
                  BagFile& file,
                  BagIndex* index,
                  BagSummary* summary,
                  std::string* error) {
  std::string why;
  summary->indexed = index->Load(file, &why);
  if (summary->indexed) {
    std::map<uint32_t, uint64_t> counts;
    for (const IndexEntry& e : index->entries) ++counts[e.connection];
    summary->topics = TopicInfos(index->connections, counts);
    summary->message_count = index->entries.size();
    if (!index->entries.empty()) {
      summary->start_ns = index->entries.front().time_ns;
      summary->end_ns = index->entries.back().time_ns;
    }
    return true;
  }
  *index = BagIndex();
  BagScanner scanner;
  if (!scanner.Open(path, error)) return false;
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
  summary->topics = TopicInfos(scanner.connections(), counts);
  summary->damage = why + (scanner.damage().empty() ? "" : "; " + scanner.damage());
  return true;
}

/// The configured topics with their roles.
std::vector<std::pair<std::string, TopicRole>> WantedTopics(const BagTopics& topics) {
  std::vector<std::pair<std::string, TopicRole>> wanted;
  for (size_t i = 0; i < topics.lidar.size(); ++i) {
    wanted.push_back({topics.lidar[i], {Role::kLidar, static_cast<uint8_t>(i), "lidar"}});
  }
  if (!topics.imu.empty()) wanted.push_back({topics.imu, {Role::kImu, 0, "imu"}});
  if (!topics.gnss.empty()) wanted.push_back({topics.gnss, {Role::kGnss, 0, "gnss"}});
  if (!topics.odometer.empty()) {
    wanted.push_back({topics.odometer, {Role::kOdometer, 0, "odometer"}});
  }
  return wanted;
}

/// Checks that the bag has `topic` with a type and md5 its role accepts.
bool CheckTopic(const std::string& path,
                const std::string& topic,
                const TopicRole& role,
                const BagSummary& summary,
                std::string* error) {
  bool found = false;
  for (const BagTopicInfo& info : summary.topics) {
    if (info.topic != topic) continue;
    found = true;
    std::string names;
    bool ok = false;
    for (const ExpectedType& e : AcceptedTypes(role.role)) {
      names += (names.empty() ? "" : " or ") + e.type;
      if (e.type != info.type) continue;
      if (e.md5sum != info.md5sum) {
        *error = "bag " + path + ": topic " + topic + " has type " + info.type + " with md5 " +
                 info.md5sum + ", expected md5 " + e.md5sum + " (a different message definition)";
        return false;
      }
      ok = true;
    }
    if (!ok) {
      *error = "bag " + path + ": " + role.name + " topic " + topic + " has type " + info.type +
               ", expected " + names;
      return false;
    }
  }
  if (!found) {
    *error = "bag " + path + " has no " + role.name + " topic " + topic +
             "; it has: " + ListTopics(summary) +
             (summary.damage.empty() ? "" : " (the bag is damaged: " + summary.damage + ")");
    return false;
  }
  return true;
}

}  // namespace

std::unique_ptr<BagReader> BagReader::Open(const std::string& path,
                                           const BagTopics& topics,
                                           std::string* error) {
  std::string ignored;
  if (!error) error = &ignored;
  if (!topics.IsValid(error)) return nullptr;
  auto impl = std::make_unique<Impl>();
  BagSummary& summary = impl->summary;
  summary.path = path;
  if (!StatBag(path, &summary.file_size_bytes, error)) return nullptr;
  if (!impl->file.Open(path, error)) return nullptr;
  try {
    if (!SummarizeBag(path, impl->file, &impl->index, &summary, error)) return nullptr;
  } catch (const std::bad_alloc&) {
    *error = "bag " + path + ": out of memory while reading its index";
    return nullptr;
  }
  // Every configured topic must be present with an accepted type and md5.
  for (const auto& [topic, role] : WantedTopics(topics)) {
    if (!CheckTopic(path, topic, role, summary, error)) return nullptr;
    impl->roles[topic] = role;
  }
  if (summary.indexed) {
    for (const IndexEntry& e : impl->index.entries) {
      if (impl->roles.count(impl->index.connections.at(e.connection).topic)) {
        impl->entries.push_back(e);
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
  try {
    return d.summary.indexed ? d.NextIndexed(message) : d.NextScanned(message);
  } catch (const std::exception& e) {  // bad_alloc on a huge yet consistent message
    return d.Fail(std::string("read failed: ") + e.what());
  }
}

const std::string& BagReader::error() const { return impl_->error; }

const BagSummary& BagReader::Summary() const { return impl_->summary; }

const std::map<std::string, uint64_t>& BagReader::delivered_counts() const {
  return impl_->delivered;
}

}  // namespace raillomer::io
