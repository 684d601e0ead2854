// Writes one message of each type, plus malformed variants, for the Python decoder test.
// Usage: write_sample_messages DIR
#include <cstdio>
#include <fstream>
#include <string>

#include "protocol/messages.hpp"

namespace {
void Write(const std::string& path, const std::vector<uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
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
  std::vector<uint8_t> bytes;
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
  protocol::EncodeSkeletonFrame(skeleton, &bytes);
  Write(dir + "/skeleton_frame.bin", bytes);
  bytes[0] = 'X';
  Write(dir + "/bad_magic.bin", bytes);
  return 0;
}
