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

/// For file and folder options: CLI11 takes `--out ""` as a value, and an empty path was
/// then either an error that did not name the option or the option silently ignored.
inline const CLI::Validator kNonEmptyPath(
    [](std::string& text) -> std::string {
      return text.empty() ? "a path is needed, not \"\"" : "";
    },
    "PATH");

/// CLI::ExistingFile, but an empty path says so: it was "File does not exist: " (no name).
inline const CLI::Validator kExistingFile(
    [](std::string& text) -> std::string {
      if (text.empty()) return "a path is needed, not \"\"";
      return CLI::ExistingFile(text);
    },
    "FILE");

/// For ZeroMQ endpoints the command binds or connects to: "" failed as "cannot bind : Invalid
/// argument".
inline const CLI::Validator kNonEmptyEndpoint(
    [](std::string& text) -> std::string {
      return text.empty() ? "an endpoint is needed (tcp://HOST:PORT, ipc://PATH), not \"\"" : "";
    },
    "ENDPOINT");

/// For text options whose empty value would be taken as not given (--actor "" solved
/// every actor's markers as one; --marker-set "" placed the default layout).
inline const CLI::Validator kNonEmptyValue(
    [](std::string& text) -> std::string {
      return text.empty() ? "a value is needed, not \"\"" : "";
    },
    "TEXT");

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
