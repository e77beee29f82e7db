// Checks a Mav_Passthrough payload: exactly one complete MAVLink v1 or v2 frame with a valid
// checksum, of a message the ardupilotmega dialect defines (MCP-PAY-6, D-4). A translation
// unit of its own: the generated MAVLink headers are heavy to compile, and every build of the
// manager (variants, faults) links the same object.
#pragma once

#include <cstddef>
#include <cstdint>

bool valid_mavlink_frame(const uint8_t* data, size_t size);
