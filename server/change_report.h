#pragma once

#include <functional>
#include <string>
#include <vector>

#include "mapstore/change_store.h"

namespace raillomer::server {

/// What a run's change report covers.
struct ChangeReportInput {
  mapstore::RunInfo run;
  mapstore::RunInfo reference;  ///< the run compared with (id 0 when there is none yet)
  mapstore::LineInfo line;
  mapstore::DetectionState detection;
  std::string reason;  ///< why nothing was compared, if so
  std::vector<mapstore::StoredChange> changes;
  mapstore::ChangeFilter filter;  ///< which changes are listed (the summary names it)
  /// A change's snapshot as PNG bytes ("" when it cannot be drawn).
  std::function<std::string(const mapstore::StoredChange&)> snapshot;
  /// Links into the viewer: <viewer_url>?run=R&change=ID; absolute, so that a saved or
  /// printed report still leads there.
  std::string viewer_url = "/";
  int64_t generated_ns = 0;  ///< when the report is written
};

/// A self-contained, printable HTML report of a run's changes: the runs compared, the km
/// covered, counts by kind, then each change (intrusions of the structure gauge first, then
/// by kilometre) with its kilometre, side, offset, size, margin, snapshot (embedded) and a
/// link into the viewer.
std::string ChangeReportHtml(const ChangeReportInput& input);

}  // namespace raillomer::server
