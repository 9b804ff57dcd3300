#pragma once
#include <stdint.h>
#include <string.h>

struct FakeEEPROM {
  uint8_t mem[64] = {0};
  template <typename T>
  T& get(int addr, T& value) {
    memcpy(&value, mem + addr, sizeof(T));
    return value;
  }
  template <typename T>
  const T& put(int addr, const T& value) {
    memcpy(mem + addr, &value, sizeof(T));
    return value;
  }
};
extern FakeEEPROM EEPROM;
