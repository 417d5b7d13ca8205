// Prints relocd's best hypothesis: every message it publishes, or (with --request) the answer to one
// relocalisation request. Build: g++ -std=c++17 -O2 -o relocd_print_best relocd_print_best.cpp
//
//   relocd_print_best [--listen udp:127.0.0.1:5454] [--control unix:/tmp/relocd-control]
//                     [--request [REASON]] [--timeout-ms 10000]
#include <cstdio>
#include <cstring>
#include <string>

#include "relocd_client.hpp"

namespace {

void print(const relocd::Message& message) {
  std::printf("seq %llu triggers [", static_cast<unsigned long long>(message.seq));
  for (std::size_t i = 0; i < message.triggers.size(); ++i)
    std::printf("%s%llu %s", i ? ", " : "", static_cast<unsigned long long>(message.triggers[i].id),
                message.triggers[i].kind.c_str());
  if (const relocd::Hypothesis* best = message.best())
    std::printf("]: best x=%.3f m y=%.3f m theta=%.3f rad weight=%.3f (%zu hypotheses)\n", best->x, best->y,
                best->theta, best->weight, message.hypotheses.size());
  else
    std::printf("]: failed: %s\n", message.failure.value_or("").c_str());
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  std::string listen = "udp:127.0.0.1:5454", control = "unix:/tmp/relocd-control", reason;
  bool request = false;
  int timeout_ms = 10000;
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    bool has_value = i + 1 < argc && std::strncmp(argv[i + 1], "--", 2) != 0;
    if (arg == "--listen" && has_value) listen = argv[++i];
    else if (arg == "--control" && has_value) control = argv[++i];
    else if (arg == "--timeout-ms" && has_value) timeout_ms = std::atoi(argv[++i]);
    else if (arg == "--request") {
      request = true;
      if (has_value) reason = argv[++i];
    } else {
      std::fprintf(stderr, "usage: %s [--listen ADDR] [--control ADDR] [--request [REASON]] [--timeout-ms MS]\n",
                   argv[0]);
      return 2;
    }
  }

  relocd::Subscriber hypotheses(listen);
  if (!hypotheses.ok()) return std::fprintf(stderr, "error: %s: %s\n", listen.c_str(), hypotheses.error().c_str()), 1;
  if (!request) {
    for (;;) {
      if (auto message = hypotheses.receive(-1)) print(*message);
      else std::fprintf(stderr, "skipped: %s\n", hypotheses.error().c_str());
    }
  }
  relocd::Control daemon(control);
  auto trigger = daemon.ok() ? daemon.relocalise(reason) : std::nullopt;
  if (!trigger) return std::fprintf(stderr, "error: %s: %s\n", control.c_str(), daemon.error().c_str()), 1;
  std::fprintf(stderr, "accepted as trigger %llu\n", static_cast<unsigned long long>(*trigger));
  auto message = hypotheses.receive_answer(*trigger, timeout_ms);
  if (!message) return std::fprintf(stderr, "error: %s\n", hypotheses.error().c_str()), 1;
  print(*message);
  return message->best() ? 0 : 1;
}
