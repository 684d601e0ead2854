#!/usr/bin/env bash
# Installs every Debian 12 package mocapd needs to build, test, fuzz and benchmark.
# Idempotent; needs root (or sudo). Nothing else is downloaded.
set -euo pipefail
packages=(
  build-essential cmake ninja-build g++ pkg-config curl
  libeigen3-dev libzmq3-dev cppzmq-dev libboost-dev
  libspdlog-dev libfmt-dev libcli11-dev libtomlplusplus-dev nlohmann-json3-dev prometheus-cpp-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  clang libclang-rt-14-dev clang-format
  python3 python3-zmq python3-prometheus-client
  libjs-three chromium python3-websocket python3-pil
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#packages[@]} packages already installed"
  exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
echo "setup: installing ${missing[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
