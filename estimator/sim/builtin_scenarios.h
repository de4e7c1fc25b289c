#pragma once

#include <string>
#include <vector>

namespace raillomer::sim {

/// A scenario file compiled into the binary (estimator/sim/scenarios/<name>.yaml).
struct BuiltinScenario {
  std::string name;
  std::string yaml;
};

/// All built-in scenarios, sorted by name. Generated at configure time.
const std::vector<BuiltinScenario>& BuiltinScenarios();

}  // namespace raillomer::sim
