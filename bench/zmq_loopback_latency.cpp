// The transport floor under the daemon's latency figures: a message of a marker frame's
// size goes PUB -> SUB to an echo thread and back PUB -> SUB over tcp loopback (two
// ZeroMQ hops, as a frame and its skeleton make), paced at 120 Hz like a capture feed
// so the idle wake-ups are included. Prints the round-trip p50/p90/p99/max.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>
#include <zmq.hpp>

#include "filters/pose_error.hpp"

int main(int argc, char** argv) {
  const int count = argc > 1 ? std::atoi(argv[1]) : 2400;
  const double rate_hz = argc > 2 ? std::atof(argv[2]) : 120.0;
  if (count < 1 || !(rate_hz > 0) || !std::isfinite(rate_hz)) {
    std::fprintf(stderr, "Usage: zmq_loopback_latency [MESSAGES >= 1] [RATE_HZ > 0] [spin]\n");
    return 2;
  }
  // "spin": both ends poll without blocking, as the daemon's data plane does with
  // input.busy_poll; otherwise they block in recv like a default consumer.
  const bool spin = argc > 3 && std::string(argv[3]) == "spin";
  auto receive = [spin](zmq::socket_t& socket, zmq::message_t& m) {
    if (!spin) return (void)socket.recv(m);
    while (!socket.recv(m, zmq::recv_flags::dontwait)) {
    }
  };
  zmq::context_t a_context, b_context;
  zmq::socket_t a_out(a_context, zmq::socket_type::pub), a_in(a_context, zmq::socket_type::sub);
  zmq::socket_t b_out(b_context, zmq::socket_type::pub), b_in(b_context, zmq::socket_type::sub);
  a_out.bind("tcp://127.0.0.1:47391");
  b_out.bind("tcp://127.0.0.1:47392");
  b_in.set(zmq::sockopt::subscribe, "");
  a_in.set(zmq::sockopt::subscribe, "");
  b_in.connect("tcp://127.0.0.1:47391");
  a_in.connect("tcp://127.0.0.1:47392");
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  std::thread echo([&] {
    zmq::message_t m;
    for (int i = 0; i < count; ++i) {
      receive(b_in, m);
      b_out.send(m, zmq::send_flags::none);
    }
  });
  std::vector<uint8_t> frame(800, 1);  // ~ a 59-marker frame
  std::vector<double> rtt_us;
  const auto start = std::chrono::steady_clock::now();
  zmq::message_t reply;
  for (int i = 0; i < count; ++i) {
    std::this_thread::sleep_until(
        start + std::chrono::nanoseconds(static_cast<int64_t>(i * 1e9 / rate_hz)));
    const auto t0 = std::chrono::steady_clock::now();
    a_out.send(zmq::buffer(frame), zmq::send_flags::none);
    receive(a_in, reply);
    rtt_us.push_back(
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
  }
  echo.join();
  std::printf(
      "zmq tcp loopback round trip (2 hops, %s), %d messages at %.0f Hz: p50 %.1f us, p90 %.1f us, "
      "p99 %.1f us, max %.1f us\n",
      spin ? "spinning" : "blocking", count, rate_hz, mocapd::Quantile(rtt_us, 0.5),
      mocapd::Quantile(rtt_us, 0.9), mocapd::Quantile(rtt_us, 0.99), mocapd::Quantile(rtt_us, 1.0));
  return 0;
}
