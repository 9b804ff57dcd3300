// Compiles arm3.ino against stub Arduino headers and runs setup()/loop(): the thin Arduino layer
// must build, start detached, attach on TORQUE and write the core's pulses to the servo pins
// (src/servo_pulses.cpp records them on the host; on the chip Timer1 times them).
#include <stdio.h>

#include "Arduino.h"
#include "EEPROM.h"

FakeSerial Serial;
FakeEEPROM EEPROM;
uint16_t fake_adc[8];
static unsigned long fake_now = 0;
unsigned long millis() { return fake_now; }

#include "../arm3.ino"

#include "../src/s2r_crc.h"

static int failures = 0;
#define CHECK(cond)                                                            \
  do {                                                                         \
    if (!(cond)) {                                                             \
      ++failures;                                                              \
      fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
    }                                                                          \
  } while (0)

static void send_frame(uint8_t seq, uint8_t type, const uint8_t* payload, uint8_t len) {
  uint8_t f[80] = {0xA5, 0x5A, len, static_cast<uint8_t>(~len), seq, type};
  for (uint8_t i = 0; i < len; ++i) f[6 + i] = payload[i];
  const uint16_t crc = arm3::crc16(f + 2, 4u + len);
  f[6 + len] = crc & 0xFF;
  f[7 + len] = crc >> 8;
  for (uint8_t i = 0; i < 8 + len; ++i) Serial.rx.push_back(f[i]);
}

int main() {
  setup();
  loop();
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) CHECK(!pulses.on(i));
  const uint8_t on = 1;
  send_frame(1, arm3::kTorque, &on, 1);
  fake_now = 5;
  loop();
  CHECK(Serial.tx.size() == 8);  // the TORQUE ack
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) {
    CHECK(pulses.on(i));
    CHECK(pulses.pin(i) == ARM3_SERVO_PIN[i]);
    CHECK(pulses.width_us(i) == ARM3_PARK_US[i]);
  }
  // No frames: after watchdog + hold the sketch detaches every servo.
  for (fake_now = 10; fake_now < 5 + ARM3_WATCHDOG_MS + ARM3_HOLD_MS + 10; fake_now += 5) loop();
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) CHECK(!pulses.on(i));
  uint16_t boot = 0;
  EEPROM.get(0, boot);
  CHECK(boot == 1);
  if (failures) {
    fprintf(stderr, "arm3 sketch: %d checks failed\n", failures);
    return 1;
  }
  printf("arm3 sketch: all checks passed\n");
  return 0;
}
