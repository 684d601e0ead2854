#!/usr/bin/env bash
# The README's main job: installs what is needed, builds, and runs the demo -- a take
# synthesized from the built-in humanoid, solved frame by frame, with accuracy and speed.
# Extra arguments go to `mocapd demo` (see `mocapd demo --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cmake -S . -B build/release -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build/release -j "$(nproc)" --target mocapd mocap-sim
exec build/release/runtime/mocapd demo "$@"
