// The change-detection routes: a run's changes (GeoJSON or CSV), recomputing them against a
// chosen reference, an engineer's status and note, a change's snapshot and a run's report.
#include <limits>
#include <optional>

#include "api/clock.h"
#include "api/printable.h"
#include "server/change_json.h"
#include "server/change_report.h"
#include "server/http_parse.h"
#include "server/route_util.h"
#include "server/routes.h"
#include "server/snapshot.h"

namespace raillomer::server {
namespace {

using nlohmann::json;

/// The `status` filter of GET .../changes: statuses separated by commas (`new,confirmed`);
/// false with a 400 naming a status there is not.
bool StatusesOf(const HttpRequest& req, HttpResponse& res, std::vector<std::string>* out) {
  if (!req.HasParam("status")) return true;
  const std::string list = req.Param("status");
  size_t start = 0;
  for (;;) {
    const size_t comma = list.find(',', start);
    const std::string status = list.substr(start, comma - start);
    if (!mapstore::IsChangeStatus(status, false)) {
      res.SetError(400,
                   "invalid",
                   "status must be new, confirmed, dismissed, fixed or closed, or several of "
                   "them separated by commas (got '" +
                       status + "')");
      return false;
    }
    out->push_back(status);
    if (comma == std::string::npos) return true;
    start = comma + 1;
  }
}

/// The filters of GET .../changes; false with a 400 naming the bad one.
bool FilterOf(const HttpRequest& req, HttpResponse& res, mapstore::ChangeFilter* f) {
  if (!KmParam(req, res, "from_km", &f->from_m) || !KmParam(req, res, "to_km", &f->to_m) ||
      !NumberParam(req, res, "min_size_m", &f->min_size_m))
    return false;
  if (f->from_m > f->to_m) {
    res.SetError(400, "invalid", "from_km must not be above to_km");
    return false;
  }
  if (req.HasParam("kind")) {
    mapstore::ChangeKind kind;
    if (!mapstore::ParseChangeKind(req.Param("kind"), &kind)) {
      res.SetError(
          400,
          "invalid",
          "kind must be added, removed, moved or vegetation (got '" + req.Param("kind") + "')");
      return false;
    }
    f->kind = kind;
  }
  if (req.HasParam("intrudes_envelope")) {
    const std::string v = req.Param("intrudes_envelope");
    if (v != "true" && v != "false") {
      res.SetError(400, "invalid", "intrudes_envelope must be true or false (got '" + v + "')");
      return false;
    }
    f->intrudes = v == "true";
  }
  return StatusesOf(req, res, &f->statuses);
}

/// Whether a PATCH's note is one: a string of at most 4000 characters (UTF-8, which the JSON
/// parser has checked) that prints as it is, line breaks and tabs allowed; else `why` says.
bool NoteIsValid(const json& note, std::string* why) {
  if (!note.is_string()) return *why = "note must be a string", false;
  const std::string& text = note.get_ref<const std::string&>();
  if (!api::Printable(text, true))
    return *why =
               "note must not hold control characters, line separators or bidirectional "
               "overrides (tab and line breaks are allowed)",
           false;
  const size_t characters = api::Utf8Characters(text);
  if (characters > 4000)
    return *why = "note must be at most 4000 characters (got " + std::to_string(characters) + ")",
           false;
  return true;
}

class ChangeApi {
 public:
  explicit ChangeApi(const ApiContext& c)
      : c_(c), store_(*c.store), changes_(*c.changes), worker_(*c.change_worker) {}

  void List(const HttpRequest& req, HttpResponse& res) {
    int64_t run = 0;
    mapstore::ChangeFilter filter;
    if (!PathId(req, res, &run) || !FilterOf(req, res, &filter)) return;
    const std::string format = req.HasParam("format") ? req.Param("format") : "geojson";
    if (format != "geojson" && format != "csv")
      return res.SetError(400, "invalid", "format must be geojson or csv (got '" + format + "')");
    mapstore::DetectionState state;
    std::string reason;
    mapstore::Result r = worker_.State(run, &state, &reason);
    std::vector<mapstore::StoredChange> found;
    if (r) r = changes_.List(run, filter, &found);
    if (!r) return SendResult(res, r);
    if (format == "csv") {
      res.SetContent(ChangesCsv(found), "text/csv; charset=utf-8");
      res.SetHeader("Content-Disposition",
                    "attachment; filename=\"changes-run-" + std::to_string(run) + ".csv\"");
      return;
    }
    SendJson(res, ChangeCollection(found, DetectionJson(state, reason)), "application/geo+json");
  }

  /// Where the comparison put the run: each compared stretch's registration onto the
  /// reference, so a viewer draws both runs registered as the detection saw them.
  void Registration(const HttpRequest& req, HttpResponse& res) {
    int64_t run = 0;
    if (!PathId(req, res, &run)) return;
    mapstore::DetectionState state;
    std::string reason;
    std::vector<mapstore::StretchFrame> frames;
    mapstore::Result r = worker_.State(run, &state, &reason);
    if (r) r = changes_.Frames(run, &frames);
    if (!r) return SendResult(res, r);
    json stretches = json::array();
    for (const mapstore::StretchFrame& f : frames) {
      json T = json::array();
      for (int row = 0; row < 3; ++row)
        for (int col = 0; col < 4; ++col) T.push_back(f.T_reference_later.matrix()(row, col));
      stretches.push_back({{"stretch", f.stretch},
                           {"from_m", f.from_m},
                           {"to_m", f.to_m},
                           {"registration_rms_m", f.rms_m},
                           {"origin", {f.origin.x(), f.origin.y(), f.origin.z()}},
                           {"T_reference_run", T}});
    }
    SendJson(
        res,
        {{"run", run},
         {"reference_run", state.reference_run == 0 ? json(nullptr) : json(state.reference_run)},
         {"stretches", stretches}});
  }

  void Recompute(const HttpRequest& req, HttpResponse& res) {
    int64_t run = 0, reference = 0;
    if (!PathId(req, res, &run) ||
        !IntParam(req, res, "reference", 1, std::numeric_limits<int64_t>::max(), &reference))
      return;
    mapstore::DetectionState state;
    const mapstore::Result r = worker_.Recompute(run, reference, &state);
    if (!r) return SendResult(res, r);
    res.status = 202;
    SendJson(res, {{"run", run}, {"detection", DetectionJson(state, "")}});
  }

  void Get(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    if (!PathId(req, res, &id, "change")) return;
    mapstore::StoredChange change;
    const mapstore::Result r = changes_.Get(id, &change);
    if (!r) return SendResult(res, r);
    SendJson(res, ChangeFeature(change), "application/geo+json");
  }

  void Update(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    json body;
    if (!PathId(req, res, &id, "change") || !ParseObject(req, res, &body) ||
        !OnlyMembers(body, res, {"status", "note"}))
      return;
    if (body.contains("status") && !body["status"].is_string())
      return res.SetError(400, "invalid", "status must be a string");
    std::string why;
    if (body.contains("note") && !NoteIsValid(body["note"], &why))
      return res.SetError(400, "invalid", why);
    if (!body.contains("status") && !body.contains("note"))
      return res.SetError(400, "invalid", "give a status, a note or both");
    std::optional<std::string> status, note;
    if (body.contains("status")) status = body["status"].get<std::string>();
    if (body.contains("note")) note = body["note"].get<std::string>();
    mapstore::StoredChange change;
    const mapstore::Result r = changes_.Update(id, status, note, &change);
    if (!r) return SendResult(res, r);
    SendJson(res, ChangeFeature(change), "application/geo+json");
  }

  void Snapshot(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    if (!PathId(req, res, &id, "change")) return;
    mapstore::StoredChange change;
    mapstore::Result r = changes_.Get(id, &change);
    std::string png;
    if (r) r = RenderSnapshot(store_, changes_, change, Clearance(), &png);
    if (!r) return SendResult(res, r);
    res.SetContent(std::move(png), "image/png");
  }

  void Report(const HttpRequest& req, HttpResponse& res) {
    int64_t run = 0;
    ChangeReportInput in;
    if (!PathId(req, res, &run) || !FilterOf(req, res, &in.filter)) return;
    mapstore::Result r = store_.GetRun(run, &in.run);
    if (r) r = store_.GetLine(in.run.line, &in.line);
    if (r) r = worker_.State(run, &in.detection, &in.reason);
    if (r) r = changes_.List(run, in.filter, &in.changes);
    if (r && in.detection.reference_run != 0)
      r = store_.GetRun(in.detection.reference_run, &in.reference);
    if (!r) return SendResult(res, r);
    in.viewer_url = ViewerUrl(req);
    in.generated_ns = api::NowNs();
    in.snapshot = [this](const mapstore::StoredChange& change) {
      std::string png;
      return RenderSnapshot(store_, changes_, change, Clearance(), &png) ? png : std::string();
    };
    res.SetContent(ChangeReportHtml(in), "text/html; charset=utf-8");
  }

 private:
  /// The viewer's address as the client reached this server (its Host header), so that the
  /// report's links work from a saved file too; "/" when the header is not a plain host[:port].
  static std::string ViewerUrl(const HttpRequest& req) {
    const std::string host = req.Header("Host");
    const bool plain = !host.empty() && host.size() <= 255 &&
                       host.find_first_not_of(
                           "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
                           "0123456789.-:[]") == std::string::npos;
    if (!plain) return "/";
    const bool https = EqualsIgnoreCase(req.Header("X-Forwarded-Proto"), "https");
    return (https ? "https://" : "http://") + host + "/";
  }

  const mapstore::ClearanceOptions& Clearance() const {
    return c_.config->changes.comparison.clearance;
  }

  ApiContext c_;
  mapstore::MapStore& store_;
  mapstore::ChangeStore& changes_;
  ChangeWorker& worker_;
};

}  // namespace

std::vector<HttpRoute> ChangeRoutes(const ApiContext& context) {
  auto api = std::make_shared<ChangeApi>(context);
  auto route = [api](auto... args) { return MemberRoute(api, args...); };
  const Access R = Access::kRead, W = Access::kWrite;
  return {
      route("GET", "/api/v1/runs/{run}/changes", "changes.list", R, &ChangeApi::List),
      route("POST", "/api/v1/runs/{run}/changes", "changes.recompute", W, &ChangeApi::Recompute),
      route("GET", "/api/v1/runs/{run}/changes/report", "changes.report", R, &ChangeApi::Report),
      route("GET",
            "/api/v1/runs/{run}/changes/registration",
            "changes.registration",
            R,
            &ChangeApi::Registration),
      route("GET", "/api/v1/changes/{id}", "changes.get", R, &ChangeApi::Get),
      route("PATCH", "/api/v1/changes/{id}", "changes.update", W, &ChangeApi::Update, 64 << 10),
      route(
          "GET", "/api/v1/changes/{id}/snapshot.png", "changes.snapshot", R, &ChangeApi::Snapshot),
  };
}

}  // namespace raillomer::server
