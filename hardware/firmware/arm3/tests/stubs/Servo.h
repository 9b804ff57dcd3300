#pragma once
#include <stdint.h>

class Servo {
 public:
  uint8_t attach(int pin, int, int) {
    pin_ = pin;
    attached_ = true;
    return 0;
  }
  void detach() { attached_ = false; }
  bool attached() const { return attached_; }
  void writeMicroseconds(int us) { us_ = us; }
  int readMicroseconds() const { return us_; }
  int pin() const { return pin_; }

 private:
  bool attached_ = false;
  int us_ = 1500;
  int pin_ = -1;
};
