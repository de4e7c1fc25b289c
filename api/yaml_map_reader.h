#pragma once

#include <array>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

namespace raillomer::api {

/// A parse failure that already carries the key path and line.
struct YamlError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// "source:line" of a node, or just the source when the node has no mark.
inline std::string Where(const std::string& source, const YAML::Node& node) {
  const YAML::Mark mark = node.Mark();
  if (mark.line < 0) return source;
  return source + ":" + std::to_string(mark.line + 1);
}

/// Reads keys from one YAML map and remembers which were used, to reject unknown ones.
class MapReader {
 public:
  MapReader(const YAML::Node& node, std::string path, const std::string& source)
      : node_(node), path_(std::move(path)), source_(source) {
    if (!node_.IsMap()) Fail(node_, "must be a map of keys");
  }

  bool Has(const char* key) {
    used_.insert(key);
    return static_cast<bool>(node_[key]);
  }

  YAML::Node Node(const char* key) {
    used_.insert(key);
    return node_[key];
  }

  template <typename T>
  void Read(const char* key, T* value) {
    used_.insert(key);
    const YAML::Node child = node_[key];
    if (!child) return;
    try {
      *value = child.as<T>();
    } catch (const YAML::Exception&) {
      Fail(child, std::string("key '") + Path(key) + "' has a value of the wrong type");
    }
  }

  void ReadRange(const char* key, double* min_value, double* max_value) {
    std::vector<double> pair;
    Read(key, &pair);
    if (!node_[key]) return;
    if (pair.size() != 2 || pair[0] > pair[1]) {
      Fail(node_[key], std::string("key '") + Path(key) + "' must be [min, max] with min <= max");
    }
    *min_value = pair[0];
    *max_value = pair[1];
  }

  template <size_t N>
  void ReadArray(const char* key, std::array<double, N>* value) {
    std::vector<double> list;
    Read(key, &list);
    if (!node_[key]) return;
    if (list.size() != N) {
      Fail(node_[key],
           std::string("key '") + Path(key) + "' must list " + std::to_string(N) + " numbers");
    }
    for (size_t i = 0; i < N; ++i) (*value)[i] = list[i];
  }

  int ReadSide(const char* key, int fallback) {
    std::string text;
    Read(key, &text);
    if (!node_[key]) return fallback;
    if (text == "left") return 1;
    if (text == "right") return -1;
    Fail(node_[key],
         std::string("key '") + Path(key) + "' must be left or right, not '" + text + "'");
    return fallback;
  }

  std::string Path(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }
  const std::string& source() const { return source_; }

  /// Throws for the first key that was never asked for.
  void Finish() const {
    for (const auto& entry : node_) {
      const std::string key = entry.first.as<std::string>();
      if (!used_.count(key)) Fail(entry.first, "unknown key '" + Path(key) + "'");
    }
  }

  [[noreturn]] void Fail(const YAML::Node& at, const std::string& message) const {
    throw YamlError(Where(source_, at) + ": " + message);
  }

 private:
  YAML::Node node_;
  std::string path_;
  const std::string& source_;
  std::set<std::string> used_;
};

/// Calls fn(reader, node) for each map in the list under `key`, rejecting unknown keys in each.
template <typename Fn>
inline void ForEachMap(MapReader& parent, const char* key, Fn fn) {
  const YAML::Node list = parent.Node(key);
  if (!list) return;
  if (!list.IsSequence()) parent.Fail(list, "key '" + parent.Path(key) + "' must be a list");
  for (size_t i = 0; i < list.size(); ++i) {
    MapReader item(list[i], parent.Path(key) + "[" + std::to_string(i) + "]", parent.source());
    fn(item, list[i]);
    item.Finish();
  }
}

}  // namespace raillomer::api
