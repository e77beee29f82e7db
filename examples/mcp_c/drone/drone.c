/*
 * drone - a CentMesh Mission Control Protocol (MCP) drone application in C.
 *
 * Written from the protocol's documents only (docs/spec.md, spec/mcp.yaml, docs/guide/drone.md,
 * docs/guide/vehicle.md): one UDP socket for MCP, one link to the autopilot (MAVLink, optional),
 * one single-threaded poll() loop, a monotonic-clock retransmission timer, a duplicate table.
 *
 *   1. connect to the autopilot; send it a HEARTBEAT each second; wait for a 3D GPS fix
 *      (GPS_RAW_INT fix_type >= 3; MCP-BLK-5);
 *   2. send Mission_Ready unicast to the manager (ID 0), every --rto seconds until the
 *      manager's ACK naming its seq comes (MCP-FLOW-1, MCP-RTX-1/2); nothing else is sent
 *      meanwhile but ACKs (stop-and-wait, MCP-BLK-1);
 *   3. ACK every well-formed unicast message to our ID but an ACK, every copy (MCP-ACK-1..3),
 *      deliver it once per (src, seq) (MCP-DUP-1..3): Start_Mission -> GUIDED, arm, take off
 *      (never an arm before it, MCP-BLK-4); WP_List -> the autopilot's mission (MISSION_COUNT,
 *      an item per MISSION_REQUEST), then AUTO; WP_On -> a guided position target;
 *      Mav_Passthrough -> its frame to the autopilot, once (MCP-PAY-8); End_Mission -> RTL
 *      after what is pending (MCP-BLK-7), then keep ACKing for --linger seconds and exit 0.
 *
 * Malformed input (short, no preamble, action > 8, a payload that does not fit its action,
 * D-4) is dropped without a reply (MCP-ROB-1..4). Broadcasts (dst 0xFFFF) are delivered, not
 * ACKed (MCP-ACK-4); messages to another ID are ignored (MCP-ACK-5); ACKs are never ACKed.
 *
 * usage: drone --id N --bind HOST:PORT --manager HOST:PORT [--autopilot URL] [--rto S]
 *              [--retries N] [--linger S] [--takeoff-alt M]
 *              [--ack-seq next|same|zero] [--ready-id] [--reply-to-source] [-v]
 *   --ack-seq: the ACK's own header seq, which the documents leave open (D-5): the next of our
 *   numbers (default, as the sample code), the acknowledged message's, or 0.
 *   --ready-id: Mission_Ready carries our ID, u16 big-endian (D-3; default: no payload).
 *   --reply-to-source: an ACK goes to the datagram's source address, not to --manager.
 *   URL: tcp:HOST:PORT (connect), udp:HOST:PORT or udpin:HOST:PORT (listen there; the
 *   autopilot sends first, as SITL's --out), udpout:HOST:PORT (send there first).
 *
 * Compile-time faults (make FAULT=...), for the harness's own tests:
 *   FAULT_ACK_LE    the ACK's payload in host byte order (a forgotten htons)
 *   FAULT_NO_DEDUP  every copy of a message delivered again (no duplicate table)
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <math.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "ardupilotmega/mavlink.h"

/* ---- the protocol's constants (docs/spec.md) ------------------------------------------ */

#define MCP_HEADER_LEN 17
#define MCP_MAX_DATAGRAM 65507
#define MCP_MANAGER_ID 0
#define MCP_BROADCAST_ID 0xFFFF /* D-1 */
#define MCP_ITEM_LEN 37         /* E-1: MAVLink v1 MISSION_ITEM payload */

enum mcp_action {
    MISSION_READY = 0,
    START_MISSION = 1,
    END_MISSION = 2,
    WP_LIST = 3,
    WP_ON = 4,
    WP_OFF = 5,
    OBSTACLES_LIST = 6,
    ACK = 7,
    MAV_PASSTHROUGH = 8,
};

static const char *const ACTION_NAMES[] = {
    "Mission_Ready", "Start_Mission", "End_Mission", "WP_List", "WP_On",
    "WP_Off", "Obstacles_List", "ACK", "Mav_Passthrough",
};

static const uint8_t PREAMBLE[9] = {'N', 'C', 'S', 'U', '-', 'C', 'M', 0x01, 0x01};

/* ArduCopter custom modes */
#define COPTER_AUTO 3
#define COPTER_GUIDED 4
#define COPTER_RTL 6

/* who we are on the autopilot link: a companion computer */
#define OUR_SYSID 255
#define OUR_COMPID MAV_COMP_ID_ONBOARD_COMPUTER

/* ---- small helpers ---------------------------------------------------------------------- */

static int verbose;

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

static double t0;

static void logf_(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static void logf_(const char *fmt, ...)
{
    va_list ap;
    fprintf(stderr, "[drone %8.3f] ", now_s() - t0);
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
    fflush(stderr);
}

static void put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v >> 8);
    p[1] = (uint8_t)(v & 0xFF);
}

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)((p[0] << 8) | p[1]);
}

static float get_f32le(const uint8_t *p)
{
    uint32_t u = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static uint16_t get_u16le(const uint8_t *p)
{
    return (uint16_t)(p[0] | (p[1] << 8));
}

/* HOST:PORT into an IPv4 address; 0 on success. */
static int parse_hostport(const char *text, struct sockaddr_in *out)
{
    char host[256];
    const char *colon = strrchr(text, ':');
    if (!colon || colon == text || (size_t)(colon - text) >= sizeof host)
        return -1;
    memcpy(host, text, (size_t)(colon - text));
    host[colon - text] = '\0';
    char *end;
    long port = strtol(colon + 1, &end, 10);
    if (*end != '\0' || port < 0 || port > 65535)
        return -1;
    struct addrinfo hints = {0}, *res = NULL;
    hints.ai_family = AF_INET;
    hints.ai_socktype = SOCK_DGRAM;
    if (getaddrinfo(host, NULL, &hints, &res) != 0 || !res)
        return -1;
    memcpy(out, res->ai_addr, sizeof *out);
    out->sin_port = htons((uint16_t)port);
    freeaddrinfo(res);
    return 0;
}

/* ---- the mission item (E-1, E-2) ------------------------------------------------------ */

typedef struct {
    float param[4], x, y, z;
    uint16_t seq, command;
    uint8_t target_system, target_component, frame, current, autocontinue;
} mission_item;

static void unpack_item(const uint8_t *p, mission_item *it)
{
    for (int i = 0; i < 4; i++)
        it->param[i] = get_f32le(p + 4 * i);
    it->x = get_f32le(p + 16);
    it->y = get_f32le(p + 20);
    it->z = get_f32le(p + 24);
    it->seq = get_u16le(p + 28);
    it->command = get_u16le(p + 30);
    it->target_system = p[32];
    it->target_component = p[33];
    it->frame = p[34];
    it->current = p[35];
    it->autocontinue = p[36];
}

/* ---- the autopilot link --------------------------------------------------------------- */

enum link_kind { LINK_NONE, LINK_TCP, LINK_UDPIN, LINK_UDPOUT };

enum job_kind { JOB_MODE, JOB_COMMAND, JOB_UPLOAD, JOB_GOTO };

typedef struct {
    enum job_kind kind;
    uint32_t mode;            /* JOB_MODE */
    uint16_t command;         /* JOB_COMMAND */
    float p[7];
    mission_item *items;      /* JOB_UPLOAD (owned); JOB_GOTO: its one item */
    uint16_t count;
    int then_auto;
} job;

#define MAX_JOBS 64

typedef struct {
    enum link_kind kind;
    int fd;
    struct sockaddr_in peer;
    int have_peer;
    mavlink_status_t status;
    mavlink_message_t rx;
    uint8_t target_sys, target_comp;
    int heard;                /* a HEARTBEAT from the autopilot came */
    int fix_type;             /* GPS_RAW_INT's, -1 before the first */
    double next_heartbeat;
    /* the job queue: one at a time, each until its COMMAND_ACK / MISSION_ACK */
    job jobs[MAX_JOBS];
    int head, n;
    int busy;                 /* jobs[head] has been sent */
    int attempts;
    double job_deadline;      /* resend (or give up) then */
    double job_started;
} autopilot;

static autopilot ap = {.kind = LINK_NONE, .fd = -1, .fix_type = -1};

static void ap_write(const uint8_t *buf, size_t len)
{
    ssize_t n;
    if (ap.kind == LINK_TCP)
        n = send(ap.fd, buf, len, MSG_NOSIGNAL | MSG_DONTWAIT);
    else if (ap.have_peer)
        n = sendto(ap.fd, buf, len, 0, (struct sockaddr *)&ap.peer, sizeof ap.peer);
    else
        return; /* udpin: the autopilot has not spoken yet */
    if (n < 0 && errno != EAGAIN && errno != ECONNREFUSED)
        logf_("autopilot write: %s", strerror(errno));
}

static void ap_send(const mavlink_message_t *msg)
{
    uint8_t buf[MAVLINK_MAX_PACKET_LEN];
    uint16_t len = mavlink_msg_to_send_buffer(buf, msg);
    ap_write(buf, len);
}

static int ap_open(const char *url)
{
    const char *rest;
    if (strncmp(url, "tcp:", 4) == 0) {
        ap.kind = LINK_TCP;
        rest = url + 4;
    } else if (strncmp(url, "udpin:", 6) == 0) {
        ap.kind = LINK_UDPIN;
        rest = url + 6;
    } else if (strncmp(url, "udp:", 4) == 0) {
        ap.kind = LINK_UDPIN;
        rest = url + 4;
    } else if (strncmp(url, "udpout:", 7) == 0) {
        ap.kind = LINK_UDPOUT;
        rest = url + 7;
    } else {
        fprintf(stderr, "drone: --autopilot: tcp:, udp:, udpin: or udpout:HOST:PORT, not %s\n", url);
        return -1;
    }
    struct sockaddr_in addr;
    if (parse_hostport(rest, &addr) != 0) {
        fprintf(stderr, "drone: --autopilot: bad HOST:PORT %s\n", rest);
        return -1;
    }
    ap.fd = socket(AF_INET, ap.kind == LINK_TCP ? SOCK_STREAM : SOCK_DGRAM, 0);
    if (ap.fd < 0) {
        perror("drone: socket");
        return -1;
    }
    if (ap.kind == LINK_TCP) {
        /* the autopilot may come up a moment after us: try for 10 s */
        double until = now_s() + 10;
        while (connect(ap.fd, (struct sockaddr *)&addr, sizeof addr) != 0) {
            if (now_s() > until || (errno != ECONNREFUSED && errno != EINTR)) {
                fprintf(stderr, "drone: connect %s: %s\n", rest, strerror(errno));
                return -1;
            }
            close(ap.fd);
            ap.fd = socket(AF_INET, SOCK_STREAM, 0);
            usleep(200 * 1000);
        }
        int one = 1;
        setsockopt(ap.fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        ap.peer = addr;
        ap.have_peer = 1;
    } else if (ap.kind == LINK_UDPIN) {
        int one = 1;
        setsockopt(ap.fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        if (bind(ap.fd, (struct sockaddr *)&addr, sizeof addr) != 0) {
            fprintf(stderr, "drone: bind %s: %s\n", rest, strerror(errno));
            return -1;
        }
    } else {
        ap.peer = addr;
        ap.have_peer = 1;
    }
    ap.target_sys = 1;
    ap.target_comp = MAV_COMP_ID_AUTOPILOT1;
    logf_("autopilot link %s", url);
    return 0;
}

static void ap_heartbeat(void)
{
    mavlink_message_t msg;
    mavlink_msg_heartbeat_pack(OUR_SYSID, OUR_COMPID, &msg, MAV_TYPE_ONBOARD_CONTROLLER,
                               MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE);
    ap_send(&msg);
}

static void ap_enqueue(const job *j)
{
    if (ap.kind == LINK_NONE) {
        free(j->items);
        return;
    }
    if (ap.n == MAX_JOBS) {
        logf_("autopilot queue full: request dropped");
        free(j->items);
        return;
    }
    ap.jobs[(ap.head + ap.n) % MAX_JOBS] = *j;
    ap.n++;
}

static void job_mode(uint32_t mode)
{
    job j = {.kind = JOB_MODE, .mode = mode};
    ap_enqueue(&j);
}

static void job_command(uint16_t command, float p1, float p7)
{
    job j = {.kind = JOB_COMMAND, .command = command};
    j.p[0] = p1;
    j.p[6] = p7;
    ap_enqueue(&j);
}

static void job_done(const char *how);

/* (Re)send the job at the head of the queue. */
static void job_send(void)
{
    job *j = &ap.jobs[ap.head];
    mavlink_message_t msg;
    switch (j->kind) {
    case JOB_MODE:
        mavlink_msg_set_mode_pack(OUR_SYSID, OUR_COMPID, &msg, ap.target_sys,
                                  MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, j->mode);
        logf_("autopilot: SET_MODE %u", j->mode);
        break;
    case JOB_COMMAND:
        mavlink_msg_command_long_pack(OUR_SYSID, OUR_COMPID, &msg, ap.target_sys, ap.target_comp,
                                      j->command, (uint8_t)ap.attempts, j->p[0], j->p[1], j->p[2],
                                      j->p[3], j->p[4], j->p[5], j->p[6]);
        logf_("autopilot: COMMAND_LONG %u (%g)", j->command, (double)j->p[0]);
        break;
    case JOB_GOTO: {
        /* no answer comes to a position target: sent, done */
        const mission_item *it = j->items;
        mavlink_msg_set_position_target_global_int_pack(
            OUR_SYSID, OUR_COMPID, &msg, 0, ap.target_sys, ap.target_comp,
            MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0x0FF8, (int32_t)lround((double)it->x * 1e7),
            (int32_t)lround((double)it->y * 1e7), it->z, 0, 0, 0, 0, 0, 0, 0, 0);
        logf_("autopilot: position target %.7f %.7f %.1f", (double)it->x, (double)it->y, (double)it->z);
        ap_send(&msg);
        ap.busy = 1;
        job_done(NULL);
        return;
    }
    case JOB_UPLOAD: {
        /* the struct, not _pack(): newer dialects add fields (opaque_id) to MISSION_COUNT */
        mavlink_mission_count_t count = {.target_system = ap.target_sys,
                                         .target_component = ap.target_comp,
                                         .count = j->count,
                                         .mission_type = MAV_MISSION_TYPE_MISSION};
        mavlink_msg_mission_count_encode(OUR_SYSID, OUR_COMPID, &msg, &count);
        logf_("autopilot: MISSION_COUNT %u", j->count);
        break;
    }
    }
    ap_send(&msg);
    ap.busy = 1;
    ap.attempts++;
    ap.job_deadline = now_s() + (j->kind == JOB_UPLOAD ? 2.0 : 1.0);
}

static void job_done(const char *how)
{
    job *j = &ap.jobs[ap.head];
    if (how)
        logf_("autopilot: done (%s)", how);
    int then_auto = j->kind == JOB_UPLOAD && j->then_auto && how && strcmp(how, "MAV_MISSION_ACCEPTED") == 0;
    free(j->items);
    j->items = NULL;
    ap.head = (ap.head + 1) % MAX_JOBS;
    ap.n--;
    ap.busy = 0;
    ap.attempts = 0;
    if (then_auto)
        job_mode(COPTER_AUTO);
}

/* The queue's clock: start the next job, resend or give up on the current one. */
static void jobs_tick(double now)
{
    if (ap.n == 0 || !ap.have_peer)
        return;
    if (!ap.busy) {
        ap.job_started = now;
        job_send();
        return;
    }
    if (now < ap.job_deadline)
        return;
    job *j = &ap.jobs[ap.head];
    int limit = j->kind == JOB_COMMAND && j->command == MAV_CMD_COMPONENT_ARM_DISARM ? 5 : 3;
    if (ap.attempts >= limit || now - ap.job_started > 10.0) {
        logf_("autopilot: no answer, giving up on this request");
        job_done(NULL);
        return;
    }
    job_send();
}

static void send_mission_item(const job *j, uint16_t seq)
{
    const mission_item *it = &j->items[seq];
    mavlink_message_t msg;
    /* MISSION_ITEM_INT (degE7), as ArduPilot prefers; the struct, not _pack(): the fields'
     * list differs between MAVLink releases */
    mavlink_mission_item_int_t m = {
        .param1 = it->param[0], .param2 = it->param[1], .param3 = it->param[2],
        .param4 = it->param[3], .x = (int32_t)lround((double)it->x * 1e7),
        .y = (int32_t)lround((double)it->y * 1e7), .z = it->z, .seq = seq,
        .command = it->command, .target_system = ap.target_sys,
        .target_component = ap.target_comp, .frame = it->frame,
        .current = seq == 0 ? 0 : it->current, .autocontinue = it->autocontinue,
        .mission_type = MAV_MISSION_TYPE_MISSION};
    mavlink_msg_mission_item_int_encode(OUR_SYSID, OUR_COMPID, &msg, &m);
    ap_send(&msg);
}

static void on_mavlink(const mavlink_message_t *msg)
{
    switch (msg->msgid) {
    case MAVLINK_MSG_ID_HEARTBEAT:
        if (mavlink_msg_heartbeat_get_type(msg) == MAV_TYPE_GCS ||
            mavlink_msg_heartbeat_get_autopilot(msg) == MAV_AUTOPILOT_INVALID)
            break;
        if (!ap.heard) {
            ap.heard = 1;
            ap.target_sys = msg->sysid;
            ap.target_comp = msg->compid;
            logf_("autopilot: system %u component %u", msg->sysid, msg->compid);
            mavlink_message_t req;
            mavlink_msg_request_data_stream_pack(OUR_SYSID, OUR_COMPID, &req, ap.target_sys,
                                                 ap.target_comp, MAV_DATA_STREAM_ALL, 4, 1);
            ap_send(&req);
        }
        break;
    case MAVLINK_MSG_ID_GPS_RAW_INT: {
        int fix = mavlink_msg_gps_raw_int_get_fix_type(msg);
        if (fix != ap.fix_type)
            logf_("autopilot: GPS fix_type %d", fix);
        ap.fix_type = fix;
        break;
    }
    case MAVLINK_MSG_ID_STATUSTEXT: {
        char text[51] = {0};
        mavlink_msg_statustext_get_text(msg, text);
        logf_("autopilot says: %s", text);
        break;
    }
    case MAVLINK_MSG_ID_COMMAND_ACK: {
        if (ap.n == 0 || !ap.busy)
            break;
        job *j = &ap.jobs[ap.head];
        uint16_t command = mavlink_msg_command_ack_get_command(msg);
        uint8_t result = mavlink_msg_command_ack_get_result(msg);
        uint16_t expect = j->kind == JOB_MODE ? MAVLINK_MSG_ID_SET_MODE : j->kind == JOB_COMMAND ? j->command : 0xFFFF;
        if (command != expect || result == MAV_RESULT_IN_PROGRESS)
            break;
        if (result == MAV_RESULT_ACCEPTED) {
            job_done("MAV_RESULT_ACCEPTED");
        } else {
            logf_("autopilot: command %u answered %u", command, result);
            /* the arm is tried again (jobs_tick) until its limit: a fix may come */
            if (!(j->kind == JOB_COMMAND && j->command == MAV_CMD_COMPONENT_ARM_DISARM))
                job_done("refused");
        }
        break;
    }
    case MAVLINK_MSG_ID_MISSION_REQUEST:
    case MAVLINK_MSG_ID_MISSION_REQUEST_INT: {
        if (ap.n == 0 || !ap.busy || ap.jobs[ap.head].kind != JOB_UPLOAD)
            break;
        job *j = &ap.jobs[ap.head];
        uint16_t seq = msg->msgid == MAVLINK_MSG_ID_MISSION_REQUEST_INT
                           ? mavlink_msg_mission_request_int_get_seq(msg)
                           : mavlink_msg_mission_request_get_seq(msg);
        if (seq >= j->count)
            break;
        send_mission_item(j, seq);
        ap.job_deadline = now_s() + 2.0;
        ap.attempts = 0;
        break;
    }
    case MAVLINK_MSG_ID_MISSION_ACK: {
        if (ap.n == 0 || !ap.busy || ap.jobs[ap.head].kind != JOB_UPLOAD)
            break;
        uint8_t type = mavlink_msg_mission_ack_get_type(msg);
        job_done(type == MAV_MISSION_ACCEPTED ? "MAV_MISSION_ACCEPTED" : "mission refused");
        break;
    }
    default:
        break;
    }
}

static void ap_readable(void)
{
    uint8_t buf[4096];
    ssize_t n;
    if (ap.kind == LINK_TCP) {
        n = recv(ap.fd, buf, sizeof buf, MSG_DONTWAIT);
        if (n == 0) {
            logf_("autopilot closed the link");
            close(ap.fd);
            ap.fd = -1;
            ap.have_peer = 0;
            return;
        }
    } else {
        struct sockaddr_in from;
        socklen_t fromlen = sizeof from;
        n = recvfrom(ap.fd, buf, sizeof buf, MSG_DONTWAIT, (struct sockaddr *)&from, &fromlen);
        if (n > 0 && ap.kind == LINK_UDPIN && !ap.have_peer) {
            ap.peer = from; /* answer whoever sends first, as udpin: does */
            ap.have_peer = 1;
            ap_heartbeat();
        }
    }
    if (n <= 0)
        return;
    for (ssize_t i = 0; i < n; i++)
        if (mavlink_parse_char(MAVLINK_COMM_0, buf[i], &ap.rx, &ap.status))
            on_mavlink(&ap.rx);
}

/* ---- MCP ------------------------------------------------------------------------------ */

typedef struct {
    int fd;
    struct sockaddr_in manager;
    uint16_t id;
    uint16_t seq;             /* the next sequence number we send */
    double rto;
    long retries;
    double linger;
    float takeoff_alt;
    /* the one unicast message awaiting its ACK (stop-and-wait, MCP-BLK-1) */
    struct {
        int active;
        uint8_t buf[MCP_HEADER_LEN + 2];
        size_t len;
        uint16_t dst, seq;
        long copies;
        double next;
    } out;
    int announced;            /* Mission_Ready sent */
    char ack_seq;             /* the ACK's own header seq (D-5): 'n'ext number, 's'ame as acked, 'z'ero */
    int ready_id;             /* Mission_Ready carries our ID (D-3) */
    int reply_to_source;      /* ACKs go to the datagram's source address */
    struct sockaddr_in from;  /* the current datagram's source */
    int started;
    double end_at;            /* after End_Mission: exit then (0: not ended) */
} mcp_node;

static mcp_node node;

/* last delivered seq per source: -1 none (MCP-DUP-1..3) */
static int32_t last_delivered[65536];

static void mcp_header(uint8_t *buf, uint16_t dst, uint16_t seq, uint16_t action)
{
    memcpy(buf, PREAMBLE, sizeof PREAMBLE);
    put_u16(buf + 9, dst);
    put_u16(buf + 11, node.id);
    put_u16(buf + 13, seq);
    put_u16(buf + 15, action);
}

static void mcp_sendto_addr(const uint8_t *buf, size_t len, const struct sockaddr_in *to)
{
    if (sendto(node.fd, buf, len, 0, (const struct sockaddr *)to, sizeof *to) < 0 &&
        errno != ECONNREFUSED)
        logf_("sendto: %s", strerror(errno));
}

static void mcp_sendto(const uint8_t *buf, size_t len)
{
    mcp_sendto_addr(buf, len, &node.manager);
}

static void send_ack(uint16_t dst, uint16_t acked)
{
    uint8_t buf[MCP_HEADER_LEN + 2];
    /* D-5: by default an ACK takes a number, as the sample code does */
    uint16_t own = node.ack_seq == 's' ? acked : node.ack_seq == 'z' ? 0 : node.seq++;
    mcp_header(buf, dst, own, ACK);
#ifdef FAULT_ACK_LE
    memcpy(buf + MCP_HEADER_LEN, &acked, 2);
#else
    put_u16(buf + MCP_HEADER_LEN, acked);
#endif
    mcp_sendto_addr(buf, sizeof buf, node.reply_to_source ? &node.from : &node.manager);
    if (verbose)
        logf_("sent ACK of seq %u to %u", acked, dst);
}

/* Start sending a unicast message (only Mission_Ready for a drone). */
static void send_unicast(uint16_t dst, uint16_t action, const uint8_t *payload, size_t plen)
{
    if (node.out.active || plen > 2)
        return; /* stop-and-wait: the caller waits for out.active to clear */
    node.out.dst = dst;
    node.out.seq = node.seq++;
    mcp_header(node.out.buf, dst, node.out.seq, action);
    if (plen)
        memcpy(node.out.buf + MCP_HEADER_LEN, payload, plen);
    node.out.len = MCP_HEADER_LEN + plen;
    node.out.active = 1;
    node.out.copies = 1;
    node.out.next = now_s() + node.rto;
    mcp_sendto(node.out.buf, node.out.len);
    logf_("sent %s seq %u to %u", ACTION_NAMES[action], node.out.seq, dst);
}

static void rtx_tick(double now)
{
    if (!node.out.active || now < node.out.next)
        return;
    if (node.out.copies > node.retries) {
        logf_("no ACK for seq %u after %ld copies: giving up", node.out.seq, node.out.copies);
        node.out.active = 0;
        return;
    }
    mcp_sendto(node.out.buf, node.out.len);
    node.out.copies++;
    /* the next copy one timeout after this one was due: evenly spaced (MCP-RTX-3) */
    node.out.next += node.rto;
    if (node.out.next < now)
        node.out.next = now + node.rto;
    logf_("retransmitted seq %u (copy %ld)", node.out.seq, node.out.copies);
}

/* Is this exactly one complete MAVLink v1/v2 frame with a valid checksum? */
static int one_mavlink_frame(const uint8_t *p, size_t len)
{
    if (len < 8 || (p[0] != MAVLINK_STX_MAVLINK1 && p[0] != MAVLINK_STX))
        return 0;
    mavlink_message_t rx, out;
    mavlink_status_t st, out_st;
    memset(&rx, 0, sizeof rx);
    memset(&st, 0, sizeof st);
    for (size_t i = 0; i < len; i++) {
        uint8_t r = mavlink_frame_char_buffer(&rx, &st, p[i], &out, &out_st);
        if (r == MAVLINK_FRAMING_OK)
            return i == len - 1;
        if (r != MAVLINK_FRAMING_INCOMPLETE)
            return 0;
    }
    return 0;
}

/* D-4: does the payload fit the action? */
static int payload_fits(uint16_t action, uint16_t src, const uint8_t *p, size_t plen)
{
    switch (action) {
    case MISSION_READY:
        return plen == 0 || (plen == 2 && get_u16(p) == src);
    case START_MISSION:
    case END_MISSION:
    case WP_OFF:
        return plen == 0;
    case WP_LIST:
    case OBSTACLES_LIST:
        return plen >= 2 && plen == 2 + (size_t)MCP_ITEM_LEN * get_u16(p);
    case WP_ON:
        return plen == MCP_ITEM_LEN;
    case ACK:
        return plen == 2;
    case MAV_PASSTHROUGH:
        return one_mavlink_frame(p, plen);
    default:
        return 0;
    }
}

static mission_item *items_of(const uint8_t *p, uint16_t count)
{
    mission_item *items = calloc(count ? count : 1, sizeof *items);
    if (!items) {
        logf_("out of memory");
        exit(1);
    }
    for (uint16_t i = 0; i < count; i++)
        unpack_item(p + (size_t)MCP_ITEM_LEN * i, &items[i]);
    return items;
}

/* The application: a message delivered once. */
static void deliver(uint16_t src, uint16_t seq, uint16_t action, const uint8_t *p, size_t plen)
{
    logf_("delivered %s seq %u from %u (%zu bytes of payload)", ACTION_NAMES[action], seq, src, plen);
    switch (action) {
    case START_MISSION:
        node.started = 1;
        job_mode(COPTER_GUIDED);
        job_command(MAV_CMD_COMPONENT_ARM_DISARM, 1, 0);
        job_command(MAV_CMD_NAV_TAKEOFF, 0, node.takeoff_alt);
        break;
    case END_MISSION:
        /* pending actions first (the queue), then RTL (MCP-BLK-7) */
        job_mode(COPTER_RTL);
        node.end_at = now_s() + node.linger;
        logf_("mission ended: RTL queued, exiting in %.1f s", node.linger);
        break;
    case WP_LIST: {
        uint16_t count = get_u16(p);
        job j = {.kind = JOB_UPLOAD, .count = count, .items = items_of(p + 2, count), .then_auto = node.started};
        if (count == 0) {
            free(j.items);
            break;
        }
        ap_enqueue(&j);
        break;
    }
    case WP_ON: {
        mission_item it;
        unpack_item(p, &it);
        logf_("waypoint on: %.7f %.7f %.1f", (double)it.x, (double)it.y, (double)it.z);
        if (node.started) { /* fly there in GUIDED (a position target is ignored in AUTO) */
            job_mode(COPTER_GUIDED);
            job j = {.kind = JOB_GOTO, .items = items_of(p, 1)};
            ap_enqueue(&j);
        }
        break;
    }
    case WP_OFF:
        logf_("waypoint off");
        break;
    case OBSTACLES_LIST:
        logf_("%u obstacles", get_u16(p));
        break;
    case MAV_PASSTHROUGH:
        if (ap.kind != LINK_NONE)
            ap_write(p, plen); /* once per delivery (MCP-PAY-8) */
        break;
    default: /* Mission_Ready from someone: nothing for a drone to do */
        break;
    }
}

static void on_datagram(const uint8_t *buf, size_t len)
{
    if (len < MCP_HEADER_LEN || memcmp(buf, PREAMBLE, sizeof PREAMBLE) != 0)
        return; /* MCP-ROB-1, MCP-ROB-2 */
    uint16_t dst = get_u16(buf + 9), src = get_u16(buf + 11), seq = get_u16(buf + 13),
             action = get_u16(buf + 15);
    const uint8_t *p = buf + MCP_HEADER_LEN;
    size_t plen = len - MCP_HEADER_LEN;
    if (action > MAV_PASSTHROUGH) /* MCP-ROB-3 */
        return;
    if (dst != node.id && dst != MCP_BROADCAST_ID) /* MCP-ACK-5 */
        return;
    if (!payload_fits(action, src, p, plen)) { /* D-4, MCP-ROB-4 */
        if (verbose)
            logf_("dropped a malformed %s seq %u from %u", ACTION_NAMES[action], seq, src);
        return;
    }
    if (action == ACK) { /* never ACKed (MCP-ACK-6); ends our retransmission (MCP-RTX-2) */
        if (dst == node.id && node.out.active && src == node.out.dst && get_u16(p) == node.out.seq) {
            node.out.active = 0;
            logf_("seq %u ACKed by %u", node.out.seq, src);
        }
        return;
    }
    if (dst == node.id)
        send_ack(src, seq); /* every copy (MCP-ACK-1); broadcasts never (MCP-ACK-4) */
#ifndef FAULT_NO_DEDUP
    if (last_delivered[src] == (int32_t)seq) { /* MCP-DUP-1 */
        if (verbose)
            logf_("duplicate %s seq %u from %u", ACTION_NAMES[action], seq, src);
        return;
    }
#endif
    last_delivered[src] = seq;
    deliver(src, seq, action, p, plen);
}

static void mcp_readable(void)
{
    static uint8_t buf[65536];
    /* read what is queued (a flood, MCP-ROB-7), a bounded batch before timers run again */
    for (int i = 0; i < 512; i++) {
        socklen_t fromlen = sizeof node.from;
        ssize_t n = recvfrom(node.fd, buf, sizeof buf, MSG_DONTWAIT, (struct sockaddr *)&node.from, &fromlen);
        if (n < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR && errno != ECONNREFUSED)
                logf_("recv: %s", strerror(errno));
            return;
        }
        on_datagram(buf, (size_t)n);
    }
}

static int mcp_open(const char *bind_text, const char *manager_text)
{
    struct sockaddr_in local;
    if (parse_hostport(bind_text, &local) != 0) {
        fprintf(stderr, "drone: --bind: bad HOST:PORT %s\n", bind_text);
        return -1;
    }
    if (parse_hostport(manager_text, &node.manager) != 0) {
        fprintf(stderr, "drone: --manager: bad HOST:PORT %s\n", manager_text);
        return -1;
    }
    node.fd = socket(AF_INET, SOCK_DGRAM, 0);
    if (node.fd < 0) {
        perror("drone: socket");
        return -1;
    }
    int one = 1;
    setsockopt(node.fd, SOL_SOCKET, SO_BROADCAST, &one, sizeof one); /* MCP-TRN-1 */
    if (bind(node.fd, (struct sockaddr *)&local, sizeof local) != 0) {
        fprintf(stderr, "drone: bind %s: %s\n", bind_text, strerror(errno));
        return -1;
    }
    return 0;
}

/* ---- main ----------------------------------------------------------------------------- */

static void usage(int code)
{
    fprintf(code ? stderr : stdout,
            "usage: drone --id N --bind HOST:PORT --manager HOST:PORT [--autopilot URL]\n"
            "             [--rto S] [--retries N] [--linger S] [--takeoff-alt M]\n"
            "             [--ack-seq next|same|zero] [--ready-id] [--reply-to-source] [-v]\n"
            "  URL: tcp:HOST:PORT, udp:HOST:PORT, udpin:HOST:PORT or udpout:HOST:PORT\n");
    exit(code);
}

static uint16_t initial_seq(void)
{
    /* MCP-SEQ-4: arbitrary */
    uint16_t v = 0;
    int fd = open("/dev/urandom", O_RDONLY);
    if (fd < 0 || read(fd, &v, sizeof v) != (ssize_t)sizeof v)
        v = (uint16_t)(getpid() ^ (unsigned)time(NULL));
    if (fd >= 0)
        close(fd);
    return v;
}

int main(int argc, char **argv)
{
    static const struct option opts[] = {
        {"id", required_argument, NULL, 'i'},
        {"bind", required_argument, NULL, 'b'},
        {"manager", required_argument, NULL, 'm'},
        {"autopilot", required_argument, NULL, 'a'},
        {"rto", required_argument, NULL, 'r'},
        {"retries", required_argument, NULL, 'n'},
        {"linger", required_argument, NULL, 'l'},
        {"takeoff-alt", required_argument, NULL, 't'},
        {"ack-seq", required_argument, NULL, 'A'},
        {"ready-id", no_argument, NULL, 'I'},
        {"reply-to-source", no_argument, NULL, 'S'},
        {"verbose", no_argument, NULL, 'v'},
        {"help", no_argument, NULL, 'h'},
        {NULL, 0, NULL, 0},
    };
    const char *bind_text = "0.0.0.0:7890", *manager_text = "127.255.255.255:7889", *url = NULL;
    long id = 1;
    double linger = -1;
    t0 = now_s();
    node.rto = 5.0;       /* the protocol document's timeout */
    node.retries = 1000;  /* and its retry limit */
    node.takeoff_alt = 10;
    int c;
    while ((c = getopt_long(argc, argv, "i:b:m:a:r:n:l:t:vh", opts, NULL)) != -1) {
        char *end = NULL;
        switch (c) {
        case 'i': id = strtol(optarg, &end, 10); break;
        case 'b': bind_text = optarg; break;
        case 'm': manager_text = optarg; break;
        case 'a': url = optarg; break;
        case 'r': node.rto = strtod(optarg, &end); break;
        case 'n': node.retries = strtol(optarg, &end, 10); break;
        case 'l': linger = strtod(optarg, &end); break;
        case 't': node.takeoff_alt = strtof(optarg, &end); break;
        case 'A':
            if (strcmp(optarg, "next") && strcmp(optarg, "same") && strcmp(optarg, "zero"))
                usage(2);
            node.ack_seq = optarg[0] == 's' ? 's' : optarg[0] == 'z' ? 'z' : 'n';
            break;
        case 'I': node.ready_id = 1; break;
        case 'S': node.reply_to_source = 1; break;
        case 'v': verbose = 1; break;
        case 'h': usage(0); break;
        default: usage(2);
        }
        if (end && *end != '\0')
            usage(2);
    }
    if (optind != argc || id <= 0 || id >= MCP_BROADCAST_ID || !(node.rto > 0) || node.retries < 0)
        usage(2);
    node.id = (uint16_t)id;
    /* after End_Mission keep ACKing its retransmissions: a manager sends up to a few copies */
    node.linger = linger >= 0 ? linger : 10 * node.rto;
    node.seq = initial_seq();
    for (size_t i = 0; i < 65536; i++)
        last_delivered[i] = -1;
    signal(SIGPIPE, SIG_IGN);

    if (mcp_open(bind_text, manager_text) != 0)
        return 1;
    if (url && ap_open(url) != 0)
        return 1;
    logf_("MCP ID %u on %s, manager at %s, rto %.3f s, first seq %u", node.id, bind_text,
          manager_text, node.rto, node.seq);

    for (;;) {
        double now = now_s();
        /* the autopilot link: heartbeat, GPS, the queue */
        if (ap.kind != LINK_NONE && ap.fd >= 0) {
            if (now >= ap.next_heartbeat) {
                ap_heartbeat();
                ap.next_heartbeat = now + 1.0;
            }
            jobs_tick(now);
        }
        /* ready to fly (MCP-BLK-5): announce once */
        if (!node.announced && (ap.kind == LINK_NONE || ap.fix_type >= 3)) {
            node.announced = 1;
            uint8_t id_be[2];
            put_u16(id_be, node.id);
            send_unicast(MCP_MANAGER_ID, MISSION_READY, id_be, node.ready_id ? 2 : 0);
        }
        rtx_tick(now);
        if (node.end_at > 0 && now >= node.end_at && ap.n == 0) {
            logf_("done");
            return 0;
        }

        /* sleep until the next timer or input */
        double next = now + 1.0;
        if (ap.kind != LINK_NONE && ap.next_heartbeat < next)
            next = ap.next_heartbeat;
        if (ap.n && ap.busy && ap.job_deadline < next)
            next = ap.job_deadline;
        if (node.out.active && node.out.next < next)
            next = node.out.next;
        if (node.end_at > 0 && node.end_at < next)
            next = node.end_at;
        int timeout_ms = (int)((next - now) * 1000.0 + 0.999);
        if (timeout_ms < 0)
            timeout_ms = 0;
        if (ap.n && !ap.busy)
            timeout_ms = 0;

        struct pollfd fds[2] = {{.fd = node.fd, .events = POLLIN}, {.fd = ap.fd, .events = POLLIN}};
        int nfds = ap.fd >= 0 ? 2 : 1;
        int r = poll(fds, (nfds_t)nfds, timeout_ms);
        if (r < 0) {
            if (errno == EINTR)
                continue;
            perror("drone: poll");
            return 1;
        }
        if (fds[0].revents & POLLIN)
            mcp_readable();
        if (nfds == 2 && (fds[1].revents & (POLLIN | POLLHUP | POLLERR)))
            ap_readable();
    }
}
