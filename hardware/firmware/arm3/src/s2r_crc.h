// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF), the checksum of protocol s2r.
#pragma once
#include <stddef.h>
#include <stdint.h>

namespace arm3 {

uint16_t crc16_update(uint16_t crc, uint8_t byte);
uint16_t crc16(const uint8_t* data, size_t len, uint16_t crc = 0xFFFF);

}  // namespace arm3
