/*
 * heartbeat - send GCS HEARTBEATs to the vehicle and print the vehicle's.
 *
 * The first frame is seed 001's exact HEARTBEAT, MAVLink 1, sequence 0, system 255,
 * component 0: FE 09 00 FF 00 00 00 00 00 00 06 03 C0 04 03 F5 C0 (MAV_TYPE_GCS,
 * MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode SAFETY_ARMED|MANUAL_INPUT_ENABLED, custom_mode 0,
 * MAV_STATE_ACTIVE, mavlink_version 3). Each frame sent is printed in hex.
 *
 * usage: heartbeat [-v PORT] [-l PORT] [-H HOST] [-t S] [-n COUNT]
 */
#include "mavlink_udp.h"

int main(int argc, char **argv)
{
    link_opts o = LINK_OPTS_DEFAULT;
    int count = 3, opt;
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
    int seen = 0;
    for (int i = 0; i < count && now_s() < link.deadline; i++) {
        mavlink_message_t msg;
        uint8_t buf[MAVLINK_MAX_PACKET_LEN];
        mavlink_msg_heartbeat_pack(255, 0, &msg, MAV_TYPE_GCS, MAV_AUTOPILOT_ARDUPILOTMEGA,
                                   MAV_MODE_FLAG_SAFETY_ARMED | MAV_MODE_FLAG_MANUAL_INPUT_ENABLED,
                                   0, MAV_STATE_ACTIVE);
        uint16_t len = mavlink_msg_to_send_buffer(buf, &msg);
        if (!link.have_vehicle) /* -l only: wait for the vehicle's telemetry first */
            link_recv(&link, &msg, 2000);
        link_send(&link, &msg);
        printf("sent");
        for (uint16_t k = 0; k < len; k++)
            printf(" %02X", buf[k]);
        printf("\n");
        double next = now_s() + 1.0;
        while (now_s() < next && link_recv(&link, &msg, (int)((next - now_s()) * 1000) + 1)) {
            if (msg.msgid == MAVLINK_MSG_ID_HEARTBEAT && msg.sysid != 255) {
                printf("vehicle HEARTBEAT: system %u, type %u, autopilot %u, base_mode 0x%02X, "
                       "custom_mode %u, status %u\n", msg.sysid,
                       mavlink_msg_heartbeat_get_type(&msg),
                       mavlink_msg_heartbeat_get_autopilot(&msg),
                       mavlink_msg_heartbeat_get_base_mode(&msg),
                       mavlink_msg_heartbeat_get_custom_mode(&msg),
                       mavlink_msg_heartbeat_get_system_status(&msg));
                seen++;
            }
        }
    }
    printf("%d vehicle heartbeat(s)\n", seen);
    return seen > 0 ? 0 : 1;
}
