#include "server/change_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <map>

#include "api/markup.h"
#include "server/api_json.h"

namespace raillomer::server {
namespace {

std::string Escape(const std::string& text) { return api::EscapeMarkup(text); }

std::string Base64(const std::string& bytes) {
  static const char* kAlphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  for (size_t i = 0; i < bytes.size(); i += 3) {
    uint32_t v = static_cast<uint8_t>(bytes[i]) << 16;
    if (i + 1 < bytes.size()) v |= static_cast<uint8_t>(bytes[i + 1]) << 8;
    if (i + 2 < bytes.size()) v |= static_cast<uint8_t>(bytes[i + 2]);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += i + 1 < bytes.size() ? kAlphabet[(v >> 6) & 63] : '=';
    out += i + 2 < bytes.size() ? kAlphabet[v & 63] : '=';
  }
  return out;
}

std::string Fixed(double v, int digits) {
  if (!std::isfinite(v)) return "&ndash;";
  char text[64];
  std::snprintf(text, sizeof(text), "%.*f", digits, v);
  return text;
}

std::string Km(double chainage_m) { return "km " + Fixed(chainage_m / 1000.0, 3); }

std::string When(int64_t ns) {
  const std::time_t t = static_cast<std::time_t>(ns / 1'000'000'000);
  char text[64];
  std::strftime(text, sizeof(text), "%Y-%m-%d %H:%M UTC", std::gmtime(&t));
  return text;
}

constexpr const char* kStyle = R"css(
body { font-family: sans-serif; margin: 2em; color: #222; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; }
table { border-collapse: collapse; margin: 0.8em 0; }
td, th { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: left; }
th { background: #eee; }
.intrudes { color: #b00; font-weight: bold; }
.change { page-break-inside: avoid; border-top: 2px solid #888; margin-top: 1.5em; }
.change img { max-width: 100%; border: 1px solid #ccc; }
@media print {
  a { color: inherit; text-decoration: none; }
  a.viewer::after { content: " (" attr(href) ")"; font-size: 0.85em; }
}
)css";

/// A filter in words: "" for every change.
std::string FilterText(const mapstore::ChangeFilter& f) {
  std::vector<std::string> parts;
  if (std::isfinite(f.from_m)) parts.push_back("from " + Km(f.from_m));
  if (std::isfinite(f.to_m)) parts.push_back("to " + Km(f.to_m));
  if (f.kind) parts.push_back(std::string("kind ") + mapstore::ToString(*f.kind));
  if (f.intrudes) parts.push_back(*f.intrudes ? "intruding the gauge" : "clear of the gauge");
  if (f.min_size_m > 0.0) parts.push_back("at least " + Fixed(f.min_size_m, 2) + " m");
  std::string statuses;
  for (const std::string& s : f.statuses) statuses += (statuses.empty() ? "" : " or ") + s;
  if (!statuses.empty()) parts.push_back("status " + statuses);
  std::string text;
  for (const std::string& p : parts) text += (text.empty() ? "" : ", ") + p;
  return text;
}

/// How the line's kilometres and sides are counted, so that a reader can find a change on site.
std::string KilometresText(const mapstore::LineInfo& line) {
  const std::string basis =
      line.km_posts > 0
          ? "from the line's " + std::to_string(line.km_posts) + " pinned km post" +
                (line.km_posts > 1 ? "s" : "")
          : "<b>no km post pinned</b>: counted along the reference run from where it started, "
            "not the line's own kilometres";
  return basis + ". Left and right as seen facing increasing kilometres.";
}

std::string Summary(const ChangeReportInput& in, const std::vector<mapstore::StoredChange>& c) {
  std::map<std::string, int> by_kind;
  int intrusions = 0;
  for (const mapstore::StoredChange& s : c) {
    ++by_kind[mapstore::ToString(s.change.kind)];
    intrusions += s.change.intrudes_envelope ? 1 : 0;
  }
  const mapstore::DetectionState& d = in.detection;
  std::string html = "<table>\n";
  const auto row = [&](const std::string& key, const std::string& value) {
    html += "<tr><th>" + key + "</th><td>" + value + "</td></tr>\n";
  };
  row("Line", Escape(in.line.name));
  row("Run",
      std::to_string(in.run.id) + " (" + Escape(in.run.vehicle) + ", streamed from " +
          When(in.run.start_ns) + ", " + Escape(in.run.status) + ")");
  row("Compared with",
      in.reference.id
          ? "run " + std::to_string(in.reference.id) + " (" + Escape(in.reference.vehicle) +
                ", streamed from " + When(in.reference.start_ns) + ")"
          : Escape(in.reason));
  row("Kilometres", KilometresText(in.line));
  row("Detection", Escape(d.status) + (d.error.empty() ? "" : ": " + Escape(d.error)));
  row("Covered",
      Fixed(d.km, 2) + " km in " + std::to_string(d.stretches_compared) +
          " stretches; registration residual " + Fixed(d.registration_rms_m * 100.0, 1) +
          " cm RMS");
  std::string kinds;
  for (const char* k : {"added", "removed", "moved", "vegetation"})
    kinds += std::string(kinds.empty() ? "" : ", ") + k + " " + std::to_string(by_kind[k]);
  const std::string listed = FilterText(in.filter);
  if (!listed.empty()) row("Listed", Escape(listed));
  row("Changes", std::to_string(c.size()) + " (" + kinds + ")");
  row("Intruding the gauge",
      "<span class=\"" + std::string(intrusions ? "intrudes" : "") + "\">" +
          std::to_string(intrusions) + "</span>");
  row("Written", When(in.generated_ns));
  return html + "</table>\n";
}

/// The status, and whether the change still waits for the final output's comparison.
std::string StatusText(const mapstore::StoredChange& s) {
  return Escape(s.status) + (s.provisional ? " (provisional)" : "");
}

std::string Overview(const std::vector<mapstore::StoredChange>& c) {
  std::string html =
      "<table>\n<tr><th>#</th><th>Kind</th><th>Kilometre</th><th>Side</th><th>Offset m</th>"
      "<th>Size m (along &times; across &times; height)</th><th>Margin m</th><th>Status</th>"
      "</tr>\n";
  for (const mapstore::StoredChange& s : c) {
    const mapstore::RunChange& x = s.change;
    html += std::string("<tr") + (x.intrudes_envelope ? " class=\"intrudes\"" : "") + ">" +
            "<td><a href=\"#change-" + std::to_string(s.id) + "\">" + std::to_string(s.id) +
            "</a></td><td>" + mapstore::ToString(x.kind) + "</td><td>" + Km(x.chainage_m) +
            "</td><td>" + mapstore::SideOf(x) + "</td><td>" + Fixed(std::abs(x.offset_m), 2) +
            "</td><td>" + Fixed(x.size_m.x(), 1) + " &times; " + Fixed(x.size_m.y(), 1) +
            " &times; " + Fixed(x.size_m.z(), 1) + "</td><td>" + Fixed(x.margin_m, 2) +
            "</td><td>" + StatusText(s) + "</td></tr>\n";
  }
  return html + "</table>\n";
}

/// The change against the structure gauge, in words: an object that is gone stood inside it but
/// no longer intrudes.
std::string GaugeText(const mapstore::RunChange& x) {
  if (x.intrudes_envelope)
    return "<span class=\"intrudes\">Intrudes the structure gauge by " + Fixed(-x.margin_m, 2) +
           " m.</span> ";
  if (x.margin_m < 0.0)
    return "Gone: it stood " + Fixed(-x.margin_m, 2) + " m inside the structure gauge. ";
  return Fixed(x.margin_m, 2) + " m clear of the structure gauge. ";
}

/// Whether an earlier run of the line found the change too, in words.
std::string SeenBeforeText(const mapstore::StoredChange& s) {
  if (s.earlier_change == 0) return "";
  return "Found before as change #" + std::to_string(s.earlier_change) + ", first seen in run " +
         std::to_string(s.first_seen_run) + ". ";
}

/// Where across the track a change lies: its centre's offset and side, or its extent when it
/// lies across the track.
std::string PlaceText(const mapstore::RunChange& x) {
  const auto side = [](double offset) {
    return Fixed(std::abs(offset), 2) + " m " + (offset >= 0.0 ? "left" : "right");
  };
  if (mapstore::LiesAcross(x))
    return "across the track (" + side(x.offset_from_m) + " to " + side(x.offset_to_m) + ")";
  return side(x.offset_m);
}

/// The centre in WGS84 for a handheld receiver: " (31.500000 N, 117.200000 E)" ("" if the
/// zone does not hold it).
std::string LatLonText(const mapstore::RunChange& x) {
  nlohmann::json lon_lat_h;
  if (!Wgs84(x.utm_zone, x.centre_utm, &lon_lat_h)) return "";
  const double lon = lon_lat_h[0], lat = lon_lat_h[1];
  return " (" + Fixed(std::abs(lat), 6) + (lat >= 0.0 ? " N, " : " S, ") + Fixed(std::abs(lon), 6) +
         (lon >= 0.0 ? " E)" : " W)");
}

std::string Section(const ChangeReportInput& in, const mapstore::StoredChange& s) {
  const mapstore::RunChange& x = s.change;
  std::string html = "<div class=\"change\" id=\"change-" + std::to_string(s.id) + "\">\n";
  html += "<h2>#" + std::to_string(s.id) + " " + mapstore::ToString(x.kind) + ", " +
          Km(x.chainage_m) + ", " + PlaceText(x) + "</h2>\n<p>";
  html += GaugeText(x);
  html += "Size " + Fixed(x.size_m.x(), 1) + " &times; " + Fixed(x.size_m.y(), 1) + " &times; " +
          Fixed(x.size_m.z(), 1) + " m (along &times; across &times; height), " +
          Fixed(x.height_above_rail_min_m, 1) + " to " + Fixed(x.height_above_rail_max_m, 1) +
          " m above the rails. UTM " + Escape(x.utm_zone) + " " + Fixed(x.centre_utm.x(), 1) +
          " E, " + Fixed(x.centre_utm.y(), 1) + " N" + LatLonText(x) + ". Confidence " +
          Fixed(x.confidence, 2) + ", level of detection " + Fixed(x.lod_m, 2) +
          " m. Status: " + StatusText(s) + (s.note.empty() ? "" : " (" + Escape(s.note) + ")") +
          ". " + SeenBeforeText(s) + "<a class=\"viewer\" href=\"" + Escape(in.viewer_url) +
          "?run=" + std::to_string(s.run_id) + "&amp;change=" + std::to_string(s.id) +
          "\">Open in the viewer</a></p>\n";
  const std::string png = in.snapshot ? in.snapshot(s) : "";
  if (!png.empty())
    html += "<img alt=\"snapshot of change " + std::to_string(s.id) +
            "\" src=\"data:image/png;base64," + Base64(png) + "\">\n";
  return html + "</div>\n";
}

}  // namespace

std::string ChangeReportHtml(const ChangeReportInput& in) {
  std::vector<mapstore::StoredChange> c = in.changes;
  std::stable_sort(c.begin(), c.end(), [](const auto& a, const auto& b) {
    if (a.change.intrudes_envelope != b.change.intrudes_envelope) return a.change.intrudes_envelope;
    return a.change.chainage_m < b.change.chainage_m;
  });
  std::string html = "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n";
  html += "<title>Changes of run " + std::to_string(in.run.id) + ", line " + Escape(in.line.name) +
          "</title>\n<style>" + kStyle + "</style></head><body>\n";
  html += "<h1>Changes of run " + std::to_string(in.run.id) + " on line " + Escape(in.line.name) +
          "</h1>\n";
  html += Summary(in, c) + Overview(c);
  for (const mapstore::StoredChange& s : c) html += Section(in, s);
  return html + "</body></html>\n";
}

}  // namespace raillomer::server
