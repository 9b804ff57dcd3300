// Replays a script of received bytes and clock ticks through the core and prints everything it
// does, one line per event. tests/hardware/test_firmware.py runs the same script through the
// Python model (hardware/emulator/firmware.py) and requires identical output.
//
// Script lines on stdin:  "R <ms> <hex bytes>" receive,  "T <ms>" tick,  "S" print state,
//                         "A <i> <counts>" actuator i's potentiometer now reads counts.
// Output lines:           "TX <hex>" for each reply,     "ST ..." for each S.
// Built against src/limits.h, or another spec's header with -DARM3_LIMITS_HEADER='"path"'.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../src/arm3_core.h"
#ifdef ARM3_LIMITS_HEADER
#include ARM3_LIMITS_HEADER
#else
#include "../src/limits.h"
#endif

static const arm3::Limits kLimits = {
    ARM3_N_ACTUATORS, ARM3_LOWER_US, ARM3_UPPER_US, ARM3_PARK_US, ARM3_MAX_STEP_US,
    ARM3_SLEW_US_PER_S, ARM3_WATCHDOG_MS, ARM3_HOLD_MS, ARM3_LIMITS_CRC,
    ARM3_POT_CHANNEL, ARM3_POT_COUNTS_MIN, ARM3_POT_COUNTS_MAX, ARM3_POT_US_MIN, ARM3_POT_US_MAX};

static void print_reply(void*, const uint8_t* data, uint8_t len) {
  printf("TX ");
  for (uint8_t i = 0; i < len; ++i) printf("%02x", data[i]);
  printf("\n");
}

static int hexval(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

int main(int argc, char** argv) {
  const uint16_t boot_id = argc > 1 ? static_cast<uint16_t>(strtoul(argv[1], nullptr, 0)) : 1;
  arm3::Core core(kLimits, print_reply, nullptr);
  core.begin(boot_id, 0);
  static char line[8192];
  while (fgets(line, sizeof line, stdin)) {
    if (line[0] == 'R') {
      char* p = line + 1;
      const uint32_t now = static_cast<uint32_t>(strtoul(p, &p, 10));
      while (*p == ' ') ++p;
      while (hexval(p[0]) >= 0 && hexval(p[1]) >= 0) {
        core.feed(static_cast<uint8_t>(hexval(p[0]) * 16 + hexval(p[1])), now);
        p += 2;
      }
    } else if (line[0] == 'A') {
      char* p = line + 1;
      const unsigned long i = strtoul(p, &p, 10);
      core.set_pot(static_cast<uint8_t>(i), static_cast<uint16_t>(strtoul(p, nullptr, 10)));
    } else if (line[0] == 'T') {
      core.tick(static_cast<uint32_t>(strtoul(line + 1, nullptr, 10)));
    } else if (line[0] == 'S') {
      const arm3::Stats& s = core.stats();
      printf("ST %d %d %u %u", core.attached() ? 1 : 0, core.holding() ? 1 : 0, core.flags(),
             core.measured_mask());
      for (uint8_t i = 0; i < core.n(); ++i) {
        printf(" %u/%u/%u", core.output(i), core.target(i), core.position(i));
      }
      printf(" | %u %u %u %u %u %u %u %u\n", s.rx_frames, s.crc_errors, s.header_errors,
             s.garbage_bytes, s.gap_resets, s.watchdog_trips, s.clamps, s.duplicates);
    }
  }
  return 0;
}
