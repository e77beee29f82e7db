// drone.cpp - a CentMesh Mission Control Protocol (MCP) drone application in C++17.
//
// Written from the protocol's documents only (docs/spec.md, spec/mcp.yaml, docs/guide/drone.md,
// docs/guide/vehicle.md). Threads:
//   receive  blocking recvfrom() on the MCP socket: validates, ACKs (on receipt, by default),
//            discards duplicates (an unordered_map src -> last delivered seq), queues commands;
//   worker   waits for the autopilot to be ready (GPS fix), sends Mission_Ready (blocking until
//            ACKed), then carries out the queued commands over MAVLink;
//   timer    retransmits unACKed unicast messages every --rto (condition_variable::wait_until
//            on steady_clock);
//   mavlink  the autopilot link's reader, plus a 1 Hz HEARTBEAT sender;
//   main     waits for SIGINT/SIGTERM (sigwait) or the end of the mission.
//
// Usage: drone --id N --listen [HOST:]PORT --manager HOST:PORT [--mavlink URL] [--rto S]
//              [--retries N] [--broadcast-id N] [--linger S] [--takeoff-alt M]
//              [--ack-seq next|zero|echo] [--ready-payload none|id] [--reply-to-source] [--send-socket]
//              [--first-seq N] [--pending-limit S] [--missions N] [-v]
//   URL: tcp:HOST:PORT | udp:HOST:PORT | udpin:HOST:PORT (listen) | udpout:HOST:PORT (send)

#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <optional>
#include <queue>
#include <random>
#include <stdexcept>
#include <string>
#include <thread>
#include <unordered_map>
#include <vector>

#include "ardupilotmega/mavlink.h"

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

// ---------------------------------------------------------------- logging

namespace {
std::mutex g_log_mutex;
const Clock::time_point g_start = Clock::now();
bool g_verbose = false;

void log(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
void log(const char* fmt, ...) {
    std::lock_guard<std::mutex> lock(g_log_mutex);
    double t = std::chrono::duration<double>(Clock::now() - g_start).count();
    std::fprintf(stderr, "[drone %8.3f] ", t);
    va_list ap;
    va_start(ap, fmt);
    std::vfprintf(stderr, fmt, ap);
    va_end(ap);
    std::fputc('\n', stderr);
    std::fflush(stderr);
}
}  // namespace

// ---------------------------------------------------------------- MCP wire format

namespace mcp {

constexpr uint16_t kManagerId = 0;
constexpr size_t kHeaderSize = 17;
constexpr size_t kItemSize = 37;
constexpr size_t kMaxDatagram = 65507;
constexpr char kPreambleText[7] = {'N', 'C', 'S', 'U', '-', 'C', 'M'};

enum class Action : uint16_t {
    MissionReady = 0,
    StartMission = 1,
    EndMission = 2,
    WpList = 3,
    WpOn = 4,
    WpOff = 5,
    ObstaclesList = 6,
    Ack = 7,
    MavPassthrough = 8,
};

const char* name(Action a) {
    switch (a) {
        case Action::MissionReady: return "Mission_Ready";
        case Action::StartMission: return "Start_Mission";
        case Action::EndMission: return "End_Mission";
        case Action::WpList: return "WP_List";
        case Action::WpOn: return "WP_On";
        case Action::WpOff: return "WP_Off";
        case Action::ObstaclesList: return "Obstacles_List";
        case Action::Ack: return "ACK";
        case Action::MavPassthrough: return "Mav_Passthrough";
    }
    return "?";
}

#pragma pack(push, 1)
struct Header {              // "!7s2B4H", 17 bytes
    char preamble[7];        // "NCSU-CM"
    uint8_t preamble_b7;     // 1
    uint8_t preamble_b8;     // 1
    uint16_t dst;            // network byte order on the wire
    uint16_t src;
    uint16_t seq;
    uint16_t action;
};

struct MissionItem {         // "<fffffffHHBBBBB", 37 bytes: MAVLink v1 MISSION_ITEM's payload
    float param1, param2, param3, param4;
    float x, y, z;           // latitude, longitude, altitude (E-2)
    uint16_t seq;
    uint16_t command;
    uint8_t target_system, target_component, frame, current, autocontinue;
};
#pragma pack(pop)
static_assert(sizeof(Header) == kHeaderSize, "MCP header is 17 bytes");
static_assert(sizeof(MissionItem) == kItemSize, "a mission item is 37 bytes");
// the mission items are little-endian on the wire and memcpy'd: this program assumes a
// little-endian host, as MAVLink's C library does by default
static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "little-endian host assumed");

struct Message {
    uint16_t dst = 0, src = 0, seq = 0;
    Action action = Action::Ack;
    std::vector<uint8_t> payload;
};

std::vector<uint8_t> encode(uint16_t dst, uint16_t src, uint16_t seq, Action action,
                            const std::vector<uint8_t>& payload) {
    Header h;
    std::memcpy(h.preamble, kPreambleText, sizeof h.preamble);
    h.preamble_b7 = 1;
    h.preamble_b8 = 1;
    h.dst = htons(dst);
    h.src = htons(src);
    h.seq = htons(seq);
    h.action = htons(static_cast<uint16_t>(action));
    std::vector<uint8_t> out(kHeaderSize + payload.size());
    std::memcpy(out.data(), &h, kHeaderSize);
    if (!payload.empty()) std::memcpy(out.data() + kHeaderSize, payload.data(), payload.size());
    return out;
}

// One complete MAVLink v1 or v2 frame, valid checksum, nothing after it (MCP-PAY-6).
bool is_one_mavlink_frame(const uint8_t* p, size_t n) {
    mavlink_message_t rx{}, msg{};
    mavlink_status_t st{}, out{};
    for (size_t i = 0; i < n; ++i) {
        uint8_t r = mavlink_frame_char_buffer(&rx, &st, p[i], &msg, &out);
        if (r == MAVLINK_FRAMING_OK) return i + 1 == n;
        if (r == MAVLINK_FRAMING_BAD_CRC || r == MAVLINK_FRAMING_BAD_SIGNATURE) return false;
        if (i == 0 && st.parse_state != MAVLINK_PARSE_STATE_GOT_STX) return false;
    }
    return false;
}

// The payload fits its action code (D-4); anything else is malformed: no ACK, no delivery.
bool payload_fits(const Message& m) {
    const size_t n = m.payload.size();
    switch (m.action) {
        case Action::MissionReady:   // empty, or the sender's ID (D-3)
            return n == 0 || (n == 2 && ((m.payload[0] << 8) | m.payload[1]) == m.src);
        case Action::StartMission:
        case Action::EndMission:
        case Action::WpOff:
            return n == 0;
        case Action::WpList:
        case Action::ObstaclesList: {
            if (n < 2) return false;
            size_t count = (m.payload[0] << 8) | m.payload[1];
            return n == 2 + kItemSize * count;
        }
        case Action::WpOn:
            return n == kItemSize;
        case Action::Ack:
            return n == 2;
        case Action::MavPassthrough:
            return is_one_mavlink_frame(m.payload.data(), n);
    }
    return false;
}

// Decodes a datagram; nullopt when it is not an MCP message (short, wrong preamble, action > 8).
std::optional<Message> decode(const uint8_t* p, size_t n) {
    if (n < kHeaderSize) return std::nullopt;
    Header h;
    std::memcpy(&h, p, kHeaderSize);
    if (std::memcmp(h.preamble, kPreambleText, sizeof h.preamble) != 0 || h.preamble_b7 != 1 ||
        h.preamble_b8 != 1)
        return std::nullopt;
    uint16_t action = ntohs(h.action);
    if (action > static_cast<uint16_t>(Action::MavPassthrough)) return std::nullopt;
    Message m;
    m.dst = ntohs(h.dst);
    m.src = ntohs(h.src);
    m.seq = ntohs(h.seq);
    m.action = static_cast<Action>(action);
    m.payload.assign(p + kHeaderSize, p + n);
    return m;
}

std::vector<MissionItem> items(const Message& m) {
    std::vector<MissionItem> out;
    if (m.action == Action::WpOn) {
        MissionItem it;
        std::memcpy(&it, m.payload.data(), kItemSize);
        out.push_back(it);
    } else {
        size_t count = (m.payload[0] << 8) | m.payload[1];
        for (size_t i = 0; i < count; ++i) {
            MissionItem it;
            std::memcpy(&it, m.payload.data() + 2 + i * kItemSize, kItemSize);
            out.push_back(it);
        }
    }
    return out;
}

}  // namespace mcp

// ---------------------------------------------------------------- options

struct Options {
    uint16_t id = 1;
    std::string listen_host = "0.0.0.0";
    uint16_t listen_port = 7890;
    std::string manager_host = "127.255.255.255";
    uint16_t manager_port = 7889;
    std::string mavlink;  // empty: no autopilot
    double rto = 5.0;
    unsigned retries = 1000;
    uint16_t broadcast_id = 0xFFFF;
    double linger = -1;   // after End_Mission; default 2 x rto, at least 1 s
    float takeoff_alt = 10;  // metres above home
    // readings the documents leave open (README): the ACK's own seq, Mission_Ready's payload,
    // where an ACK goes
    enum class AckSeq { Next, Zero, Echo } ack_seq = AckSeq::Next;
    bool ready_with_id = false;
    bool reply_to_source = false;
    bool send_socket = false;  // send from a socket of its own (an ephemeral port)
    unsigned missions = 1;  // missions to fly, each announced by a Mission_Ready; 0: no end
    int pending_limit = 120;  // s: the longest End_Mission waits for the mission to end
    std::optional<uint16_t> first_seq;  // default: random ("an arbitrary initial sequence number")
};

[[noreturn]] void usage(const char* prog, const std::string& why) {
    if (!why.empty()) std::fprintf(stderr, "%s: %s\n", prog, why.c_str());
    std::fprintf(stderr,
                 "usage: %s --id N [--listen [HOST:]PORT] [--manager HOST:PORT] [--mavlink URL]\n"
                 "          [--rto SECONDS] [--retries N] [--broadcast-id N] [--linger S] [--takeoff-alt M]\n"
                 "          [--ack-seq next|zero|echo] [--ready-payload none|id] [--reply-to-source] [--send-socket]\n"
                 "          [--first-seq N] [--pending-limit S] [--missions N] [-v]\n",
                 prog);
    std::exit(2);
}

void split_host_port(const char* prog, const std::string& s, std::string& host, uint16_t& port,
                     bool port_alone_ok) {
    auto colon = s.rfind(':');
    std::string p = s;
    if (colon != std::string::npos) {
        host = s.substr(0, colon);
        p = s.substr(colon + 1);
    } else if (!port_alone_ok) {
        usage(prog, "expected HOST:PORT, got '" + s + "'");
    }
    char* end = nullptr;
    long v = std::strtol(p.c_str(), &end, 10);
    if (p.empty() || *end != '\0' || v <= 0 || v > 65535) usage(prog, "bad port in '" + s + "'");
    port = static_cast<uint16_t>(v);
}

Options parse_options(int argc, char** argv) {
    Options o;
    bool have_id = false;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        auto value = [&]() -> std::string {
            if (i + 1 >= argc) usage(argv[0], a + " needs a value");
            return argv[++i];
        };
        try {
            if (a == "--id") {
                long v = std::stol(value());
                if (v <= 0 || v >= 0xFFFF) usage(argv[0], "--id is 1..65534 (0 is the manager)");
                o.id = static_cast<uint16_t>(v);
                have_id = true;
            } else if (a == "--listen") {
                split_host_port(argv[0], value(), o.listen_host, o.listen_port, true);
            } else if (a == "--manager") {
                split_host_port(argv[0], value(), o.manager_host, o.manager_port, false);
            } else if (a == "--mavlink") {
                o.mavlink = value();
            } else if (a == "--rto") {
                o.rto = std::stod(value());
                if (!(o.rto > 0)) usage(argv[0], "--rto must be > 0");
            } else if (a == "--retries") {
                o.retries = static_cast<unsigned>(std::stoul(value()));
            } else if (a == "--broadcast-id") {
                o.broadcast_id = static_cast<uint16_t>(std::stoul(value(), nullptr, 0));
            } else if (a == "--ack-seq") {
                std::string v = value();
                if (v == "next") o.ack_seq = Options::AckSeq::Next;
                else if (v == "zero") o.ack_seq = Options::AckSeq::Zero;
                else if (v == "echo") o.ack_seq = Options::AckSeq::Echo;
                else usage(argv[0], "--ack-seq is next, zero or echo");
            } else if (a == "--ready-payload") {
                std::string v = value();
                if (v != "none" && v != "id") usage(argv[0], "--ready-payload is none or id");
                o.ready_with_id = v == "id";
            } else if (a == "--missions") {
                o.missions = static_cast<unsigned>(std::stoul(value()));
            } else if (a == "--pending-limit") {
                o.pending_limit = std::stoi(value());
            } else if (a == "--first-seq") {
                o.first_seq = static_cast<uint16_t>(std::stoul(value(), nullptr, 0));
            } else if (a == "--send-socket") {
                o.send_socket = true;
            } else if (a == "--reply-to-source") {
                o.reply_to_source = true;
            } else if (a == "--takeoff-alt") {
                o.takeoff_alt = std::stof(value());
            } else if (a == "--linger") {
                o.linger = std::stod(value());
            } else if (a == "-v" || a == "--verbose") {
                g_verbose = true;
            } else if (a == "-h" || a == "--help") {
                usage(argv[0], "");
            } else {
                usage(argv[0], "unknown option " + a);
            }
        } catch (const std::logic_error&) {
            usage(argv[0], "bad value for " + a);
        }
    }
    if (!have_id) usage(argv[0], "--id is required");
    if (o.linger < 0) o.linger = std::max(1.0, 2 * o.rto);
    return o;
}

sockaddr_in resolve(const std::string& host, uint16_t port) {
    sockaddr_in sa{};
    sa.sin_family = AF_INET;
    sa.sin_port = htons(port);
    if (host.empty() || host == "0.0.0.0" || host == "*") {
        sa.sin_addr.s_addr = htonl(INADDR_ANY);
        return sa;
    }
    if (inet_pton(AF_INET, host.c_str(), &sa.sin_addr) == 1) return sa;
    addrinfo hints{}, *res = nullptr;
    hints.ai_family = AF_INET;
    if (getaddrinfo(host.c_str(), nullptr, &hints, &res) != 0 || res == nullptr)
        throw std::runtime_error("cannot resolve " + host);
    sa.sin_addr = reinterpret_cast<sockaddr_in*>(res->ai_addr)->sin_addr;
    freeaddrinfo(res);
    return sa;
}

// ---------------------------------------------------------------- the MCP endpoint

// The socket, the sequence numbers and the retransmission of unACKed unicast messages.
class McpEndpoint {
public:
    McpEndpoint(const Options& o) : opt_(o) {
        fd_ = ::socket(AF_INET, SOCK_DGRAM, 0);
        if (fd_ < 0) throw std::runtime_error(std::string("socket: ") + std::strerror(errno));
        int one = 1;
        ::setsockopt(fd_, SOL_SOCKET, SO_BROADCAST, &one, sizeof one);  // the manager may be a broadcast address
        int rcvbuf = 1 << 20;
        ::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
        sockaddr_in local = resolve(o.listen_host, o.listen_port);
        if (::bind(fd_, reinterpret_cast<sockaddr*>(&local), sizeof local) != 0)
            throw std::runtime_error("bind " + o.listen_host + ":" + std::to_string(o.listen_port) + ": " +
                                     std::strerror(errno));
        manager_ = resolve(o.manager_host, o.manager_port);
        send_fd_ = fd_;
        if (o.send_socket) {  // a socket of its own for sending, on an ephemeral port
            send_fd_ = ::socket(AF_INET, SOCK_DGRAM, 0);
            if (send_fd_ < 0) throw std::runtime_error(std::string("socket: ") + std::strerror(errno));
            ::setsockopt(send_fd_, SOL_SOCKET, SO_BROADCAST, &one, sizeof one);
        }
        std::random_device rd;  // "starts with an arbitrary initial sequence number value"
        next_seq_ = o.first_seq ? *o.first_seq : static_cast<uint16_t>(rd());
        timer_ = std::thread([this] { timer_loop(); });
    }

    ~McpEndpoint() {
        stop();
        if (timer_.joinable()) timer_.join();
        if (send_fd_ != fd_) ::close(send_fd_);
        ::close(fd_);
    }

    int fd() const { return fd_; }

    void stop() {
        {
            std::lock_guard<std::mutex> lock(mutex_);
            stopping_ = true;
        }
        cv_.notify_all();
        done_cv_.notify_all();
        ::shutdown(fd_, SHUT_RDWR);  // wakes the receive thread's recvfrom
    }

    // Every send takes the next number ("increments it for successive messages"); ACKs too.
    uint16_t take_seq() { return next_seq_.fetch_add(1); }

    void send_raw(const std::vector<uint8_t>& bytes, const sockaddr_in* to = nullptr) {
        if (to == nullptr) to = &manager_;
        ssize_t n = ::sendto(send_fd_, bytes.data(), bytes.size(), 0, reinterpret_cast<const sockaddr*>(to), sizeof *to);
        if (n < 0) log("sendto: %s", std::strerror(errno));
    }

    // `from`: where the message came from; the ACK goes there with --reply-to-source
    void send_ack(const mcp::Message& m, const sockaddr_in& from) {
        uint16_t acked = m.seq;
#ifdef FAULT_ACK_LE
        std::vector<uint8_t> payload{static_cast<uint8_t>(acked & 0xFF), static_cast<uint8_t>(acked >> 8)};
#else
        uint16_t be = htons(acked);
        std::vector<uint8_t> payload(2);
        std::memcpy(payload.data(), &be, 2);
#endif
        uint16_t own = opt_.ack_seq == Options::AckSeq::Next ? take_seq()
                       : opt_.ack_seq == Options::AckSeq::Echo ? acked : 0;  // D-5: ACKs may take no number
        send_raw(mcp::encode(m.src, opt_.id, own, mcp::Action::Ack, payload), opt_.reply_to_source ? &from : nullptr);
        if (g_verbose) log("ACK seq %u of %s to %u", acked, mcp::name(m.action), m.src);
    }

    // Blocks until the message is ACKed by its destination (true) or the retry limit is reached
    // (false), as the protocol's send_unicast_message() does. One at a time (stop-and-wait).
    bool send_unicast(mcp::Action action, const std::vector<uint8_t>& payload, uint16_t dst) {
        std::unique_lock<std::mutex> unicast(unicast_mutex_);
        std::unique_lock<std::mutex> lock(mutex_);
        Pending p;
        p.seq = take_seq();
        p.dst = dst;
        p.bytes = mcp::encode(dst, opt_.id, p.seq, action, payload);
        p.next = Clock::now() + rto();
        pending_ = p;
        send_raw(p.bytes);
        log("sent %s seq %u to %u", mcp::name(action), p.seq, dst);
        cv_.notify_all();  // the timer thread picks up the new deadline
        done_cv_.wait(lock, [&] { return stopping_ || !pending_ || pending_->seq != p.seq; });
        bool acked = acked_seq_ && *acked_seq_ == p.seq;
        pending_.reset();
        return acked;
    }

    // An ACK addressed to us: ends the retransmission only when it comes from the message's
    // destination and names its sequence number (MCP-RTX-2).
    void on_ack(uint16_t from, uint16_t acked) {
        std::lock_guard<std::mutex> lock(mutex_);
        if (pending_ && pending_->dst == from && pending_->seq == acked) {
            log("ACK for seq %u received", acked);
            acked_seq_ = acked;
            pending_.reset();
            done_cv_.notify_all();
            cv_.notify_all();
        } else if (g_verbose) {
            log("ACK naming seq %u from %u ignored", acked, from);
        }
    }

private:
    struct Pending {
        uint16_t seq = 0, dst = 0;
        std::vector<uint8_t> bytes;
        Clock::time_point next;
        unsigned retransmissions = 0;
    };

    Clock::duration rto() const {
        return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(opt_.rto));
    }

    void timer_loop() {
        std::unique_lock<std::mutex> lock(mutex_);
        while (!stopping_) {
            if (!pending_) {
                cv_.wait(lock);
                continue;
            }
            auto due = pending_->next;
            if (cv_.wait_until(lock, due) == std::cv_status::no_timeout) continue;  // woken: re-read
            if (stopping_ || !pending_ || Clock::now() < pending_->next) continue;
#ifdef FAULT_NO_RETRANSMIT
            pending_->next = Clock::now() + 1000 * rto();
            continue;
#endif
            if (pending_->retransmissions >= opt_.retries) {
                log("seq %u: retry limit %u reached, giving up", pending_->seq, opt_.retries);
                pending_.reset();
                done_cv_.notify_all();
                continue;
            }
            ++pending_->retransmissions;
            send_raw(pending_->bytes);  // the same bytes, the same seq (MCP-SEQ-2)
            pending_->next = Clock::now() + rto();
            if (g_verbose) log("retransmitted seq %u (copy %u)", pending_->seq, pending_->retransmissions + 1);
        }
    }

    const Options& opt_;
    int fd_ = -1;
    int send_fd_ = -1;  // fd_, or with --send-socket a socket of its own
    sockaddr_in manager_{};
    std::atomic<uint16_t> next_seq_{0};
    std::mutex unicast_mutex_;  // stop-and-wait: one unicast message in flight
    std::mutex mutex_;
    std::condition_variable cv_;       // the timer thread's
    std::condition_variable done_cv_;  // the blocked sender's
    std::optional<Pending> pending_;
    std::optional<uint16_t> acked_seq_;
    bool stopping_ = false;
    std::thread timer_;
};

// ---------------------------------------------------------------- the command queue

template <typename T>
class BlockingQueue {
public:
    void push(T v) {
        {
            std::lock_guard<std::mutex> lock(m_);
            q_.push(std::move(v));
        }
        cv_.notify_one();
    }
    // nullopt once closed
    std::optional<T> pop() {
        std::unique_lock<std::mutex> lock(m_);
        cv_.wait(lock, [&] { return closed_ || !q_.empty(); });
        if (closed_) return std::nullopt;
        T v = std::move(q_.front());
        q_.pop();
        return v;
    }
    void close() {
        {
            std::lock_guard<std::mutex> lock(m_);
            closed_ = true;
        }
        cv_.notify_all();
    }

private:
    std::mutex m_;
    std::condition_variable cv_;
    std::queue<T> q_;
    bool closed_ = false;
};

// ---------------------------------------------------------------- the autopilot (MAVLink)

class Autopilot {
public:
    static constexpr uint8_t kSysId = 1;
    static constexpr uint8_t kCompId = MAV_COMP_ID_ONBOARD_COMPUTER;
    static constexpr uint8_t kChan = MAVLINK_COMM_1;
    static constexpr uint32_t kGuided = 4, kAuto = 3;  // ArduCopter's custom modes

    explicit Autopilot(const std::string& url) { open(url); }

    ~Autopilot() {
        stop();
        ::close(fd_);
    }

    void start() {
        reader_ = std::thread([this] { read_loop(); });
        heartbeat_ = std::thread([this] { heartbeat_loop(); });
    }

    void stop() {
        {
            std::lock_guard<std::mutex> lock(m_);
            if (stopping_) return;
            stopping_ = true;
        }
        cv_.notify_all();
        ::shutdown(fd_, SHUT_RDWR);
        if (reader_.joinable()) reader_.join();
        if (heartbeat_.joinable()) heartbeat_.join();
    }

    // Waits until the autopilot's heartbeat and a 3D GPS fix are seen; false when stopping.
    bool wait_ready() {
        std::unique_lock<std::mutex> lock(m_);
        bool logged = false;
        while (!stopping_ && !(have_target_ && fix_type_ >= GPS_FIX_TYPE_3D_FIX)) {
            if (have_target_ && !logged) {
                log("autopilot sys %u comp %u: waiting for a 3D GPS fix", target_sys_, target_comp_);
                logged = true;
            }
            cv_.wait_for(lock, 1s);
        }
        if (!stopping_) log("autopilot ready: GPS fix type %u", fix_type_);
        return !stopping_;
    }

    // COMMAND_LONG until its COMMAND_ACK (3 tries, 1 s each); the result, or -1.
    int command(uint16_t cmd, float p1 = 0, float p2 = 0, float p3 = 0, float p4 = 0, float p5 = 0,
                float p6 = 0, float p7 = 0) {
        for (uint8_t confirmation = 0; confirmation < 3; ++confirmation) {
            {
                std::lock_guard<std::mutex> lock(m_);
                acks_.erase(cmd);
            }
            mavlink_message_t msg;
            mavlink_msg_command_long_pack_chan(kSysId, kCompId, kChan, &msg, target_sys(), target_comp(), cmd,
                                               confirmation, p1, p2, p3, p4, p5, p6, p7);
            send(msg);
            std::unique_lock<std::mutex> lock(m_);
            if (cv_.wait_for(lock, 1s, [&] { return stopping_ || acks_.count(cmd) > 0; }) && !stopping_) {
                int r = acks_[cmd];
                log("COMMAND_LONG %u -> result %d", cmd, r);
                return r;
            }
            if (stopping_) return -1;
        }
        log("COMMAND_LONG %u: no COMMAND_ACK", cmd);
        return -1;
    }

    int set_mode(uint32_t custom_mode) {
        return command(MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, static_cast<float>(custom_mode));
    }

    // The mission protocol: MISSION_COUNT, then each item the autopilot requests, until MISSION_ACK.
    bool upload_mission(const std::vector<mcp::MissionItem>& items) {
        {
            std::lock_guard<std::mutex> lock(m_);
            requested_.reset();
            mission_ack_.reset();
        }
        mavlink_message_t msg;
        mavlink_msg_mission_count_pack_chan(kSysId, kCompId, kChan, &msg, target_sys(), target_comp(),
                                            static_cast<uint16_t>(items.size()), MAV_MISSION_TYPE_MISSION);
        send(msg);
        mavlink_message_t last = msg;
        int quiet = 0;
        while (true) {
            std::unique_lock<std::mutex> lock(m_);
            bool woke = cv_.wait_for(lock, 1s, [&] { return stopping_ || requested_ || mission_ack_; });
            if (stopping_) return false;
            if (!woke) {
                if (++quiet > 3) {
                    log("mission upload: the autopilot went quiet");
                    return false;
                }
                lock.unlock();
                send(last);
                continue;
            }
            quiet = 0;
            if (mission_ack_) {
                uint8_t type = *mission_ack_;
                log("mission upload of %zu items: MISSION_ACK %u", items.size(), type);
                return type == MAV_MISSION_ACCEPTED;
            }
            auto [seq, as_int] = *requested_;
            requested_.reset();
            lock.unlock();
            if (seq >= items.size()) continue;
            const mcp::MissionItem& it = items[seq];
            if (as_int) {
                mavlink_msg_mission_item_int_pack_chan(
                    kSysId, kCompId, kChan, &msg, target_sys(), target_comp(), seq, it.frame, it.command,
                    seq == 0 ? 1 : 0, it.autocontinue, it.param1, it.param2, it.param3, it.param4,
                    static_cast<int32_t>(std::lround(it.x * 1e7)), static_cast<int32_t>(std::lround(it.y * 1e7)),
                    it.z, MAV_MISSION_TYPE_MISSION);
            } else {
                mavlink_msg_mission_item_pack_chan(kSysId, kCompId, kChan, &msg, target_sys(), target_comp(), seq,
                                                   it.frame, it.command, seq == 0 ? 1 : 0, it.autocontinue,
                                                   it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z,
                                                   MAV_MISSION_TYPE_MISSION);
            }
            send(msg);
            last = msg;
        }
    }

    void goto_position(const mcp::MissionItem& it) {
        mavlink_message_t msg;
        const uint16_t position_only = POSITION_TARGET_TYPEMASK_VX_IGNORE | POSITION_TARGET_TYPEMASK_VY_IGNORE |
                                       POSITION_TARGET_TYPEMASK_VZ_IGNORE | POSITION_TARGET_TYPEMASK_AX_IGNORE |
                                       POSITION_TARGET_TYPEMASK_AY_IGNORE | POSITION_TARGET_TYPEMASK_AZ_IGNORE |
                                       POSITION_TARGET_TYPEMASK_YAW_IGNORE |
                                       POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE;
        mavlink_msg_set_position_target_global_int_pack_chan(
            kSysId, kCompId, kChan, &msg, 0, target_sys(), target_comp(), MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            position_only, static_cast<int32_t>(std::lround(it.x * 1e7)),
            static_cast<int32_t>(std::lround(it.y * 1e7)), it.z, 0, 0, 0, 0, 0, 0, 0, 0);
        send(msg);
    }

    // A Mav_Passthrough frame, forwarded as it came, once (MCP-PAY-8).
    void send_raw(const std::vector<uint8_t>& frame) { write_bytes(frame.data(), frame.size()); }

private:
    enum class Kind { Tcp, UdpIn, UdpOut };

    void open(const std::string& url) {
        auto colon = url.find(':');
        if (colon == std::string::npos) throw std::runtime_error("--mavlink URL: tcp:|udp:|udpin:|udpout:HOST:PORT");
        std::string scheme = url.substr(0, colon), rest = url.substr(colon + 1);
        std::string host = "127.0.0.1";
        uint16_t port = 0;
        split_host_port("drone", rest, host, port, false);
        sockaddr_in sa = resolve(host, port);
        if (scheme == "tcp") {
            kind_ = Kind::Tcp;
            // the autopilot may still be starting: a few tries, as MAVProxy does
            for (int attempt = 0;; ++attempt) {
                fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
                if (::connect(fd_, reinterpret_cast<sockaddr*>(&sa), sizeof sa) == 0) break;
                int err = errno;
                ::close(fd_);
                if (attempt >= 50) throw std::runtime_error("connect " + url + ": " + std::strerror(err));
                std::this_thread::sleep_for(200ms);
            }
            int one = 1;
            ::setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        } else if (scheme == "udp" || scheme == "udpin") {
            kind_ = Kind::UdpIn;
            fd_ = ::socket(AF_INET, SOCK_DGRAM, 0);
            if (::bind(fd_, reinterpret_cast<sockaddr*>(&sa), sizeof sa) != 0)
                throw std::runtime_error("bind " + url + ": " + std::strerror(errno));
        } else if (scheme == "udpout") {
            kind_ = Kind::UdpOut;
            fd_ = ::socket(AF_INET, SOCK_DGRAM, 0);
            peer_ = sa;
            have_peer_ = true;
        } else {
            throw std::runtime_error("--mavlink URL scheme must be tcp, udp, udpin or udpout: " + url);
        }
        log("autopilot link %s", url.c_str());
    }

    uint8_t target_sys() {
        std::lock_guard<std::mutex> lock(m_);
        return target_sys_;
    }
    uint8_t target_comp() {
        std::lock_guard<std::mutex> lock(m_);
        return target_comp_;
    }

    void send(const mavlink_message_t& msg) {
        uint8_t buf[MAVLINK_MAX_PACKET_LEN];
        uint16_t n = mavlink_msg_to_send_buffer(buf, &msg);
        write_bytes(buf, n);
    }

    void write_bytes(const uint8_t* p, size_t n) {
        std::lock_guard<std::mutex> lock(write_m_);
        if (kind_ == Kind::Tcp) {
            while (n > 0) {
                ssize_t w = ::send(fd_, p, n, MSG_NOSIGNAL);
                if (w <= 0) {
                    if (w < 0 && errno == EINTR) continue;
                    return;
                }
                p += w;
                n -= static_cast<size_t>(w);
            }
            return;
        }
        sockaddr_in to;
        {
            std::lock_guard<std::mutex> lock2(m_);
            if (!have_peer_) return;  // udpin: the autopilot is learnt from its first datagram
            to = peer_;
        }
        ::sendto(fd_, p, n, 0, reinterpret_cast<sockaddr*>(&to), sizeof to);
    }

    void heartbeat_loop() {
        std::unique_lock<std::mutex> lock(m_);
        while (!stopping_) {
            lock.unlock();
            mavlink_message_t msg;
            mavlink_msg_heartbeat_pack_chan(kSysId, kCompId, kChan, &msg, MAV_TYPE_ONBOARD_CONTROLLER,
                                            MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE);
            send(msg);
            lock.lock();
            cv_.wait_for(lock, 1s, [&] { return stopping_; });
        }
    }

    void read_loop() {
        mavlink_message_t rx{}, msg{};
        mavlink_status_t st{}, out{};
        std::vector<uint8_t> buf(65536);
        while (true) {
            sockaddr_in from{};
            socklen_t fl = sizeof from;
            ssize_t n = kind_ == Kind::Tcp ? ::recv(fd_, buf.data(), buf.size(), 0)
                                           : ::recvfrom(fd_, buf.data(), buf.size(), 0,
                                                        reinterpret_cast<sockaddr*>(&from), &fl);
            {
                std::lock_guard<std::mutex> lock(m_);
                if (stopping_) return;
            }
            if (n < 0 && errno == EINTR) continue;
            if (n <= 0) {
                log("autopilot link closed");
                return;
            }
            if (kind_ == Kind::UdpIn) {
                std::lock_guard<std::mutex> lock(m_);
                peer_ = from;
                have_peer_ = true;
            }
            for (ssize_t i = 0; i < n; ++i)
                if (mavlink_frame_char_buffer(&rx, &st, buf[i], &msg, &out) == MAVLINK_FRAMING_OK) handle(msg);
        }
    }

    void handle(const mavlink_message_t& msg) {
        std::lock_guard<std::mutex> lock(m_);
        switch (msg.msgid) {
            case MAVLINK_MSG_ID_HEARTBEAT: {
                mavlink_heartbeat_t hb;
                mavlink_msg_heartbeat_decode(&msg, &hb);
                if (hb.type == MAV_TYPE_GCS || hb.autopilot == MAV_AUTOPILOT_INVALID) break;
                if (!have_target_) {
                    target_sys_ = msg.sysid;
                    target_comp_ = msg.compid;
                    have_target_ = true;
                    want_gps_stream_ = true;
                }
                break;
            }
            case MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
                relative_alt_mm_ = mavlink_msg_global_position_int_get_relative_alt(&msg);
                break;
            case MAVLINK_MSG_ID_GPS_RAW_INT:
                fix_type_ = mavlink_msg_gps_raw_int_get_fix_type(&msg);
                break;
            case MAVLINK_MSG_ID_COMMAND_ACK:
                acks_[mavlink_msg_command_ack_get_command(&msg)] = mavlink_msg_command_ack_get_result(&msg);
                break;
            case MAVLINK_MSG_ID_MISSION_REQUEST:
                requested_ = std::make_pair(mavlink_msg_mission_request_get_seq(&msg), false);
                break;
            case MAVLINK_MSG_ID_MISSION_REQUEST_INT:
                requested_ = std::make_pair(mavlink_msg_mission_request_int_get_seq(&msg), true);
                break;
            case MAVLINK_MSG_ID_MISSION_ACK:
                mission_ack_ = mavlink_msg_mission_ack_get_type(&msg);
                break;
            case MAVLINK_MSG_ID_MISSION_ITEM_REACHED:
                reached_ = mavlink_msg_mission_item_reached_get_seq(&msg);
                log("autopilot: mission item %u reached", *reached_);
                break;
            case MAVLINK_MSG_ID_STATUSTEXT: {
                char text[51] = {0};
                mavlink_msg_statustext_get_text(&msg, text);
                if (g_verbose) log("autopilot: %s", text);
                break;
            }
            default:
                break;
        }
        cv_.notify_all();
    }

public:
    // Asks for GPS_RAW_INT at 2 Hz once the autopilot is known (the worker calls it).
    void request_gps_stream() {
        bool want;
        {
            std::lock_guard<std::mutex> lock(m_);
            want = want_gps_stream_;
            want_gps_stream_ = false;
        }
        if (want) {
            mavlink_message_t msg;
            mavlink_msg_command_long_pack_chan(kSysId, kCompId, kChan, &msg, target_sys(), target_comp(),
                                               MAV_CMD_SET_MESSAGE_INTERVAL, 0, MAVLINK_MSG_ID_GPS_RAW_INT,
                                               500000, 0, 0, 0, 0, 0);
            send(msg);
        }
    }

    // Waits until the vehicle is at 95 % of the altitude (m) above home, at most `limit`.
    bool wait_altitude(float alt, std::chrono::seconds limit) {
        std::unique_lock<std::mutex> lock(m_);
        bool reached = cv_.wait_for(lock, limit, [&] { return stopping_ || relative_alt_mm_ >= alt * 950; });
        if (!stopping_) log("altitude %.1f m%s", relative_alt_mm_ / 1000.0, reached ? "" : " (not reached)");
        return reached && !stopping_;
    }

    // Waits until the mission item `last` is reached, at most `limit`; false if not.
    bool wait_mission_done(uint16_t last, std::chrono::seconds limit) {
        std::unique_lock<std::mutex> lock(m_);
        bool done = cv_.wait_for(lock, limit, [&] { return stopping_ || (reached_ && *reached_ >= last); });
        return done && !stopping_;
    }

    void forget_progress() {
        std::lock_guard<std::mutex> lock(m_);
        reached_.reset();
    }

    // Waits for the autopilot's first HEARTBEAT; false when stopping.
    bool wait_heartbeat() {
        std::unique_lock<std::mutex> lock(m_);
        cv_.wait(lock, [&] { return stopping_ || have_target_; });
        return !stopping_;
    }

private:
    Kind kind_ = Kind::Tcp;
    int fd_ = -1;
    std::mutex write_m_;
    std::mutex m_;
    std::condition_variable cv_;
    bool stopping_ = false;
    sockaddr_in peer_{};
    bool have_peer_ = false;
    bool have_target_ = false;
    bool want_gps_stream_ = false;
    uint8_t target_sys_ = 1, target_comp_ = 1;
    uint8_t fix_type_ = 0;
    int32_t relative_alt_mm_ = 0;
    std::map<uint16_t, int> acks_;
    std::optional<std::pair<uint16_t, bool>> requested_;
    std::optional<uint8_t> mission_ack_;
    std::optional<uint16_t> reached_;  // the last MISSION_ITEM_REACHED
    std::thread reader_, heartbeat_;
};

// ---------------------------------------------------------------- the drone application

class Drone {
public:
    explicit Drone(const Options& o) : opt_(o), mcp_(o) {
        if (!o.mavlink.empty()) autopilot_ = std::make_unique<Autopilot>(o.mavlink);
    }

    void start() {
        if (autopilot_) autopilot_->start();
        receiver_ = std::thread([this] { receive_loop(); });
        worker_ = std::thread([this] { work_loop(); });
    }

    // Blocks until the mission ended or stop() was called; the exit code.
    int wait() {
        std::unique_lock<std::mutex> lock(done_m_);
        done_cv_.wait(lock, [&] { return done_; });
        return exit_code_;
    }

    void finish(int code) {
        {
            std::lock_guard<std::mutex> lock(done_m_);
            if (done_) return;
            done_ = true;
            exit_code_ = code;
        }
        done_cv_.notify_all();
    }

    void shutdown() {
        stopping_ = true;
        mcp_.stop();
        commands_.close();
        if (autopilot_) autopilot_->stop();
        if (receiver_.joinable()) receiver_.join();
        {
            std::lock_guard<std::mutex> lock(done_m_);
            done_ = true;
        }
        done_cv_.notify_all();
        if (worker_.joinable()) worker_.join();
    }

private:
    void receive_loop() {
        std::vector<uint8_t> buf(mcp::kMaxDatagram + 1);
        while (!stopping_) {
            sockaddr_in from{};
            socklen_t fl = sizeof from;
            ssize_t n = ::recvfrom(mcp_.fd(), buf.data(), buf.size(), 0, reinterpret_cast<sockaddr*>(&from), &fl);
            if (stopping_) return;
            if (n < 0) {
                if (errno == EINTR) continue;
                log("recvfrom: %s", std::strerror(errno));
                continue;
            }
            auto m = mcp::decode(buf.data(), static_cast<size_t>(n));
            if (!m) {
                if (g_verbose) log("discarded a %zd-byte datagram that is not MCP", n);
                continue;
            }
            const bool unicast = m->dst == opt_.id;
            const bool broadcast = m->dst == opt_.broadcast_id;
            if (!unicast && !broadcast) continue;  // for another ID: no ACK, no action (MCP-ACK-5)
            if (!mcp::payload_fits(*m)) {           // D-4: no ACK, no delivery
                if (g_verbose) log("discarded %s seq %u: payload of %zu bytes does not fit", mcp::name(m->action),
                                   m->seq, m->payload.size());
                continue;
            }
            if (m->action == mcp::Action::Ack) {  // never ACK an ACK (MCP-ACK-6)
                if (unicast) mcp_.on_ack(m->src, static_cast<uint16_t>((m->payload[0] << 8) | m->payload[1]));
                continue;
            }
            // duplicate: the same (src, seq) as the last message delivered from that src
            auto last = last_delivered_.find(m->src);
            bool duplicate = last != last_delivered_.end() && last->second == m->seq;
#ifdef FAULT_NO_DEDUP
            duplicate = false;
#endif
#ifdef ACK_AFTER_DELIVERY
            if (unicast && duplicate) mcp_.send_ack(*m, from);  // the original's ACK is the worker's
#else
            if (unicast) mcp_.send_ack(*m, from);  // "for every unicast message received"
#endif
            if (duplicate) {
                if (g_verbose) log("duplicate %s seq %u from %u: ACKed, not delivered", mcp::name(m->action), m->seq,
                                   m->src);
                continue;
            }
            last_delivered_[m->src] = m->seq;
            log("received %s seq %u from %u (%s, %zu payload bytes)", mcp::name(m->action), m->seq, m->src,
                unicast ? "unicast" : "broadcast", m->payload.size());
            commands_.push(Command{std::move(*m), unicast, from});
        }
    }

    struct Command {
        mcp::Message msg;
        bool unicast;
        sockaddr_in from;
    };

    void work_loop() {
        if (autopilot_) {
            if (!autopilot_->wait_heartbeat()) return;
            autopilot_->request_gps_stream();
            // "verify GPS lock and other similar ready-to-fly capabilities before sending this message"
#ifndef FAULT_NO_FIX_WAIT
            if (!autopilot_->wait_ready()) return;
#endif
        }
        std::vector<uint8_t> ready;  // empty, as the document's drone sends it, or our ID (D-3)
        if (opt_.ready_with_id) ready = {static_cast<uint8_t>(opt_.id >> 8), static_cast<uint8_t>(opt_.id & 0xFF)};
        for (unsigned mission = 1;; ++mission) {
            if (!mcp_.send_unicast(mcp::Action::MissionReady, ready, mcp::kManagerId)) {
                if (!stopping_) {
                    log("Mission_Ready was never ACKed");
                    finish(1);
                }
                return;
            }
            log("Mission_Ready ACKed: mission %u may start", mission);
            if (!run_mission()) return;  // stopping
            if (opt_.missions != 0 && mission >= opt_.missions) break;
            started_ = false;  // ready for the next one (--missions): announce again
        }
        log("mission ended; ACKing repeats for %.1f s", opt_.linger);
        std::unique_lock<std::mutex> lock(done_m_);
        done_cv_.wait_for(lock, std::chrono::duration<double>(opt_.linger), [&] { return done_; });
        lock.unlock();
        finish(0);
    }

    // Carries out the queued commands until End_Mission (true) or the program stops (false).
    bool run_mission() {
        while (auto cmd = commands_.pop()) {
            carry_out(cmd->msg);
#ifdef ACK_AFTER_DELIVERY
            if (cmd->unicast) mcp_.send_ack(cmd->msg, cmd->from);
#endif
            if (cmd->msg.action == mcp::Action::EndMission) return true;
        }
        return false;
    }

    void carry_out(const mcp::Message& m) {
        using mcp::Action;
        switch (m.action) {
            case Action::StartMission:
                started_ = true;
                if (autopilot_) {
                    if (autopilot_->set_mode(Autopilot::kGuided) == MAV_RESULT_ACCEPTED) mode_ = Autopilot::kGuided;
                    // arm, take off, and wait to be up before anything else
                    if (autopilot_->command(MAV_CMD_COMPONENT_ARM_DISARM, 1) == MAV_RESULT_ACCEPTED &&
                        autopilot_->command(MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, opt_.takeoff_alt) == MAV_RESULT_ACCEPTED)
                        autopilot_->wait_altitude(opt_.takeoff_alt, 60s);
                }
                break;
            case Action::WpList: {
                auto wps = mcp::items(m);
                log("WP_List: %zu waypoints", wps.size());
                if (autopilot_ && !wps.empty() && autopilot_->upload_mission(wps)) {
                    mission_items_ = wps.size();
                    autopilot_->forget_progress();
                    if (started_ && autopilot_->set_mode(Autopilot::kAuto) == MAV_RESULT_ACCEPTED) mode_ = Autopilot::kAuto;
                }
                break;
            }
            case Action::WpOn: {
                auto wp = mcp::items(m).front();
                log("WP_On: %.7f %.7f %.1f", wp.x, wp.y, wp.z);
                if (autopilot_ && started_) {
                    if (mode_ != Autopilot::kGuided && autopilot_->set_mode(Autopilot::kGuided) == MAV_RESULT_ACCEPTED)
                        mode_ = Autopilot::kGuided;
                    autopilot_->goto_position(wp);  // GUIDED: ArduCopter ignores position targets otherwise
                }
                break;
            }
            case Action::WpOff:
                log("WP_Off: the active waypoint is inactive");
                break;
            case Action::ObstaclesList:
                obstacles_ = mcp::items(m);
                log("Obstacles_List: %zu obstacles", obstacles_.size());
                break;
            case Action::MavPassthrough:
                if (autopilot_) autopilot_->send_raw(m.payload);
                break;
            case Action::EndMission:
                // "complete carrying out all currently pending actions (from previously received
                // commands), then execute an RTL": the commands queued before this one are done;
                // a mission flying in AUTO is flown to its last item first
                if (autopilot_) {
                    if (mode_ == Autopilot::kAuto && mission_items_ > 1) {
                        log("End_Mission: flying the mission to its last item before RTL");
                        if (!autopilot_->wait_mission_done(static_cast<uint16_t>(mission_items_ - 1),
                                                           std::chrono::seconds(opt_.pending_limit)))
                            log("End_Mission: the mission did not end within %d s", opt_.pending_limit);
                    }
                    autopilot_->command(MAV_CMD_NAV_RETURN_TO_LAUNCH);
                }
                break;
            case Action::MissionReady:
            case Action::Ack:
                break;  // nothing for a drone to do
        }
    }

    const Options& opt_;
    McpEndpoint mcp_;
    std::unique_ptr<Autopilot> autopilot_;
    BlockingQueue<Command> commands_;
    std::unordered_map<uint16_t, uint16_t> last_delivered_;  // src -> seq (the receive thread's)
    std::vector<mcp::MissionItem> obstacles_;
    bool started_ = false;   // the worker's
    uint32_t mode_ = 0;      // the flight mode last set (the worker's)
    size_t mission_items_ = 0;  // of the mission last uploaded (the worker's)
    std::atomic<bool> stopping_{false};
    std::thread receiver_, worker_;
    std::mutex done_m_;
    std::condition_variable done_cv_;
    bool done_ = false;
    int exit_code_ = 0;
};

int main(int argc, char** argv) {
    Options opt = parse_options(argc, argv);

    // SIGINT/SIGTERM are taken by a thread of their own (sigwait); every thread inherits the mask
    sigset_t signals;
    sigemptyset(&signals);
    sigaddset(&signals, SIGINT);
    sigaddset(&signals, SIGTERM);
    sigset_t waited = signals;
    sigaddset(&waited, SIGUSR1);  // SIGUSR1: the mission ended, stop waiting
    pthread_sigmask(SIG_BLOCK, &waited, nullptr);
    ::signal(SIGPIPE, SIG_IGN);

    std::unique_ptr<Drone> drone;
    try {
        drone = std::make_unique<Drone>(opt);
    } catch (const std::exception& e) {
        std::fprintf(stderr, "drone: %s\n", e.what());
        return 2;
    }
    log("MCP drone %u listening on %s:%u, manager %s:%u, rto %.3f s, retries %u%s%s", opt.id,
        opt.listen_host.c_str(), opt.listen_port, opt.manager_host.c_str(), opt.manager_port, opt.rto, opt.retries,
        opt.mavlink.empty() ? "" : ", autopilot ", opt.mavlink.c_str());
    drone->start();

    std::atomic<int> signal_number{0};
    std::thread signal_thread([&] {
        int sig = 0;
        if (sigwait(&waited, &sig) == 0 && sig != SIGUSR1) {
            signal_number = sig;
            drone->finish(128 + sig);
        }
    });
    int code = drone->wait();
    if (signal_number == 0) pthread_kill(signal_thread.native_handle(), SIGUSR1);  // ends the sigwait
    signal_thread.join();
    drone->shutdown();
    log("exit %d", signal_number ? 128 + signal_number.load() : code);
    return signal_number ? 128 + signal_number.load() : code;
}
