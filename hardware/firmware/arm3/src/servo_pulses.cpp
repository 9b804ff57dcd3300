#include "servo_pulses.h"

namespace arm3 {

namespace {

uint16_t clamp_width(uint16_t us) {
  return us < kPulseMinUs ? kPulseMinUs : (us > kPulseMaxUs ? kPulseMaxUs : us);
}

}  // namespace

}  // namespace arm3

#if defined(__AVR__)
#include <Arduino.h>
#include <avr/interrupt.h>
#include <util/atomic.h>

namespace arm3 {
namespace {

const uint16_t kTicksPerUs = F_CPU / 8 / 1000000UL;  // prescaler 8: 2 ticks per us at 16 MHz
const uint16_t kFrameTicks = kFrameUs * kTicksPerUs;

uint8_t g_n = 0;
uint8_t g_pins[kMaxPulseChannels];
volatile uint8_t* g_port[kMaxPulseChannels];
uint8_t g_mask[kMaxPulseChannels];
volatile uint16_t g_ticks[kMaxPulseChannels];
volatile uint8_t g_on[kMaxPulseChannels];
uint8_t g_high[kMaxPulseChannels];  // slot i raised its pin (ISR only)
// The ISR's state: the slot that starts at the next compare (0..n-1 a pulse, n the frame's rest)
// and the two edges it will make there, precomputed so both edges come at the same instant.
volatile uint8_t g_scratch;  // a harmless target for "no edge"
uint8_t g_chan = 0;
volatile uint8_t* g_lo_port = &g_scratch;
uint8_t g_lo_mask = 0;
volatile uint8_t* g_hi_port = &g_scratch;
uint8_t g_hi_mask = 0;
uint16_t g_frame_start = 0;

}  // namespace

void ServoPulses::begin(const uint8_t* pins, uint8_t n, const uint16_t* park_us) {
  g_n = n > kMaxPulseChannels ? kMaxPulseChannels : n;
  for (uint8_t i = 0; i < g_n; ++i) {
    g_pins[i] = pins[i];
    g_port[i] = portOutputRegister(digitalPinToPort(pins[i]));
    g_mask[i] = digitalPinToBitMask(pins[i]);
    g_ticks[i] = clamp_width(park_us[i]) * kTicksPerUs;
    g_on[i] = 0;
    g_high[i] = 0;
    digitalWrite(pins[i], LOW);
    pinMode(pins[i], OUTPUT);
  }
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    TCCR1A = 0;          // normal mode: Timer1 counts 0..0xFFFF and wraps
    TCCR1B = _BV(CS11);  // clk / 8
    g_chan = 0;
    g_lo_port = g_hi_port = &g_scratch;
    OCR1A = static_cast<uint16_t>(TCNT1 + 100u);
    TIFR1 = _BV(OCF1A);
    TIMSK1 |= _BV(OCIE1A);
  }
}

void ServoPulses::set(uint8_t i, bool on, uint16_t width_us) {
  if (i >= g_n) return;
  const uint16_t ticks = clamp_width(width_us) * kTicksPerUs;
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    g_ticks[i] = ticks;
    g_on[i] = on ? 1 : 0;
  }
}

bool ServoPulses::on(uint8_t i) const { return i < g_n && g_on[i] != 0; }

uint16_t ServoPulses::width_us(uint8_t i) const {
  uint16_t ticks;
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { ticks = g_ticks[i]; }
  return ticks / kTicksPerUs;
}

uint8_t ServoPulses::pin(uint8_t i) const { return g_pins[i]; }

}  // namespace arm3

// One compare match = one instant: end the running pulse and start the next one, both first
// thing, one instruction apart, then schedule the next instant. OCR1A advances from the previous
// compare value, never from TCNT1, so a width is exact in timer ticks; only another interrupt
// running at that instant (millis, UART) delays both edges of this compare by a few us.
ISR(TIMER1_COMPA_vect) {
  using namespace arm3;
  volatile uint8_t* const lo = g_lo_port;
  volatile uint8_t* const hi = g_hi_port;
  if (lo == hi) {
    *lo = static_cast<uint8_t>((*lo & ~g_lo_mask) | g_hi_mask);
  } else {  // both values first, then two stores one instruction apart
    const uint8_t lo_value = static_cast<uint8_t>(*lo & ~g_lo_mask);
    const uint8_t hi_value = static_cast<uint8_t>(*hi | g_hi_mask);
    *lo = lo_value;
    *hi = hi_value;
  }
  const uint8_t c = g_chan;  // the slot that starts now
  if (c < g_n) {
    if (c == 0) g_frame_start = OCR1A;
    OCR1A = static_cast<uint16_t>(OCR1A + g_ticks[c]);
  } else {
    OCR1A = static_cast<uint16_t>(g_frame_start + kFrameTicks);
  }
  const uint8_t next = c < g_n ? static_cast<uint8_t>(c + 1) : 0;
  if (c < g_n && g_high[c]) {
    g_lo_port = g_port[c];
    g_lo_mask = g_mask[c];
  } else {
    g_lo_port = &g_scratch;
    g_lo_mask = 0;
  }
  if (next < g_n && g_on[next]) {
    g_high[next] = 1;
    g_hi_port = g_port[next];
    g_hi_mask = g_mask[next];
  } else {
    if (next < g_n) g_high[next] = 0;
    g_hi_port = &g_scratch;
    g_hi_mask = 0;
  }
  g_chan = next;
}

#else  // host build: record only

namespace arm3 {
namespace {
uint8_t h_n = 0;
uint8_t h_pins[kMaxPulseChannels];
uint16_t h_width[kMaxPulseChannels];
bool h_on[kMaxPulseChannels];
}  // namespace

void ServoPulses::begin(const uint8_t* pins, uint8_t n, const uint16_t* park_us) {
  h_n = n > kMaxPulseChannels ? kMaxPulseChannels : n;
  for (uint8_t i = 0; i < h_n; ++i) {
    h_pins[i] = pins[i];
    h_width[i] = clamp_width(park_us[i]);
    h_on[i] = false;
  }
}

void ServoPulses::set(uint8_t i, bool on, uint16_t width_us) {
  if (i >= h_n) return;
  h_on[i] = on;
  h_width[i] = clamp_width(width_us);
}

bool ServoPulses::on(uint8_t i) const { return i < h_n && h_on[i]; }
uint16_t ServoPulses::width_us(uint8_t i) const { return h_width[i]; }
uint8_t ServoPulses::pin(uint8_t i) const { return h_pins[i]; }

}  // namespace arm3

#endif
