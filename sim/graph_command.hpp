// `mocap-sim graph build|synth|match`: the motion graph's verbs on the command line.
#pragma once

#include <CLI/CLI.hpp>
#include <memory>

namespace mocapd {

/// Adds the `graph` subcommand and its verbs to app. After parsing, Selected() says
/// whether one was chosen and Run() runs it (throwing on failure, for the caller to
/// print and exit 1).
class GraphCommands {
 public:
  explicit GraphCommands(CLI::App& app);
  ~GraphCommands();
  bool Selected() const;
  int Run();

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace mocapd
