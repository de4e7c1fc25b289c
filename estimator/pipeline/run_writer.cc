#include "estimator/pipeline/run_writer.h"

#include <algorithm>
#include <cstring>
#include <filesystem>

#include "api/atomic_file.h"
#include "api/trajectory.h"

namespace raillomer {

namespace {

double Percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  const size_t k =
      std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

std::string PoseLine(int64_t stamp_ns, const Eigen::Isometry3d& T) {
  api::StampedPose pose;
  pose.stamp_ns = stamp_ns;
  pose.p_world = T.translation();
  pose.q_world_body = Eigen::Quaterniond(T.linear()).normalized();
  return api::FormatTumLine(pose) + "\n";
}

}  // namespace

RunWriter::~RunWriter() {
  for (std::FILE* f : {trajectory_, timing_, keyframes_, submap_index_, provisional_index_}) {
    if (f) std::fclose(f);
  }
}

bool RunWriter::Open(const std::string& out_dir,
                     bool write_keyframes,
                     const std::string& header,
                     std::string* error) {
  out_dir_ = out_dir;
  write_keyframes_ = write_keyframes;
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (ec) {
    *error = "cannot create the output folder " + out_dir + ": " + ec.message();
    return false;
  }
  if (write_keyframes) {
    std::filesystem::create_directories(out_dir + "/keyframes", ec);
    if (ec) {
      *error = "cannot create " + out_dir + "/keyframes: " + ec.message();
      return false;
    }
  }
  auto open = [&](const std::string& name, std::FILE** f) {
    *f = std::fopen((out_dir + "/" + name).c_str(), "w");
    if (!*f) *error = "cannot write " + out_dir + "/" + name;
    return *f != nullptr;
  };
  if (!open("trajectory.tum", &trajectory_) || !open("timing.csv", &timing_)) return false;
  if (write_keyframes && !open("keyframes.tum", &keyframes_)) return false;
  header_ = header;
  std::fprintf(timing_,
               "stamp_s,frontend_ms,backend_ms,total_ms,solver_iterations,odometer_used,rail_plane,"
               "height_shift,degeneracy,projected,odometer_scale,speed_mps,gyro_bias_x,gyro_bias_y,"
               "gyro_bias_z,accel_bias_x,"
               "accel_bias_y,accel_bias_z");
  for (const char* lidar : {"up", "down"}) {
    std::fprintf(timing_,
                 ",%s_points,%s_edges,%s_planes,%s_matches,%s_degeneracy,%s_xi_f,%s_xi_d,%s_xi_p",
                 lidar,
                 lidar,
                 lidar,
                 lidar,
                 lidar,
                 lidar,
                 lidar,
                 lidar);
  }
  std::fprintf(timing_,
               ",bed_shift_m,heading_information,heading_projected,straight_hold,"
               "odometer_pitch_mrad,odometer_yaw_mrad\n");
  return true;
}

bool RunWriter::OpenSubmaps(std::string* error) {
  return OpenSubmapIndex("submaps", &submap_index_, error);
}

bool RunWriter::OpenProvisional(std::string* error) {
  return OpenSubmapIndex("provisional", &provisional_index_, error);
}

bool RunWriter::OpenSubmapIndex(const std::string& folder, std::FILE** index, std::string* error) {
  const std::string dir = out_dir_ + "/" + folder;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) {
    *error = "cannot create " + dir + ": " + ec.message();
    return false;
  }
  const std::string path = dir + "/index.csv";
  *index = std::fopen(path.c_str(), "w");
  if (!*index) {
    *error = "cannot write " + path;
    return false;
  }
  std::fprintf(*index,
               "sequence,index,file,first_stamp_s,last_stamp_s,keyframes,points,frame,origin_x,"
               "origin_y,origin_z\n");
  std::fflush(*index);
  return true;
}

void RunWriter::WriteSubmap(const api::Submap& s) {
  if (submap_index_) WriteSubmapTo("submaps", submap_index_, s.index, s);
}

void RunWriter::WriteProvisionalSubmap(const api::Submap& s) {
  if (provisional_index_)
    WriteSubmapTo("provisional", provisional_index_, provisional_written_++, s);
}

void RunWriter::WriteSubmapTo(const std::string& folder,
                              std::FILE* index,
                              uint32_t number,
                              const api::Submap& s) {
  char name[32];
  std::snprintf(name, sizeof(name), "%06u.pcd", number);
  std::string error;
  if (!api::WriteFileAtomically(
          out_dir_ + "/" + folder + "/" + name, api::EncodeSubmapPcd(s), &error)) {
    Failed(error);
    return;
  }
  std::fprintf(index,
               "%llu,%u,%s,%s,%s,%zu,%zu,%s,%.4f,%.4f,%.4f\n",
               static_cast<unsigned long long>(s.sequence),
               s.index,
               name,
               api::FormatStampSeconds(s.first_stamp_ns).c_str(),
               api::FormatStampSeconds(s.last_stamp_ns).c_str(),
               s.keyframes.size(),
               s.points.size(),
               s.georeferenced ? s.utm_zone.c_str() : "local",
               s.origin.x(),
               s.origin.y(),
               s.origin.z());
  std::fflush(index);
}

void RunWriter::WriteHeader(const FrameResult* first) {
  if (header_written_ || !trajectory_) return;
  header_written_ = true;
  if (first && first->georeferenced) {
    std::fprintf(trajectory_,
                 "# utm_zone %s\n# raillomer-estimator: body pose at every LiDAR frame in UTM zone "
                 "%s (easting, northing, ellipsoidal height), georeferenced with GNSS\n",
                 first->utm_zone.c_str(),
                 first->utm_zone.c_str());
  } else {
    std::fprintf(trajectory_, "%s", header_.c_str());
  }
  std::fflush(trajectory_);
}

namespace {

/// The timing row's first columns: stamp, times, solver and cue flags, and the state's scale,
/// speed and biases.
void WriteStateColumns(std::FILE* out, const FrameResult& f) {
  std::fprintf(out,
               "%s,%.3f,%.3f,%.3f,%d,%d,%d,%d,%.4f,%d,%.5f,%.3f",
               api::FormatStampSeconds(f.stamp_ns).c_str(),
               f.frontend_ms,
               f.backend_ms,
               f.frontend_ms + f.backend_ms,
               f.solver_iterations,
               f.odometer_used ? 1 : 0,
               f.rail_plane ? 1 : 0,
               f.height_shift ? 1 : 0,
               f.degeneracy,
               f.projected ? 1 : 0,
               f.odometer_scale,
               f.v_world.norm());
  std::fprintf(out,
               ",%.3e,%.3e,%.3e,%.3e,%.3e,%.3e",
               f.gyro_bias.x(),
               f.gyro_bias.y(),
               f.gyro_bias.z(),
               f.accel_bias.x(),
               f.accel_bias.y(),
               f.accel_bias.z());
}

/// The two LiDARs' columns (a missing one as no points and unit favour factors).
void WriteLidarColumns(std::FILE* out, const std::vector<LidarDiagnostics>& lidars) {
  for (size_t i = 0; i < 2; ++i) {
    if (i < lidars.size()) {
      const LidarDiagnostics& d = lidars[i];
      std::fprintf(out,
                   ",%zu,%zu,%zu,%zu,%.4f,%.0f,%.0f,%.2f",
                   d.points,
                   d.edges,
                   d.planes,
                   d.matches,
                   d.degeneracy,
                   d.xi_failure,
                   d.xi_degeneracy,
                   d.xi_pose);
    } else {
      std::fprintf(out, ",0,0,0,0,0,1,1,1");
    }
  }
}

/// The last columns: sleeper shift, heading information and hold, odometer misalignment.
void WriteTrackColumns(std::FILE* out, const FrameResult& f) {
  // Empty when the sleepers gave no measurement.
  if (f.bed_shift_m) {
    std::fprintf(out, ",%.4f", *f.bed_shift_m);
  } else {
    std::fprintf(out, ",");
  }
  std::fprintf(out,
               ",%.3f,%d,%d,%.4f,%.4f\n",
               f.heading_information,
               f.heading_projected ? 1 : 0,
               f.straight_hold ? 1 : 0,
               f.odometer_misalignment.x() * 1e3,
               f.odometer_misalignment.y() * 1e3);
}

}  // namespace

void RunWriter::WriteFrame(const FrameResult& f) {
  WriteHeader(&f);
  Eigen::Isometry3d T = f.T_world_body;
  if (f.georeferenced) T.translation() += f.origin_utm;
  const std::string line = PoseLine(f.stamp_ns, T);
  std::fputs(line.c_str(), trajectory_);
  std::fflush(trajectory_);
  frame_ms_.push_back(f.frontend_ms + f.backend_ms);
  frontend_ms_.push_back(f.frontend_ms);
  backend_ms_.push_back(f.backend_ms);
  WriteStateColumns(timing_, f);
  WriteLidarColumns(timing_, f.lidars);
  WriteTrackColumns(timing_, f);
  if (frame_ms_.size() % 50 == 0) std::fflush(timing_);
}

void RunWriter::WriteKeyframe(const Keyframe& k) {
  if (!write_keyframes_) return;
  const std::string stamp = api::FormatStampSeconds(k.stamp_ns);
  const std::string name = out_dir_ + "/keyframes/" + stamp + ".pcd";
  Eigen::Isometry3d T = k.T_world_body;
  if (k.georeferenced) T.translation() += k.origin_utm;
  const Eigen::Quaterniond q(T.linear());
  const Eigen::Vector3d t = T.translation();
  std::string pcd;
  char head[512];
  std::snprintf(head,
                sizeof(head),
                "# .PCD v0.7 - RailLoMer keyframe %s, body frame, deskewed\n"
                "VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
                "WIDTH %zu\nHEIGHT 1\nVIEWPOINT %.4f %.4f %.4f %.9f %.9f %.9f %.9f\nPOINTS "
                "%zu\nDATA binary\n",
                stamp.c_str(),
                k.points_body.size(),
                t.x(),
                t.y(),
                t.z(),
                q.w(),
                q.x(),
                q.y(),
                q.z(),
                k.points_body.size());
  pcd = head;
  const size_t offset = pcd.size();
  pcd.resize(offset + 16 * k.points_body.size());
  for (size_t i = 0; i < k.points_body.size(); ++i) {
    const float v[4] = {k.points_body[i].x(),
                        k.points_body[i].y(),
                        k.points_body[i].z(),
                        i < k.intensities.size() ? k.intensities[i] : 0.f};
    std::memcpy(&pcd[offset + 16 * i], v, sizeof(v));
  }
  std::string error;
  if (!api::WriteFileAtomically(name, pcd, &error)) {
    Failed(error);
    return;
  }
  std::fputs(PoseLine(k.stamp_ns, T).c_str(), keyframes_);
  std::fflush(keyframes_);
}

double RunWriter::MedianFrameMs() const { return Percentile(frame_ms_, 0.5); }
double RunWriter::PercentileFrameMs(double q) const { return Percentile(frame_ms_, q); }

namespace {

std::string SubmapJson(const SubmapStats& m) {
  char text[512];
  std::snprintf(text,
                sizeof(text),
                "\"submaps\": {\"count\": %llu, \"chained\": %llu, \"chain_resets\": %llu, "
                "\"icp_odometry\": %llu, \"icp_gnss\": %llu, \"icp_failed\": %llu, "
                "\"ndt_applied\": %llu, \"ndt_rejected\": %llu, \"ndt_turn_held\": %llu, "
                "\"ndt_revisits\": %llu}",
                static_cast<unsigned long long>(m.submaps),
                static_cast<unsigned long long>(m.chained),
                static_cast<unsigned long long>(m.chain_resets),
                static_cast<unsigned long long>(m.icp_odometry),
                static_cast<unsigned long long>(m.icp_gnss),
                static_cast<unsigned long long>(m.icp_failed),
                static_cast<unsigned long long>(m.ndt_applied),
                static_cast<unsigned long long>(m.ndt_rejected),
                static_cast<unsigned long long>(m.ndt_turn_held),
                static_cast<unsigned long long>(m.ndt_revisits));
  return text;
}

}  // namespace

bool RunWriter::Close(const EstimatorStats& s,
                      double data_duration_s,
                      double wall_s,
                      const std::string& extra_json,
                      std::string* error) {
  WriteHeader(nullptr);
  for (std::FILE** f : {&trajectory_, &timing_, &keyframes_}) {
    if (*f) std::fclose(*f);
    *f = nullptr;
  }
  char text[4096];
  std::snprintf(text,
                sizeof(text),
                "{\n  \"frames\": %zu,\n  \"keyframes\": %llu,\n  \"distance_m\": %.3f,\n"
                "  \"data_duration_s\": %.3f,\n  \"wall_s\": %.3f,\n  \"real_time_factor\": %.3f,\n"
                "  \"frame_ms\": {\"median\": %.3f, \"p95\": %.3f, \"max\": %.3f},\n"
                "  \"frontend_ms\": {\"median\": %.3f, \"p95\": %.3f},\n"
                "  \"backend_ms\": {\"median\": %.3f, \"p95\": %.3f},\n"
                "  \"warnings\": %llu,\n  \"lidar_frames_dropped\": %llu,\n  \"imu_gaps\": %llu,\n"
                "  \"imu_rejected\": %llu,\n  \"odometer_outliers\": %llu,\n  "
                "\"odometer_rejected\": %llu,\n  \"bed_shifts\": %llu,\n  \"georeferenced\": %s,\n "
                " \"gnss\": {\"fixes\": "
                "%llu, \"rejected\": %llu, \"outliers\": %llu, \"factors\": %llu, "
                "\"realignments\": %llu},\n  %s%s%s\n}\n",
                frame_ms_.size(),
                static_cast<unsigned long long>(s.keyframes),
                s.distance_m,
                data_duration_s,
                wall_s,
                wall_s > 0 ? data_duration_s / wall_s : 0.0,
                Percentile(frame_ms_, 0.5),
                Percentile(frame_ms_, 0.95),
                Percentile(frame_ms_, 1.0),
                Percentile(frontend_ms_, 0.5),
                Percentile(frontend_ms_, 0.95),
                Percentile(backend_ms_, 0.5),
                Percentile(backend_ms_, 0.95),
                static_cast<unsigned long long>(s.warnings),
                static_cast<unsigned long long>(s.lidar_frames_dropped),
                static_cast<unsigned long long>(s.imu_gaps),
                static_cast<unsigned long long>(s.imu_rejected),
                static_cast<unsigned long long>(s.odometer_outliers),
                static_cast<unsigned long long>(s.odometer_rejected),
                static_cast<unsigned long long>(s.bed_shifts),
                s.georeferenced ? "true" : "false",
                static_cast<unsigned long long>(s.gnss.fixes),
                static_cast<unsigned long long>(s.gnss.rejected),
                static_cast<unsigned long long>(s.gnss.outliers),
                static_cast<unsigned long long>(s.gnss.factors),
                static_cast<unsigned long long>(s.gnss.realignments),
                SubmapJson(s.submaps).c_str(),
                extra_json.empty() ? "" : ",\n  ",
                extra_json.c_str());
  if (!api::WriteFileAtomically(out_dir_ + "/summary.json", text, error)) return false;
  if (failed()) {
    *error = failure();
    return false;
  }
  return true;
}

void RunWriter::Failed(const std::string& error) {
  std::lock_guard<std::mutex> lock(failure_mutex_);
  if (failed_) return;  // the first failure is the one to report
  failed_ = true;
  failure_ = error;
}

bool RunWriter::failed() const {
  std::lock_guard<std::mutex> lock(failure_mutex_);
  return failed_;
}

std::string RunWriter::failure() const {
  std::lock_guard<std::mutex> lock(failure_mutex_);
  return failure_;
}

}  // namespace raillomer
