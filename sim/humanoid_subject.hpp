// The built-in humanoid as a subject model (skeleton + the default ~60-marker layout):
// what the demo, the replay simulator and the tests solve when no capture is given, and
// what config/demo_subject.toml holds.
#pragma once

#include <string>

#include "formats/subject_file.hpp"

namespace mocapd {

SubjectModel MakeHumanoidSubject(const std::string& name);

}  // namespace mocapd
