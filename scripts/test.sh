#!/usr/bin/env bash
# The README's test command: installs what is needed, builds, and runs every test --
# once in an optimised build (GCC), once more (unit tests) under AddressSanitizer and
# UndefinedBehaviorSanitizer (Clang).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
jobs=$(nproc)

echo "== release build"
cmake -S . -B build/release -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build build/release -j "$jobs"
ctest --test-dir build/release --output-on-failure -j "$jobs"

echo "== AddressSanitizer + UndefinedBehaviorSanitizer build"
# Clang, because it compiles this instrumented build in well under half GCC's time (the
# release build above stays GCC's); line tables (-g1) are all a sanitizer report needs.
# -O2, not -O1: Eigen's code relies on inlining, and the sanitized tests took a third
# longer at -O1 for about the same build time (7.5 vs 8.7 min). UndefinedBehaviorSanitizer
# leaves Eigen's own functions alone (cmake/ubsan_ignore.txt): its checks there kept them
# out of line, and the sanitized tests took 7.7 min instead of under 2.
cmake -S . -B build/asan -G Ninja -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=Debug \
  -DCMAKE_CXX_FLAGS_DEBUG="-O2 -g1" -DMOCAPD_SANITIZE=ON -DMOCAPD_BUILD_BENCHMARKS=OFF
# Only what the unit tests run (the daemon's and simulator's executables serve the process
# tests, which this build does not run).
cmake --build build/asan -j "$jobs" --target unit_tests
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir build/asan --output-on-failure -j "$jobs" -L unit
