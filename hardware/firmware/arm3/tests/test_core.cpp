// Host tests of the arm3 core: `make test` in hardware/firmware/arm3 (or pytest runs them).
#include <stdio.h>
#include <string.h>

#include <vector>

#include "../src/arm3_core.h"
#include "../src/limits.h"
#include "../src/s2r_crc.h"

static int failures = 0;
static int checks = 0;
#define CHECK(cond)                                                   \
  do {                                                                \
    ++checks;                                                         \
    if (!(cond)) {                                                    \
      ++failures;                                                     \
      fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
    }                                                                 \
  } while (0)

static const arm3::Limits kLimits = {
    ARM3_N_ACTUATORS, ARM3_LOWER_US, ARM3_UPPER_US, ARM3_PARK_US, ARM3_MAX_STEP_US,
    ARM3_SLEW_US_PER_S, ARM3_WATCHDOG_MS, ARM3_HOLD_MS, ARM3_LIMITS_CRC,
    ARM3_POT_CHANNEL, ARM3_POT_COUNTS_MIN, ARM3_POT_COUNTS_MAX, ARM3_POT_US_MIN, ARM3_POT_US_MAX};

typedef std::vector<uint8_t> Bytes;
static std::vector<Bytes> replies;
static void collect(void*, const uint8_t* data, uint8_t len) { replies.push_back(Bytes(data, data + len)); }

static Bytes frame(uint8_t seq, uint8_t type, const Bytes& payload) {
  Bytes f = {arm3::kSync0, arm3::kSync1, static_cast<uint8_t>(payload.size()),
             static_cast<uint8_t>(~payload.size()), seq, type};
  for (uint8_t b : payload) f.push_back(b);
  const uint16_t crc = arm3::crc16(f.data() + 2, f.size() - 2);
  f.push_back(crc & 0xFF);
  f.push_back(crc >> 8);
  return f;
}

static void feed(arm3::Core& core, const Bytes& bytes, uint32_t now) {
  for (uint8_t b : bytes) core.feed(b, now);
}

static Bytes targets(const uint16_t* us) {
  Bytes p;
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) {
    p.push_back(us[i] & 0xFF);
    p.push_back(us[i] >> 8);
  }
  return p;
}

static void test_crc() {
  const char* s = "123456789";
  CHECK(arm3::crc16(reinterpret_cast<const uint8_t*>(s), 9) == 0x29B1);  // CRC-16/CCITT-FALSE
  CHECK(arm3::limits_crc(kLimits) == ARM3_LIMITS_CRC);  // limits.h agrees with its own CRC
}

static void test_ping_and_resync() {
  arm3::Core core(kLimits, collect, nullptr);
  core.begin(0x1234, 0);
  replies.clear();
  Bytes noise = {0x00, 0xA5, 0xA5, 0x13, 0x5A, 0xFF};
  feed(core, noise, 1);
  feed(core, frame(7, arm3::kPing, Bytes()), 1);
  CHECK(replies.size() == 1);
  CHECK(replies[0][4] == 7 && replies[0][5] == (arm3::kPing | arm3::kReply));
  CHECK(replies[0][6 + 3] == ARM3_N_ACTUATORS);
  CHECK((replies[0][6 + 4] | (replies[0][6 + 5] << 8)) == 0x1234);
  CHECK(core.stats().garbage_bytes == noise.size());
  // A corrupted CRC is dropped silently and counted; the next good frame still gets through.
  Bytes bad = frame(8, arm3::kPing, Bytes());
  bad[bad.size() - 1] ^= 0x01;
  feed(core, bad, 2);
  feed(core, frame(9, arm3::kPing, Bytes()), 2);
  CHECK(replies.size() == 2 && replies[1][4] == 9);
  CHECK(core.stats().crc_errors == 1);
  // A corrupted length byte fails the ~LEN check at once.
  Bytes badlen = frame(10, arm3::kPing, Bytes());
  badlen[2] = 40;
  feed(core, badlen, 3);
  feed(core, frame(11, arm3::kPing, Bytes()), 3);
  CHECK(replies.size() == 3 && replies[2][4] == 11);
  CHECK(core.stats().header_errors == 1);
  // A partial frame is abandoned after a gap longer than kGapMs.
  Bytes part = frame(12, arm3::kPing, Bytes());
  part.resize(5);
  feed(core, part, 10);
  feed(core, frame(13, arm3::kPing, Bytes()), 10 + arm3::kGapMs + 1);
  CHECK(replies.size() == 4 && replies[3][4] == 13);
  CHECK(core.stats().gap_resets == 1);
}

static void test_limits_step_and_torque() {
  arm3::Core core(kLimits, collect, nullptr);
  core.begin(1, 0);
  replies.clear();
  uint16_t far[ARM3_N_ACTUATORS];
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) far[i] = 2500;
  feed(core, frame(1, arm3::kSetTargets, targets(far)), 0);
  CHECK(replies.size() == 1 && replies[0][5] == arm3::kError && replies[0][6] == arm3::kErrTorqueOff);
  feed(core, frame(2, arm3::kTorque, Bytes{1}), 0);
  CHECK(core.attached());
  feed(core, frame(3, arm3::kSetTargets, targets(far)), 1);
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) {
    // one step from park towards 2500, never past the upper limit
    const int expect = ARM3_PARK_US[i] + ARM3_MAX_STEP_US[i] < ARM3_UPPER_US[i]
                           ? ARM3_PARK_US[i] + ARM3_MAX_STEP_US[i]
                           : ARM3_UPPER_US[i];
    CHECK(core.target(i) == expect);
  }
  CHECK(core.flags() & arm3::kFlagClamped);
  CHECK(core.stats().clamps == 1);
  // A retransmission (same SEQ, same bytes) is answered but not applied again.
  const uint16_t before = core.target(0);
  feed(core, frame(3, arm3::kSetTargets, targets(far)), 2);
  CHECK(core.target(0) == before);
  CHECK(core.stats().duplicates == 1);
  // Wrong payload length and unknown type produce error replies.
  replies.clear();
  feed(core, frame(4, arm3::kSetTargets, Bytes{1, 2, 3}), 3);
  CHECK(replies.size() == 1 && replies[0][6] == arm3::kErrBadLength);
  feed(core, frame(5, 0x42, Bytes()), 3);
  CHECK(replies.size() == 2 && replies[1][6] == arm3::kErrUnknownType);
  // SET_LIMITS may tighten but never widen the compiled limits.
  Bytes wide;
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) {
    const uint16_t v[3] = {static_cast<uint16_t>(ARM3_LOWER_US[i] - 1), ARM3_UPPER_US[i], ARM3_MAX_STEP_US[i]};
    for (uint16_t x : v) {
      wide.push_back(x & 0xFF);
      wide.push_back(x >> 8);
    }
  }
  feed(core, frame(6, arm3::kSetLimits, wide), 4);
  CHECK(replies.size() == 3 && replies[2][6] == arm3::kErrLimitRange);
}

static void test_slew_and_watchdog() {
  arm3::Core core(kLimits, collect, nullptr);
  core.begin(1, 0);
  replies.clear();
  feed(core, frame(1, arm3::kTorque, Bytes{1}), 0);
  uint16_t t[ARM3_N_ACTUATORS];
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) t[i] = ARM3_PARK_US[i];
  t[0] = static_cast<uint16_t>(ARM3_PARK_US[0] + ARM3_MAX_STEP_US[0]);
  feed(core, frame(2, arm3::kSetTargets, targets(t)), 0);
  core.tick(10);  // 10 ms at the slew rate
  const int moved = core.output(0) - ARM3_PARK_US[0];
  CHECK(moved == static_cast<int>(ARM3_SLEW_US_PER_S[0] * 10 / 1000));
  // Heartbeats keep the watchdog fed.
  for (uint32_t now = 20; now <= 400; now += 20) {
    feed(core, frame(static_cast<uint8_t>(3 + now / 20), arm3::kHeartbeat, Bytes()), now);
    core.tick(now);
  }
  CHECK(core.attached() && !core.holding());
  CHECK(core.output(0) == t[0]);
  // Silence: hold at watchdog_ms, detach hold_ms later.
  const uint32_t last = 400;
  core.tick(last + ARM3_WATCHDOG_MS - 1);
  CHECK(!core.holding());
  core.tick(last + ARM3_WATCHDOG_MS);
  CHECK(core.holding() && core.attached());
  CHECK(core.stats().watchdog_trips == 1);
  core.tick(last + ARM3_WATCHDOG_MS + ARM3_HOLD_MS - 1);
  CHECK(core.attached());
  core.tick(last + ARM3_WATCHDOG_MS + ARM3_HOLD_MS);
  CHECK(!core.attached());
  // Detached: targets are refused until torque is switched on again.
  replies.clear();
  feed(core, frame(200, arm3::kSetTargets, targets(t)), 2000);
  CHECK(replies.size() == 1 && replies[0][6] == arm3::kErrTorqueOff);
}

static void test_hold_then_resume() {
  arm3::Core core(kLimits, collect, nullptr);
  core.begin(1, 0);
  feed(core, frame(1, arm3::kTorque, Bytes{1}), 0);
  uint16_t t[ARM3_N_ACTUATORS];
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) t[i] = ARM3_PARK_US[i];
  t[0] = static_cast<uint16_t>(ARM3_PARK_US[0] + ARM3_MAX_STEP_US[0]);
  feed(core, frame(2, arm3::kSetTargets, targets(t)), 0);
  core.tick(ARM3_WATCHDOG_MS);  // watchdog: hold where the output is now
  CHECK(core.holding());
  const uint16_t held = core.output(0);
  CHECK(core.target(0) == held);
  core.tick(ARM3_WATCHDOG_MS + 50);
  CHECK(core.output(0) == held);  // holding: no more motion
  feed(core, frame(3, arm3::kHeartbeat, Bytes()), ARM3_WATCHDOG_MS + 60);
  CHECK(!core.holding() && core.attached());  // a valid frame within hold_ms resumes
}

// The committed limits with a potentiometer on actuators 0 (wired as nominal) and 2 (wired the
// other way round): the pot build's logic, whatever the committed header says.
static uint8_t pot_channel[ARM3_N_ACTUATORS];
static uint16_t pot_min[ARM3_N_ACTUATORS];
static uint16_t pot_max[ARM3_N_ACTUATORS];

static arm3::Limits pot_limits() {
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) {
    pot_channel[i] = (i == 0 || i == 2) ? static_cast<uint8_t>(i) : arm3::kNoPot;
    pot_min[i] = i == 2 ? 819 : 205;
    pot_max[i] = i == 2 ? 205 : 819;
  }
  arm3::Limits l = kLimits;
  l.pot_channel = pot_channel;
  l.pot_counts_min = pot_min;
  l.pot_counts_max = pot_max;
  return l;
}

static uint16_t state_position(const Bytes& reply, int i) {
  return static_cast<uint16_t>(reply[6 + 4 + 2 * i] | (reply[6 + 5 + 2 * i] << 8));
}

static void test_pots_and_attach() {
  const arm3::Limits limits = pot_limits();
  arm3::Core core(limits, collect, nullptr);
  core.begin(1, 0);
  CHECK(core.measured_mask() == 0x05);
  // counts -> µs: the two calibration points, the middle, and beyond the span (clamped)
  core.set_pot(0, 205);
  CHECK(core.position(0) == 500);
  core.set_pot(0, 819);
  CHECK(core.position(0) == 2500);
  core.set_pot(0, 512);
  CHECK(core.position(0) == 1500);
  core.set_pot(0, 1000);
  CHECK(core.position(0) == 2500);
  core.set_pot(2, 819);  // reversed: the high count is the low pulse
  CHECK(core.position(2) == 500);
  core.set_pot(2, 512);
  CHECK(core.position(2) == 1500);
  CHECK(core.position(1) == ARM3_PARK_US[1]);  // no pot: the output pulse
  // STATE says which readings are measured
  replies.clear();
  feed(core, frame(1, arm3::kReadState, Bytes()), 1);
  CHECK(replies.size() == 1 && replies[0][6 + 3] == 0x05);
  CHECK(state_position(replies[0], 2) == 1500 && state_position(replies[0], 1) == ARM3_PARK_US[1]);
  // Torque on: a pot servo starts where it is (inside the limits), no snap to park
  core.set_pot(0, 450);  // 500 + (245 * 2000 + 307) / 614 = 1298 µs
  core.set_pot(2, 1023);  // beyond the span: 500 µs, under the elbow's lower limit
  feed(core, frame(2, arm3::kTorque, Bytes{1}), 2);
  CHECK(core.attached());
  CHECK(core.output(0) == 1298 && core.target(0) == 1298);
  CHECK(core.output(2) == ARM3_LOWER_US[2] && core.target(2) == ARM3_LOWER_US[2]);
  CHECK(core.output(1) == ARM3_PARK_US[1] && core.target(1) == ARM3_PARK_US[1]);
  // Torque off, then on from where the host last sent them: servos without a pot start there
  // (clamped), servos with one still from the pot
  feed(core, frame(3, arm3::kTorque, Bytes{0}), 3);
  CHECK(!core.attached());
  uint16_t start[ARM3_N_ACTUATORS];
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) start[i] = 1600;
  start[3] = 100;  // below the gripper's lower limit
  Bytes on = targets(start);
  on.insert(on.begin(), 1);
  feed(core, frame(4, arm3::kTorque, on), 4);
  CHECK(core.attached());
  CHECK(core.output(1) == 1600 && core.target(1) == 1600);
  CHECK(core.output(3) == ARM3_LOWER_US[3]);
  CHECK(core.output(0) == 1298);
  // Already on: a start pulse must not jump a driven servo
  for (int i = 0; i < ARM3_N_ACTUATORS; ++i) start[i] = 2000;
  on = targets(start);
  on.insert(on.begin(), 1);
  feed(core, frame(5, arm3::kTorque, on), 5);
  CHECK(core.output(1) == 1600);
  // Malformed TORQUE payloads are refused
  replies.clear();
  feed(core, frame(6, arm3::kTorque, Bytes{1, 2}), 6);
  CHECK(replies.size() == 1 && replies[0][6] == arm3::kErrBadLength);
  on[0] = 0;  // torque off with start pulses means nothing
  feed(core, frame(7, arm3::kTorque, on), 6);
  CHECK(replies.size() == 2 && replies[1][6] == arm3::kErrBadValue && core.attached());
}

int main() {
  test_crc();
  test_ping_and_resync();
  test_limits_step_and_torque();
  test_slew_and_watchdog();
  test_hold_then_resume();
  test_pots_and_attach();
  if (failures) {
    fprintf(stderr, "arm3 core: %d of %d checks failed\n", failures, checks);
    return 1;
  }
  printf("arm3 core: all %d checks passed\n", checks);
  return 0;
}
