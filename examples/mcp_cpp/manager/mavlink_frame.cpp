#include "mavlink_frame.h"

#include <cstring>

#include "ardupilotmega/mavlink.h"

bool valid_mavlink_frame(const uint8_t* p, size_t n) {
    if (n == 0) return false;
    if (p[0] != MAVLINK_STX_MAVLINK1 && p[0] != MAVLINK_STX) return false;  // a v1 or v2 frame
    mavlink_message_t rx, msg;
    mavlink_status_t rx_status, status;
    std::memset(&rx, 0, sizeof rx);
    std::memset(&rx_status, 0, sizeof rx_status);
    int frames = 0;
    for (size_t i = 0; i < n; ++i) {
        uint8_t r = mavlink_frame_char_buffer(&rx, &rx_status, p[i], &msg, &status);
        if (r == MAVLINK_FRAMING_OK) {
            if (++frames > 1 || i + 1 != n) return false;                    // one frame, nothing after it
            if (mavlink_get_msg_entry(msg.msgid) == nullptr) return false;  // not in the dialect
        } else if (r == MAVLINK_FRAMING_BAD_CRC || r == MAVLINK_FRAMING_BAD_SIGNATURE) {
            return false;
        }
    }
    return frames == 1;
}

std::vector<uint8_t> change_speed_frame(uint8_t seq, float speed) {
    mavlink_message_t msg;
    mavlink_status_t* status = mavlink_get_channel_status(MAVLINK_COMM_0);
    status->current_tx_seq = seq;
    mavlink_msg_command_long_pack_chan(255, 190, MAVLINK_COMM_0, &msg, 0, 0, MAV_CMD_DO_CHANGE_SPEED, 0,
                                       1 /* ground speed */, speed, -1 /* throttle unchanged */, 0, 0, 0, 0);
    std::vector<uint8_t> out(MAVLINK_MAX_PACKET_LEN);
    out.resize(mavlink_msg_to_send_buffer(out.data(), &msg));
    return out;
}
