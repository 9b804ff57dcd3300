// arm3: firmware for a 3-DOF hobby servo arm plus gripper on an Arduino Uno/Nano.
//
// Speaks protocol s2r (docs/protocols.md) at 115200 baud. Everything that decides anything lives
// in src/arm3_core.{h,cpp} (plain C++, tested on the host with g++); this file only moves bytes
// between Serial and the core and pulses between the core and the servos.
//
// Limits, step clamp, slew rate and watchdog timings come from src/limits.h, generated from the
// ArmSpec by `sim2real arm gen-limits` -- regenerate and reflash whenever the spec changes.
//
// Servo driver: Timer1 pulses on pins ARM3_SERVO_PIN (default; src/servo_pulses.h, no Servo
// library needed, so Debian's Arduino packages build it), or a PCA9685 board on channels
// ARM3_SERVO_CHANNEL when built with -DARM3_USE_PCA9685 (needs Adafruit's PWM servo library).
// Power-up: servos stay detached (limp) until a TORQUE frame. A servo whose potentiometer is
// wired to an analog input (ARM3_POT_CHANNEL, from `feedback: measured` in the spec) then holds
// where it is; one without holds the pulse the host says it last sent, or the park pose after a
// power-up, so power the arm up resting in the park pose.
//
// Potentiometers: one analogRead (~0.11 ms) per loop() pass, round robin, so each pot is
// sampled every few milliseconds, far faster than a servo's 20 ms frame.
//
// Between loop() passes the CPU sleeps (idle mode) until the next interrupt: a UART byte, the
// 1.024 ms millis() tick or a pulse edge. Nothing is late for it, and an emulator of the chip
// (simavr) skips the sleep instead of simulating it.

// #define ARM3_USE_PCA9685

#include <Arduino.h>
#include <EEPROM.h>

#include "src/arm3_core.h"
#ifdef ARM3_LIMITS_HEADER
#include ARM3_LIMITS_HEADER  // a build for another spec: make avr LIMITS=path/to/limits.h
#else
#include "src/limits.h"
#endif

#ifdef ARM3_USE_PCA9685
#include <Adafruit_PWMServoDriver.h>
#include <Wire.h>
static Adafruit_PWMServoDriver pca;
#else
#include "src/servo_pulses.h"
static arm3::ServoPulses pulses;
#endif
#if defined(__AVR__)
#include <avr/sleep.h>
#endif

static const arm3::Limits kLimits = {
    ARM3_N_ACTUATORS, ARM3_LOWER_US, ARM3_UPPER_US, ARM3_PARK_US, ARM3_MAX_STEP_US,
    ARM3_SLEW_US_PER_S, ARM3_WATCHDOG_MS, ARM3_HOLD_MS, ARM3_LIMITS_CRC,
    ARM3_POT_CHANNEL, ARM3_POT_COUNTS_MIN, ARM3_POT_COUNTS_MAX, ARM3_POT_US_MIN, ARM3_POT_US_MAX};

static void send_reply(void*, const uint8_t* data, uint8_t len) { Serial.write(data, len); }

static arm3::Core core(kLimits, send_reply, nullptr);
static bool driven[ARM3_N_ACTUATORS];
static uint8_t next_pot = 0;

// A boot counter in EEPROM: the host sees a new boot id after any reset (brown-out included).
static uint16_t next_boot_id() {
  uint16_t id = 0;
  EEPROM.get(0, id);
  id = static_cast<uint16_t>(id + 1);
  EEPROM.put(0, id);
  return id;
}

static void sample_pot(uint8_t i) {
  if (ARM3_POT_CHANNEL[i] != ARM3_NO_POT) {
    core.set_pot(i, static_cast<uint16_t>(analogRead(A0 + ARM3_POT_CHANNEL[i])));
  }
}

static void drive(uint8_t i, bool on, uint16_t pulse_us) {
#ifdef ARM3_USE_PCA9685
  if (on) {
    pca.writeMicroseconds(ARM3_SERVO_CHANNEL[i], pulse_us);
  } else if (driven[i]) {
    pca.setPWM(ARM3_SERVO_CHANNEL[i], 0, 4096);  // full off: no pulses, the servo goes limp
  }
#else
  pulses.set(i, on, pulse_us);  // width and power change together: no glitch on attach
#endif
  driven[i] = on;
}

void setup() {
  Serial.begin(115200);
#ifdef ARM3_USE_PCA9685
  pca.begin();
  pca.setOscillatorFrequency(27000000);
  pca.setPWMFreq(50);
#else
  pulses.begin(ARM3_SERVO_PIN, ARM3_N_ACTUATORS, ARM3_PARK_US);
#endif
  for (uint8_t i = 0; i < ARM3_N_ACTUATORS; ++i) driven[i] = false;
  core.begin(next_boot_id(), millis());
  for (uint8_t i = 0; i < ARM3_N_ACTUATORS; ++i) sample_pot(i);  // before the first frame
}

// Sleep until the next interrupt unless a byte is already waiting (checked with interrupts off,
// and sei() lets exactly one more instruction run, the sleep, so no wake-up is missed).
static void idle() {
#if defined(__AVR__)
  set_sleep_mode(SLEEP_MODE_IDLE);
  cli();
  if (Serial.available() == 0) {
    sleep_enable();
    sei();
    sleep_cpu();
    sleep_disable();
  }
  sei();
#endif
}

void loop() {
  while (Serial.available() > 0) {
    core.feed(static_cast<uint8_t>(Serial.read()), millis());
  }
  sample_pot(next_pot);
  next_pot = static_cast<uint8_t>((next_pot + 1) % ARM3_N_ACTUATORS);
  core.tick(millis());
  const bool on = core.attached();
  for (uint8_t i = 0; i < ARM3_N_ACTUATORS; ++i) drive(i, on, core.output(i));
  idle();
}
