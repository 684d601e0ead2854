// Runs a fuzz target without libFuzzer: over seed inputs the project generates and
// seeded random mutations of them, so plain (and sanitizer) builds exercise the harness.
// Usage: <target> [--mutations N] [FILE...]
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "formats/bvh.hpp"
#include "formats/c3d.hpp"
#include "protocol/messages.hpp"
#include "sim/humanoid.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

namespace {
std::vector<std::vector<uint8_t>> Seeds() {
  const mocapd::Skeleton sk = mocapd::MakeHumanoidSkeleton();
  auto frames = mocapd::MakeHumanoidMotion(sk, mocapd::HumanoidMotion::kWalk, 0.2, 30.0);
  const std::string bvh = mocapd::FormatBvh(mocapd::MakeBvhTake(sk, frames, 1.0 / 30.0));
  mocapd::C3dTake take;
  take.labels = {"A", "B", "C"};
  take.rate_hz = 100.0;
  take.Allocate(4);
  for (size_t i = 0; i < take.positions.size(); ++i) {
    take.positions[i] = mocapd::Vec3(0.1 * static_cast<double>(i), 0.2, 0.3);
    take.residuals[i] = i % 5 == 0 ? -1.0f : 0.0f;
  }
  mocapd::C3dEncoding dec;
  dec.processor = mocapd::C3dEncoding::Processor::kDec;
  dec.integer_storage = true;
  mocapd::protocol::MarkerFrameMessage markers;
  markers.subject = "actor";
  markers.rate_hz = 120.0f;
  markers.positions = {mocapd::Vec3(0.1, 0.2, 0.3), mocapd::Vec3(0.4, 0.5, 0.6)};
  markers.valid = {1, 0};
  std::vector<uint8_t> marker_bytes, skeleton_bytes;
  mocapd::protocol::EncodeMarkerFrame(markers, &marker_bytes);
  mocapd::protocol::SkeletonFrameMessage skeleton;
  skeleton.subject = "actor";
  skeleton.rotations.assign(3, mocapd::Quat::Identity());
  mocapd::protocol::EncodeSkeletonFrame(skeleton, &skeleton_bytes);
  return {std::vector<uint8_t>(bvh.begin(), bvh.end()), mocapd::EncodeC3d(take),
          mocapd::EncodeC3d(take, dec), marker_bytes, skeleton_bytes};
}
}  // namespace

int main(int argc, char** argv) {
  int mutations = 1000;
  std::vector<std::vector<uint8_t>> inputs = Seeds();
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--mutations") == 0 && i + 1 < argc) {
      mutations = std::atoi(argv[++i]);
    } else {
      std::ifstream in(argv[i], std::ios::binary);
      inputs.emplace_back((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    }
  }
  std::mt19937_64 rng(12345);
  size_t runs = 0;
  for (const auto& input : inputs) {
    LLVMFuzzerTestOneInput(input.data(), input.size());
    ++runs;
    for (int m = 0; m < mutations; ++m) {
      std::vector<uint8_t> bytes = input;
      const int edits = 1 + static_cast<int>(rng() % 6);
      for (int e = 0; e < edits && !bytes.empty(); ++e) {
        const size_t at = rng() % bytes.size();
        switch (rng() % 4) {
          case 0: bytes[at] = static_cast<uint8_t>(rng()); break;
          case 1: bytes.resize(at); break;
          case 2:
            bytes.insert(bytes.begin() + static_cast<std::ptrdiff_t>(at),
                         static_cast<uint8_t>(rng()));
            break;
          default: bytes[at] ^= static_cast<uint8_t>(1u << (rng() % 8)); break;
        }
      }
      LLVMFuzzerTestOneInput(bytes.data(), bytes.size());
      ++runs;
    }
  }
  std::printf("%zu inputs ran without a crash\n", runs);
  return 0;
}
