#include "mapstore/tile_codec.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>

#include <draco/compression/decode.h>
#include <draco/compression/encode.h>
#include <draco/metadata/geometry_metadata.h>
#include <draco/point_cloud/point_cloud.h>
#include <draco/point_cloud/point_cloud_builder.h>

namespace raillomer::mapstore {
namespace {

constexpr char kOrigin[] = "raillomer_origin";
constexpr char kZone[] = "raillomer_utm_zone";
constexpr char kMaxError[] = "raillomer_max_error_m";
constexpr char kGridOrigin[] = "raillomer_grid_origin";
constexpr char kGridRange[] = "raillomer_grid_range_m";
constexpr char kGridBits[] = "raillomer_grid_bits";

}  // namespace

double TileQuantization::MaxErrorM() const {
  // Half a step, plus float32 rounding as Draco dequantises (origin + q x step, two roundings
  // at the cube's far end).
  return 0.5 * static_cast<double>(range_m) / (std::ldexp(1.0, bits) - 1.0) +
         static_cast<double>(range_m) * std::ldexp(1.0, -22);
}

int TileQuantization::BitsFor(double range_m, double max_error_m) {
  for (int bits = 1; bits < 30; ++bits) {
    if (TileQuantization{Eigen::Vector3f::Zero(), static_cast<float>(range_m), bits}.MaxErrorM() <=
        max_error_m)
      return bits;
  }
  return 30;
}

bool TileQuantization::Covers(const Eigen::Vector3f& p) const {
  const Eigen::Vector3f q = p - grid_origin;
  return q.allFinite() && (q.array() >= 0.0f).all() && (q.array() <= range_m).all();
}

namespace {

/// Why the tile cannot be encoded (no points, intensities missing, a point off the grid), or an
/// empty string.
std::string WhyNotEncodable(const TilePoints& tile, const TileQuantization& quantization) {
  const size_t n = tile.points.size();
  if (n == 0) return "a tile needs at least one point";
  if (tile.intensities.size() != n) {
    return "a tile needs one intensity per point (" + std::to_string(tile.intensities.size()) +
           " for " + std::to_string(n) + " points)";
  }
  for (size_t i = 0; i < n; ++i) {
    if (!quantization.Covers(tile.points[i])) {
      return "point " + std::to_string(i) + " lies off the tile's quantisation grid";
    }
  }
  return "";
}

/// The tile as a Draco point cloud (positions, intensities) with its origin, zone and grid as
/// metadata; null if Draco cannot build it.
std::unique_ptr<draco::PointCloud> DracoCloud(const TilePoints& tile,
                                              const TileQuantization& quantization) {
  draco::PointCloudBuilder builder;
  builder.Start(static_cast<draco::PointIndex::ValueType>(tile.points.size()));
  const int position =
      builder.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
  const int intensity = builder.AddAttribute(draco::GeometryAttribute::GENERIC, 1, draco::DT_UINT8);
  builder.SetAttributeValuesForAllPoints(position, tile.points.data(), sizeof(Eigen::Vector3f));
  builder.SetAttributeValuesForAllPoints(intensity, tile.intensities.data(), 1);
  std::unique_ptr<draco::PointCloud> cloud = builder.Finalize(false);
  if (!cloud) return cloud;
  auto metadata = std::make_unique<draco::GeometryMetadata>();
  metadata->AddEntryDoubleArray(kOrigin, {tile.origin.x(), tile.origin.y(), tile.origin.z()});
  metadata->AddEntryString(kZone, tile.utm_zone);
  metadata->AddEntryDouble(kMaxError, quantization.MaxErrorM());
  metadata->AddEntryDoubleArray(
      kGridOrigin,
      {quantization.grid_origin.x(), quantization.grid_origin.y(), quantization.grid_origin.z()});
  metadata->AddEntryDouble(kGridRange, quantization.range_m);
  metadata->AddEntryInt(kGridBits, quantization.bits);
  cloud->AddMetadata(std::move(metadata));
  return cloud;
}

}  // namespace

bool EncodeTile(const TilePoints& tile,
                const TileQuantization& quantization,
                int speed,
                std::string* bytes,
                std::string* error) {
  const std::string why = WhyNotEncodable(tile, quantization);
  if (!why.empty()) {
    *error = why;
    return false;
  }
  const std::unique_ptr<draco::PointCloud> cloud = DracoCloud(tile, quantization);
  if (!cloud) {
    *error = "Draco could not build the point cloud";
    return false;
  }
  draco::Encoder encoder;
  encoder.SetSpeedOptions(std::clamp(speed, 0, 9), std::clamp(speed, 0, 9));
  encoder.SetAttributeExplicitQuantization(draco::GeometryAttribute::POSITION,
                                           quantization.bits,
                                           3,
                                           quantization.grid_origin.data(),
                                           quantization.range_m);
  encoder.SetEncodingMethod(draco::POINT_CLOUD_KD_TREE_ENCODING);
  draco::EncoderBuffer buffer;
  const draco::Status status = encoder.EncodePointCloudToBuffer(*cloud, &buffer);
  if (!status.ok()) {
    *error = "Draco encoding failed: " + status.error_msg_string();
    return false;
  }
  bytes->assign(buffer.data(), buffer.size());
  return true;
}

bool DecodeTile(const std::string& bytes,
                TilePoints* tile,
                std::string* error,
                TileQuantization* quantization) {
  draco::DecoderBuffer buffer;
  buffer.Init(bytes.data(), bytes.size());
  draco::Decoder decoder;
  auto decoded = decoder.DecodePointCloudFromBuffer(&buffer);
  if (!decoded.ok()) {
    *error = "not a Draco point cloud: " + decoded.status().error_msg_string();
    return false;
  }
  const std::unique_ptr<draco::PointCloud> cloud = std::move(decoded).value();
  const draco::GeometryMetadata* metadata = cloud->GetMetadata();
  std::vector<double> origin, grid_origin;
  double grid_range = 0.0;
  int grid_bits = 0;
  if (!metadata || !metadata->GetEntryDoubleArray(kOrigin, &origin) || origin.size() != 3 ||
      !metadata->GetEntryString(kZone, &tile->utm_zone)) {
    *error = "a Draco point cloud without a RailLoMer tile origin and zone";
    return false;
  }
  const draco::PointAttribute* position =
      cloud->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  const draco::PointAttribute* intensity =
      cloud->GetNamedAttribute(draco::GeometryAttribute::GENERIC);
  if (!position || position->num_components() != 3 || !intensity ||
      intensity->num_components() != 1) {
    *error = "a tile needs a 3-component position and a 1-component intensity";
    return false;
  }
  tile->origin = Eigen::Vector3d(origin[0], origin[1], origin[2]);
  const size_t n = cloud->num_points();
  tile->points.resize(n);
  tile->intensities.resize(n);
  for (draco::PointIndex i(0); i < static_cast<uint32_t>(n); ++i) {
    float p[3];
    uint8_t value = 0;
    position->ConvertValue<float, 3>(position->mapped_index(i), p);
    intensity->ConvertValue<uint8_t, 1>(intensity->mapped_index(i), &value);
    tile->points[i.value()] = Eigen::Vector3f(p[0], p[1], p[2]);
    tile->intensities[i.value()] = value;
  }
  if (quantization) {
    if (!metadata->GetEntryDoubleArray(kGridOrigin, &grid_origin) || grid_origin.size() != 3 ||
        !metadata->GetEntryDouble(kGridRange, &grid_range) ||
        !metadata->GetEntryInt(kGridBits, &grid_bits)) {
      *error = "a tile without its quantisation grid";
      return false;
    }
    quantization->grid_origin =
        Eigen::Vector3d(grid_origin[0], grid_origin[1], grid_origin[2]).cast<float>();
    quantization->range_m = static_cast<float>(grid_range);
    quantization->bits = grid_bits;
  }
  return true;
}

}  // namespace raillomer::mapstore
