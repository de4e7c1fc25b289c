#include "estimator/sim/raycaster.h"

#include <cstring>
#include <limits>
#include <stdexcept>

#include <embree3/rtcore.h>

namespace raillomer::sim {

struct RayCaster::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
};

RayCaster::RayCaster(const Mesh& mesh)
    : impl_(std::make_unique<Impl>()), materials_(mesh.materials) {
  impl_->device = rtcNewDevice(nullptr);
  if (!impl_->device) throw std::runtime_error("Embree: cannot create a device");
  impl_->scene = rtcNewScene(impl_->device);
  rtcSetSceneBuildQuality(impl_->scene, RTC_BUILD_QUALITY_HIGH);
  RTCGeometry geometry = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geometry,
                                                               RTC_BUFFER_TYPE_VERTEX,
                                                               0,
                                                               RTC_FORMAT_FLOAT3,
                                                               3 * sizeof(float),
                                                               mesh.vertices.size()));
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    std::memcpy(vertices + 3 * i, mesh.vertices[i].data(), 3 * sizeof(float));
  }
  auto* indices = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geometry,
                                                                 RTC_BUFFER_TYPE_INDEX,
                                                                 0,
                                                                 RTC_FORMAT_UINT3,
                                                                 3 * sizeof(unsigned),
                                                                 mesh.triangles.size()));
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    for (int k = 0; k < 3; ++k) indices[3 * i + k] = static_cast<unsigned>(mesh.triangles[i][k]);
  }
  rtcCommitGeometry(geometry);
  rtcAttachGeometry(impl_->scene, geometry);
  rtcReleaseGeometry(geometry);
  rtcCommitScene(impl_->scene);
  if (rtcGetDeviceError(impl_->device) != RTC_ERROR_NONE) {
    throw std::runtime_error("Embree: building the scene failed");
  }
}

RayCaster::~RayCaster() {
  if (impl_->scene) rtcReleaseScene(impl_->scene);
  if (impl_->device) rtcReleaseDevice(impl_->device);
}

RayHit RayCaster::Cast(const Eigen::Vector3d& origin,
                       const Eigen::Vector3d& dir,
                       double max_range_m) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rh;
  rh.ray.org_x = static_cast<float>(origin.x());
  rh.ray.org_y = static_cast<float>(origin.y());
  rh.ray.org_z = static_cast<float>(origin.z());
  rh.ray.dir_x = static_cast<float>(dir.x());
  rh.ray.dir_y = static_cast<float>(dir.y());
  rh.ray.dir_z = static_cast<float>(dir.z());
  rh.ray.tnear = 0.0f;
  rh.ray.tfar = static_cast<float>(max_range_m);
  rh.ray.mask = std::numeric_limits<unsigned>::max();
  rh.ray.flags = 0;
  rh.ray.time = 0.0f;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(impl_->scene, &context, &rh);
  RayHit hit;
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return hit;
  hit.hit = true;
  hit.range_m = rh.ray.tfar;
  hit.material = materials_[rh.hit.primID];
  Eigen::Vector3d n(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
  const double norm = n.norm();
  n = norm > 0.0 ? Eigen::Vector3d(n / norm) : Eigen::Vector3d(-dir);
  if (n.dot(dir) > 0.0) n = -n;
  hit.normal = n;
  return hit;
}

}  // namespace raillomer::sim
