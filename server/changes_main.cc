// raillomer-changes: compares a run of a line with a reference run in a store folder, offline
// (the server's own detection does the same as runs arrive), and prints the changes.
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "mapstore/change_store.h"
#include "mapstore/run_comparison.h"

using namespace raillomer::mapstore;

namespace {

nlohmann::json ChangeJson(const RunChange& c) {
  return {{"kind", ToString(c.kind)},
          {"utm", {c.centre_utm.x(), c.centre_utm.y(), c.centre_utm.z()}},
          {"utm_zone", c.utm_zone},
          {"chainage_m", c.chainage_m},
          {"offset_m", c.offset_m},
          {"side", SideOf(c)},
          {"offset_range_m", {c.offset_from_m, c.offset_to_m}},
          {"size_m", {c.size_m.x(), c.size_m.y(), c.size_m.z()}},
          {"height_above_rail_m", {c.height_above_rail_min_m, c.height_above_rail_max_m}},
          {"margin_m", c.margin_m},
          {"intrudes_envelope", c.intrudes_envelope},
          {"lod_m", c.lod_m},
          {"confidence", c.confidence},
          {"voxels", c.voxels}};
}

/// Where to explain what the comparison made of the objects near a point (UTM).
struct Explain {
  bool on = false;
  Eigen::Vector2d at = Eigen::Vector2d::Zero();
  double radius_m = 5.0;
};

/// The stretch's objects near the point: the changes and the clusters that were not, with
/// their evidence.
void PrintExplained(const StretchOutcome& outcome, const Explain& explain) {
  const auto print = [&](const StretchChange& c, const std::string& verdict) {
    const Eigen::Vector3d p = c.centre + outcome.origin;
    if ((p.head<2>() - explain.at).norm() > explain.radius_m) return;
    const Eigen::Vector3d size = c.box.sizes();
    std::fprintf(stderr,
                 "\n  %s %s at %.2f %.2f %.2f, %.2f x %.2f x %.2f m, %zu voxels: %zu of the "
                 "sampled voxels reached, %zu seen empty (%.0f %%)",
                 verdict.c_str(),
                 c.kind == StretchChange::Kind::kAdded ? "added" : "removed",
                 p.x(),
                 p.y(),
                 p.z(),
                 size.x(),
                 size.y(),
                 size.z(),
                 c.voxels.size(),
                 c.samples,
                 c.seen_empty,
                 100.0 * c.seen_empty_share);
  };
  for (const auto& [c, why] : outcome.summary.rejected) print(c, "not reported (" + why + "):");
  for (const RunChange& c : outcome.changes) {
    if ((c.centre_utm.head<2>() - explain.at).norm() > explain.radius_m) continue;
    std::fprintf(stderr,
                 "\n  reported: %s at %.2f %.2f %.2f, confidence %.2f",
                 ToString(c.kind),
                 c.centre_utm.x(),
                 c.centre_utm.y(),
                 c.centre_utm.z(),
                 c.confidence);
  }
}

/// Whether progress overwrites itself on one line (a terminal) or takes a line each (a log).
bool ProgressInPlace() { return isatty(STDERR_FILENO) != 0; }

/// CompareRuns, printing progress; with `save`, each stretch is stored as the server stores it.
Result Compare(const MapStore& store,
               int64_t reference,
               int64_t run,
               const RunComparisonOptions& options,
               bool save,
               const Explain& explain,
               std::vector<RunChange>* changes,
               RunComparisonSummary* summary) {
  std::unique_ptr<ChangeStore> saved;
  if (save) {
    std::string error;
    saved = ChangeStore::Open(store.IndexPath(), &error);
    if (!saved) return {Outcome::kError, error};
  }
  bool requested = false;
  Result r = CompareRuns(
      store, reference, run, options, changes, summary, [&](const StretchOutcome& outcome) {
        std::fprintf(
            stderr,
            ProgressInPlace() ? "\rraillomer-changes: km %.3f" : "raillomer-changes: km %.3f\n",
            outcome.range.to_m / 1000.0);
        if (explain.on) PrintExplained(outcome, explain);
        if (!saved) return Result{};
        // The run's earlier changes are checked again once the runs are known to compare.
        if (!requested) {
          requested = true;
          const Result q = saved->Request(run, reference, true, nullptr);
          if (!q) return q;
        }
        std::vector<StoredChange> found, closed;
        return saved->SaveStretch(run, reference, outcome, &found, &closed);
      });
  if (!r || !saved) return r;
  RunInfo info;
  r = store.GetRun(run, &info);
  if (!r || info.status != "finished") return r;
  DetectionState state;
  r = saved->Detection(run, &state);
  return r ? saved->Finish(run, state.requested_ns, nullptr) : r;
}

/// The summary line and a row per change.
void PrintTable(int64_t run,
                int64_t reference,
                const std::string& line,
                const RunComparisonSummary& summary,
                const std::vector<RunChange>& changes) {
  std::printf(
      "run %lld against run %lld (line '%s'): %.2f km in %zu stretches, registration "
      "RMS %.3f m (rails %.3f m); %zu objects differed, %zu not observed by the other run\n",
      static_cast<long long>(run),
      static_cast<long long>(reference),
      line.c_str(),
      summary.km,
      summary.stretches_compared,
      summary.registration_rms_m,
      summary.rail_rms_m,
      summary.objects,
      summary.not_observed);
  std::printf("%-10s %10s %7s %6s %18s %9s %9s %5s\n",
              "kind",
              "km",
              "offset",
              "side",
              "size m (a x c x h)",
              "margin",
              "intrudes",
              "conf");
  for (const RunChange& c : changes)
    std::printf("%-10s %10.3f %7.2f %6s %6.1f %5.1f %5.1f %9.2f %9s %5.2f\n",
                ToString(c.kind),
                c.chainage_m / 1000.0,
                c.offset_m,
                SideOf(c),
                c.size_m.x(),
                c.size_m.y(),
                c.size_m.z(),
                c.margin_m,
                c.intrudes_envelope ? "yes" : "no",
                c.confidence);
}

/// The summary and the changes as JSON; false if the file could not be written.
bool WriteJson(const std::string& path,
               int64_t run,
               int64_t reference,
               const RunComparisonSummary& summary,
               const std::vector<RunChange>& changes) {
  nlohmann::json out = {{"run", run},
                        {"reference_run", reference},
                        {"km", summary.km},
                        {"registration_rms_m", summary.registration_rms_m},
                        {"rail_residual_m",
                         std::isnan(summary.rail_rms_m) ? nlohmann::json(nullptr)
                                                        : nlohmann::json(summary.rail_rms_m)},
                        {"changes", nlohmann::json::array()}};
  for (const RunChange& c : changes) out["changes"].push_back(ChangeJson(c));
  std::ofstream file(path);
  file << out.dump(1) << "\n";
  return static_cast<bool>(file.flush());
}

/// The command line.
struct Options {
  std::string data_dir, json_path;
  bool save = false;
  int64_t run = 0, reference = 0;
  std::vector<double> explain_at;
  Explain explain;  ///< its radius from --explain-radius; the rest from --explain-at
  double from_km = -std::numeric_limits<double>::infinity();
  double to_km = std::numeric_limits<double>::infinity();
};

void AddOptions(CLI::App* app, Options* o) {
  app->add_option("--data", o->data_dir, "the store's folder")->required();
  app->add_option("--run", o->run, "the run to compare")->required();
  app->add_option("--reference", o->reference, "the run to compare with (default: the line's)");
  app->add_option("--json", o->json_path, "also write the changes and the summary as JSON here");
  app->add_flag("--save",
                o->save,
                "store the changes in the store as the server's own detection does (a change "
                "found again keeps its id, status and note; the rest are withdrawn), for the "
                "server to serve");
  app->add_option("--explain-at",
                  o->explain_at,
                  "easting,northing (the reference run's map): print every object compared "
                  "near it, reported or not, with its evidence")
      ->expected(2)
      ->delimiter(',');
  app->add_option(
      "--explain-radius", o->explain.radius_m, "metres around --explain-at (default 5)");
  app->add_option(
      "--from-km", o->from_km, "compare from this kilometre of the line (default: start)");
  app->add_option("--to-km", o->to_km, "compare up to this kilometre (default: the line's end)");
}

/// Whether `path` can be written (checked before a long comparison): "" or why not.
std::string WritableFile(const std::string& path) {
  const std::filesystem::path file(path);
  const std::filesystem::path folder = file.has_parent_path() ? file.parent_path() : ".";
  std::error_code ec;
  if (std::filesystem::is_directory(file, ec)) return "cannot write " + path + ": it is a folder";
  if (!std::filesystem::is_directory(folder, ec))
    return "cannot write " + path + ": no folder " + folder.string();
  const bool exists = std::filesystem::exists(file, ec);
  if (::access(exists ? file.c_str() : folder.c_str(), W_OK) != 0)
    return "cannot write " + path + ": " + std::strerror(errno);
  return "";
}

/// What is wrong with the options on their own (before the store is opened), or "".
std::string CheckOptions(const CLI::App& app, const Options& o) {
  const bool range = app.count("--from-km") > 0 || app.count("--to-km") > 0;
  for (const auto& [name, km] : {std::pair{"--from-km", o.from_km}, {"--to-km", o.to_km}})
    if (app.count(name) > 0 && !std::isfinite(km)) return std::string(name) + " must be a number";
  if (range && !(o.from_km < o.to_km)) return "--from-km must be below --to-km";
  if (range && o.save)
    return "--save compares and stores the whole run: leave out --from-km and --to-km (the "
           "changes outside them would be withdrawn)";
  if (o.explain_at.size() == 2 &&
      !(std::isfinite(o.explain_at[0]) && std::isfinite(o.explain_at[1])))
    return "--explain-at must be two numbers: easting,northing";
  if (!(o.explain.radius_m > 0.0 && std::isfinite(o.explain.radius_m)))
    return "--explain-radius must be a positive number of metres";
  return o.json_path.empty() ? "" : WritableFile(o.json_path);
}

/// The store's index, or what is wrong with it: missing, unreadable or empty (a store is never
/// created here).
std::string CheckStore(const std::string& data_dir) {
  const std::filesystem::path index = std::filesystem::path(data_dir) / "index.sqlite";
  std::error_code ec;
  const auto status = std::filesystem::status(index, ec);
  if (ec && ec != std::errc::no_such_file_or_directory)
    return "cannot read " + index.string() + ": " + ec.message();
  if (!std::filesystem::is_regular_file(status))
    return "no store in " + data_dir +
           " (no index.sqlite): name the folder raillomer-server --data stores into";
  if (std::filesystem::file_size(index, ec) == 0)
    return index.string() + " is empty: not a store (a store's index is never empty)";
  if (::access(index.c_str(), R_OK | W_OK) != 0)
    return "cannot open " + index.string() + ": " + std::strerror(errno);
  return "";
}

/// The run and the run to compare it with: --reference, else its line's reference run; the
/// kilometres asked for must reach the line.
Result ResolveRuns(const MapStore& store, const Options& o, RunInfo* info, int64_t* reference) {
  LineInfo line;
  Result r = store.GetRun(o.run, info);
  if (r) r = store.GetLine(info->line, &line);
  if (!r) return r;
  *reference = o.reference != 0 ? o.reference : line.reference_run;
  if (*reference == 0) return {Outcome::kInvalid, "no reference run: name one with --reference"};
  if (*reference == o.run)
    return {
        Outcome::kInvalid,
        o.reference != 0
            ? "--reference names the run itself: name another run of line '" + info->line + "'"
            : "run " + std::to_string(o.run) +
                  " is its line's reference run: name another to compare with, --reference <id>"};
  const double start_km = line.chainage_offset_m / 1000.0;
  const double end_km = start_km + line.length_m / 1000.0;
  if (o.from_km > end_km || o.to_km < start_km) {
    char text[200];
    std::snprintf(text,
                  sizeof(text),
                  "line '%s' runs from km %.3f to km %.3f: nothing of it lies between --from-km "
                  "and --to-km",
                  line.name.c_str(),
                  start_km,
                  end_km);
    return {Outcome::kInvalid, text};
  }
  return {};
}

int Fail(const std::string& message) {
  std::fprintf(stderr, "raillomer-changes: %s\n", message.c_str());
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-changes: compares a run of a line with a reference run of the same line in a "
      "store folder (stop the server serving it first) and prints each change with its "
      "kilometre, side, offset, size and margin against the structure gauge.\n\n"
      "  raillomer-changes --data <dir> --run <id> [--reference <id>] [--from-km <km>] "
      "[--to-km <km>] [--json <file>] [--save] [--explain-at <easting,northing>]"};
  Options o;
  AddOptions(&app, &o);
  CLI11_PARSE(app, argc, argv);
  std::string error = CheckOptions(app, o);
  if (error.empty()) error = CheckStore(o.data_dir);
  if (!error.empty()) return Fail(error);
  StoreOptions store_options;
  store_options.flush_interval_ms = 0;
  auto store = MapStore::Open(o.data_dir, store_options, &error);
  if (!store) return Fail("cannot open the store in " + o.data_dir + ": " + error);
  RunInfo info;
  int64_t reference = 0;
  Result r = ResolveRuns(*store, o, &info, &reference);
  if (!r) return Fail(r.message);
  RunComparisonOptions options;
  Explain explain = o.explain;
  if (o.explain_at.size() == 2) {
    explain.on = options.change.keep_rejected = true;
    explain.at = Eigen::Vector2d(o.explain_at[0], o.explain_at[1]);
  }
  options.from_m = 1000.0 * o.from_km;
  options.to_m = 1000.0 * o.to_km;
  std::vector<RunChange> changes;
  RunComparisonSummary summary;
  r = Compare(*store, reference, o.run, options, o.save, explain, &changes, &summary);
  if (ProgressInPlace()) std::fprintf(stderr, "\n");
  if (!r) return Fail(r.message);
  PrintTable(o.run, reference, info.line, summary, changes);
  if (!o.json_path.empty() && !WriteJson(o.json_path, o.run, reference, summary, changes))
    return Fail("cannot write " + o.json_path + ": " + std::strerror(errno));
  return 0;
}
