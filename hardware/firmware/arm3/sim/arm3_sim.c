// arm3_sim: runs the arm3 firmware .elf on a simulated ATmega328P (simavr) in step with wall time.
//
//   arm3_sim FIRMWARE.elf PIN[,PIN...] [BOOT_ID] [CH=MV[,CH=MV...]]
//
// * The analog inputs start at the given millivolts (potentiometer wipers at power-up, so the
//   sketch's first samples in setup() read them) and change with "A" commands.
// * UART0 is bridged to a pseudo-terminal; its slave path is the first line on stdout. Bytes go
//   into the simulated UART at the chip's own baud rate (simavr times them from UBRR0), and a
//   host at another baud is heard as noise, as on a real UART.
// * Each servo pin's pulse width is measured from its pin changes, in CPU cycles.
// * Simulated time never runs ahead of wall time (the firmware's watchdog sees real
//   milliseconds); when the host starves the process it falls behind and catches up.
// * The firmware sleeps between interrupts, and the harness jumps over that sleep: an idle chip
//   costs one wake-up per timer interrupt, not 16 million cycles a second.
//
// Events on stdout, one per line, times in simulated microseconds since power-up:
//   PTY <path>                 the serial port to open
//   BAUD <actual> <ubrr> <u2x> the UART's real baud rate once the firmware set it
//   P <t_us> <ch> <width_ns>   a pulse on channel ch ended at t_us and lasted width_ns
//   O <t_us> <ch>              channel ch stopped pulsing (no pulse within 25 ms)
//   RX <t_us> <hex>            bytes the UART received (delivered to the firmware's RX)
//   TX <t_us> <hex>            bytes the firmware sent
//   T <t_us> <min_sp>          a heartbeat (every 10 ms of simulated time) with the lowest stack
//                              pointer seen so far
//   RESET <t_us>               the chip was reset (brown-out command)
//   ADC <t_us> <ch> <mv>       analog input ch now carries mv millivolts (from an "A" command)
// Commands on stdin, one per line: "B" brown-out reset (EEPROM kept), "Q" quit,
// "A <ch> <mv>" set analog input ch (A0..A7) to mv millivolts (a potentiometer's wiper; the
// ADC's references are 5 V, so the firmware reads mv * 1023 / 5000 counts). EOF on stdin also
// quits, so the harness never outlives its parent.
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_adc.h"
#include "avr_eeprom.h"
#include "avr_extint.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"

#define MAX_CH 8
#define F_CPU_HZ 16000000ULL
#define CHUNK_CYCLES 4000ULL          // 0.25 ms of simulated time between I/O checks
#define OFF_AFTER_CYCLES (F_CPU_HZ / 40)  // 25 ms without a rising edge: the channel is off
#define HEARTBEAT_CYCLES (F_CPU_HZ / 100)
#define RX_BUF 4096
#define QUIET_CYCLES (F_CPU_HZ / 200)  // 5 ms without a UART byte: the line is quiet
#define IDLE_WAIT_S 0.005
#define VREF_MV 5000  // AVCC and AREF: an Uno's 5 V

static avr_t* avr;
static int n_ch;
static int ch_pin[MAX_CH];
static avr_cycle_count_t rise_at[MAX_CH];
static int rising[MAX_CH];
static int pulsing[MAX_CH];
static uint8_t rx_buf[RX_BUF];
static int rx_head, rx_len;
static int uart_xoff;
static char tx_line[3 * 256 + 64];
static int tx_count;
static avr_cycle_count_t tx_t0;
static uint16_t min_sp = 0xFFFF;
static int baud_reported;
static int pty_master = -1;
static avr_cycle_count_t last_activity;  // last UART byte either way: keep fine steps after it
static char cmd_line[64];
static int cmd_len;

static double t_us(avr_cycle_count_t c) { return (double)c * 1e6 / (double)F_CPU_HZ; }

static void quiet_logger(avr_t* a, const int level, const char* fmt, va_list ap) {
  (void)a;
  if (level <= LOG_WARNING) vfprintf(stderr, fmt, ap);
}

static void no_sleep(avr_t* a, avr_cycle_count_t how_long) {
  (void)a;
  (void)how_long;  // pacing is ours: see main()
}

static void flush_tx(void) {
  if (tx_count == 0) return;
  printf("TX %.0f %s\n", t_us(tx_t0), tx_line);
  tx_count = 0;
  tx_line[0] = 0;
}

static void on_uart_out(struct avr_irq_t* irq, uint32_t value, void* param) {
  (void)irq;
  (void)param;
  const uint8_t b = (uint8_t)(value & 0xFF);
  last_activity = avr->cycle;
  if (pty_master >= 0 && write(pty_master, &b, 1) != 1) {
    // nobody reads the port: the byte is lost, as on a real wire
  }
  if (tx_count == 0) tx_t0 = avr->cycle;
  sprintf(tx_line + 2 * tx_count, "%02x", value & 0xFF);
  if (++tx_count >= 256) flush_tx();
}

static void on_xon(struct avr_irq_t* irq, uint32_t value, void* param) {
  (void)irq;
  (void)value;
  (void)param;
  uart_xoff = 0;
}

static void on_xoff(struct avr_irq_t* irq, uint32_t value, void* param) {
  (void)irq;
  (void)value;
  (void)param;
  uart_xoff = 1;
}

static void on_pin(struct avr_irq_t* irq, uint32_t value, void* param) {
  (void)irq;
  const int ch = (int)(intptr_t)param;
  if (value) {
    rise_at[ch] = avr->cycle;
    rising[ch] = 1;
  } else if (rising[ch]) {
    rising[ch] = 0;
    pulsing[ch] = 1;
    const avr_cycle_count_t cycles = avr->cycle - rise_at[ch];
    printf("P %.0f %d %llu\n", t_us(avr->cycle), ch,
           (unsigned long long)(cycles * 1000000000ULL / F_CPU_HZ));
  }
}

// Arduino Uno pin numbers: 0-7 port D, 8-13 port B, 14-19 port C.
static int pin_port(int pin, char* port, int* bit) {
  if (pin >= 0 && pin <= 7) {
    *port = 'D';
    *bit = pin;
  } else if (pin >= 8 && pin <= 13) {
    *port = 'B';
    *bit = pin - 8;
  } else if (pin >= 14 && pin <= 19) {
    *port = 'C';
    *bit = pin - 14;
  } else {
    return -1;
  }
  return 0;
}

static void set_references(void) {
  avr->vcc = VREF_MV;
  avr->avcc = VREF_MV;
  avr->aref = VREF_MV;
}

// One command line from stdin; returns 1 on "Q".
static int run_command(const char* line) {
  if (line[0] == 'Q') return 1;
  if (line[0] == 'B') {
    avr_reset(avr);
    avr->sleep = no_sleep;
    set_references();
    avr_extint_set_strict_lvl_trig(avr, 0, 0);
    avr_extint_set_strict_lvl_trig(avr, 1, 0);
    uart_xoff = 0;
    baud_reported = 0;
    for (int ch = 0; ch < n_ch; ++ch) rising[ch] = 0;
    printf("RESET %.0f\n", t_us(avr->cycle));
  } else if (line[0] == 'A') {
    int ch = -1, mv = -1;
    if (sscanf(line + 1, "%d %d", &ch, &mv) == 2 && ch >= 0 && ch <= 7 && mv >= 0 &&
        mv <= VREF_MV) {
      avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + ch), (uint32_t)mv);
      printf("ADC %.0f %d %d\n", t_us(avr->cycle), ch, mv);
    } else {
      fprintf(stderr, "arm3_sim: bad command %s (want: A <ch 0-7> <mv 0-%d>)\n", line, VREF_MV);
    }
  }
  return 0;
}

static int open_pty(int* slave_fd, char* path, size_t path_len) {
  const int master = posix_openpt(O_RDWR | O_NOCTTY);
  if (master < 0 || grantpt(master) || unlockpt(master)) return -1;
  if (ptsname_r(master, path, path_len)) return -1;
  *slave_fd = open(path, O_RDWR | O_NOCTTY);  // held open: the host may close and reopen
  if (*slave_fd < 0) return -1;
  struct termios tio;
  tcgetattr(*slave_fd, &tio);
  cfmakeraw(&tio);
  cfsetispeed(&tio, B115200);
  cfsetospeed(&tio, B115200);
  tcsetattr(*slave_fd, TCSANOW, &tio);
  fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
  return master;
}

// The host's line speed as set on the pty, or 0 when it is not a standard one.
static speed_t host_speed(int slave_fd) {
  struct termios tio;
  if (tcgetattr(slave_fd, &tio)) return 0;
  return cfgetospeed(&tio);
}

static double now_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static void report_baud(void) {
  // UCSR0A 0xC0 (U2X0 = bit 1), UCSR0B 0xC1 (RXEN0 = bit 4), UBRR0L 0xC4, UBRR0H 0xC5
  if (baud_reported || !(avr->data[0xC1] & (1 << 4))) return;
  const unsigned ubrr = avr->data[0xC4] | ((avr->data[0xC5] & 0x0F) << 8);
  const int u2x = (avr->data[0xC0] >> 1) & 1;
  const double baud = (double)F_CPU_HZ / ((u2x ? 8.0 : 16.0) * (ubrr + 1));
  printf("BAUD %.0f %u %d\n", baud, ubrr, u2x);
  baud_reported = 1;
}

int main(int argc, char** argv) {
  if (argc < 3) {
    fprintf(stderr, "usage: %s FIRMWARE.elf PIN[,PIN...] [BOOT_ID] [CH=MV,...]\n", argv[0]);
    return 2;
  }
  setvbuf(stdout, NULL, _IOFBF, 1 << 16);
  avr_global_logger_set(quiet_logger);
  elf_firmware_t fw;
  memset(&fw, 0, sizeof fw);
  if (elf_read_firmware(argv[1], &fw)) {
    fprintf(stderr, "arm3_sim: cannot read firmware %s\n", argv[1]);
    return 2;
  }
  avr = avr_make_mcu_by_name("atmega328p");
  if (!avr) {
    fprintf(stderr, "arm3_sim: simavr has no atmega328p\n");
    return 2;
  }
  avr_init(avr);
  avr->log = LOG_WARNING;
  avr_load_firmware(avr, &fw);
  avr->frequency = F_CPU_HZ;
  avr->sleep = no_sleep;
  set_references();
  // simavr polls INT0/INT1 every cycle while their pin is low ("strict" low-level trigger), even
  // with the interrupt masked; pin 3 (INT1) carries servo pulses and is low most of the time.
  // The firmware never enables INT0/INT1, so the poll only stops the sleeping core from jumping
  // to its next interrupt: switch it off.
  avr_extint_set_strict_lvl_trig(avr, 0, 0);
  avr_extint_set_strict_lvl_trig(avr, 1, 0);
  if (argc > 3) {  // the boot counter in EEPROM: the firmware adds one at boot
    const uint16_t before = (uint16_t)(strtoul(argv[3], NULL, 0) - 1);
    uint8_t ee[2] = {(uint8_t)(before & 0xFF), (uint8_t)(before >> 8)};
    avr_eeprom_desc_t d = {.ee = ee, .offset = 0, .size = 2};
    avr_ioctl(avr, AVR_IOCTL_EEPROM_SET, &d);
  }

  char* spec = argv[2];
  for (char* tok = strtok(spec, ","); tok && n_ch < MAX_CH; tok = strtok(NULL, ",")) {
    char port;
    int bit;
    const int pin = atoi(tok);
    if (pin_port(pin, &port, &bit)) {
      fprintf(stderr, "arm3_sim: pin %d is not an Uno digital pin (0-19)\n", pin);
      return 2;
    }
    ch_pin[n_ch] = pin;
    avr_irq_t* irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit);
    avr_irq_register_notify(irq, on_pin, (void*)(intptr_t)n_ch);
    ++n_ch;
  }

  uint32_t flags = 0;
  avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
  flags &= ~(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
  avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
  avr_irq_t* uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                          on_uart_out, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                          on_xon, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                          on_xoff, NULL);

  int slave = -1;
  char path[256];
  const int master = open_pty(&slave, path, sizeof path);
  if (master < 0) {
    fprintf(stderr, "arm3_sim: cannot open a pseudo-terminal: %s\n", strerror(errno));
    return 2;
  }
  pty_master = master;
  printf("PTY %s\n", path);
  fflush(stdout);
  if (argc > 4) {
    char* adc_spec = argv[4];
    for (char* tok = strtok(adc_spec, ","); tok; tok = strtok(NULL, ",")) {
      char line[32];
      snprintf(line, sizeof line, "A %s", tok);
      for (char* c = line; *c; ++c) {
        if (*c == '=') *c = ' ';
      }
      run_command(line);
    }
  }
  fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);

  const double t0 = now_s();
  avr_cycle_count_t next_beat = HEARTBEAT_CYCLES;
  int quit = 0;
  unsigned rng = 12345u;
  while (!quit) {
    // 1. run the chip up to wall time, one chunk at a time
    const avr_cycle_count_t wall = (avr_cycle_count_t)((now_s() - t0) * (double)F_CPU_HZ);
    if (avr->cycle < wall) {
      const avr_cycle_count_t end = avr->cycle + CHUNK_CYCLES < wall ? avr->cycle + CHUNK_CYCLES
                                                                     : wall;
      while (avr->cycle < end) {
        const int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
          fprintf(stderr, "arm3_sim: the firmware stopped (state %d) at %.0f us\n", state,
                  t_us(avr->cycle));
          printf("CRASH %.0f %d\n", t_us(avr->cycle), state);
          fflush(stdout);
          return 3;
        }
        const uint16_t sp = (uint16_t)(avr->data[0x5D] | (avr->data[0x5E] << 8));
        if (sp < min_sp && sp > 0x100) min_sp = sp;
      }
    }
    report_baud();
    flush_tx();
    for (int ch = 0; ch < n_ch; ++ch) {
      if (pulsing[ch] && !rising[ch] && avr->cycle - rise_at[ch] > OFF_AFTER_CYCLES) {
        pulsing[ch] = 0;
        printf("O %.0f %d\n", t_us(rise_at[ch] + F_CPU_HZ / 50), ch);
      }
    }
    if (avr->cycle >= next_beat) {
      printf("T %.0f %u\n", t_us(avr->cycle), min_sp);
      next_beat = avr->cycle + HEARTBEAT_CYCLES;
    }
    // 2. bytes from the host into the UART while its FIFO has room
    if (rx_len == 0) {
      const ssize_t got = read(master, rx_buf, sizeof rx_buf);
      if (got > 0) {
        rx_head = 0;
        rx_len = (int)got;
        const speed_t sp = host_speed(slave);
        if (sp != 0 && sp != B115200) {  // a UART at another baud hears noise
          for (int i = 0; i < rx_len; ++i) {
            rng = rng * 1103515245u + 12345u;
            rx_buf[i] = (uint8_t)(rng >> 16);
          }
        }
      }
    }
    if (rx_len > 0 && !uart_xoff) {
      char hex[2 * 64 + 1];
      int k = 0;
      while (rx_len > 0 && !uart_xoff && k < 64) {
        const uint8_t b = rx_buf[rx_head++];
        --rx_len;
        sprintf(hex + 2 * k, "%02x", b);
        ++k;
        avr_raise_irq(uart_in, b);
        last_activity = avr->cycle;
      }
      printf("RX %.0f %s\n", t_us(avr->cycle), hex);
    }
    // 3. commands
    char cmd[64];
    const ssize_t c = read(0, cmd, sizeof cmd);
    if (c == 0) quit = 1;
    for (ssize_t i = 0; i < c; ++i) {
      if (cmd[i] == '\n' || cmd_len == (int)sizeof cmd_line - 1) {
        cmd_line[cmd_len] = 0;
        if (cmd_len > 0 && run_command(cmd_line)) quit = 1;
        cmd_len = 0;
      } else {
        cmd_line[cmd_len++] = cmd[i];
      }
    }
    fflush(stdout);
    // 4. ahead of wall time (or nothing to do): wait for the host, at most until wall time
    //    catches up with the chip
    //    With no UART traffic for a while, wait IDLE_WAIT_S longer and then catch up in one
    //    burst: a byte from the host ends the wait at once, and nothing else needs the chip
    //    to be simulated the moment it happens (pulses are timed from simulated cycles).
    double wait_s = t_us(avr->cycle) * 1e-6 - (now_s() - t0);
    const int quiet = rx_len == 0 && avr->cycle - last_activity > QUIET_CYCLES;
    if (quiet && wait_s >= 0) wait_s += IDLE_WAIT_S;  // caught up: wait, then a burst
    if (wait_s > 0 && rx_len == 0) {
      struct pollfd fds[2] = {{master, POLLIN, 0}, {0, POLLIN, 0}};
      const struct timespec ts = {0, (long)(wait_s * 1e9)};
      ppoll(fds, 2, &ts, NULL);
    }
  }
  (void)ch_pin;
  close(master);
  close(slave);
  return 0;
}
