// The bridge firmware's board layer for QEMU's lm3s6965evb (a Stellaris LM3S6965,
// ARM Cortex-M3, here clocked at 25 MHz, with PL011 UARTs and general-purpose timers):
// what the Arduino Due sketch does with pins, done with the emulated peripherals, around
// the same core (bridge_core.cpp, joint_protocol.cpp).
//
//   UART0  the host link (the Due's USB serial): Joint protocol lines.
//   UART1  the plant channel, standing in for the pins: the "DAC" and the
//          amplifier enable go out, the HCTL-2021 "bus" bytes and the limit
//          switches come back. Lines (no checksum: a simulation's own wire):
//            firmware -> plant   T,<t_us>                  sample the plant at t_us
//                                O,<t_us>,<dac>,<enable>,<c> the output written at t_us
//                                                          (c: the host line's type, A: the
//                                                          every-pass refresh changed it)
//                                R,<t_us>                  the decoders' counters reset
//                                M,<statistics>            see send_statistics()
//            plant -> firmware   C,<HHLLHHLLm>              the answer to T, in hex: the cart's
//                                                          bus bytes (high, low), the
//                                                          pendulum's, the limits (bit 0
//                                                          left, bit 1 right)
//                                Q                         asks for an M line
//                                G,<limits>                go: the plant is served (the
//                                                          firmware starts its clock then)
//          Both UARTs run with their 16-byte receive FIFOs: QEMU's I/O thread fills a
//          FIFO while the CPU works and the CPU empties it in one interrupt, where a
//          1-byte UART (the mps2-an385's CMSDK UART, this layer's first machine) needed a
//          hand-over between QEMU's threads for every byte, which a host whose CPUs are
//          taken makes slow (docs/rig.md).
//   SysTick free-running at the 25 MHz CPU clock: micros() (its 24 bits wrap every 0.67 s;
//          the loop reads it at least every 5 ms and extends it in software) and the work
//          of each pass in clocks (under QEMU's -icount, a fixed number of instructions).
//          QEMU computes its value from the guest clock, so no count is lost when the host
//          is slow to run QEMU, unless it does not run it for a whole wrap (0.67 s).
//   Timer 0A one-shot, armed before the loop sleeps for the next sample deadline.
//
// The sample is taken at its deadline: its time is the deadline's (k x 5000 us).
// The watchdog and the limits run then and the output follows at once; the
// plant is asked for the counters at that time (T) and the S line goes out
// when they come back (C), with the device's state of the deadline. So the
// host's round trip through the plant's process never holds up the firmware,
// its watchdog or the host's commands, and the plant still sees every output
// at the firmware's time. The limit switches are those the plant reported
// with the previous sample (5 ms old; the Due reads its pins at the deadline).
// A plant 40 samples (200 ms) behind loses the oldest sample (its seq is skipped).
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "bridge_core.h"

extern "C" uint32_t stack_high_water(void);
extern "C" void Uart0_Handler(void);
extern "C" void Uart1_Handler(void);
extern "C" void Timer0A_Handler(void);

namespace {

struct Pl011 {   // the Stellaris UART (an ARM PL011)
  volatile uint32_t dr, rsr, reserved0[4], fr, reserved1, ilpr, ibrd, fbrd, lcrh, cr, ifls,
      imsc, ris, mis, icr;
};
struct Gptm {    // a Stellaris general-purpose timer
  volatile uint32_t cfg, tamr, tbmr, ctl, reserved0[2], imr, ris, mis, icr, tailr;
};
Pl011 *const kUart0 = reinterpret_cast<Pl011 *>(0x4000C000);
Pl011 *const kUart1 = reinterpret_cast<Pl011 *>(0x4000D000);
Gptm *const kTimer0 = reinterpret_cast<Gptm *>(0x40030000);
volatile uint32_t *const kRcc = reinterpret_cast<volatile uint32_t *>(0x400FE060);
volatile uint32_t *const kRcgc1 = reinterpret_cast<volatile uint32_t *>(0x400FE104);
volatile uint32_t *const kNvicIser = reinterpret_cast<volatile uint32_t *>(0xE000E100);
volatile uint32_t *const kSysTick = reinterpret_cast<volatile uint32_t *>(0xE000E010);

const uint32_t kSysClock = 25000000;                          // Hz: 200 MHz PLL / (SYSDIV 7 + 1)
const uint32_t kClocksPerUs = kSysClock / 1000000;
const uint32_t kRccSysdiv = 0xFu << 23;
const uint32_t kUartRxEmpty = 1u << 4, kUartTxFull = 1u << 5;                // FR
const uint32_t kUartRx = 1u << 4, kUartTx = 1u << 5, kUartRxTimeout = 1u << 6;  // IMSC/MIS/ICR
const uint32_t kUartEnable = 1u << 0, kUartTxEnable = 1u << 8, kUartRxEnable = 1u << 9;  // CR
const uint32_t kUart8Bits = 3u << 5, kUartFifos = 1u << 4;                   // LCRH
const uint32_t kTimerOneShot = 1, kTimerEnable = 1, kTimerTimeout = 1;       // TAMR, CTL, IMR/ICR
const uint32_t kIrqUart0 = 5, kIrqUart1 = 6, kIrqTimer0A = 19;

inline void irq_off() { __asm volatile("cpsid i" ::: "memory"); }
inline void irq_on() { __asm volatile("cpsie i" ::: "memory"); }
inline void wait_for_interrupt() { __asm volatile("wfi" ::: "memory"); }
inline uint32_t clocks() { return kSysTick[2] & 0xFFFFFF; }   // SysTick CVR, counts down
inline uint32_t clocks_since(uint32_t start) { return (start - clocks()) & 0xFFFFFF; }

// Single-producer single-consumer byte ring (one side in an interrupt).
template <unsigned N>
struct Ring {
  uint8_t buf[N];
  volatile uint32_t head, tail;   // free-running; N is a power of two
  bool empty() const { return head == tail; }
  uint32_t used() const { return head - tail; }
  uint32_t room() const { return N - used(); }
  void put(uint8_t c) { buf[head % N] = c; head = head + 1; }
  uint8_t get() { uint8_t c = buf[tail % N]; tail = tail + 1; return c; }
};

Ring<512> host_rx;
Ring<1024> host_tx;
Ring<256> plant_rx;
Ring<1024> plant_tx;
volatile bool host_rx_paused;     // ring full: the bytes wait in the UART's FIFO (flow control)
uint32_t micros_total;            // microseconds since the clock started (wrapping)
uint32_t clock_rest;              // SysTick clocks since then not yet in micros_total
uint32_t clock_last;
bool sampling;                    // G received: micros() counts (0 before), the deadlines are on
uint32_t wakeup_for;              // the deadline Timer 0A is armed for

BridgeCore core;

struct Statistics {
  uint32_t tick_max;       // clocks of the worst deadline (watchdog, limits, output, T)
  uint32_t sample_max;     // clocks of the worst completion (C parsed, S line sent)
  uint32_t line_max;       // clocks of the worst host byte handled (a whole line's work)
  uint32_t period_max;     // clocks of the busiest 5 ms period (all the loop's work in it)
  uint32_t period_work;
  uint32_t pending_max;    // most samples waiting for the plant at once
  uint32_t plant_timeouts; // samples lost: the plant was 40 samples behind
  bool requested;
} stats;

int last_dac = -1;
int last_enable = -1;

// ---- UARTs ----------------------------------------------------------------------------
void uart_init(Pl011 *u) {
  u->cr = 0;
  u->ibrd = kSysClock / (16 * 115200);                                   // 115 200 Bd
  u->fbrd = (kSysClock % (16 * 115200) * 64 + 8 * 115200) / (16 * 115200);
  u->lcrh = kUart8Bits | kUartFifos;
  u->imsc = kUartRx | kUartRxTimeout | kUartTx;
  u->cr = kUartEnable | kUartTxEnable | kUartRxEnable;
}

void host_tx_kick() {   // with interrupts off, or in the UART's interrupt
  while (!host_tx.empty() && !(kUart0->fr & kUartTxFull)) kUart0->dr = host_tx.get();
}

void plant_tx_kick() {   // with interrupts off, or in the UART's interrupt
  while (!plant_tx.empty() && !(kUart1->fr & kUartTxFull)) kUart1->dr = plant_tx.get();
}

// The host's bytes from UART0's FIFO into the ring; with the ring full they stay in the FIFO
// (and QEMU stops reading the host's socket: flow control) until take_paused_bytes().
void host_rx_take() {   // with interrupts off, or in the UART's interrupt
  while (!(kUart0->fr & kUartRxEmpty)) {
    if (host_rx.room() == 0) {
      host_rx_paused = true;
      kUart0->imsc = kUart0->imsc & ~(kUartRx | kUartRxTimeout);
      return;
    }
    host_rx.put((uint8_t)kUart0->dr);
  }
}

// The plant channel loses nothing: with its buffer full (never, in practice) this waits.
void plant_write(const char *s, size_t n) {
  for (size_t i = 0; i < n; ++i) {
    while (plant_tx.room() == 0) {
      irq_off();
      plant_tx_kick();
      irq_on();
    }
    irq_off();
    plant_tx.put((uint8_t)s[i]);
    irq_on();
  }
  irq_off();
  plant_tx_kick();
  irq_on();
}

void plant_printf(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
void plant_printf(const char *fmt, ...) {
  char line[96];
  va_list ap;
  va_start(ap, fmt);
  int n = vsnprintf(line, sizeof line, fmt, ap);
  va_end(ap);
  if (n > 0) plant_write(line, (size_t)n < sizeof line ? (size_t)n : sizeof line - 1);
}

// ---- time ----------------------------------------------------------------------------
uint32_t micros_now() {   // from the main loop only (it runs at least every 5 ms)
  if (!sampling) return 0;
  uint32_t value = clocks();                      // counts down, 24 bits
  clock_rest += (clock_last - value) & 0xFFFFFF;  // clocks not yet counted as whole microseconds
  clock_last = value;
  micros_total += clock_rest / kClocksPerUs;      // 32-bit: wraps like the Due's micros()
  clock_rest %= kClocksPerUs;
  return micros_total;
}

// Timer 0A wakes the loop at the next deadline (re-armed when the deadline moves on or the
// one-shot has run out), so the wake-up never falls just before a deadline, whatever the two
// clocks' phase.
void arm_wakeup() {   // with interrupts off
  if (wakeup_for == core.next_sample_us && (kTimer0->ctl & kTimerEnable)) return;
  int32_t ahead_us = (int32_t)(core.next_sample_us - micros_now());
  if (ahead_us <= 0) return;
  wakeup_for = core.next_sample_us;
  kTimer0->ctl = 0;
  kTimer0->icr = kTimerTimeout;
  kTimer0->tailr = ((uint32_t)ahead_us + 1) * kClocksPerUs;
  kTimer0->ctl = kTimerEnable;
}

bool deadline_passed(uint32_t now_us) { return (int32_t)(now_us - core.next_sample_us) >= 0; }
bool sample_due_now() { return deadline_passed(micros_now()); }

// The device time of what the loop does now, in the loop's order (bridge_core.h). QEMU runs
// the emulated CPU on the host's clock, which runs on while the host runs QEMU's other
// threads or other processes: a host line the loop took before a deadline can complete, by
// micros(), after it (the graph's runs saw 10-20 such U lines in 15 s, by up to 0.4 ms).
// Stamped so, it would be newer than the deadline taken next: that deadline's watchdog would
// take it as 2^32 us old (device fault 16 with U lines arriving every 5 ms) and its S line
// would report the command as written after the sample. So everything done at a deadline is
// stamped with the deadline's time, and anything else with micros(), but before the first
// deadline the loop has not taken yet.
bool at_deadline;         // sample() runs: its events are at deadline_us
uint32_t deadline_us;

uint32_t event_us() {
  if (at_deadline) return deadline_us;
  uint32_t now = micros_now();
  if (sampling && deadline_passed(now)) return core.next_sample_us - 1;
  return now;
}

// ---- the board hooks of the core ------------------------------------------------------
uint32_t board_micros(void *) { return event_us(); }
size_t board_tx_room(void *) { return host_tx.room(); }

void board_tx(void *, const char *buf, size_t n) {
  irq_off();
  for (size_t i = 0; i < n; ++i) host_tx.put((uint8_t)buf[i]);
  host_tx_kick();
  irq_on();
}

void board_write_output(void *, int dac, bool enable, char cause) {
  if (cause == 0 && dac == last_dac && (int)enable == last_enable) return;
  last_dac = dac;
  last_enable = enable;
  plant_printf("O,%lu,%d,%d,%c\n", (unsigned long)event_us(), dac, enable ? 1 : 0,
               cause ? cause : 'A');
}

void board_reset_counters(void *) { plant_printf("R,%lu\n", (unsigned long)event_us()); }

const BridgeBoard board = {0, board_micros, board_tx_room, board_tx, board_write_output,
                           board_reset_counters};

// ---- the plant channel --------------------------------------------------------------------
// Samples whose counts the plant has not answered yet, oldest first: the deadline's
// time and the device's state then (bridge_tick).
struct Pending {
  uint32_t t_us;
  JpDevice at;
};
const unsigned kPendingMax = 40;  // 200 ms of samples (the Python emulator resynchronises after 0.2 s too)
Pending pending[kPendingMax];
unsigned pending_head, pending_count;
bool limit_left, limit_right;     // the switches as the plant last reported them

char plant_line[64];
size_t plant_len;
bool plant_ready;   // G received

// The oldest pending sample: its S line with the counts (or none: dropped).
void complete_sample(bool answered, int16_t cart, int16_t pend) {
  Pending &p = pending[pending_head];
  pending_head = (pending_head + 1) % kPendingMax;
  --pending_count;
  if (answered) {
    uint32_t start = clocks();
    bridge_send_sample(&core, &board, &p.at, p.t_us, cart, pend);
    uint32_t work = clocks_since(start);
    if (work > stats.sample_max) stats.sample_max = work;
  } else {
    ++stats.plant_timeouts;   // the plant never answered: the sample is lost (seq skipped)
  }
}

// "G,<limits>": the plant is served; the limit switches before the first sample.
void take_go(const char *s) {
  unsigned long limits = 0;
  sscanf(s, "G,%lu", &limits);
  limit_left = (limits & 1) != 0;
  limit_right = (limits & 2) != 0;
  plant_ready = true;
}

int hex_digit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

// "C,HHLLHHLLm": the bus bytes of both decoders and the limit switches, in hex.
void take_counts(const char *s, size_t n) {
  uint8_t v[5];
  if (n != 11 || s[1] != ',') return;
  for (int i = 0; i < 5; ++i) {
    int hi = i < 4 ? hex_digit(s[2 + 2 * i]) : 0, lo = hex_digit(s[i < 4 ? 3 + 2 * i : 10]);
    if (hi < 0 || lo < 0) return;
    v[i] = (uint8_t)(hi << 4 | lo);
  }
  if (pending_count == 0) return;
  limit_left = (v[4] & 1) != 0;
  limit_right = (v[4] & 2) != 0;
  complete_sample(true, bridge_count(v[0], v[1]), bridge_count(v[2], v[3]));
}

void plant_poll() {
  while (!plant_rx.empty()) {
    char c = (char)plant_rx.get();
    if (c != '\n') {
      if (plant_len < sizeof plant_line - 1) plant_line[plant_len++] = c;
      continue;
    }
    plant_line[plant_len] = 0;
    if (plant_line[0] == 'Q') stats.requested = true;
    else if (plant_line[0] == 'G') take_go(plant_line);
    else if (plant_line[0] == 'C') take_counts(plant_line, plant_len);
    plant_len = 0;
  }
}

void send_statistics() {
  const BridgeCounters &k = core.counters;
  plant_printf("M,%lu,%lu,%lu,%lu,%lu,%lu,%lu,%lu,%lu,%lu,%lu,%lu,%lu,%lu\n",
               (unsigned long)k.samples, (unsigned long)stats.tick_max,
               (unsigned long)stats.sample_max,
               (unsigned long)stats.period_max, (unsigned long)stats.line_max,
               (unsigned long)stack_high_water(), (unsigned long)k.lines_in,
               (unsigned long)k.refused, (unsigned long)k.oversized,
               (unsigned long)k.tx_dropped, (unsigned long)k.overruns,
               (unsigned long)stats.plant_timeouts, (unsigned long)stats.pending_max,
               (unsigned long)kSysClock);
}

void take_paused_bytes() {   // flow control: the bytes the full ring left in the FIFO
  if (!host_rx_paused || host_rx.room() == 0) return;
  irq_off();
  host_rx_paused = false;
  kUart0->imsc = kUart0->imsc | kUartRx | kUartRxTimeout;
  host_rx_take();
  irq_on();
}

// The deadline t_us: watchdog and limits now (the output follows at once), the plant
// asked for the counts at t_us; the S line goes out when they come (take_counts).
void sample(uint32_t t_us) {
  uint32_t start = clocks();
  if (pending_count == kPendingMax) complete_sample(false, 0, 0);   // the plant is 200 ms behind
  Pending &p = pending[(pending_head + pending_count) % kPendingMax];
  ++pending_count;
  if (pending_count > stats.pending_max) stats.pending_max = pending_count;
  p.t_us = t_us;
  at_deadline = true;
  deadline_us = t_us;
  bridge_tick(&core, &board, t_us, limit_left, limit_right, &p.at);
  bridge_apply_output(&core, &board, 0);
  at_deadline = false;
  plant_printf("T,%lu\n", (unsigned long)t_us);
  uint32_t work = clocks_since(start);
  if (work > stats.tick_max) stats.tick_max = work;
  if (core.counters.samples % 200 == 0) stats.requested = true;   // once a second
}

}  // namespace

extern "C" void Timer0A_Handler(void) {
  kTimer0->icr = kTimerTimeout;   // the loop wakes: the deadline it was armed for is due
}

// Clearing first: a byte QEMU puts in the FIFO while the handler empties it raises the
// interrupt again rather than being left behind.
extern "C" void Uart0_Handler(void) {
  uint32_t cause = kUart0->mis;
  kUart0->icr = cause;
  if (cause & (kUartRx | kUartRxTimeout)) host_rx_take();
  if (cause & kUartTx) host_tx_kick();
}

extern "C" void Uart1_Handler(void) {
  uint32_t cause = kUart1->mis;
  kUart1->icr = cause;
  if (cause & (kUartRx | kUartRxTimeout)) {
    while (!(kUart1->fr & kUartRxEmpty)) {
      uint8_t c = (uint8_t)kUart1->dr;
      if (plant_rx.room() > 0) plant_rx.put(c);
    }
  }
  if (cause & kUartTx) plant_tx_kick();
}

int main() {
  kSysTick[1] = 0xFFFFFF;   // RVR
  kSysTick[2] = 0;          // CVR
  kSysTick[0] = 5;          // CSR: processor clock, enabled, no interrupt
  *kRcc = (*kRcc & ~kRccSysdiv) | (7u << 23);   // 25 MHz
  *kRcgc1 = *kRcgc1 | (1u << 16) | (1u << 1) | (1u << 0);   // clocks of Timer 0, UART1, UART0
  uart_init(kUart0);
  uart_init(kUart1);
  kTimer0->ctl = 0;
  kTimer0->cfg = 0;               // 32-bit
  kTimer0->tamr = kTimerOneShot;
  kTimer0->imr = kTimerTimeout;
  kNvicIser[0] = (1u << kIrqUart0) | (1u << kIrqUart1) | (1u << kIrqTimer0A);
  bridge_init(&core, &board, "cartpole_bridge", true);
  // the plant must answer from the first sample on: wait for its G
  for (;;) {
    plant_poll();
    if (plant_ready) break;
    irq_off();
    if (plant_rx.empty()) wait_for_interrupt();
    irq_on();
  }
  clock_last = clocks();    // micros() counts from here
  core.next_sample_us = JP_SAMPLE_US;   // samples at t_us = k x 5000
  sampling = true;
  // QEMU is a process on a shared host: it may not run the CPU for tens of ms (the Due's
  // loop never lags so). Catch up every deadline within 200 ms, as many samples as may wait
  // for the plant, as the Python emulator does; resynchronise beyond.
  core.resync_us = kPendingMax * JP_SAMPLE_US;
  for (;;) {
    irq_off();
    if (host_rx.empty() && plant_rx.empty() && !stats.requested && !sample_due_now()) {
      arm_wakeup();
      wait_for_interrupt();
    }
    irq_on();
    uint32_t start = clocks();
    // every deadline passed (more than one if QEMU was not run for a while), each at its time
    while (bridge_sample_due(&core, micros_now())) {
      if (stats.period_work > stats.period_max) stats.period_max = stats.period_work;
      stats.period_work = 0;
      sample(core.next_sample_us - JP_SAMPLE_US);
    }
    while (!host_rx.empty() && !sample_due_now()) {   // a due sample goes first
      uint32_t t = clocks();
      bridge_receive(&core, &board, (char)host_rx.get());
      uint32_t work = clocks_since(t);
      if (work > stats.line_max) stats.line_max = work;
    }
    take_paused_bytes();
    plant_poll();
    bridge_apply_output(&core, &board, 0);
    stats.period_work += clocks_since(start);
    if (stats.requested) {
      stats.requested = false;
      send_statistics();
    }
  }
}
