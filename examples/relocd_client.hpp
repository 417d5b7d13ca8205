// relocd_client.hpp: a header-only C++17 client for relocd (docs/protocol.md, schema 1).
//
// Receives the JSON hypotheses messages relocd publishes and asks it to relocalise. POSIX sockets and
// the standard library only; copy this file into your code base.
//
//   relocd::Subscriber hypotheses("udp:127.0.0.1:5454");
//   relocd::Control control("unix:/tmp/relocd-control");
//   auto trigger = control.relocalise("particle filter diverged");       // std::optional<uint64_t>
//   auto message = hypotheses.receive_answer(*trigger, 5000);           // std::optional<Message>
//   if (message && message->best()) use(message->best()->x, ...);
//
// Every call that can fail returns an empty optional and leaves the reason in `error()`.
// Publish JSON (`publish.encoding = "json"`, the default) for this client.
#pragma once

#include <arpa/inet.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <locale>
#include <optional>
#include <sstream>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace relocd {

inline constexpr int kSchemaVersion = 1;
inline constexpr std::size_t kMaxDatagram = 65536;

// ---------------------------------------------------------------------------------------------
// A small JSON reader: enough for relocd's messages and answers (objects, arrays, numbers, strings,
// true/false/null; \uXXXX escapes are kept as '?').
namespace json {

struct Value {
  enum class Kind { Null, Bool, Number, String, Array, Object } kind = Kind::Null;
  bool boolean = false;
  double number = 0.0;
  std::string string;
  std::vector<Value> array;
  std::vector<std::pair<std::string, Value>> object;  // in order; vector allows the incomplete Value

  // The member `key` of an object (the last one of that name), or nullptr.
  const Value* get(const std::string& key) const {
    if (kind != Kind::Object) return nullptr;
    for (auto member = object.rbegin(); member != object.rend(); ++member)
      if (member->first == key) return &member->second;
    return nullptr;
  }
};

class Parser {
 public:
  explicit Parser(std::string_view text) : text_(text) {}

  std::optional<Value> parse(std::string* error) {
    Value value;
    if (!parse_value(value, 0) || (skip_space(), position_ != text_.size())) {
      if (error) *error = "malformed JSON at byte " + std::to_string(position_);
      return std::nullopt;
    }
    return value;
  }

 private:
  static constexpr int kMaxDepth = 32;

  void skip_space() {
    while (position_ < text_.size() && (text_[position_] == ' ' || text_[position_] == '\t' ||
                                         text_[position_] == '\r' || text_[position_] == '\n'))
      ++position_;
  }
  bool consume(char c) {
    skip_space();
    if (position_ < text_.size() && text_[position_] == c) return ++position_, true;
    return false;
  }
  bool literal(std::string_view word) {
    if (text_.substr(position_, word.size()) != word) return false;
    position_ += word.size();
    return true;
  }
  bool parse_string(std::string& out) {
    if (!consume('"')) return false;
    while (position_ < text_.size()) {
      char c = text_[position_++];
      if (c == '"') return true;
      if (c != '\\') { out += c; continue; }
      if (position_ >= text_.size()) return false;
      char escaped = text_[position_++];
      switch (escaped) {
        case 'n': out += '\n'; break;
        case 't': out += '\t'; break;
        case 'r': out += '\r'; break;
        case 'b': out += '\b'; break;
        case 'f': out += '\f'; break;
        case 'u':
          if (position_ + 4 > text_.size()) return false;
          position_ += 4;
          out += '?';
          break;
        default: out += escaped;
      }
    }
    return false;
  }
  bool parse_value(Value& value, int depth) {
    if (depth > kMaxDepth) return false;
    skip_space();
    if (position_ >= text_.size()) return false;
    char c = text_[position_];
    if (c == '{') {
      ++position_;
      value.kind = Value::Kind::Object;
      if (consume('}')) return true;
      do {
        std::string key;
        Value member;
        if (!parse_string(key) || !consume(':') || !parse_value(member, depth + 1)) return false;
        value.object.emplace_back(std::move(key), std::move(member));
      } while (consume(','));
      return consume('}');
    }
    if (c == '[') {
      ++position_;
      value.kind = Value::Kind::Array;
      if (consume(']')) return true;
      do {
        value.array.emplace_back();
        if (!parse_value(value.array.back(), depth + 1)) return false;
      } while (consume(','));
      return consume(']');
    }
    if (c == '"') return value.kind = Value::Kind::String, parse_string(value.string);
    if (literal("true")) return value.kind = Value::Kind::Bool, value.boolean = true, true;
    if (literal("false")) return value.kind = Value::Kind::Bool, true;
    if (literal("null")) return true;
    // JSON numbers use '.', whatever the program's locale says.
    std::size_t end = position_;
    while (end < text_.size() && std::strchr("0123456789+-.eE", text_[end]) && text_[end] != '\0') ++end;
    std::istringstream number(std::string(text_.substr(position_, end - position_)));
    number.imbue(std::locale::classic());
    if (end == position_ || !(number >> value.number) || number.peek() != EOF) return false;
    position_ = end;
    value.kind = Value::Kind::Number;
    return true;
  }

  std::string_view text_;
  std::size_t position_ = 0;
};

}  // namespace json

// ---------------------------------------------------------------------------------------------
// The hypotheses message.

// One weighted full-field robot pose: metres, radians; sigma = standard deviations of x, y, theta.
struct Hypothesis {
  double x = 0, y = 0, theta = 0, weight = 0;
  std::array<double, 3> sigma{};
};

// One trigger a message answers: kind is penalty_return, fall, pick_up or request.
struct Trigger {
  std::uint64_t id = 0;
  std::string kind;
  std::string reason;
  double t = 0;
};

struct Message {
  std::uint64_t seq = 0;
  double published = 0;
  std::vector<Trigger> triggers;
  std::vector<Hypothesis> hypotheses;  // heaviest first; empty when relocalisation failed
  std::optional<std::string> failure;
  std::optional<std::string> prior;

  // The heaviest hypothesis, or nullptr when relocalisation failed.
  const Hypothesis* best() const { return hypotheses.empty() ? nullptr : &hypotheses.front(); }
  bool answers(std::uint64_t trigger) const {
    for (const auto& t : triggers)
      if (t.id == trigger) return true;
    return false;
  }
};

// A whole number in [0, 2^53] (what a JSON double holds exactly) as an integer.
inline std::optional<std::uint64_t> whole_number(const json::Value* value) {
  if (!value || value->kind != json::Value::Kind::Number) return std::nullopt;
  double number = value->number;
  if (!(number >= 0 && number <= 9007199254740992.0) || std::floor(number) != number) return std::nullopt;
  return static_cast<std::uint64_t>(number);
}

// Decodes one JSON datagram and checks what it reads: the schema, the triggers, finite hypotheses
// weighted in [0, 1] with sigma >= 0, and either hypotheses or a failure.
inline std::optional<Message> decode(std::string_view datagram, std::string* error) {
  auto fail = [error](const std::string& why) -> std::optional<Message> {
    if (error) *error = "not a relocd message: " + why;
    return std::nullopt;
  };
  auto root = json::Parser(datagram).parse(error);
  if (!root) return std::nullopt;
  auto number = [](const json::Value* value, double& out) {
    if (!value || value->kind != json::Value::Kind::Number || !std::isfinite(value->number)) return false;
    return out = value->number, true;
  };
  auto schema = whole_number(root->get("schema"));
  if (!schema) return fail("no schema");
  if (*schema != kSchemaVersion) return fail("schema " + std::to_string(*schema) + ", this client reads 1");
  Message message;
  auto seq = whole_number(root->get("seq"));
  if (!seq || !number(root->get("published"), message.published)) return fail("no seq");
  message.seq = *seq;
  const json::Value* triggers = root->get("triggers");
  if (!triggers || triggers->kind != json::Value::Kind::Array || triggers->array.empty()) return fail("no triggers");
  for (const auto& item : triggers->array) {
    Trigger trigger;
    auto id = whole_number(item.get("id"));
    const json::Value* kind = item.get("kind");
    if (!id || !kind || kind->kind != json::Value::Kind::String) return fail("bad trigger");
    trigger.id = *id;
    trigger.kind = kind->string;
    if (const json::Value* reason = item.get("reason"); reason && reason->kind == json::Value::Kind::String)
      trigger.reason = reason->string;
    number(item.get("t"), trigger.t);
    message.triggers.push_back(std::move(trigger));
  }
  const json::Value* hypotheses = root->get("hypotheses");
  if (!hypotheses || hypotheses->kind != json::Value::Kind::Array) return fail("no hypotheses");
  for (const auto& item : hypotheses->array) {
    Hypothesis h;
    const json::Value* sigma = item.get("sigma");
    bool ok = number(item.get("x"), h.x) && number(item.get("y"), h.y) && number(item.get("theta"), h.theta) &&
              number(item.get("weight"), h.weight) && sigma && sigma->kind == json::Value::Kind::Array &&
              sigma->array.size() == 3;
    for (std::size_t i = 0; ok && i < 3; ++i) ok = number(&sigma->array[i], h.sigma[i]) && h.sigma[i] >= 0;
    if (!ok || h.weight < 0 || h.weight > 1) return fail("bad hypothesis");
    message.hypotheses.push_back(h);
  }
  if (const json::Value* failure = root->get("failure"); failure && failure->kind == json::Value::Kind::String)
    message.failure = failure->string;
  if (const json::Value* prior = root->get("prior"); prior && prior->kind == json::Value::Kind::String)
    message.prior = prior->string;
  if (message.hypotheses.empty() != message.failure.has_value())
    return fail("a message has either hypotheses or a failure");
  return message;
}

// ---------------------------------------------------------------------------------------------
// Sockets: addresses are "udp:IP:PORT" (numeric, IPv4) or "unix:PATH", as in relocd's config.

namespace detail {

struct Address {
  sockaddr_storage storage{};
  socklen_t length = 0;
  int family = AF_UNSPEC;
};

inline std::optional<Address> parse_address(const std::string& text, std::string* error) {
  Address address;
  if (text.rfind("unix:", 0) == 0 && text.size() > 5) {
    auto* un = reinterpret_cast<sockaddr_un*>(&address.storage);
    std::string path = text.substr(5);
    if (path.size() >= sizeof(un->sun_path)) {
      if (error) *error = "socket path too long: " + path;
      return std::nullopt;
    }
    un->sun_family = AF_UNIX;
    std::memcpy(un->sun_path, path.c_str(), path.size() + 1);
    address.length = socklen_t(sizeof(sockaddr_un));
    address.family = AF_UNIX;
    return address;
  }
  if (text.rfind("udp:", 0) == 0) {
    auto colon = text.rfind(':');
    auto* in = reinterpret_cast<sockaddr_in*>(&address.storage);
    in->sin_family = AF_INET;
    std::string host = text.substr(4, colon - 4);
    char* end = nullptr;
    long port = std::strtol(text.c_str() + colon + 1, &end, 10);
    if (colon > 4 && *end == '\0' && port > 0 && port < 65536 && inet_pton(AF_INET, host.c_str(), &in->sin_addr) == 1) {
      in->sin_port = htons(static_cast<std::uint16_t>(port));
      address.length = socklen_t(sizeof(sockaddr_in));
      address.family = AF_INET;
      return address;
    }
  }
  if (error) *error = "'" + text + "': expected udp:IPv4:PORT or unix:PATH";
  return std::nullopt;
}

// A datagram socket that closes itself and removes the Unix socket file it bound.
class Socket {
 public:
  Socket() = default;
  Socket(const Socket&) = delete;
  Socket& operator=(const Socket&) = delete;
  ~Socket() {
    if (fd_ >= 0) ::close(fd_);
    if (!bound_path_.empty()) ::unlink(bound_path_.c_str());
  }

  bool open(int family, std::string* error) {
    fd_ = ::socket(family, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (fd_ < 0 && error) *error = std::string("socket: ") + std::strerror(errno);
    return fd_ >= 0;
  }
  bool bind(const Address& address, std::string* error) {
    if (address.family == AF_UNIX) {
      const char* path = reinterpret_cast<const sockaddr_un*>(&address.storage)->sun_path;
      if (!remove_stale_socket(address, error)) return false;
      bound_path_ = path;
    }
    if (::bind(fd_, reinterpret_cast<const sockaddr*>(&address.storage), address.length) == 0) return true;
    if (error) *error = std::string("bind: ") + std::strerror(errno);
    bound_path_.clear();
    return false;
  }
  bool send_to(std::string_view bytes, const Address& to, std::string* error) const {
    if (::sendto(fd_, bytes.data(), bytes.size(), 0, reinterpret_cast<const sockaddr*>(&to.storage), to.length) ==
        static_cast<ssize_t>(bytes.size()))
      return true;
    if (error) *error = std::string("sendto: ") + std::strerror(errno);
    return false;
  }
  // One datagram within `timeout_ms` (negative: wait for ever).
  std::optional<std::string> receive(int timeout_ms, std::string* error) const {
    pollfd ready{fd_, POLLIN, 0};
    int polled = ::poll(&ready, 1, timeout_ms);
    if (polled <= 0) {
      if (error) *error = polled == 0 ? "timed out" : std::string("poll: ") + std::strerror(errno);
      return std::nullopt;
    }
    std::string buffer(kMaxDatagram, '\0');
    ssize_t length = ::recv(fd_, buffer.data(), buffer.size(), 0);
    if (length < 0) {
      if (error) *error = std::string("recv: ") + std::strerror(errno);
      return std::nullopt;
    }
    buffer.resize(static_cast<std::size_t>(length));
    return buffer;
  }
  // Discards datagrams already waiting (answers to requests that timed out).
  void drain() const {
    char byte;
    while (::recv(fd_, &byte, 1, MSG_DONTWAIT) >= 0) {
    }
  }
  int fd() const { return fd_; }

 private:
  // Removes a socket file left behind by a process that died; refuses a live socket or another file.
  static bool remove_stale_socket(const Address& address, std::string* error) {
    const char* path = reinterpret_cast<const sockaddr_un*>(&address.storage)->sun_path;
    struct stat status {};
    if (::lstat(path, &status) != 0) return true;  // nothing there
    bool live = false;
    if (S_ISSOCK(status.st_mode)) {
      int probe = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
      live = probe >= 0 && ::connect(probe, reinterpret_cast<const sockaddr*>(&address.storage), address.length) == 0;
      if (probe >= 0) ::close(probe);
      if (!live && ::unlink(path) == 0) return true;
      if (!live) {
        if (error) *error = std::string("unlink: ") + std::strerror(errno);
        return false;
      }
    }
    if (error) *error = std::string(path) + (live ? " is in use by another process" : " exists and is not a socket");
    return false;
  }

  int fd_ = -1;
  std::string bound_path_;
};

}  // namespace detail

// Receives the messages relocd publishes to one of its `publish.targets`.
class Subscriber {
 public:
  explicit Subscriber(const std::string& address) {
    auto parsed = detail::parse_address(address, &error_);
    ok_ = parsed && socket_.open(parsed->family, &error_) && socket_.bind(*parsed, &error_);
  }
  bool ok() const { return ok_; }
  const std::string& error() const { return error_; }
  // The file descriptor, to poll it in your own loop.
  int fd() const { return socket_.fd(); }

  // The next message within `timeout_ms` (0: only if one is waiting; negative: wait for ever).
  std::optional<Message> receive(int timeout_ms) {
    auto datagram = socket_.receive(timeout_ms, &error_);
    return datagram ? decode(*datagram, &error_) : std::nullopt;
  }

  // The message answering trigger `trigger`, skipping others, within `timeout_ms`.
  std::optional<Message> receive_answer(std::uint64_t trigger, int timeout_ms) {
    auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
    for (;;) {
      auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
      if (left.count() <= 0) {
        error_ = "no answer to trigger " + std::to_string(trigger) + " in time";
        return std::nullopt;
      }
      auto datagram = socket_.receive(static_cast<int>(left.count()), &error_);
      if (!datagram) return std::nullopt;
      auto message = decode(*datagram, &error_);
      if (message && message->answers(trigger)) return message;
    }
  }

 private:
  detail::Socket socket_;
  std::string error_;
  bool ok_ = false;
};

// A pose estimate for the belief stream or a request's prior: metres, radians, seconds (sigma > 0).
struct PoseInput {
  double x = 0.0, y = 0.0, theta = 0.0;
  struct Sigma {
    double x = 0.5, y = 0.5, theta = 0.3;
  } sigma;
  std::optional<double> age_s;
};

// The robot's own ball (distance m, bearing rad) and the team's (x, y, sigma m; teammates agreeing).
struct BallInput {
  double own_distance = 0.0, own_bearing = 0.0;
  double team_x = 0.0, team_y = 0.0, team_sigma = 0.3;
  int teammates = 1;
};

// Context of a relocalise request that tells the symmetric twins apart (docs/protocol.md).
struct Context {
  std::optional<PoseInput> prior;
  std::optional<bool> own_half;
  std::optional<BallInput> ball;
};

namespace detail {
inline std::string number(double value) {
  std::ostringstream text;
  text.imbue(std::locale::classic());
  text.precision(17);
  text << value;
  return text.str();
}

inline std::string pose_json(const PoseInput& pose) {
  std::string text = "{\"x\": " + number(pose.x) + ", \"y\": " + number(pose.y) +
                     ", \"theta\": " + number(pose.theta) + ", \"sigma\": {\"x\": " +
                     number(pose.sigma.x) + ", \"y\": " + number(pose.sigma.y) +
                     ", \"theta\": " + number(pose.sigma.theta) + "}";
  if (pose.age_s) text += ", \"age_s\": " + number(*pose.age_s);
  return text + "}";
}
}  // namespace detail

// Asks relocd (its `control` address) to relocalise.
class Control {
 public:
  explicit Control(const std::string& daemon, int timeout_ms = 2000) : timeout_ms_(timeout_ms) {
    auto parsed = detail::parse_address(daemon, &error_);
    if (!parsed || !socket_.open(parsed->family, &error_)) return;
    daemon_ = *parsed;
    // relocd answers to the sender's address: bind our own (a temporary path for Unix sockets).
    detail::Address own;
    if (parsed->family == AF_UNIX) {
      auto path = "unix:/tmp/relocd-client-" + std::to_string(::getpid()) + "-" +
                  std::to_string(reinterpret_cast<std::uintptr_t>(this));
      auto unix_address = detail::parse_address(path, &error_);
      if (!unix_address) return;
      own = *unix_address;
    } else {
      reinterpret_cast<sockaddr_in*>(&own.storage)->sin_family = AF_INET;  // any address, any port
      own.length = socklen_t(sizeof(sockaddr_in));
      own.family = AF_INET;
    }
    ok_ = socket_.bind(own, &error_);
  }
  bool ok() const { return ok_; }
  const std::string& error() const { return error_; }

  // Asks for a relocalisation; the trigger id the published message will list (the request's own, or
  // the waiting one it joined when relocd had too many waiting: "coalesced_into").
  std::optional<std::uint64_t> relocalise(const std::string& reason = "") {
    return relocalise(reason, Context{}, nullptr);
  }

  // The same with context; what relocd could not use of it is left out and, when `context_errors` is
  // given, named there (the relocalisation runs anyway).
  std::optional<std::uint64_t> relocalise(const std::string& reason, const Context& context,
                                          std::vector<std::string>* context_errors) {
    std::vector<std::string> members;
    if (!reason.empty()) {
      std::string text = "\"reason\": \"";
      for (char c : reason) {
        if (c == '"' || c == '\\') text += '\\';
        if (static_cast<unsigned char>(c) >= 0x20) text += c;
      }
      members.push_back(text + "\"");
    }
    if (context.prior) members.push_back("\"prior\": {\"pose\": " + detail::pose_json(*context.prior) + "}");
    if (context.own_half) members.push_back(std::string("\"own_half\": ") + (*context.own_half ? "true" : "false"));
    if (context.ball) {
      const BallInput& ball = *context.ball;
      members.push_back("\"ball\": {\"own\": {\"distance\": " + detail::number(ball.own_distance) +
                        ", \"bearing\": " + detail::number(ball.own_bearing) + "}, \"team\": {\"x\": " +
                        detail::number(ball.team_x) + ", \"y\": " + detail::number(ball.team_y) +
                        ", \"sigma\": " + detail::number(ball.team_sigma) +
                        ", \"teammates\": " + std::to_string(ball.teammates) + "}}");
    }
    std::string request = "{\"relocalise\": {";
    for (std::size_t i = 0; i < members.size(); ++i) request += (i ? ", " : "") + members[i];
    request += "}}";
    auto answer = ask(request);
    if (!answer) return std::nullopt;
    const json::Value* accepted = answer->get("accepted");
    auto trigger = whole_number(accepted ? accepted->get("coalesced_into") : nullptr);
    if (!trigger) trigger = whole_number(accepted ? accepted->get("trigger") : nullptr);
    if (!trigger) error_ = "unexpected answer from relocd";
    const json::Value* errors = accepted ? accepted->get("context_errors") : nullptr;
    if (context_errors) {
      context_errors->clear();
      if (errors)
        for (const json::Value& error : errors->array) context_errors->push_back(error.string);
    }
    return trigger;
  }

  // Sends the team's current pose estimate (the belief stream, 1-10 Hz): the last one from before a
  // fall or pick-up becomes that relocalisation's prior. relocd does not answer.
  bool belief(const PoseInput& pose) {
    if (!ok_) return false;
    return socket_.send_to("{\"belief\": " + detail::pose_json(pose) + "}", daemon_, &error_);
  }

 private:
  std::optional<json::Value> ask(const std::string& request) {
    if (!ok_) return std::nullopt;
    socket_.drain();  // an answer that came after an earlier request timed out is not this one's
    if (!socket_.send_to(request, daemon_, &error_)) return std::nullopt;
    auto datagram = socket_.receive(timeout_ms_, &error_);
    if (!datagram) return std::nullopt;
    auto answer = json::Parser(*datagram).parse(&error_);
    if (answer) {
      if (const json::Value* refused = answer->get("error")) {
        error_ = "relocd refused the request: " + refused->string;
        return std::nullopt;
      }
      if (answer->kind != json::Value::Kind::Object) {
        error_ = "unexpected answer from relocd";
        return std::nullopt;
      }
    }
    return answer;
  }

  detail::Socket socket_;
  detail::Address daemon_;
  std::string error_;
  int timeout_ms_;
  bool ok_ = false;
};

}  // namespace relocd
