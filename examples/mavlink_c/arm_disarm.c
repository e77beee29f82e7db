/*
 * arm_disarm - set mode GUIDED, arm, disarm; print each answer and the autopilot's reasons.
 *
 * It does not wait for a GPS fix before asking: a vehicle without a fix refuses GUIDED
 * ("Flight mode change failed", MAV_RESULT_FAILED) and arming ("PreArm: Need 3D Fix");
 * the program asks again each second, as an operator would, until the vehicle accepts or
 * the time is up.
 *
 * usage: arm_disarm [-v PORT] [-l PORT] [-H HOST] [-t S]
 */
#include "mavlink_udp.h"

static const char *result_name(int r)
{
    switch (r) {
    case MAV_RESULT_ACCEPTED: return "ACCEPTED";
    case MAV_RESULT_TEMPORARILY_REJECTED: return "TEMPORARILY_REJECTED";
    case MAV_RESULT_DENIED: return "DENIED";
    case MAV_RESULT_UNSUPPORTED: return "UNSUPPORTED";
    case MAV_RESULT_FAILED: return "FAILED";
    case -1: return "no answer";
    default: return "other";
    }
}

int main(int argc, char **argv)
{
    link_opts o = LINK_OPTS_DEFAULT;
    int opt;
    while ((opt = getopt(argc, argv, COMMON_OPTS)) != -1)
        if (!common_option(&o, opt, optarg))
            usage_exit(argv[0], "");
    udp_link link;
    link_open(&link, o.vehicle_port, o.local_port, o.host, o.seconds);
    await_vehicle(&link);

    int r = -1;
    while (r != MAV_RESULT_ACCEPTED && now_s() < link.deadline) {
        r = set_mode(&link, COPTER_GUIDED);
        printf("set mode GUIDED: %s\n", result_name(r));
        if (r != MAV_RESULT_ACCEPTED) { /* GUIDED needs a position: wait for the fix */
            mavlink_message_t msg;
            send_gcs_heartbeat(&link);
            link_wait(&link, MAVLINK_MSG_ID_GPS_RAW_INT, &msg, 1000, print_statustext);
        }
    }
    int armed = 0;
    while (!armed && now_s() < link.deadline) {
        r = command_long(&link, MAV_CMD_COMPONENT_ARM_DISARM, 1, 0, 0);
        printf("arm: %s\n", result_name(r));
        armed = r == MAV_RESULT_ACCEPTED;
        if (!armed) { /* keep the link alive while waiting for the fix */
            mavlink_message_t msg;
            send_gcs_heartbeat(&link);
            link_wait(&link, MAVLINK_MSG_ID_GPS_RAW_INT, &msg, 1000, print_statustext);
        }
    }
    if (!armed)
        return 1;
    r = command_long(&link, MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0);
    printf("disarm: %s\n", result_name(r));
    return r == MAV_RESULT_ACCEPTED ? 0 : 1;
}
