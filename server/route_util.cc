#include "server/route_util.h"

#include <cmath>
#include <limits>

#include "server/api_json.h"
#include "server/http_parse.h"

namespace raillomer::server {

using nlohmann::json;

int StatusOf(mapstore::Outcome outcome) {
  switch (outcome) {
    case mapstore::Outcome::kOk:
    case mapstore::Outcome::kDuplicate:
      return 200;
    case mapstore::Outcome::kInvalid:
      return 400;
    case mapstore::Outcome::kNotFound:
      return 404;
    case mapstore::Outcome::kConflict:
      return 409;
    case mapstore::Outcome::kError:
      return 500;
  }
  return 500;
}

void SendResult(HttpResponse& res, const mapstore::Result& r) {
  res.SetError(StatusOf(r.outcome), mapstore::ToString(r.outcome), r.message);
}

void SendJson(HttpResponse& res, const json& j, const char* type) {
  res.SetContent(JsonText(j), type);
}

/// A JSON body as an object; false (and a 400 set) if it is not one.
bool ParseObject(const HttpRequest& req, HttpResponse& res, json* out) {
  const std::string wrong = ParseJson(req.body, out);
  if (!wrong.empty()) {
    res.SetError(400, "invalid", "the body is not JSON: " + wrong);
    return false;
  }
  if (!out->is_object()) {
    res.SetError(
        400, "invalid", std::string("the body must be a JSON object, not ") + out->type_name());
    return false;
  }
  return true;
}

bool OnlyMembers(const json& body,
                 HttpResponse& res,
                 std::initializer_list<const char*> known,
                 std::initializer_list<const char*> ignored) {
  const std::string unknown = UnknownMember(body, known, ignored);
  if (unknown.empty()) return true;
  res.SetError(400, "invalid", unknown);
  return false;
}

/// The id in the path's first capture; a 404 if it is not one the store could hold.
bool PathId(const HttpRequest& req, HttpResponse& res, int64_t* id, const char* what) {
  if (req.matches.size() < 2 ||
      !ParseInt64(req.matches[1], 1, std::numeric_limits<int64_t>::max(), id)) {
    res.SetError(404, "not_found", std::string("no such ") + what);
    return false;
  }
  return true;
}

/// An optional integer query parameter in [min, max]; a 400 naming it if it is not one.
bool IntParam(const HttpRequest& req,
              HttpResponse& res,
              const char* name,
              int64_t min,
              int64_t max,
              int64_t* value) {
  if (!req.HasParam(name)) return true;
  if (!ParseInt64(req.Param(name), min, max, value)) {
    res.SetError(400,
                 "invalid",
                 std::string(name) + " must be a whole number in [" + std::to_string(min) + ", " +
                     std::to_string(max) + "] (got '" + req.Param(name) + "')");
    return false;
  }
  return true;
}

/// An optional number query parameter; a 400 naming it if it is not a finite number.
bool NumberParam(const HttpRequest& req, HttpResponse& res, const char* name, double* value) {
  if (!req.HasParam(name)) return true;
  if (!ParseFiniteDouble(req.Param(name), value)) {
    res.SetError(
        400, "invalid", std::string(name) + " must be a number (got '" + req.Param(name) + "')");
    return false;
  }
  return true;
}

bool KmParam(const HttpRequest& req, HttpResponse& res, const char* name, double* metres) {
  double km = 0.0;
  if (!req.HasParam(name)) return true;
  if (!NumberParam(req, res, name, &km)) return false;
  if (!std::isfinite(1000.0 * km)) {
    res.SetError(
        400,
        "invalid",
        std::string(name) + " must be kilometres a line can have (got '" + req.Param(name) + "')");
    return false;
  }
  *metres = 1000.0 * km;
  return true;
}

}  // namespace raillomer::server
