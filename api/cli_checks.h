#pragma once

// Checks of command-line values that CLI11's own let through: NaN passes PositiveNumber (NaN
// <= 0 is false), and an empty string is a value like any other.

#include <cmath>
#include <string>

#include <CLI/CLI.hpp>

namespace raillomer::api {

/// A finite number above 0 (a duration, a size).
inline CLI::Validator FinitePositive() {
  return CLI::Validator(
      [](std::string& text) {
        double v = 0.0;
        if (!CLI::detail::lexical_cast(text, v) || !std::isfinite(v) || v <= 0.0)
          return "must be a finite number above 0, not '" + text + "'";
        return std::string();
      },
      "POSITIVE");
}

/// A finite number of at least 0.
inline CLI::Validator FiniteNonNegative() {
  return CLI::Validator(
      [](std::string& text) {
        double v = 0.0;
        if (!CLI::detail::lexical_cast(text, v) || !std::isfinite(v) || v < 0.0)
          return "must be a finite number of at least 0, not '" + text + "'";
        return std::string();
      },
      "NONNEGATIVE");
}

/// A name or path that is not empty.
inline CLI::Validator NotEmpty() {
  return CLI::Validator(
      [](std::string& text) { return text.empty() ? std::string("must not be empty") : ""; },
      "TEXT");
}

}  // namespace raillomer::api
