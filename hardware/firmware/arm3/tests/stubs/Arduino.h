// Host-side stand-in for the few Arduino APIs arm3.ino uses, so g++ can compile the sketch.
#pragma once
#include <stddef.h>
#include <stdint.h>

#include <deque>
#include <vector>

unsigned long millis();

// Analog inputs: analogRead(A0 + ch) returns fake_adc[ch] (the test sets it).
const uint8_t A0 = 14;
extern uint16_t fake_adc[8];
inline int analogRead(uint8_t pin) { return fake_adc[(pin - A0) & 7]; }

struct FakeSerial {
  std::deque<uint8_t> rx;
  std::vector<uint8_t> tx;
  void begin(unsigned long) {}
  int available() { return static_cast<int>(rx.size()); }
  int read() {
    if (rx.empty()) return -1;
    const uint8_t b = rx.front();
    rx.pop_front();
    return b;
  }
  size_t write(const uint8_t* data, size_t len) {
    tx.insert(tx.end(), data, data + len);
    return len;
  }
};
extern FakeSerial Serial;
