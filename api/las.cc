#include "api/las.h"

#include "api/raw_bytes.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <limits>

namespace raillomer::api::las {
namespace {

constexpr size_t kLasHeader = 227;    // the LAS 1.2 public header block
constexpr size_t kLasVlrHeader = 54;  // a variable-length record's own header
constexpr uint16_t kGeoKeyDirectory = 34735;

// GeoTIFF keys (GeoTIFF 1.0, section 6.2) and their values.
constexpr uint16_t kGtModelType = 1024, kGtRasterType = 1025, kProjectedCsType = 3072,
                   kProjLinearUnits = 3076, kVerticalUnits = 4099;
constexpr uint16_t kModelTypeProjected = 1, kRasterPixelIsArea = 1, kLinearMetre = 9001,
                   kUserDefined = 32767;

// Writes a value at a byte offset of a buffer that already has the room.
template <typename T>
void PutAt(std::string* out, size_t at, T value) {
  std::memcpy(&(*out)[at], &value, sizeof(T));
}

// Copies text into a fixed, NUL-padded field.
void PutText(std::string* out, size_t at, size_t width, const std::string& text) {
  std::memcpy(&(*out)[at], text.data(), std::min(text.size(), width));
}

std::string TextAt(const std::string& in, size_t at, size_t width) {
  std::string text = in.substr(at, width);
  return text.substr(0, text.find('\0'));
}

// The bounds as written: zero when there are no points.
Eigen::Vector3d MinOf(const Header& header) {
  return header.bounds.isEmpty() ? Eigen::Vector3d::Zero() : header.bounds.min();
}
Eigen::Vector3d MaxOf(const Header& header) {
  return header.bounds.isEmpty() ? Eigen::Vector3d::Zero() : header.bounds.max();
}

}  // namespace

Eigen::Vector3d OffsetOf(const Header& header) { return MinOf(header).array().floor().matrix(); }

int EpsgOfUtmZone(const std::string& utm_zone) {
  int zone = 0;
  char hemisphere = 0, extra = 0;
  if (std::sscanf(utm_zone.c_str(), "%d%c%c", &zone, &hemisphere, &extra) != 2) return 0;
  if (zone < 1 || zone > 60 || (hemisphere != 'N' && hemisphere != 'S')) return 0;
  return (hemisphere == 'N' ? 32600 : 32700) + zone;
}

namespace {

/// Why the points do not fit LAS 1.2 at 1 mm (count, bounds, span), or an empty string.
std::string WhyNotLas12(const Header& header,
                        const Eigen::Vector3d& min,
                        const Eigen::Vector3d& max) {
  if (header.points > std::numeric_limits<uint32_t>::max()) {
    return "LAS 1.2 holds at most 4294967295 points, not " + std::to_string(header.points);
  }
  if (!min.allFinite() || !max.allFinite()) return "the points' bounds are not finite";
  const Eigen::Vector3d offset = OffsetOf(header);
  const double reach =
      std::max((max - offset).cwiseAbs().maxCoeff(), (min - offset).cwiseAbs().maxCoeff());
  if (reach / kScale >= std::numeric_limits<int32_t>::max()) {
    return "the points span " + std::to_string(static_cast<int64_t>(reach)) +
           " m, beyond what LAS 1.2 holds at 1 mm (2147 km)";
  }
  return "";
}

/// The GeoTIFF key directory (mandatory in LAS 1.2): its own header (version 1.1.0 and the
/// number of keys), then one entry per key, sorted, each four shorts (key, location 0: the value
/// is in the entry, count 1, value). A frame that is no UTM zone is a user-defined projected
/// system in metres.
std::vector<uint16_t> GeoKeyDirectory(const std::string& utm_zone) {
  const int epsg = EpsgOfUtmZone(utm_zone);
  std::vector<uint16_t> keys = {1, 1, 0, 0};
  auto key = [&](uint16_t id, uint16_t value) {
    keys.insert(keys.end(), {id, 0, 1, value});
    ++keys[3];
  };
  key(kGtModelType, kModelTypeProjected);
  key(kGtRasterType, kRasterPixelIsArea);
  key(kProjectedCsType, static_cast<uint16_t>(epsg != 0 ? epsg : kUserDefined));
  key(kProjLinearUnits, kLinearMetre);
  key(kVerticalUnits, kLinearMetre);  // ellipsoidal height in metres
  return keys;
}

/// Fills the public header block: signature, version, frame, date, sizes, scale, offset and
/// the bounds of the points as stored.
void PutPublicHeader(const Header& header,
                     size_t header_bytes,
                     const Eigen::Vector3d& min,
                     const Eigen::Vector3d& max,
                     std::string* out) {
  std::memcpy(&(*out)[0], "LASF", 4);
  (*out)[24] = 1;  // version 1.2
  (*out)[25] = 2;
  PutText(out,
          26,
          32,
          header.utm_zone.empty() ? std::string("RailLoMer local odometry frame")
                                  : "RailLoMer UTM zone " + header.utm_zone);
  PutText(out, 58, 32, header.software);
  if (header.created > 0) {
    std::tm utc{};
    gmtime_r(&header.created, &utc);
    PutAt(out, 90, static_cast<uint16_t>(utc.tm_yday + 1));  // 1 January is day 1
    PutAt(out, 92, static_cast<uint16_t>(utc.tm_year + 1900));
  }
  const uint32_t n = static_cast<uint32_t>(header.points);
  PutAt(out, 94, static_cast<uint16_t>(kLasHeader));     // header size
  PutAt(out, 96, static_cast<uint32_t>(header_bytes));   // offset to the points
  PutAt(out, 100, static_cast<uint32_t>(1));             // variable-length records
  (*out)[104] = 0;                                       // point format 0
  PutAt(out, 105, static_cast<uint16_t>(kRecordBytes));  // record length
  PutAt(out, 107, n);                                    // legacy point count
  PutAt(out, 111, n);                                    // points by return (first return)
  const Eigen::Vector3d offset = OffsetOf(header);
  for (int a = 0; a < 3; ++a) PutAt(out, 131 + 8 * a, kScale);
  for (int a = 0; a < 3; ++a) PutAt(out, 155 + 8 * a, offset[a]);
  // The bounds of the points as stored (rounded to the millimetre), so that every point read
  // back lies within them.
  for (int a = 0; a < 3; ++a) {
    auto stored = [&](double v) {
      return offset[a] + kScale * static_cast<double>(std::llround((v - offset[a]) / kScale));
    };
    PutAt(out, 179 + 16 * a, stored(max[a]));
    PutAt(out, 187 + 16 * a, stored(min[a]));
  }
}

}  // namespace

bool EncodeHeader(const Header& header, std::string* out, std::string* error) {
  const Eigen::Vector3d min = MinOf(header), max = MaxOf(header);
  const std::string why = WhyNotLas12(header, min, max);
  if (!why.empty()) {
    *error = why;
    return false;
  }
  const std::vector<uint16_t> keys = GeoKeyDirectory(header.utm_zone);
  const size_t key_bytes = keys.size() * sizeof(uint16_t);
  const size_t header_bytes = kLasHeader + kLasVlrHeader + key_bytes;
  out->assign(header_bytes, '\0');
  PutPublicHeader(header, header_bytes, min, max, out);
  // The key record's header: reserved, user id, record id, length after the header, description.
  PutText(out, kLasHeader + 2, 16, "LASF_Projection");
  PutAt(out, kLasHeader + 18, kGeoKeyDirectory);
  PutAt(out, kLasHeader + 20, static_cast<uint16_t>(key_bytes));
  PutText(out, kLasHeader + 22, 32, "GeoKeyDirectoryTag");
  std::memcpy(&(*out)[kLasHeader + kLasVlrHeader], keys.data(), key_bytes);
  return true;
}

void AppendRecord(std::string* out,
                  const Eigen::Vector3d& p,
                  const Eigen::Vector3d& offset,
                  uint16_t intensity) {
  for (int a = 0; a < 3; ++a)
    AppendRaw(out, static_cast<int32_t>(std::lround((p[a] - offset[a]) / kScale)));
  AppendRaw(out, intensity);
  AppendRaw(out, static_cast<uint8_t>(1 | (1 << 3)));  // return 1 of 1
  AppendRaw(out, static_cast<uint8_t>(0));             // classification: never classified
  AppendRaw(out, static_cast<int8_t>(0));              // scan angle
  AppendRaw(out, static_cast<uint8_t>(0));             // user data
  AppendRaw(out, static_cast<uint16_t>(0));            // point source
}

bool Decode(const std::string& bytes, Contents* contents, std::string* error) {
  if (bytes.size() < kLasHeader || bytes.compare(0, 4, "LASF") != 0)
    return *error = "not a LAS file", false;
  const uint16_t header_size = ReadRaw<uint16_t>(bytes, 94);
  const uint32_t offset = ReadRaw<uint32_t>(bytes, 96), records = ReadRaw<uint32_t>(bytes, 100);
  const uint32_t n = ReadRaw<uint32_t>(bytes, 107);
  const uint16_t record = ReadRaw<uint16_t>(bytes, 105);
  if (record < kRecordBytes || offset < header_size ||
      bytes.size() < offset + static_cast<size_t>(record) * n)
    return *error = "the LAS file is truncated", false;
  contents->system_identifier = TextAt(bytes, 26, 32);
  contents->epsg = 0;
  contents->creation_day = ReadRaw<uint16_t>(bytes, 90);
  contents->creation_year = ReadRaw<uint16_t>(bytes, 92);
  for (int a = 0; a < 3; ++a) {
    contents->max[a] = ReadRaw<double>(bytes, 179 + 16 * a);
    contents->min[a] = ReadRaw<double>(bytes, 187 + 16 * a);
  }
  size_t at = header_size;
  for (uint32_t r = 0; r < records && at + kLasVlrHeader <= offset; ++r) {
    const uint16_t id = ReadRaw<uint16_t>(bytes, at + 18),
                   length = ReadRaw<uint16_t>(bytes, at + 20);
    const size_t data = at + kLasVlrHeader;
    if (data + length > offset) return *error = "a LAS variable-length record is cut", false;
    if (TextAt(bytes, at + 2, 16) == "LASF_Projection" && id == kGeoKeyDirectory && length >= 8) {
      const uint16_t count = ReadRaw<uint16_t>(bytes, data + 6);
      for (uint16_t k = 1; k <= count && data + 8 * k + 8 <= data + length; ++k) {
        if (ReadRaw<uint16_t>(bytes, data + 8 * k) == kProjectedCsType &&
            ReadRaw<uint16_t>(bytes, data + 8 * k + 2) == 0)
          contents->epsg = ReadRaw<uint16_t>(bytes, data + 8 * k + 6);
      }
    }
    at = data + length;
  }
  double scale[3], shift[3];
  for (int a = 0; a < 3; ++a) {
    scale[a] = ReadRaw<double>(bytes, 131 + 8 * a);
    shift[a] = ReadRaw<double>(bytes, 155 + 8 * a);
  }
  contents->points.resize(n);
  contents->intensities.resize(n);
  for (uint32_t i = 0; i < n; ++i) {
    const size_t p = offset + static_cast<size_t>(record) * i;
    for (int a = 0; a < 3; ++a)
      contents->points[i][a] = shift[a] + scale[a] * ReadRaw<int32_t>(bytes, p + 4 * a);
    contents->intensities[i] = ReadRaw<uint16_t>(bytes, p + 12);
  }
  return true;
}

}  // namespace raillomer::api::las
