/*
 * mavlink_udp.h - the UDP link shared by the examples (header only, one per program).
 *
 * In the style of seed 001's programs (MAVLink C library v1, one UDP socket, a vehicle on
 * 127.0.0.1): pack with mavlink_msg_*_pack(), serialise with mavlink_msg_to_send_buffer(),
 * sendto(); recvfrom() and feed every byte to mavlink_parse_char().
 *
 * Options common to every program:
 *   -v PORT  the vehicle's UDP port to send to (python -m vehicle --udp-in 127.0.0.1:PORT)
 *   -l PORT  the local UDP port to listen on (python -m vehicle --udp-out 127.0.0.1:PORT);
 *            without -v the first sender becomes the vehicle, as pymavlink's udpin: does
 *   -H HOST  the vehicle's address (127.0.0.1)
 *   -t S     give up after S seconds (20)
 * The MAVLink headers are generated at build time by pymavlink's mavgen (see Makefile).
 */
#ifndef MAVLINK_UDP_H
#define MAVLINK_UDP_H

#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

#include "ardupilotmega/mavlink.h"

#define GCS_SYSID 255
#define GCS_COMPID MAV_COMP_ID_MISSIONPLANNER

typedef struct {
    int fd;
    struct sockaddr_in vehicle;  /* where we send */
    int have_vehicle;            /* known from -v, or from the first datagram */
    double deadline;             /* monotonic seconds: every wait ends by then */
    uint8_t target_sys, target_comp; /* the autopilot, from its HEARTBEAT */
    mavlink_status_t status;
} udp_link;

static inline double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec / 1e9;
}

static inline void usage_exit(const char *prog, const char *extra)
{
    fprintf(stderr, "usage: %s [-v VEHICLE_PORT] [-l LOCAL_PORT] [-H HOST] [-t SECONDS]%s\n",
            prog, extra);
    exit(2);
}

typedef struct {
    int vehicle_port, local_port;
    const char *host;
    double seconds;
} link_opts;

#define COMMON_OPTS "v:l:H:t:"
#define LINK_OPTS_DEFAULT {0, 0, "127.0.0.1", 20.0}

/* One of the common options (-v -l -H -t): 1 if it was one, else 0. */
static inline int common_option(link_opts *o, int opt, const char *arg)
{
    switch (opt) {
    case 'v': o->vehicle_port = atoi(arg); return 1;
    case 'l': o->local_port = atoi(arg); return 1;
    case 'H': o->host = arg; return 1;
    case 't': o->seconds = atof(arg); return 1;
    default: return 0;
    }
}

/* Open and bind the socket (see the options above). */
static inline void link_open(udp_link *link, int vehicle_port, int local_port, const char *host,
                      double seconds)
{
    memset(link, 0, sizeof *link);
    link->target_sys = 1;
    link->target_comp = MAV_COMP_ID_AUTOPILOT1;
    link->deadline = now_s() + seconds;
    link->fd = socket(AF_INET, SOCK_DGRAM, 0);
    if (link->fd < 0) {
        perror("socket");
        exit(1);
    }
    struct sockaddr_in local = {0};
    local.sin_family = AF_INET;
    local.sin_addr.s_addr = htonl(INADDR_ANY);
    local.sin_port = htons((uint16_t)local_port);
    if (bind(link->fd, (struct sockaddr *)&local, sizeof local) < 0) {
        perror("bind");
        exit(1);
    }
    if (vehicle_port > 0) {
        link->vehicle.sin_family = AF_INET;
        link->vehicle.sin_port = htons((uint16_t)vehicle_port);
        if (inet_pton(AF_INET, host, &link->vehicle.sin_addr) != 1) {
            fprintf(stderr, "not an IPv4 address: %s\n", host);
            exit(2);
        }
        link->have_vehicle = 1;
    }
}

/* Serialise and send one message; returns the frame length (0 if no vehicle yet). */
static inline int link_send(udp_link *link, const mavlink_message_t *msg)
{
    uint8_t buf[MAVLINK_MAX_PACKET_LEN];
    uint16_t len = mavlink_msg_to_send_buffer(buf, msg);
    if (!link->have_vehicle)
        return 0;
    if (sendto(link->fd, buf, len, 0, (struct sockaddr *)&link->vehicle,
               sizeof link->vehicle) < 0 && errno != ECONNREFUSED)
        perror("sendto");
    return len;
}

/* The next decoded message within timeout_ms (bounded by the deadline): 1, or 0. */
static inline int link_recv(udp_link *link, mavlink_message_t *msg, int timeout_ms)
{
    static uint8_t buf[2048];
    static ssize_t len = 0, pos = 0;
    double until = now_s() + timeout_ms / 1000.0;
    if (until > link->deadline)
        until = link->deadline;
    for (;;) {
        while (pos < len) {
            if (mavlink_parse_char(MAVLINK_COMM_0, buf[pos++], msg, &link->status)) {
                if (msg->msgid == MAVLINK_MSG_ID_HEARTBEAT &&
                    mavlink_msg_heartbeat_get_type(msg) != MAV_TYPE_GCS) {
                    link->target_sys = msg->sysid;
                    link->target_comp = msg->compid;
                }
                return 1;
            }
        }
        double left = until - now_s();
        if (left <= 0)
            return 0;
        fd_set fds;
        FD_ZERO(&fds);
        FD_SET(link->fd, &fds);
        struct timeval tv = {(time_t)left, (suseconds_t)((left - (time_t)left) * 1e6)};
        if (select(link->fd + 1, &fds, NULL, NULL, &tv) <= 0)
            continue;
        struct sockaddr_in from;
        socklen_t fromlen = sizeof from;
        len = recvfrom(link->fd, buf, sizeof buf, 0, (struct sockaddr *)&from, &fromlen);
        pos = 0;
        if (len < 0) {
            len = 0;
            continue;
        }
        if (!link->have_vehicle) { /* answer whoever sent first, as udpin: does */
            link->vehicle = from;
            link->have_vehicle = 1;
        }
    }
}

/* Wait for a message with this id (others are passed to on_other, which may be NULL). */
static inline int link_wait(udp_link *link, uint32_t msgid, mavlink_message_t *msg, int timeout_ms,
                     void (*on_other)(const mavlink_message_t *))
{
    double until = now_s() + timeout_ms / 1000.0;
    while (now_s() < until && now_s() < link->deadline) {
        int left = (int)((until - now_s()) * 1000) + 1;
        if (!link_recv(link, msg, left))
            continue;
        if (msg->msgid == msgid && msg->sysid != GCS_SYSID)
            return 1;
        if (on_other)
            on_other(msg);
    }
    return 0;
}

/* A GCS HEARTBEAT (the vehicle learns our address from it over UDP). */
static inline void send_gcs_heartbeat(udp_link *link)
{
    mavlink_message_t msg;
    mavlink_msg_heartbeat_pack(GCS_SYSID, GCS_COMPID, &msg, MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID,
                               0, 0, MAV_STATE_ACTIVE);
    link_send(link, &msg);
}

/* Print a STATUSTEXT (the autopilot's reasons: "PreArm: Need 3D Fix" ...). */
static inline void print_statustext(const mavlink_message_t *msg)
{
    if (msg->msgid == MAVLINK_MSG_ID_STATUSTEXT) {
        char text[51] = {0};
        mavlink_msg_statustext_get_text(msg, text);
        printf("autopilot says: %s\n", text);
    }
}

/* Send COMMAND_LONG and wait for its COMMAND_ACK; returns the MAV_RESULT or -1. */
static inline int command_long(udp_link *link, uint16_t command, float p1, float p2, float p7)
{
    mavlink_message_t msg;
    for (int attempt = 0; attempt < 3; attempt++) {
        mavlink_msg_command_long_pack(GCS_SYSID, GCS_COMPID, &msg, link->target_sys,
                                      link->target_comp, command, attempt, p1, p2, 0, 0, 0, 0, p7);
        link_send(link, &msg);
        double until = now_s() + 1.0;
        while (now_s() < until) {
            if (!link_wait(link, MAVLINK_MSG_ID_COMMAND_ACK, &msg, 1000, print_statustext))
                break;
            if (mavlink_msg_command_ack_get_command(&msg) == command)
                return mavlink_msg_command_ack_get_result(&msg);
        }
    }
    return -1;
}

/* SET_MODE with a custom (ArduCopter) mode; ArduPilot ACKs it as command 11. */
static inline int set_mode(udp_link *link, uint32_t custom_mode)
{
    mavlink_message_t msg;
    for (int attempt = 0; attempt < 3; attempt++) {
        mavlink_msg_set_mode_pack(GCS_SYSID, GCS_COMPID, &msg, link->target_sys,
                                  MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode);
        link_send(link, &msg);
        double until = now_s() + 1.0;
        while (now_s() < until) {
            if (!link_wait(link, MAVLINK_MSG_ID_COMMAND_ACK, &msg, 1000, print_statustext))
                break;
            if (mavlink_msg_command_ack_get_command(&msg) == MAVLINK_MSG_ID_SET_MODE)
                return mavlink_msg_command_ack_get_result(&msg);
        }
    }
    return -1;
}

/* Say hello and wait for the autopilot's HEARTBEAT; exits 1 if it never comes. */
static inline void await_vehicle(udp_link *link)
{
    mavlink_message_t msg;
    for (int i = 0; i < 20; i++) {
        send_gcs_heartbeat(link);
        if (link_wait(link, MAVLINK_MSG_ID_HEARTBEAT, &msg, 500, NULL) &&
            mavlink_msg_heartbeat_get_type(&msg) != MAV_TYPE_GCS) {
            printf("vehicle: system %u component %u, MAV_TYPE %u, autopilot %u, mode %u\n",
                   msg.sysid, msg.compid, mavlink_msg_heartbeat_get_type(&msg),
                   mavlink_msg_heartbeat_get_autopilot(&msg),
                   mavlink_msg_heartbeat_get_custom_mode(&msg));
            return;
        }
    }
    fprintf(stderr, "no HEARTBEAT from the vehicle\n");
    exit(1);
}

#define COPTER_GUIDED 4

#endif
