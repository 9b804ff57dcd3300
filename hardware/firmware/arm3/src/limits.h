// Generated from the ArmSpec by `sim2real arm gen-limits` -- do not edit by hand.
// Source: spec arm3-mg996r-pwm (hardware/specs/arm3_mg996r_pwm.yaml), nominal calibration
// Units: pulse widths in microseconds, times in milliseconds.
#pragma once
#include <stdint.h>

#define ARM3_N_ACTUATORS 4
#define ARM3_WATCHDOG_MS 250
#define ARM3_HOLD_MS 500
#define ARM3_LIMITS_CRC 0xD172
#define ARM3_POT_US_MIN 500
#define ARM3_POT_US_MAX 2500
#define ARM3_NO_POT 255

// Actuators, in order: base_yaw, shoulder, elbow, gripper
static const uint16_t ARM3_LOWER_US[ARM3_N_ACTUATORS] = {501, 1182, 928, 1500};
static const uint16_t ARM3_UPPER_US[ARM3_N_ACTUATORS] = {2499, 2327, 2391, 2263};
static const uint16_t ARM3_PARK_US[ARM3_N_ACTUATORS] = {1500, 1309, 2073, 1500};
static const uint16_t ARM3_MAX_STEP_US[ARM3_N_ACTUATORS] = {159, 159, 159, 159};
static const uint16_t ARM3_SLEW_US_PER_S[ARM3_N_ACTUATORS] = {4774, 4774, 4774, 6366};
static const uint8_t ARM3_SERVO_CHANNEL[ARM3_N_ACTUATORS] = {0, 1, 2, 3};
static const uint8_t ARM3_SERVO_PIN[ARM3_N_ACTUATORS] = {3, 5, 6, 9};
// Potentiometers (spec feedback: measured): ADC channel (A0..A5), or ARM3_NO_POT: the
// reading is the output pulse. Counts read with the horn where ARM3_POT_US_MIN/MAX put it.
static const uint8_t ARM3_POT_CHANNEL[ARM3_N_ACTUATORS] = {255, 255, 255, 255};
static const uint16_t ARM3_POT_COUNTS_MIN[ARM3_N_ACTUATORS] = {205, 205, 205, 205};
static const uint16_t ARM3_POT_COUNTS_MAX[ARM3_N_ACTUATORS] = {819, 819, 819, 819};
