// The arm3 firmware core: protocol s2r framing and the control logic, in plain C++ (no Arduino
// headers), so the host can compile and test it with g++. arm3.ino is a thin layer around it.
//
// Mirrors hardware/emulator/firmware.py line by line; tests feed both the same bytes.
#pragma once
#include <stddef.h>
#include <stdint.h>

namespace arm3 {

const uint8_t kMaxActuators = 8;
const uint8_t kMaxPayload = 64;
const uint8_t kHeaderLen = 6;  // A5 5A LEN ~LEN SEQ TYPE
const uint8_t kMaxFrame = kHeaderLen + kMaxPayload + 2;
const uint8_t kSync0 = 0xA5;
const uint8_t kSync1 = 0x5A;
const uint16_t kGapMs = 10;  // a partial frame older than this is abandoned

// 2: STATE carries a readings byte (which positions are measured); TORQUE 1 may carry where to
// start the outputs of servos without a potentiometer.
const uint8_t kProtoVersion = 2;
const uint8_t kFwMajor = 1;
const uint8_t kFwMinor = 1;

// Message types (reply = request | kReply, or kError)
const uint8_t kPing = 0x01;
const uint8_t kSetTargets = 0x02;
const uint8_t kReadState = 0x03;
const uint8_t kSetLimits = 0x04;
const uint8_t kTorque = 0x05;
const uint8_t kHeartbeat = 0x06;
const uint8_t kGetStats = 0x07;
const uint8_t kReply = 0x80;
const uint8_t kError = 0xFF;

// Error codes
const uint8_t kErrBadLength = 1;
const uint8_t kErrUnknownType = 2;
const uint8_t kErrTorqueOff = 3;
const uint8_t kErrLimitRange = 4;
const uint8_t kErrBadValue = 5;

// STATE flags
const uint8_t kFlagTorqueOn = 0x01;
const uint8_t kFlagWatchdogHold = 0x02;
const uint8_t kFlagClamped = 0x04;
const uint8_t kFlagCustomLimits = 0x08;

const uint8_t kNoPot = 255;  // pot_channel of a servo without a wired potentiometer

struct Limits {
  uint8_t n;
  const uint16_t* lower_us;
  const uint16_t* upper_us;
  const uint16_t* park_us;
  const uint16_t* max_step_us;
  const uint16_t* slew_us_per_s;
  uint16_t watchdog_ms;
  uint16_t hold_ms;
  uint16_t limits_crc;
  // Potentiometers: ADC channel per actuator (kNoPot: none, the reading is the output pulse),
  // and the counts read with the horn where pot_us_min / pot_us_max pulses put it.
  const uint8_t* pot_channel;
  const uint16_t* pot_counts_min;
  const uint16_t* pot_counts_max;
  uint16_t pot_us_min;
  uint16_t pot_us_max;
};

struct Stats {
  uint16_t rx_frames;
  uint16_t crc_errors;
  uint16_t header_errors;
  uint16_t garbage_bytes;
  uint16_t gap_resets;
  uint16_t watchdog_trips;
  uint16_t clamps;
  uint16_t duplicates;
};

// Where reply frames go (Serial.write on the board, a buffer in tests).
typedef void (*ReplyFn)(void* ctx, const uint8_t* data, uint8_t len);

// The CRC over the canonical packing of the limits (must equal limits.limits_crc).
uint16_t limits_crc(const Limits& limits);

class Core {
 public:
  Core(const Limits& limits, ReplyFn reply, void* ctx);
  void begin(uint16_t boot_id, uint32_t now_ms);

  // One received byte; replies go out through ReplyFn as frames complete.
  void feed(uint8_t byte, uint32_t now_ms);
  // The control loop: watchdog, then the slew-rate limiter. Call every loop().
  void tick(uint32_t now_ms);
  // The latest ADC counts of actuator i's potentiometer (the sketch samples them; ignored for
  // an actuator without one).
  void set_pot(uint8_t i, uint16_t counts) { pot_[i] = counts; }
  bool measured(uint8_t i) const { return limits_.pot_channel[i] != kNoPot; }
  // Bit i: actuator i's reading is measured (its pot), else it is the output pulse.
  uint8_t measured_mask() const;
  // The reading of actuator i in µs: its pot mapped to pulse, or the output pulse.
  uint16_t position(uint8_t i) const;

  bool attached() const { return attached_; }
  bool holding() const { return holding_; }
  uint16_t output(uint8_t i) const { return output_[i]; }
  uint16_t target(uint8_t i) const { return target_[i]; }
  uint8_t flags() const;
  const Stats& stats() const { return stats_; }
  uint8_t n() const { return limits_.n; }

 private:
  void process(uint32_t now_ms);
  void drop(uint8_t count);
  void handle(uint8_t seq, uint8_t type, const uint8_t* p, uint8_t len, uint16_t crc, uint32_t now_ms);
  void apply_targets(const uint8_t* p);
  void attach(const uint8_t* start_us);
  uint16_t pot_us(uint8_t i) const;
  void send(uint8_t seq, uint8_t type, const uint8_t* payload, uint8_t len);
  void send_error(uint8_t seq, uint8_t code, uint8_t type);
  void send_state(uint8_t seq, uint8_t type);

  const Limits& limits_;
  ReplyFn reply_;
  void* ctx_;
  uint16_t pot_[kMaxActuators];
  uint16_t boot_id_;
  Stats stats_;
  uint16_t lower_[kMaxActuators];
  uint16_t upper_[kMaxActuators];
  uint16_t step_[kMaxActuators];
  uint16_t target_[kMaxActuators];
  uint16_t output_[kMaxActuators];
  uint32_t carry_[kMaxActuators];
  bool attached_;
  bool holding_;
  bool clamped_;
  bool custom_limits_;
  uint32_t last_valid_ms_;
  uint32_t hold_since_ms_;
  uint32_t last_tick_ms_;
  bool have_last_;
  uint8_t last_seq_;
  uint16_t last_crc_;
  uint8_t buf_[kMaxFrame];
  uint8_t len_;
  bool have_byte_time_;
  uint32_t last_byte_ms_;
};

}  // namespace arm3
