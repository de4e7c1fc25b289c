#pragma once

#include <string>

#include "mapstore/change_store.h"
#include "mapstore/map_store.h"

namespace raillomer::server {

/// A picture of a change, rendered from the stored runs so that a report reads without the
/// viewer: a plan view around it (along the track left to right, its left side up) and a
/// cross-section across the track through it (seen in the direction of increasing chainage),
/// the reference run's points in blue, the compared run's (where the comparison registered
/// them) in orange, the change's box in red, the track centre dashed and the structure gauge
/// in green. PNG bytes in `png`.
mapstore::Result RenderSnapshot(const mapstore::MapStore& store,
                                const mapstore::ChangeStore& changes,
                                const mapstore::StoredChange& change,
                                const mapstore::ClearanceOptions& clearance,
                                std::string* png);

}  // namespace raillomer::server
