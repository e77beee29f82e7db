/*
 * mission_takeoff - upload a mission with the mission protocol's handshake, take off, fly it.
 *
 * Upload, done right: MISSION_COUNT, then answer every MISSION_REQUEST (ArduPilot) or
 * MISSION_REQUEST_INT (the protocol page, PX4) with the item it names, as often as it is
 * asked, until MISSION_ACK; MISSION_COUNT again if nothing is asked within a second.
 * A MISSION_ACK with an error is printed; the upload goes on while the vehicle keeps asking.
 * Then GUIDED, arm (again each second until the GPS fix lets it), MAV_CMD_NAV_TAKEOFF to
 * 10 m, MAV_CMD_MISSION_START, and MISSION_ITEM_REACHED up to the final RTL.
 *
 * -b sends item 1 the first time with the classic bug: a MISSION_ITEM whose latitude is the
 * degE7 integer (357713320) in the degrees field; ArduCopter answers
 * MAV_MISSION_INVALID_PARAM5_X and asks for item 1 again, which then goes out right.
 *
 * usage: mission_takeoff [-v PORT] [-l PORT] [-H HOST] [-t S] [-b]
 */
#include "mavlink_udp.h"

typedef struct {
    uint16_t command;
    uint8_t frame;
    int32_t lat, lon; /* degE7 */
    float alt;        /* metres */
} item_t;

static const item_t MISSION[] = {
    {MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL, 357713320, -786744210, 0},  /* 0: home */
    {MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT, 0, 0, 10},
    {MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, 357711030, -786746590, 10},
    {MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT, 357715000, -786742000, 12},
    {MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_FRAME_GLOBAL_RELATIVE_ALT, 0, 0, 0},
};
#define N_ITEMS ((uint16_t)(sizeof MISSION / sizeof MISSION[0]))

static const char *mission_result(int r)
{
    static const char *names[] = {
        "MAV_MISSION_ACCEPTED", "MAV_MISSION_ERROR", "MAV_MISSION_UNSUPPORTED_FRAME",
        "MAV_MISSION_UNSUPPORTED", "MAV_MISSION_NO_SPACE", "MAV_MISSION_INVALID",
        "MAV_MISSION_INVALID_PARAM1", "MAV_MISSION_INVALID_PARAM2", "MAV_MISSION_INVALID_PARAM3",
        "MAV_MISSION_INVALID_PARAM4", "MAV_MISSION_INVALID_PARAM5_X",
        "MAV_MISSION_INVALID_PARAM6_Y", "MAV_MISSION_INVALID_PARAM7",
        "MAV_MISSION_INVALID_SEQUENCE", "MAV_MISSION_DENIED", "MAV_MISSION_OPERATION_CANCELLED"};
    return r >= 0 && r < (int)(sizeof names / sizeof names[0]) ? names[r] : "unknown";
}

static void send_item(udp_link *link, uint16_t seq, int buggy)
{
    const item_t *it = &MISSION[seq];
    mavlink_message_t msg;
    if (buggy) { /* the bug: degE7 integer where MISSION_ITEM wants degrees */
        mavlink_msg_mission_item_pack(GCS_SYSID, GCS_COMPID, &msg, link->target_sys,
                                      link->target_comp, seq, it->frame, it->command, 0, 1,
                                      0, 0, 0, 0, (float)357713320, (float)-786744210, it->alt);
        printf("sent item %u as MISSION_ITEM with x=357713320 (degE7 sent as degrees)\n", seq);
    } else {
        mavlink_msg_mission_item_int_pack(GCS_SYSID, GCS_COMPID, &msg, link->target_sys,
                                          link->target_comp, seq, it->frame, it->command, 0, 1,
                                          0, 0, 0, 0, it->lat, it->lon, it->alt);
        printf("sent item %u (MISSION_ITEM_INT, command %u)\n", seq, it->command);
    }
    link_send(link, &msg);
}

/* The upload; returns 1 when the vehicle answered MAV_MISSION_ACCEPTED. */
static int upload(udp_link *link, int bug)
{
    mavlink_message_t msg;
    int counts = 0, last_sent = -1;
    double last_heard = 0;
    while (now_s() < link->deadline) {
        if (now_s() - last_heard > 1.0) { /* nothing asked for a second */
            if (last_sent >= 0 && now_s() - last_heard > 2.5) {
                fprintf(stderr, "the vehicle stopped asking for items\n");
                return 0;
            }
            if (last_sent < 0) {
                if (++counts > 3)
                    return 0;
                mavlink_msg_mission_count_pack(GCS_SYSID, GCS_COMPID, &msg, link->target_sys,
                                               link->target_comp, N_ITEMS);
                link_send(link, &msg);
                printf("sent MISSION_COUNT %u\n", N_ITEMS);
                last_heard = now_s();
            }
        }
        if (!link_recv(link, &msg, 200))
            continue;
        switch (msg.msgid) {
        case MAVLINK_MSG_ID_MISSION_REQUEST:
        case MAVLINK_MSG_ID_MISSION_REQUEST_INT: {
            uint16_t seq = msg.msgid == MAVLINK_MSG_ID_MISSION_REQUEST
                               ? mavlink_msg_mission_request_get_seq(&msg)
                               : mavlink_msg_mission_request_int_get_seq(&msg);
            printf("vehicle asks for item %u (%s)\n", seq,
                   msg.msgid == MAVLINK_MSG_ID_MISSION_REQUEST ? "MISSION_REQUEST"
                                                               : "MISSION_REQUEST_INT");
            last_heard = now_s();
            if (seq < N_ITEMS) {
                send_item(link, seq, bug && seq == 1);
                if (bug && seq == 1)
                    bug = 0;
                last_sent = seq;
            }
            break;
        }
        case MAVLINK_MSG_ID_MISSION_ACK: {
            int r = mavlink_msg_mission_ack_get_type(&msg);
            printf("MISSION_ACK %s\n", mission_result(r));
            last_heard = now_s();
            if (r == MAV_MISSION_ACCEPTED && last_sent == N_ITEMS - 1)
                return 1;
            break;
        }
        default:
            print_statustext(&msg);
        }
    }
    return 0;
}

int main(int argc, char **argv)
{
    link_opts o = LINK_OPTS_DEFAULT;
    int bug = 0, opt;
    o.seconds = 30;
    while ((opt = getopt(argc, argv, COMMON_OPTS "b")) != -1) {
        if (common_option(&o, opt, optarg))
            continue;
        if (opt == 'b')
            bug = 1;
        else
            usage_exit(argv[0], " [-b]");
    }
    udp_link link;
    link_open(&link, o.vehicle_port, o.local_port, o.host, o.seconds);
    await_vehicle(&link);
    if (!upload(&link, bug)) {
        fprintf(stderr, "mission upload failed\n");
        return 1;
    }
    printf("mission of %u items uploaded\n", N_ITEMS);

    printf("set mode GUIDED: result %d\n", set_mode(&link, COPTER_GUIDED));
    int r = -1;
    mavlink_message_t msg;
    while (r != MAV_RESULT_ACCEPTED && now_s() < link.deadline) {
        r = command_long(&link, MAV_CMD_COMPONENT_ARM_DISARM, 1, 0, 0);
        printf("arm: result %d\n", r);
        if (r != MAV_RESULT_ACCEPTED)
            link_wait(&link, MAVLINK_MSG_ID_GPS_RAW_INT, &msg, 1000, print_statustext);
    }
    r = command_long(&link, MAV_CMD_NAV_TAKEOFF, 0, 0, 10);
    printf("takeoff to 10 m: result %d\n", r);
    if (r != MAV_RESULT_ACCEPTED)
        return 1;
    int32_t alt_mm = 0;
    while (alt_mm < 9500 && link_wait(&link, MAVLINK_MSG_ID_GLOBAL_POSITION_INT, &msg, 2000, NULL))
        alt_mm = mavlink_msg_global_position_int_get_relative_alt(&msg);
    printf("altitude %.1f m\n", alt_mm / 1000.0);
    r = command_long(&link, MAV_CMD_MISSION_START, 0, 0, 0);
    printf("mission start: result %d\n", r);
    if (r != MAV_RESULT_ACCEPTED)
        return 1;
    int last = -1;
    while (last != N_ITEMS - 1 && link_wait(&link, MAVLINK_MSG_ID_MISSION_ITEM_REACHED, &msg,
                                             5000, print_statustext)) {
        last = mavlink_msg_mission_item_reached_get_seq(&msg);
        printf("reached item %d\n", last);
    }
    return last == N_ITEMS - 1 ? 0 : 1;
}
