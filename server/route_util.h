#pragma once

// What every route handler shares: the store's outcomes as HTTP statuses, JSON answers, and
// path and query parameters checked with a 4xx naming what is wrong.

#include <cstdint>
#include <initializer_list>
#include <memory>

#include <nlohmann/json.hpp>

#include "mapstore/map_store.h"
#include "server/http_front.h"

namespace raillomer::server {

int StatusOf(mapstore::Outcome outcome);
/// The store's error as the API states it.
void SendResult(HttpResponse& res, const mapstore::Result& r);
void SendJson(HttpResponse& res, const nlohmann::json& j, const char* type = "application/json");
/// A JSON body as an object (each member named once); false (and a 400 set) if it is not one.
bool ParseObject(const HttpRequest& req, HttpResponse& res, nlohmann::json* out);
/// Whether `body` holds only members among `known` and `ignored` (see UnknownMember); a 400
/// naming the first other one if not.
bool OnlyMembers(const nlohmann::json& body,
                 HttpResponse& res,
                 std::initializer_list<const char*> known,
                 std::initializer_list<const char*> ignored = {});
/// The id in the path's first capture; a 404 if it is not one the store could hold.
bool PathId(const HttpRequest& req, HttpResponse& res, int64_t* id, const char* what = "run");
/// An optional integer query parameter in [min, max]; a 400 naming it if it is not one.
bool IntParam(const HttpRequest& req,
              HttpResponse& res,
              const char* name,
              int64_t min,
              int64_t max,
              int64_t* value);
/// An optional number query parameter; a 400 naming it if it is not a finite number.
bool NumberParam(const HttpRequest& req, HttpResponse& res, const char* name, double* value);
/// An optional kilometre query parameter (from_km, to_km) in metres; a 400 naming it if it is
/// not a number or its metres are not finite.
bool KmParam(const HttpRequest& req, HttpResponse& res, const char* name, double* metres);

/// A route whose handler is a member function of `api` (shared by the routes it serves).
template <typename Api>
HttpRoute MemberRoute(const std::shared_ptr<Api>& api,
                      const char* method,
                      const char* pattern,
                      const char* name,
                      Access access,
                      void (Api::*handler)(const HttpRequest&, HttpResponse&),
                      uint64_t max_body_bytes = 0) {
  HttpRoute r;
  r.method = method;
  r.pattern = pattern;
  r.name = name;
  r.access = access;
  r.max_body_bytes = max_body_bytes;
  r.handler = [api, handler](const HttpRequest& req, HttpResponse& res) {
    ((*api).*handler)(req, res);
  };
  return r;
}

}  // namespace raillomer::server
