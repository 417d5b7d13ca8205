// Forwards YUYV camera frames to relocd and asks it to relocalise: what a team's process does when it
// owns the top camera (relocd's source `frames:unix:PATH`, docs/protocol.md "Forwarded frames").
// Build: g++ -std=c++17 -O2 -o relocd_send_frame relocd_send_frame.cpp
//
//   relocd_send_frame FRAME.yuyv WIDTH HEIGHT [FRAME_SOCKET] [CONTROL] [SECONDS]
//
// Sends the frame at 30 Hz for SECONDS (default 2; a camera loop), asks for a relocalisation after the
// first frame, and prints the accepted trigger id on stdout.
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>
#include <vector>

#include "relocd_client.hpp"

namespace {

// docs/protocol.md: 48 bytes, little-endian (the Nao is x86), no padding.
struct RelocdFrameHeader {
  char magic[4];
  std::uint16_t version, format;
  std::uint32_t width, height, payload_bytes, flags;
  double timestamp;
  float camera_height, camera_pitch, camera_roll, head_yaw;
};
static_assert(sizeof(RelocdFrameHeader) == 48, "no padding");

int connect_relocd(const char* path) {
  int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  std::strncpy(address.sun_path, path, sizeof(address.sun_path) - 1);
  if (fd >= 0 && ::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof(address)) == 0) return fd;
  if (fd >= 0) ::close(fd);
  return -1;
}

// Writes all of `bytes`; false once relocd has gone (no SIGPIPE).
bool send_all(int fd, const void* bytes, std::size_t length) {
  const char* data = static_cast<const char*>(bytes);
  while (length > 0) {
    ssize_t sent = ::send(fd, data, length, MSG_NOSIGNAL);
    if (sent <= 0) return false;
    data += sent;
    length -= static_cast<std::size_t>(sent);
  }
  return true;
}

bool send_frame(int fd, const std::vector<char>& yuyv, std::uint32_t width, std::uint32_t height) {
  double now = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  // flags 0: no camera pose; set bit 0 and fill in the pose from your kinematics when you have it.
  RelocdFrameHeader header{{'R', 'L', 'F', '1'}, 1, 1, width, height, width * height * 2, 0, now,
                           0.0f, 0.0f, 0.0f, 0.0f};
  return send_all(fd, &header, sizeof(header)) && send_all(fd, yuyv.data(), yuyv.size());
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: %s FRAME.yuyv WIDTH HEIGHT [FRAME_SOCKET] [CONTROL] [SECONDS]\n", argv[0]);
    return 2;
  }
  std::ifstream file(argv[1], std::ios::binary);
  std::vector<char> yuyv((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  auto width = static_cast<std::uint32_t>(std::strtoul(argv[2], nullptr, 10));
  auto height = static_cast<std::uint32_t>(std::strtoul(argv[3], nullptr, 10));
  const char* frames_path = argc > 4 ? argv[4] : "/tmp/relocd-frames";
  std::string control_address = argc > 5 ? argv[5] : "unix:/tmp/relocd-control";
  double seconds = argc > 6 ? std::atof(argv[6]) : 2.0;
  if (!file || yuyv.size() != std::size_t(width) * height * 2) {
    std::fprintf(stderr, "error: %s is not a %ux%u YUYV frame (%zu bytes)\n", argv[1], width, height, yuyv.size());
    return 1;
  }

  int frames = connect_relocd(frames_path);
  if (frames < 0) return std::fprintf(stderr, "error: cannot connect to %s\n", frames_path), 1;
  relocd::Control control(control_address);
  bool asked = false;
  auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    if (!send_frame(frames, yuyv, width, height)) {
      std::fprintf(stderr, "error: relocd closed the frame socket\n");
      break;
    }
    if (!asked) {
      asked = true;
      auto trigger = control.ok() ? control.relocalise("forwarded frame example") : std::nullopt;
      if (!trigger) return ::close(frames), std::fprintf(stderr, "error: %s\n", control.error().c_str()), 1;
      std::printf("%llu\n", static_cast<unsigned long long>(*trigger));
      std::fflush(stdout);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(33));
  }
  ::close(frames);
  return asked ? 0 : 1;
}
