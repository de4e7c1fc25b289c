#pragma once

// Changes as the API gives them: GeoJSON Features (RFC 7946, WGS84 [lon, lat, h]), the run's
// detection state, and CSV rows of the same properties.

#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "mapstore/change_store.h"

namespace raillomer::server {

/// A change as a GeoJSON Feature: its footprint as a Polygon, its properties as the API
/// states them (api/openapi.yaml, Change).
nlohmann::json ChangeFeature(const mapstore::StoredChange& change);
/// The run's detection: status, reference run, registration residual, progress; `reason` when
/// nothing is compared (the run is the reference, no reference yet).
nlohmann::json DetectionJson(const mapstore::DetectionState& state, const std::string& reason);
/// A FeatureCollection of the changes with the `detection` member.
nlohmann::json ChangeCollection(const std::vector<mapstore::StoredChange>& changes,
                                const nlohmann::json& detection);
/// The same properties as CSV, a header line and a row per change.
std::string ChangesCsv(const std::vector<mapstore::StoredChange>& changes);

}  // namespace raillomer::server
