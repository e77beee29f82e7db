// An MCP (CentMesh Mission Control Protocol) Mission Manager in C++17, written from the
// protocol's documents (docs/spec.md, spec/mcp.yaml, docs/guide/manager.md).
//
//   ./manager --port 7889 --drones 1,2,3 --send-to 127.255.255.255:7890
//             --challenge 1 --waypoints mission.waypoints [--obstacles obstacles.waypoints]
//             [--rto 5] [--retries 1000] [--broadcast-id 65535] [-v]
//
// Threads: one receiver (blocking recvfrom: ACKs every well-formed unicast addressed to ID 0,
// matches ACKs to outstanding messages, delivers Mission_Ready once per (src, seq)); one timer
// (condition_variable::wait_until on steady_clock: retransmits each outstanding message when
// its own deadline passes, gives up after --retries retransmissions); the main thread runs the
// mission.
//
// Unicast sends are stop-and-wait by default (MCP-BLK-1, "a node sends no new unicast message
// other than an ACK while one of its unicast messages awaits its ACK"). Built with
// -DMCP_PIPELINE (make VARIANT=PIPELINE) the other reading: after a drone's Start_Mission is
// ACKed (MCP-BLK-3), the mission messages of every drone are sent without waiting for each
// other's ACKs, each with a timer of its own; End_Mission goes once all of them are ACKed.
//
// Faults for testing the tester (make FAULT=...): NO_RETRANSMIT (never retransmits),
// ACK_WRONG_SEQ (every ACK names the message's seq + 1).

#include <arpa/inet.h>
#include <netdb.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdarg>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "mavlink_frame.h"

#if defined(MCP_PIPELINE) && defined(MCP_STOP_AND_WAIT)
#error "choose one of MCP_PIPELINE and MCP_STOP_AND_WAIT"
#endif

namespace {

using Clock = std::chrono::steady_clock;
using Bytes = std::vector<uint8_t>;

// ---- the protocol's constants (docs/spec.md) ------------------------------------------------

constexpr uint16_t kManagerId = 0;
constexpr char kPreamble[9] = {'N', 'C', 'S', 'U', '-', 'C', 'M', 1, 1};
constexpr size_t kItemSize = 37;
constexpr size_t kMaxDatagram = 65507;

enum Action : uint16_t {
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

const char* action_name(uint16_t a) {
    static const char* names[] = {"Mission_Ready", "Start_Mission", "End_Mission", "WP_List", "WP_On",
                                  "WP_Off", "Obstacles_List", "ACK", "Mav_Passthrough"};
    return a <= 8 ? names[a] : "?";
}

#pragma pack(push, 1)
struct Header {            // struct !7s2B4H
    char preamble[9];      // "NCSU-CM", 1, 1
    uint16_t dst;          // network byte order on the wire
    uint16_t src;
    uint16_t seq;
    uint16_t action;
};
#pragma pack(pop)
static_assert(sizeof(Header) == 17, "the MCP header is 17 bytes");

Bytes make_message(uint16_t dst, uint16_t seq, uint16_t action, const Bytes& payload) {
    Header h{};
    std::memcpy(h.preamble, kPreamble, sizeof kPreamble);
    h.dst = htons(dst);
    h.src = htons(kManagerId);
    h.seq = htons(seq);
    h.action = htons(action);
    Bytes out(sizeof h + payload.size());
    std::memcpy(out.data(), &h, sizeof h);
    std::copy(payload.begin(), payload.end(), out.begin() + sizeof h);
    return out;
}

// ---- mission items: the MAVLink v1 MISSION_ITEM payload, little-endian ('<fffffffHHBBBBB') --

struct MissionItem {
    float param[7]{};  // param1..4, x (lat), y (lon), z (alt)
    uint16_t seq = 0;
    uint16_t command = 0;
    uint8_t target_system = 0;
    uint8_t target_component = 0;
    uint8_t frame = 0;
    uint8_t current = 0;
    uint8_t autocontinue = 0;
};

void put_le16(Bytes& b, uint16_t v) {
    b.push_back(static_cast<uint8_t>(v & 0xFF));
    b.push_back(static_cast<uint8_t>(v >> 8));
}

void put_le_float(Bytes& b, float f) {
    uint32_t u;
    static_assert(sizeof u == sizeof f, "IEEE-754 single");
    std::memcpy(&u, &f, sizeof u);
    for (int i = 0; i < 4; ++i) b.push_back(static_cast<uint8_t>(u >> (8 * i)));
}

void append_item(Bytes& b, const MissionItem& it) {
    for (float p : it.param) put_le_float(b, p);
    put_le16(b, it.seq);
    put_le16(b, it.command);
    b.push_back(it.target_system);
    b.push_back(it.target_component);
    b.push_back(it.frame);
    b.push_back(it.current);
    b.push_back(it.autocontinue);
}

Bytes item_list_payload(const std::vector<MissionItem>& items) {
    Bytes b;
    uint16_t count = htons(static_cast<uint16_t>(items.size()));  // u16 big-endian count (D-2)
    b.resize(2);
    std::memcpy(b.data(), &count, 2);
    for (const auto& it : items) append_item(b, it);
    return b;
}

// A QGC WPL 110 file: "INDEX CURRENT FRAME COMMAND P1 P2 P3 P4 X Y Z AUTOCONTINUE" per line.
std::vector<MissionItem> read_waypoints(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw std::runtime_error("cannot open " + path);
    std::string line;
    if (!std::getline(in, line) || line.rfind("QGC WPL 110", 0) != 0)
        throw std::runtime_error(path + ": not a QGC WPL 110 file");
    std::vector<MissionItem> items;
    int lineno = 1;
    while (std::getline(in, line)) {
        ++lineno;
        if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
        std::istringstream fields(line);
        unsigned index, current, frame, command, autocontinue;
        double p[7];
        fields >> index >> current >> frame >> command;
        for (double& v : p) fields >> v;
        fields >> autocontinue;
        if (!fields) throw std::runtime_error(path + ":" + std::to_string(lineno) + ": bad waypoint line");
        MissionItem it;
        for (int i = 0; i < 7; ++i) it.param[i] = static_cast<float>(p[i]);
        it.seq = static_cast<uint16_t>(index);
        it.command = static_cast<uint16_t>(command);
        it.frame = static_cast<uint8_t>(frame);
        it.current = static_cast<uint8_t>(current);
        it.autocontinue = static_cast<uint8_t>(autocontinue);
        items.push_back(it);
    }
    return items;
}

// ---- options -------------------------------------------------------------------------------

struct Options {
    std::string bind_host = "0.0.0.0";
    uint16_t port = 7889;
    std::string send_host = "127.255.255.255";
    uint16_t send_port = 7890;
    std::vector<uint16_t> drones{1};
    int challenge = 1;
    std::string waypoints;
    std::string obstacles;
    double rto = 5.0;
    long retries = 1000;
    uint16_t broadcast_id = 0xFFFF;
    bool broadcast_lists = false;      // WP_List and Obstacles_List once, to the broadcast ID
    bool reply_to_source = false;      // unicasts to the address a drone's datagrams came from
    long initial_seq = -1;             // >= 0: the first sequence number (default: random)
    double hold = 0;                   // challenge 2: seconds a waypoint stays active
    double speed = -1;                 // >= 0: a Mav_Passthrough DO_CHANGE_SPEED after Start_Mission
    bool verbose = false;
};

[[noreturn]] void usage(const char* argv0, const std::string& why = "") {
    if (!why.empty()) std::cerr << argv0 << ": " << why << "\n";
    std::cerr << "usage: " << argv0
              << " [--port N | --bind HOST:PORT] [--send-to HOST:PORT] --drones ID,ID,..."
                 " [--challenge 1|2|3] --waypoints FILE [--obstacles FILE]"
                 " [--rto SECONDS] [--retries N] [--broadcast-id N] [--broadcast-obstacles]"
                 " [--hold SECONDS] [--speed M/S] [--reply-to-source] [--initial-seq N] [-v]\n";
    std::exit(2);
}

void split_host_port(const std::string& s, std::string& host, uint16_t& port) {
    auto colon = s.rfind(':');
    if (colon == std::string::npos) throw std::invalid_argument("HOST:PORT expected: " + s);
    host = s.substr(0, colon);
    port = static_cast<uint16_t>(std::stoul(s.substr(colon + 1)));
}

Options parse_options(int argc, char** argv) {
    Options o;
    auto value = [&](int& i) -> std::string {
        if (i + 1 >= argc) usage(argv[0], std::string(argv[i]) + " needs a value");
        return argv[++i];
    };
    try {
        for (int i = 1; i < argc; ++i) {
            std::string a = argv[i];
            if (a == "--port") o.port = static_cast<uint16_t>(std::stoul(value(i)));
            else if (a == "--bind") split_host_port(value(i), o.bind_host, o.port);
            else if (a == "--send-to") split_host_port(value(i), o.send_host, o.send_port);
            else if (a == "--drones") {
                o.drones.clear();
                std::istringstream ids(value(i));
                std::string id;
                while (std::getline(ids, id, ',')) o.drones.push_back(static_cast<uint16_t>(std::stoul(id)));
            } else if (a == "--challenge") o.challenge = std::stoi(value(i));
            else if (a == "--waypoints") o.waypoints = value(i);
            else if (a == "--obstacles") o.obstacles = value(i);
            else if (a == "--rto") o.rto = std::stod(value(i));
            else if (a == "--retries") o.retries = std::stol(value(i));
            else if (a == "--broadcast-id") o.broadcast_id = static_cast<uint16_t>(std::stoul(value(i), nullptr, 0));
            else if (a == "--broadcast-lists") o.broadcast_lists = true;
            else if (a == "--reply-to-source") o.reply_to_source = true;
            else if (a == "--initial-seq") o.initial_seq = std::stol(value(i), nullptr, 0) & 0xFFFF;
            else if (a == "--hold") o.hold = std::stod(value(i));
            else if (a == "--speed") o.speed = std::stod(value(i));
            else if (a == "-v" || a == "--verbose") o.verbose = true;
            else if (a == "-h" || a == "--help") usage(argv[0]);
            else usage(argv[0], "unknown option " + a);
        }
    } catch (const std::exception& e) {
        usage(argv[0], e.what());
    }
    if (o.drones.empty()) usage(argv[0], "--drones is empty");
    if (o.challenge < 1 || o.challenge > 3) usage(argv[0], "--challenge is 1, 2 or 3");
    if (o.waypoints.empty()) usage(argv[0], "--waypoints FILE is required");
    if (o.challenge == 3 && o.obstacles.empty()) usage(argv[0], "--challenge 3 needs --obstacles FILE");
    if (!(o.rto > 0) || o.retries < 0) usage(argv[0], "--rto must be > 0 and --retries >= 0");
    return o;
}

// ---- the endpoint: socket, receiver thread, timer thread, outstanding messages -------------

struct Outstanding {
    uint16_t drone;
    uint16_t seq;
    uint16_t action;
    Bytes bytes;
    sockaddr_in to;
    Clock::time_point deadline;
    long retransmissions = 0;
    enum State { Waiting, Acked, GaveUp } state = Waiting;
};

struct KeyHash {
    size_t operator()(const std::pair<uint16_t, uint16_t>& k) const noexcept {
        return (static_cast<size_t>(k.first) << 16) | k.second;
    }
};

class Manager {
public:
    explicit Manager(const Options& o) : opt_(o), drones_(o.drones.begin(), o.drones.end()) {
        std::random_device rd;
        next_seq_ = static_cast<uint16_t>(o.initial_seq >= 0 ? o.initial_seq : rd());  // arbitrary (MCP-SEQ-4)
        fd_ = ::socket(AF_INET, SOCK_DGRAM, 0);
        if (fd_ < 0) throw std::runtime_error(std::string("socket: ") + std::strerror(errno));
        int one = 1;
        ::setsockopt(fd_, SOL_SOCKET, SO_BROADCAST, &one, sizeof one);  // local-subnet broadcasts
        sockaddr_in local = resolve(o.bind_host, o.port);
        if (::bind(fd_, reinterpret_cast<sockaddr*>(&local), sizeof local) < 0)
            throw std::runtime_error("bind " + o.bind_host + ":" + std::to_string(o.port) + ": " + std::strerror(errno));
        peer_ = resolve(o.send_host, o.send_port);
        rto_ = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(o.rto));
    }

    ~Manager() { stop(); if (fd_ >= 0) ::close(fd_); }

    void start() {
        receiver_ = std::thread(&Manager::receive_loop, this);
        timer_ = std::thread(&Manager::timer_loop, this);
    }

    void stop() {
        {
            std::lock_guard<std::mutex> lock(mu_);
            if (stopping_) return;
            stopping_ = true;
        }
        timer_cv_.notify_all();
        done_cv_.notify_all();
        ::shutdown(fd_, SHUT_RDWR);  // wakes the blocking recvfrom
        if (receiver_.joinable()) receiver_.join();
        if (timer_.joinable()) timer_.join();
    }

    // Waits until every drone of the mission has sent Mission_Ready (MCP-BLK-2).
    bool wait_all_ready() {
        std::unique_lock<std::mutex> lock(mu_);
        done_cv_.wait(lock, [&] { return stopping_ || ready_.size() == drones_.size(); });
        return !stopping_;
    }

    // Sends a unicast message and returns its key; the timer retransmits it until ACKed.
    std::pair<uint16_t, uint16_t> submit(uint16_t drone, uint16_t action, const Bytes& payload) {
        std::lock_guard<std::mutex> lock(mu_);
        uint16_t seq = next_seq_++;  // ACKs take no number of their own (D-5)
        auto msg = std::make_unique<Outstanding>();
        msg->drone = drone;
        msg->seq = seq;
        msg->action = action;
        msg->bytes = make_message(drone, seq, action, payload);
        msg->deadline = Clock::now() + rto_;
        msg->to = address_of(drone);
        send_raw(msg->bytes, msg->to);
        log("-> %s to %u seq %u (%zu bytes)", action_name(action), drone, seq, msg->bytes.size());
        auto key = std::make_pair(drone, seq);
        outstanding_[key] = std::move(msg);
        timer_cv_.notify_all();
        return key;
    }

    // Blocks until the message is ACKed (true) or its retry limit is reached (false).
    bool wait(const std::pair<uint16_t, uint16_t>& key) {
        std::unique_lock<std::mutex> lock(mu_);
        done_cv_.wait(lock, [&] {
            auto it = outstanding_.find(key);
            return stopping_ || it == outstanding_.end() || it->second->state != Outstanding::Waiting;
        });
        auto it = outstanding_.find(key);
        if (it == outstanding_.end()) return false;
        bool acked = it->second->state == Outstanding::Acked;
        outstanding_.erase(it);
        return acked;
    }

    bool send_unicast(uint16_t drone, uint16_t action, const Bytes& payload) {
        return wait(submit(drone, action, payload));
    }

    // A broadcast: sent once, never ACKed, never retransmitted (MCP-ACK-4, MCP-RTX-4).
    void send_broadcast(uint16_t action, const Bytes& payload) {
        std::lock_guard<std::mutex> lock(mu_);
        uint16_t seq = next_seq_++;
        send_raw(make_message(opt_.broadcast_id, seq, action, payload), peer_);
        log("-> %s broadcast seq %u", action_name(action), seq);
    }

    void log(const char* fmt, ...) __attribute__((format(printf, 2, 3))) {
        if (!opt_.verbose) return;
        va_list ap;
        va_start(ap, fmt);
        std::fprintf(stderr, "manager: ");
        std::vfprintf(stderr, fmt, ap);
        std::fprintf(stderr, "\n");
        va_end(ap);
    }

private:
    static sockaddr_in resolve(const std::string& host, uint16_t port) {
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(port);
        if (host.empty() || host == "0.0.0.0" || host == "*") {
            a.sin_addr.s_addr = htonl(INADDR_ANY);
        } else if (::inet_pton(AF_INET, host.c_str(), &a.sin_addr) != 1) {
            addrinfo hints{}, *res = nullptr;
            hints.ai_family = AF_INET;
            hints.ai_socktype = SOCK_DGRAM;
            if (::getaddrinfo(host.c_str(), nullptr, &hints, &res) != 0 || res == nullptr)
                throw std::runtime_error("cannot resolve " + host);
            a.sin_addr = reinterpret_cast<sockaddr_in*>(res->ai_addr)->sin_addr;
            ::freeaddrinfo(res);
        }
        return a;
    }

    // Where a unicast to this drone goes: --send-to (the local broadcast address by default), or
    // with --reply-to-source the address its last Mission_Ready came from. Called under mu_.
    sockaddr_in address_of(uint16_t drone) const {
        auto it = drone_addr_.find(drone);
        return opt_.reply_to_source && it != drone_addr_.end() ? it->second : peer_;
    }

    void send_raw(const Bytes& b, const sockaddr_in& to) {
        if (::sendto(fd_, b.data(), b.size(), 0, reinterpret_cast<const sockaddr*>(&to), sizeof to) < 0)
            std::perror("manager: sendto");
    }

    void send_ack(uint16_t to, uint16_t acked_seq, const sockaddr_in& from) {
#ifdef MCP_FAULT_ACK_WRONG_SEQ
        acked_seq = static_cast<uint16_t>(acked_seq + 1);
#endif
        uint16_t be = htons(acked_seq);  // the acknowledged seq, u16 big-endian (D-2)
        Bytes payload(2);
        std::memcpy(payload.data(), &be, 2);
        uint16_t seq;
        {
            std::lock_guard<std::mutex> lock(mu_);
            seq = next_seq_;  // an ACK's own number is not judged (D-5); not consumed
        }
        send_raw(make_message(to, seq, Ack, payload), opt_.reply_to_source ? from : peer_);
    }

    // Does the payload fit the action code (D-4)?
    static bool payload_fits(uint16_t action, uint16_t src, const uint8_t* p, size_t n) {
        switch (action) {
            case MissionReady: {
                if (n == 0) return true;
                if (n != 2) return false;
                uint16_t id;
                std::memcpy(&id, p, 2);
                return ntohs(id) == src;  // D-3
            }
            case StartMission:
            case EndMission:
            case WpOff:
                return n == 0;
            case WpList:
            case ObstaclesList: {
                if (n < 2) return false;
                uint16_t count;
                std::memcpy(&count, p, 2);
                return n == 2 + kItemSize * ntohs(count);
            }
            case WpOn:
                return n == kItemSize;
            case Ack:
                return n == 2;
            case MavPassthrough:
                return valid_mavlink_frame(p, n);
            default:
                return false;
        }
    }

    void receive_loop() {
        std::vector<uint8_t> buf(kMaxDatagram + 1);
        for (;;) {
            sockaddr_in from{};
            socklen_t fromlen = sizeof from;
            ssize_t n = ::recvfrom(fd_, buf.data(), buf.size(), 0, reinterpret_cast<sockaddr*>(&from), &fromlen);
            if (n < 0) {
                if (errno == EINTR) continue;
                std::lock_guard<std::mutex> lock(mu_);
                if (stopping_) return;
                std::perror("manager: recvfrom");
                continue;
            }
            if (stopping_hint()) return;
            handle(buf.data(), static_cast<size_t>(n), from);
        }
    }

    bool stopping_hint() {
        std::lock_guard<std::mutex> lock(mu_);
        return stopping_;
    }

    void handle(const uint8_t* data, size_t n, const sockaddr_in& from) {
        if (n < sizeof(Header)) return;                                   // MCP-ROB-1
        Header h;
        std::memcpy(&h, data, sizeof h);
        if (std::memcmp(h.preamble, kPreamble, sizeof kPreamble) != 0) return;  // MCP-ROB-2
        const uint16_t dst = ntohs(h.dst), src = ntohs(h.src), seq = ntohs(h.seq), action = ntohs(h.action);
        if (action > MavPassthrough) return;                              // MCP-ROB-3
        const uint8_t* payload = data + sizeof h;
        const size_t len = n - sizeof h;
        const bool broadcast = dst == opt_.broadcast_id;
        if (dst != kManagerId && !broadcast) return;                      // MCP-ACK-5
        if (!payload_fits(action, src, payload, len)) {                   // D-4, MCP-ROB-4
            log("<- %s from %u seq %u: payload does not fit (%zu bytes), dropped", action_name(action), src, seq, len);
            return;
        }
        if (action == Ack) {                                              // MCP-ACK-6: never ACKed
            if (broadcast) return;
            uint16_t acked;
            std::memcpy(&acked, payload, 2);
            acked = ntohs(acked);
            std::lock_guard<std::mutex> lock(mu_);
            auto it = outstanding_.find({src, acked});  // MCP-RTX-2: from the destination, right seq
            if (it != outstanding_.end() && it->second->state == Outstanding::Waiting) {
                it->second->state = Outstanding::Acked;
                log("<- ACK from %u for seq %u", src, acked);
                done_cv_.notify_all();
                timer_cv_.notify_all();
            } else {
                log("<- ACK from %u for seq %u: nothing outstanding, ignored", src, acked);
            }
            return;
        }
        if (!broadcast) send_ack(src, seq, from);                         // MCP-ACK-1, MCP-ACK-4
        // duplicate discard: the last (src, seq) delivered per source (MCP-DUP-1..3)
        std::lock_guard<std::mutex> lock(mu_);
        auto last = last_delivered_.find(src);
        if (!broadcast && last != last_delivered_.end() && last->second == seq) {
            log("<- %s from %u seq %u: duplicate, ACKed again", action_name(action), src, seq);
            return;
        }
        if (!broadcast) last_delivered_[src] = seq;
        log("<- %s from %u seq %u", action_name(action), src, seq);
        if (action == MissionReady && drones_.count(src)) drone_addr_[src] = from;
        if (action == MissionReady && drones_.count(src) && !ready_.count(src)) {
            ready_.insert(src);
            done_cv_.notify_all();
        }
    }

    void timer_loop() {
        std::unique_lock<std::mutex> lock(mu_);
        while (!stopping_) {
            auto next = Clock::time_point::max();
            for (auto& kv : outstanding_)
                if (kv.second->state == Outstanding::Waiting) next = std::min(next, kv.second->deadline);
            if (next == Clock::time_point::max()) {
                timer_cv_.wait(lock);
                continue;
            }
            if (timer_cv_.wait_until(lock, next) == std::cv_status::no_timeout) continue;
            auto now = Clock::now();
            for (auto& kv : outstanding_) {
                Outstanding& m = *kv.second;
                if (m.state != Outstanding::Waiting || m.deadline > now) continue;
#ifdef MCP_FAULT_NO_RETRANSMIT
                const bool give_up = true;
#else
                const bool give_up = m.retransmissions >= opt_.retries;
#endif
                if (give_up) {
                    m.state = Outstanding::GaveUp;
                    std::fprintf(stderr, "manager: %s to drone %u (seq %u) not ACKed after %ld retransmissions: gave up\n",
                                 action_name(m.action), m.drone, m.seq, m.retransmissions);
                    done_cv_.notify_all();
                    continue;
                }
                send_raw(m.bytes, m.to);  // the same bytes, the same seq (MCP-SEQ-2)
                ++m.retransmissions;
                m.deadline = Clock::now() + rto_;
                log("-> %s to %u seq %u (retransmission %ld)", action_name(m.action), m.drone, m.seq, m.retransmissions);
            }
        }
    }

    const Options opt_;
    const std::unordered_set<uint16_t> drones_;
    int fd_ = -1;
    sockaddr_in peer_{};
    Clock::duration rto_{};
    std::thread receiver_, timer_;

    std::mutex mu_;  // guards everything below
    std::condition_variable timer_cv_, done_cv_;
    bool stopping_ = false;
    uint16_t next_seq_ = 0;
    std::unordered_map<std::pair<uint16_t, uint16_t>, std::unique_ptr<Outstanding>, KeyHash> outstanding_;
    std::unordered_map<uint16_t, uint16_t> last_delivered_;  // src -> last delivered seq
    std::unordered_set<uint16_t> ready_;
    std::unordered_map<uint16_t, sockaddr_in> drone_addr_;  // drone -> its last Mission_Ready's source
};

// ---- the mission ----------------------------------------------------------------------------

struct Command {
    uint16_t action;
    Bytes payload;
    bool broadcast = false;  // once to the broadcast ID instead of to each drone
    double hold = 0;         // seconds to wait once every drone has it
};

std::vector<Command> mission_commands(const Options& o, const std::vector<MissionItem>& waypoints,
                                      const std::vector<MissionItem>& obstacles) {
    std::vector<Command> cmds;
    if (o.speed >= 0) cmds.push_back({MavPassthrough, change_speed_frame(0, static_cast<float>(o.speed))});
    switch (o.challenge) {
        case 1:  // the waypoints as one WP_List (MCP-FLOW-4)
            cmds.push_back({WpList, item_list_payload(waypoints), o.broadcast_lists});
            break;
        case 2:  // each waypoint active then inactive: WP_On, WP_Off (MCP-FLOW-5)
            for (const auto& wp : waypoints) {
                Bytes item;
                append_item(item, wp);
                cmds.push_back({WpOn, item, false, o.hold});
                cmds.push_back({WpOff, {}});
            }
            break;
        case 3:  // the obstacles as one Obstacles_List (MCP-FLOW-6), then the waypoints
            cmds.push_back({ObstaclesList, item_list_payload(obstacles), o.broadcast_lists});
            cmds.push_back({WpList, item_list_payload(waypoints), o.broadcast_lists});
            break;
    }
    return cmds;
}

int run(const Options& o) {
    auto waypoints = read_waypoints(o.waypoints);
    std::vector<MissionItem> obstacles;
    if (o.challenge == 3) obstacles = read_waypoints(o.obstacles);
    const auto commands = mission_commands(o, waypoints, obstacles);

    Manager m(o);
    m.start();
    std::fprintf(stderr, "manager: listening on %s:%u, waiting for Mission_Ready from %zu drone(s)\n",
                 o.bind_host.c_str(), o.port, o.drones.size());
    if (!m.wait_all_ready()) return 130;

    std::vector<uint16_t> live;  // drones still answering
    // Start_Mission to each drone; nothing more to a drone until it is ACKed (MCP-BLK-3)
    for (uint16_t d : o.drones) {
        if (m.send_unicast(d, StartMission, {})) live.push_back(d);
    }
#ifdef MCP_PIPELINE
    // every drone's mission messages outstanding at once, each with its own timer
    // (--hold does not apply: nothing waits between a drone's messages)
    std::map<uint16_t, std::vector<std::pair<uint16_t, uint16_t>>> sent;
    for (const auto& c : commands)
        if (c.broadcast) m.send_broadcast(c.action, c.payload);
    for (uint16_t d : live)
        for (const auto& c : commands)
            if (!c.broadcast) sent[d].push_back(m.submit(d, c.action, c.payload));
    std::vector<uint16_t> finished;
    for (uint16_t d : live) {
        bool ok = true;
        for (const auto& key : sent[d]) ok = m.wait(key) && ok;
        if (ok) finished.push_back(d);
    }
    live = finished;
#else
    // stop-and-wait (MCP-BLK-1): one unicast outstanding at a time
    for (const auto& c : commands) {
        if (c.broadcast) {
            m.send_broadcast(c.action, c.payload);
        } else {
            std::vector<uint16_t> still;
            for (uint16_t d : live)
                if (m.send_unicast(d, c.action, c.payload)) still.push_back(d);
            live = still;
        }
        if (c.hold > 0) std::this_thread::sleep_for(std::chrono::duration<double>(c.hold));
    }
#endif
    // End_Mission last (MCP-FLOW-3): no command to a drone after it (MCP-BLK-6)
    size_t ended = 0;
    for (uint16_t d : live) ended += m.send_unicast(d, EndMission, {});
    std::fprintf(stderr, "manager: mission ended on %zu of %zu drone(s)\n", ended, o.drones.size());
    m.stop();
    return ended == o.drones.size() ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
    Options o = parse_options(argc, argv);
    try {
        return run(o);
    } catch (const std::exception& e) {
        std::cerr << argv[0] << ": " << e.what() << "\n";
        return 2;
    }
}
