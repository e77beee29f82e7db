// Builds and checks Mav_Passthrough payloads. Checks: exactly one complete MAVLink v1 or v2 frame with a valid
// checksum, of a message the ardupilotmega dialect defines (MCP-PAY-6, D-4). A translation
// unit of its own: the generated MAVLink headers are heavy to compile, and every build of the
// manager (variants, faults) links the same object.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

bool valid_mavlink_frame(const uint8_t* data, size_t size);

// A MAVLink 2 COMMAND_LONG frame, MAV_CMD_DO_CHANGE_SPEED (ground speed, m/s) to the drone's
// autopilot, from a ground station's IDs (255/190): the payload of a Mav_Passthrough.
std::vector<uint8_t> change_speed_frame(uint8_t seq, float speed);
