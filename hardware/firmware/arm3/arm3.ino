// arm3: firmware for a 3-DOF hobby servo arm plus gripper on an Arduino Uno/Nano.
//
// Speaks protocol s2r (docs/protocols.md) at 115200 baud. Everything that decides anything lives
// in src/arm3_core.{h,cpp} (plain C++, tested on the host with g++); this file only moves bytes
// between Serial and the core and pulses between the core and the servos.
//
// Limits, step clamp, slew rate and watchdog timings come from src/limits.h, generated from the
// ArmSpec by `sim2real arm gen-limits` -- regenerate and reflash whenever the spec changes.
//
// Servo driver: the Servo library on pins ARM3_SERVO_PIN (default), or a PCA9685 board on
// channels ARM3_SERVO_CHANNEL when built with -DARM3_USE_PCA9685 (uncomment the define below).
// Power-up: servos stay detached (limp) until a TORQUE frame; they then hold the park pose, so
// power the arm up resting in the park pose.

// #define ARM3_USE_PCA9685

#include <Arduino.h>
#include <EEPROM.h>

#include "src/arm3_core.h"
#include "src/limits.h"

#ifdef ARM3_USE_PCA9685
#include <Adafruit_PWMServoDriver.h>
#include <Wire.h>
static Adafruit_PWMServoDriver pca;
#else
#include <Servo.h>
static Servo servos[ARM3_N_ACTUATORS];
#endif

static const arm3::Limits kLimits = {
    ARM3_N_ACTUATORS, ARM3_LOWER_US, ARM3_UPPER_US, ARM3_PARK_US, ARM3_MAX_STEP_US,
    ARM3_SLEW_US_PER_S, ARM3_WATCHDOG_MS, ARM3_HOLD_MS, ARM3_LIMITS_CRC};

static void send_reply(void*, const uint8_t* data, uint8_t len) { Serial.write(data, len); }

static arm3::Core core(kLimits, send_reply, nullptr);
static bool driven[ARM3_N_ACTUATORS];

// A boot counter in EEPROM: the host sees a new boot id after any reset (brown-out included).
static uint16_t next_boot_id() {
  uint16_t id = 0;
  EEPROM.get(0, id);
  id = static_cast<uint16_t>(id + 1);
  EEPROM.put(0, id);
  return id;
}

static void drive(uint8_t i, bool on, uint16_t pulse_us) {
#ifdef ARM3_USE_PCA9685
  if (on) {
    pca.writeMicroseconds(ARM3_SERVO_CHANNEL[i], pulse_us);
  } else if (driven[i]) {
    pca.setPWM(ARM3_SERVO_CHANNEL[i], 0, 4096);  // full off: no pulses, the servo goes limp
  }
#else
  if (on) {
    servos[i].writeMicroseconds(pulse_us);  // before attach: no 1500 us glitch on attach
    if (!servos[i].attached()) servos[i].attach(ARM3_SERVO_PIN[i], 500, 2500);
  } else if (servos[i].attached()) {
    servos[i].detach();
  }
#endif
  driven[i] = on;
}

void setup() {
  Serial.begin(115200);
#ifdef ARM3_USE_PCA9685
  pca.begin();
  pca.setOscillatorFrequency(27000000);
  pca.setPWMFreq(50);
#endif
  for (uint8_t i = 0; i < ARM3_N_ACTUATORS; ++i) driven[i] = false;
  core.begin(next_boot_id(), millis());
}

void loop() {
  while (Serial.available() > 0) {
    core.feed(static_cast<uint8_t>(Serial.read()), millis());
  }
  core.tick(millis());
  const bool on = core.attached();
  for (uint8_t i = 0; i < ARM3_N_ACTUATORS; ++i) drive(i, on, core.output(i));
}
