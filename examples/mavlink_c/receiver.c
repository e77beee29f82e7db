/*
 * receiver - print every MAVLink message it decodes from the vehicle.
 *
 * With -l PORT it listens where the vehicle's --udp-out sends; with -v PORT it greets the
 * vehicle's --udp-in socket with a HEARTBEAT (each second) so the vehicle streams to it.
 * Stops after -n messages (50) or -t seconds.
 *
 * usage: receiver [-v PORT] [-l PORT] [-H HOST] [-t S] [-n COUNT]
 */
#include "mavlink_udp.h"

static void print_message(const mavlink_message_t *msg)
{
    printf("%3u sys %u comp %u seq %3u: ", msg->msgid, msg->sysid, msg->compid, msg->seq);
    switch (msg->msgid) {
    case MAVLINK_MSG_ID_HEARTBEAT:
        printf("HEARTBEAT type %u autopilot %u base_mode 0x%02X custom_mode %u status %u\n",
               mavlink_msg_heartbeat_get_type(msg), mavlink_msg_heartbeat_get_autopilot(msg),
               mavlink_msg_heartbeat_get_base_mode(msg),
               mavlink_msg_heartbeat_get_custom_mode(msg),
               mavlink_msg_heartbeat_get_system_status(msg));
        break;
    case MAVLINK_MSG_ID_SYS_STATUS:
        printf("SYS_STATUS battery %.2f V\n",
               mavlink_msg_sys_status_get_voltage_battery(msg) / 1000.0);
        break;
    case MAVLINK_MSG_ID_GPS_RAW_INT:
        printf("GPS_RAW_INT fix_type %u lat %.7f lon %.7f satellites %u\n",
               mavlink_msg_gps_raw_int_get_fix_type(msg),
               mavlink_msg_gps_raw_int_get_lat(msg) / 1e7,
               mavlink_msg_gps_raw_int_get_lon(msg) / 1e7,
               mavlink_msg_gps_raw_int_get_satellites_visible(msg));
        break;
    case MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
        printf("GLOBAL_POSITION_INT lat %.7f lon %.7f relative_alt %.2f m\n",
               mavlink_msg_global_position_int_get_lat(msg) / 1e7,
               mavlink_msg_global_position_int_get_lon(msg) / 1e7,
               mavlink_msg_global_position_int_get_relative_alt(msg) / 1000.0);
        break;
    case MAVLINK_MSG_ID_VFR_HUD:
        printf("VFR_HUD alt %.2f m climb %.2f m/s\n", mavlink_msg_vfr_hud_get_alt(msg),
               mavlink_msg_vfr_hud_get_climb(msg));
        break;
    case MAVLINK_MSG_ID_ATTITUDE:
        printf("ATTITUDE roll %.2f pitch %.2f yaw %.2f\n", mavlink_msg_attitude_get_roll(msg),
               mavlink_msg_attitude_get_pitch(msg), mavlink_msg_attitude_get_yaw(msg));
        break;
    case MAVLINK_MSG_ID_MISSION_CURRENT:
        printf("MISSION_CURRENT seq %u\n", mavlink_msg_mission_current_get_seq(msg));
        break;
    case MAVLINK_MSG_ID_STATUSTEXT: {
        char text[51] = {0};
        mavlink_msg_statustext_get_text(msg, text);
        printf("STATUSTEXT severity %u \"%s\"\n", mavlink_msg_statustext_get_severity(msg), text);
        break;
    }
    case MAVLINK_MSG_ID_COMMAND_ACK:
        printf("COMMAND_ACK command %u result %u\n", mavlink_msg_command_ack_get_command(msg),
               mavlink_msg_command_ack_get_result(msg));
        break;
    default:
        printf("(not printed in detail)\n");
    }
}

int main(int argc, char **argv)
{
    link_opts o = LINK_OPTS_DEFAULT;
    int count = 50, opt;
    o.seconds = 10;
    while ((opt = getopt(argc, argv, COMMON_OPTS "n:")) != -1) {
        if (common_option(&o, opt, optarg))
            continue;
        if (opt == 'n')
            count = atoi(optarg);
        else
            usage_exit(argv[0], " [-n COUNT]");
    }
    udp_link link;
    link_open(&link, o.vehicle_port, o.local_port, o.host, o.seconds);
    int got = 0;
    double next_hello = 0;
    mavlink_message_t msg;
    while (got < count && now_s() < link.deadline) {
        if (o.vehicle_port > 0 && now_s() >= next_hello) {
            send_gcs_heartbeat(&link);
            next_hello = now_s() + 1.0;
        }
        if (link_recv(&link, &msg, 200)) {
            print_message(&msg);
            got++;
        }
    }
    printf("%d message(s) decoded, %u parse error(s)\n", got, link.status.parse_error);
    return got > 0 ? 0 : 1;
}
