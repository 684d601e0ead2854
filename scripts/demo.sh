#!/usr/bin/env bash
# The README's main job: installs what is needed, builds, starts the daemon with the
# default config (config/mocapd.toml) and replays a take synthesized from the built-in
# humanoid through it over tcp loopback -- medium corruption, real time, live status --
# then stops the daemon and prints the latency / accuracy table.
# Extra arguments go to `mocap-sim replay` (e.g. --seconds 60 --corrupt heavy --rate max).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cmake -S . -B build/release -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build/release -j "$(nproc)" --target mocapd mocap-sim
mkdir -p build/demo

build/release/runtime/mocapd run --config config/mocapd.toml &
daemon=$!
trap 'kill -TERM $daemon 2>/dev/null || true' EXIT
sleep 0.5
kill -0 $daemon 2>/dev/null || { echo "demo: the daemon did not start (see its error above)"; exit 1; }
echo "demo: watch it live in a browser on this machine: http://127.0.0.1:8480/"

status=0
build/release/sim/mocap-sim replay --humanoid mixed --seconds 20 --corrupt medium \
  --report build/demo/report.json --plot build/demo/latency.svg "$@" || status=$?

echo
echo "daemon's view: $(curl -s http://127.0.0.1:8480/health 2>/dev/null | tr -d '\n ' || echo unavailable)"
kill -TERM $daemon
wait $daemon || status=$?
trap - EXIT
echo "demo: report in build/demo/report.json, latency histogram in build/demo/latency.svg"
exit $status
