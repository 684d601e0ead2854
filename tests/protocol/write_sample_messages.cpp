// Writes one message of each type, plus malformed variants, for the Python decoder test.
// Usage: write_sample_messages DIR
#include <cstdio>
#include <fstream>
#include <string>

#include "protocol/messages.hpp"

namespace {
void Write(const std::string& path, const std::vector<uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
}
}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: write_sample_messages DIR\n");
    return 2;
  }
  const std::string dir = argv[1];
  using namespace mocapd;
  protocol::MarkerFrameMessage markers;
  markers.subject = "actor1";
  markers.model_hash = protocol::NamesHash(std::vector<std::string>{"LASI", "RASI", "LKNE"});
  markers.frame_number = 1234;
  markers.capture_time_ns = 987654321;
  markers.rate_hz = 120.0f;
  markers.positions = {Vec3(0.5, 1.25, -0.75), Vec3::Constant(kNaN), Vec3(-1.5, 0.0, 2.0)};
  markers.valid = {1, 0, 1};
  markers.stream.session_id = 0x0123456789abcdefull;
  markers.stream.rate_numerator = 120;
  markers.stream.rate_denominator = 1;
  markers.stream.has_timecode = true;
  markers.stream.timecode = {1, 2, 3, 4, 2, false, 30};
  std::vector<uint8_t> bytes;
  markers.version = protocol::kVersion1;
  protocol::EncodeMarkerFrame(markers, &bytes);
  Write(dir + "/marker_frame_v1.bin", bytes);
  markers.version = protocol::kVersion2;
  protocol::EncodeMarkerFrame(markers, &bytes);
  Write(dir + "/marker_frame.bin", bytes);
  std::vector<uint8_t> truncated(bytes.begin(), bytes.end() - 5);
  Write(dir + "/marker_frame_truncated.bin", truncated);
  protocol::SkeletonFrameMessage skeleton;
  skeleton.subject = "actor1";
  skeleton.model_hash = 99;
  skeleton.frame_number = 1234;
  skeleton.capture_time_ns = 987654321;
  skeleton.publish_time_ns = 987754321;
  skeleton.residual_m = 0.5f;
  skeleton.root_translation = Vec3(0.25, 0.875, -3.5);
  skeleton.rotations = {Quat::Identity(), Quat(0.5, 0.5, 0.5, 0.5)};
  skeleton.subject_state = protocol::SubjectState::kRepairing;
  skeleton.stream.session_id = 42;
  skeleton.stream.rate_numerator = 120000;
  skeleton.stream.rate_denominator = 1001;
  skeleton.stream.has_timecode = true;
  skeleton.stream.timecode = {23, 59, 59, 29, 3, true, 30};
  protocol::EncodeSkeletonFrame(skeleton, &bytes);
  Write(dir + "/skeleton_frame.bin", bytes);
  skeleton.global_rotations = {Quat::Identity(), Quat(0.5, -0.5, 0.5, -0.5)};
  skeleton.global_positions = {Vec3(0.25, 0.875, -3.5), Vec3(0.5, 1.0, -3.0)};
  std::vector<uint8_t> with_globals;
  protocol::EncodeSkeletonFrame(skeleton, &with_globals);
  Write(dir + "/skeleton_frame_globals.bin", with_globals);
  protocol::SubjectDescriptionMessage description;
  description.subject = "actor1";
  description.marker_set_hash = markers.model_hash;
  description.skeleton_hash = 99;
  description.rate_hz = 120.0f;
  description.lookahead_frames = 12;
  description.marker_names = {"LASI", "RASI", "LKNE"};
  description.joint_names = {"Hips", "Spine"};
  description.joint_parents = {-1, 0};
  description.rest_offsets = {Vec3(0, 0.875, 0), Vec3(0, 0.125, 0)};
  description.rest_rotations = {Quat::Identity(), Quat::Identity()};
  std::vector<uint8_t> other;
  protocol::EncodeSubjectDescription(description, &other);
  Write(dir + "/subject_description.bin", other);
  protocol::CleanedMarkersMessage cleaned;
  cleaned.subject = "actor1";
  cleaned.model_hash = markers.model_hash;
  cleaned.frame_number = 1234;
  cleaned.positions = {Vec3(0.5, 1.25, -0.75), Vec3(0.25, 1.0, -0.5), Vec3::Constant(kNaN)};
  cleaned.status = {0, 1, 2};
  cleaned.reason = {0, 1, 0};
  protocol::EncodeCleanedMarkers(cleaned, &other);
  Write(dir + "/cleaned_markers.bin", other);
  protocol::SubjectStatusMessage status;
  status.subject = "actor1";
  status.state = protocol::SubjectState::kStalled;
  status.last_frame_number = 1234;
  status.since_last_input_ns = 1500000000;
  status.frames_in = 1235;
  status.frames_out = 1223;
  status.frames_dropped = 0;
  status.problems = protocol::kProblemRejectingInput;
  protocol::EncodeSubjectStatus(status, &other);
  Write(dir + "/subject_status.bin", other);
  protocol::CalibrationStatusMessage calibration;
  calibration.subject = "actor1";
  calibration.skeleton_hash = 77;
  calibration.state = protocol::CalibrationState::kCollecting;
  calibration.refinements = 3;
  calibration.height_m = 1.75f;
  calibration.collected_s = 12.5f;
  calibration.joints = {{0, protocol::kJointCalibrated | protocol::kJointReady, 0.0f, 0.5f},
                        {2, protocol::kJointCalibrated, 4.5f, -1.0f}};
  protocol::EncodeCalibrationStatus(calibration, &other);
  Write(dir + "/calibration_status.bin", other);
  bytes[0] = 'X';
  Write(dir + "/bad_magic.bin", bytes);
  return 0;
}
