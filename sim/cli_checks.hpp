// Command-line checks shared by mocapd and mocap-sim where CLI11's own fall short.
#pragma once

#include <CLI/CLI.hpp>
#include <cmath>
#include <string>

namespace mocapd {

/// For floating options, in place of CLI::Number: that passes "nan" and "inf", and
/// CLI::Range then lets NaN through (every comparison with it is false), so
/// `--seconds nan` ran a one-frame take and `--rate nan` a default rate without a word.
inline const CLI::Validator kFiniteNumber(
    [](std::string& text) -> std::string {
      double value = 0.0;
      if (!CLI::detail::lexical_cast(text, value)) return "Failed parsing " + text + " as a FLOAT";
      if (!std::isfinite(value)) return "Value " + text + " is not a finite number";
      return {};
    },
    "FLOAT");

}  // namespace mocapd
