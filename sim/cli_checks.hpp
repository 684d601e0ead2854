// Command-line checks shared by mocapd and mocap-sim where CLI11's own fall short.
#pragma once

#include <CLI/CLI.hpp>
#include <cmath>
#include <stdexcept>
#include <string>

#include "formats/c3d.hpp"

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

/// A check that refuses an empty value: CLI11 takes `--out ""` as a value.
inline CLI::Validator NonEmpty(const std::string& needed, const std::string& type) {
  return CLI::Validator(
      [needed](std::string& text) { return text.empty() ? needed + ", not \"\"" : std::string(); },
      type);
}

/// For file and folder options: an empty path was either an error that did not name the
/// option or the option silently ignored (--plot "").
inline const CLI::Validator kNonEmptyPath = NonEmpty("a path is needed", "PATH");

/// CLI::ExistingFile, but an empty path says so: it was "File does not exist: " (no name).
inline const CLI::Validator kExistingFile(
    [](std::string& text) {
      return text.empty() ? std::string("a path is needed, not \"\"") : CLI::ExistingFile(text);
    },
    "FILE");

/// For ZeroMQ endpoints the command binds or connects to: "" failed as "cannot bind : Invalid
/// argument".
inline const CLI::Validator kNonEmptyEndpoint =
    NonEmpty("an endpoint is needed (tcp://HOST:PORT, ipc://PATH)", "ENDPOINT");

/// For text options whose empty value would be taken as not given (--actor "", and
/// --marker-set "", which placed the default layout).
inline const CLI::Validator kNonEmptyValue = NonEmpty("a value is needed", "TEXT");

/// For length-unit options: checked when the command line is read, by the readers' own
/// table (an unknown unit was found only once its file was read, and "" meant "guess").
inline const CLI::Validator kLengthUnit(
    [](std::string& text) -> std::string {
      try {
        (void)MetresPerUnit(text);
        return {};
      } catch (const std::invalid_argument& e) {
        return e.what();
      }
    },
    "UNIT");

}  // namespace mocapd
