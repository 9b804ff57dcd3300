// Servo pulses without the Servo library: Timer1 times one pulse after another on any pins.
//
// A 20 ms frame: channel 0's pulse, then channel 1's, ... then idle until the frame ends. Each
// compare interrupt ends one pulse and starts the next at the same compare instant, so a pulse is
// exactly its width in Timer1 ticks (0.5 us at 16 MHz / 8); interrupt latency shifts both edges
// alike. A channel that is off keeps its pin low (the servo goes limp) and keeps its time slot.
//
// On the host (g++, no __AVR__) the same class only records what it was told, for tests.
#pragma once
#include <stdint.h>

namespace arm3 {

const uint8_t kMaxPulseChannels = 8;
const uint16_t kPulseMinUs = 400;   // narrower pulses are widened to this
const uint16_t kPulseMaxUs = 2600;  // wider ones are narrowed: 8 slots always fit a 20 ms frame
const uint16_t kFrameUs = 20000;    // 50 Hz, the hobby-servo standard

class ServoPulses {
 public:
  // Pins are Arduino pin numbers; every channel starts off at ``park_us``.
  void begin(const uint8_t* pins, uint8_t n, const uint16_t* park_us);
  // Drive channel i with pulses of ``width_us`` (on) or keep its pin low (off).
  void set(uint8_t i, bool on, uint16_t width_us);
  bool on(uint8_t i) const;
  uint16_t width_us(uint8_t i) const;
  uint8_t pin(uint8_t i) const;
};

}  // namespace arm3
