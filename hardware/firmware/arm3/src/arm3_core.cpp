#include "arm3_core.h"

#include "s2r_crc.h"

namespace arm3 {

namespace {

int32_t clamp32(int32_t v, int32_t lo, int32_t hi) { return v < lo ? lo : (v > hi ? hi : v); }

uint16_t get16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }

void put16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v & 0xFF);
  p[1] = static_cast<uint8_t>(v >> 8);
}

}  // namespace

uint16_t limits_crc(const Limits& limits) {
  uint16_t crc = crc16_update(0xFFFF, limits.n);
  for (uint8_t i = 0; i < limits.n; ++i) {
    const uint16_t fields[5] = {limits.lower_us[i], limits.upper_us[i], limits.park_us[i],
                                limits.max_step_us[i], limits.slew_us_per_s[i]};
    for (uint8_t k = 0; k < 5; ++k) {
      crc = crc16_update(crc, static_cast<uint8_t>(fields[k] & 0xFF));
      crc = crc16_update(crc, static_cast<uint8_t>(fields[k] >> 8));
    }
  }
  const uint16_t tail[2] = {limits.watchdog_ms, limits.hold_ms};
  for (uint8_t k = 0; k < 2; ++k) {
    crc = crc16_update(crc, static_cast<uint8_t>(tail[k] & 0xFF));
    crc = crc16_update(crc, static_cast<uint8_t>(tail[k] >> 8));
  }
  for (uint8_t i = 0; i < limits.n; ++i) {
    crc = crc16_update(crc, limits.pot_channel[i]);
    const uint16_t counts[2] = {limits.pot_counts_min[i], limits.pot_counts_max[i]};
    for (uint8_t k = 0; k < 2; ++k) {
      crc = crc16_update(crc, static_cast<uint8_t>(counts[k] & 0xFF));
      crc = crc16_update(crc, static_cast<uint8_t>(counts[k] >> 8));
    }
  }
  const uint16_t us[2] = {limits.pot_us_min, limits.pot_us_max};
  for (uint8_t k = 0; k < 2; ++k) {
    crc = crc16_update(crc, static_cast<uint8_t>(us[k] & 0xFF));
    crc = crc16_update(crc, static_cast<uint8_t>(us[k] >> 8));
  }
  return crc;
}

Core::Core(const Limits& limits, ReplyFn reply, void* ctx)
    : limits_(limits), reply_(reply), ctx_(ctx) {
  for (uint8_t i = 0; i < kMaxActuators; ++i) pot_[i] = 0;
  begin(0, 0);
}

void Core::begin(uint16_t boot_id, uint32_t now_ms) {
  boot_id_ = boot_id;
  stats_ = Stats();
  for (uint8_t i = 0; i < limits_.n; ++i) {
    lower_[i] = limits_.lower_us[i];
    upper_[i] = limits_.upper_us[i];
    step_[i] = limits_.max_step_us[i];
    target_[i] = limits_.park_us[i];
    output_[i] = limits_.park_us[i];
    carry_[i] = 0;
  }
  attached_ = false;
  holding_ = false;
  clamped_ = false;
  custom_limits_ = false;
  last_valid_ms_ = now_ms;
  hold_since_ms_ = now_ms;
  last_tick_ms_ = now_ms;
  have_last_ = false;
  last_seq_ = 0;
  last_crc_ = 0;
  len_ = 0;
  have_byte_time_ = false;
  last_byte_ms_ = now_ms;
}

uint8_t Core::measured_mask() const {
  uint8_t mask = 0;
  for (uint8_t i = 0; i < limits_.n; ++i) {
    if (measured(i)) mask = static_cast<uint8_t>(mask | (1u << i));
  }
  return mask;
}

// Two-point linear map, counts clamped to the calibrated span, rounded to the nearest µs; every
// operand is >= 0 here, so C++ and Python (hardware/firmware/limits.py) divide alike.
uint16_t Core::pot_us(uint8_t i) const {
  int32_t c0 = limits_.pot_counts_min[i];
  int32_t c1 = limits_.pot_counts_max[i];
  int32_t c = pot_[i];
  if (c1 < c0) {  // a pot wired the other way round
    c0 = -c0;
    c1 = -c1;
    c = -c;
  }
  c = clamp32(c, c0, c1);
  const int32_t span = static_cast<int32_t>(limits_.pot_us_max) - limits_.pot_us_min;
  return static_cast<uint16_t>(limits_.pot_us_min + ((c - c0) * span + (c1 - c0) / 2) / (c1 - c0));
}

uint16_t Core::position(uint8_t i) const { return measured(i) ? pot_us(i) : output_[i]; }

uint8_t Core::flags() const {
  return static_cast<uint8_t>((attached_ ? kFlagTorqueOn : 0) | (holding_ ? kFlagWatchdogHold : 0) |
                              (clamped_ ? kFlagClamped : 0) |
                              (custom_limits_ ? kFlagCustomLimits : 0));
}

// ---- receive -------------------------------------------------------------------------------
void Core::feed(uint8_t byte, uint32_t now_ms) {
  if (len_ > 0 && have_byte_time_ && static_cast<uint32_t>(now_ms - last_byte_ms_) > kGapMs) {
    stats_.gap_resets++;
    stats_.garbage_bytes += len_;
    len_ = 0;
  }
  have_byte_time_ = true;
  last_byte_ms_ = now_ms;
  buf_[len_++] = byte;
  process(now_ms);
}

void Core::drop(uint8_t count) {
  for (uint8_t i = count; i < len_; ++i) buf_[i - count] = buf_[i];
  len_ = static_cast<uint8_t>(len_ - count);
}

// Drop one byte and rescan after any failure, so a frame hidden behind garbage is still found.
void Core::process(uint32_t now_ms) {
  for (;;) {
    if (len_ == 0) return;
    if (buf_[0] != kSync0) {
      stats_.garbage_bytes++;
      drop(1);
      continue;
    }
    if (len_ < 2) return;
    if (buf_[1] != kSync1) {
      stats_.garbage_bytes++;
      drop(1);
      continue;
    }
    if (len_ < 4) return;
    const uint8_t n = buf_[2];
    if (n > kMaxPayload || buf_[3] != static_cast<uint8_t>(~n)) {
      stats_.header_errors++;
      drop(1);
      continue;
    }
    const uint8_t total = static_cast<uint8_t>(kHeaderLen + n + 2);
    if (len_ < total) return;
    const uint16_t got = get16(buf_ + kHeaderLen + n);
    if (crc16(buf_ + 2, kHeaderLen - 2 + n) != got) {
      stats_.crc_errors++;
      drop(1);
      continue;
    }
    handle(buf_[4], buf_[5], buf_ + kHeaderLen, n, got, now_ms);
    drop(total);
  }
}

// ---- replies -------------------------------------------------------------------------------
void Core::send(uint8_t seq, uint8_t type, const uint8_t* payload, uint8_t len) {
  uint8_t frame[kMaxFrame];
  frame[0] = kSync0;
  frame[1] = kSync1;
  frame[2] = len;
  frame[3] = static_cast<uint8_t>(~len);
  frame[4] = seq;
  frame[5] = type;
  for (uint8_t i = 0; i < len; ++i) frame[kHeaderLen + i] = payload[i];
  put16(frame + kHeaderLen + len, crc16(frame + 2, kHeaderLen - 2 + len));
  reply_(ctx_, frame, static_cast<uint8_t>(kHeaderLen + len + 2));
}

void Core::send_error(uint8_t seq, uint8_t code, uint8_t type) {
  const uint8_t p[2] = {code, type};
  send(seq, kError, p, 2);
}

void Core::send_state(uint8_t seq, uint8_t type) {
  uint8_t p[4 + 4 * kMaxActuators];
  const uint8_t n = limits_.n;
  p[0] = flags();
  put16(p + 1, boot_id_);
  p[3] = measured_mask();
  for (uint8_t i = 0; i < n; ++i) {
    put16(p + 4 + 2 * i, position(i));
    put16(p + 4 + 2 * n + 2 * i, target_[i]);
  }
  send(seq, type, p, static_cast<uint8_t>(4 + 4 * n));
}

// ---- messages ------------------------------------------------------------------------------
void Core::handle(uint8_t seq, uint8_t type, const uint8_t* p, uint8_t len, uint16_t crc,
                  uint32_t now_ms) {
  stats_.rx_frames++;
  last_valid_ms_ = now_ms;
  holding_ = false;
  const bool dup = have_last_ && seq == last_seq_ && crc == last_crc_;
  have_last_ = true;
  last_seq_ = seq;
  last_crc_ = crc;
  if (dup) stats_.duplicates++;
  const uint8_t n = limits_.n;
  const uint8_t reply = static_cast<uint8_t>(type | kReply);

  switch (type) {
    case kPing: {
      if (len != 0) return send_error(seq, kErrBadLength, type);
      uint8_t q[10];
      q[0] = kProtoVersion;
      q[1] = kFwMajor;
      q[2] = kFwMinor;
      q[3] = n;
      put16(q + 4, boot_id_);
      put16(q + 6, limits_.limits_crc);
      put16(q + 8, limits_.watchdog_ms);
      return send(seq, reply, q, 10);
    }
    case kSetTargets:
      if (len != 2 * n) return send_error(seq, kErrBadLength, type);
      if (!attached_) return send_error(seq, kErrTorqueOff, type);
      if (!dup) apply_targets(p);
      return send_state(seq, reply);
    case kReadState:
      if (len != 0) return send_error(seq, kErrBadLength, type);
      return send_state(seq, reply);
    case kSetLimits: {
      if (len != 6 * n) return send_error(seq, kErrBadLength, type);
      for (uint8_t i = 0; i < n; ++i) {
        const uint16_t lo = get16(p + 6 * i), hi = get16(p + 6 * i + 2), st = get16(p + 6 * i + 4);
        const bool ok = limits_.lower_us[i] <= lo && lo < hi && hi <= limits_.upper_us[i] &&
                        st >= 1 && st <= limits_.max_step_us[i];
        if (!ok) return send_error(seq, kErrLimitRange, type);
      }
      if (!dup) {
        for (uint8_t i = 0; i < n; ++i) {
          lower_[i] = get16(p + 6 * i);
          upper_[i] = get16(p + 6 * i + 2);
          step_[i] = get16(p + 6 * i + 4);
          target_[i] = static_cast<uint16_t>(clamp32(target_[i], lower_[i], upper_[i]));
        }
        custom_limits_ = true;
      }
      return send(seq, reply, nullptr, 0);
    }
    case kTorque:
      if (len != 1 && len != 1 + 2 * n) return send_error(seq, kErrBadLength, type);
      if (p[0] > 1 || (len > 1 && p[0] != 1)) return send_error(seq, kErrBadValue, type);
      if (!dup) {
        if (p[0] == 1) {
          attach(len > 1 ? p + 1 : nullptr);
        } else {
          attached_ = false;
        }
      }
      return send(seq, reply, nullptr, 0);
    case kHeartbeat:
      if (len != 0) return send_error(seq, kErrBadLength, type);
      return send(seq, reply, nullptr, 0);
    case kGetStats: {
      if (len != 0) return send_error(seq, kErrBadLength, type);
      const uint16_t v[8] = {stats_.rx_frames,   stats_.crc_errors,     stats_.header_errors,
                             stats_.garbage_bytes, stats_.gap_resets,   stats_.watchdog_trips,
                             stats_.clamps,      stats_.duplicates};
      uint8_t q[16];
      for (uint8_t k = 0; k < 8; ++k) put16(q + 2 * k, v[k]);
      return send(seq, reply, q, 16);
    }
    default:
      return send_error(seq, kErrUnknownType, type);
  }
}

// Joint limits, then the per-frame step clamp around the current target, then limits again
// (a SET_LIMITS may have moved them under the current target).
void Core::apply_targets(const uint8_t* p) {
  bool clamped = false;
  for (uint8_t i = 0; i < limits_.n; ++i) {
    const int32_t req = get16(p + 2 * i);
    int32_t v = clamp32(req, lower_[i], upper_[i]);
    v = clamp32(v, static_cast<int32_t>(target_[i]) - step_[i],
                static_cast<int32_t>(target_[i]) + step_[i]);
    v = clamp32(v, lower_[i], upper_[i]);
    if (v != req) clamped = true;
    target_[i] = static_cast<uint16_t>(v);
  }
  clamped_ = clamped;
  if (clamped) stats_.clamps++;
}

// Torque on without a snap: a servo with a pot starts from where it is, one without from where
// the host says it was last sent (start_us, when given) or the output it had. Every start is
// clamped to the limits; the target is the start, so nothing moves until a SET_TARGETS.
// Already attached, only the pots count: a start pulse must not jump a driven servo.
void Core::attach(const uint8_t* start_us) {
  for (uint8_t i = 0; i < limits_.n; ++i) {
    int32_t v = output_[i];
    if (measured(i)) {
      v = pot_us(i);
    } else if (start_us != nullptr && !attached_) {
      v = get16(start_us + 2 * i);
    }
    output_[i] = static_cast<uint16_t>(clamp32(v, lower_[i], upper_[i]));
    target_[i] = output_[i];
    carry_[i] = 0;
  }
  attached_ = true;
}

// ---- time ----------------------------------------------------------------------------------
void Core::tick(uint32_t now_ms) {
  uint32_t dt = static_cast<uint32_t>(now_ms - last_tick_ms_);
  if (dt > 1000) dt = 1000;
  last_tick_ms_ = now_ms;
  if (!attached_) return;
  if (!holding_) {
    if (static_cast<uint32_t>(now_ms - last_valid_ms_) >= limits_.watchdog_ms) {
      // No valid frame for watchdog_ms: stop where the outputs are now.
      holding_ = true;
      hold_since_ms_ = now_ms;
      stats_.watchdog_trips++;
      for (uint8_t i = 0; i < limits_.n; ++i) {
        target_[i] = output_[i];
        carry_[i] = 0;
      }
    }
  } else if (static_cast<uint32_t>(now_ms - hold_since_ms_) >= limits_.hold_ms) {
    // Still nothing after holding for hold_ms: let the servos go.
    attached_ = false;
    holding_ = false;
    return;
  }
  for (uint8_t i = 0; i < limits_.n; ++i) {
    const int32_t d = static_cast<int32_t>(target_[i]) - output_[i];
    if (d == 0) {
      carry_[i] = 0;
      continue;
    }
    const uint32_t budget = static_cast<uint32_t>(limits_.slew_us_per_s[i]) * dt + carry_[i];
    const int32_t step = static_cast<int32_t>(budget / 1000);
    carry_[i] = budget % 1000;
    const int32_t ad = d < 0 ? -d : d;
    if (ad <= step) {
      output_[i] = target_[i];
      carry_[i] = 0;
    } else {
      output_[i] = static_cast<uint16_t>(output_[i] + (d > 0 ? step : -step));
    }
  }
}

}  // namespace arm3
