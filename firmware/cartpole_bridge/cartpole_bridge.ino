// cartpole_bridge: Arduino Due I/O bridge of the cart-pole rig (the Joint protocol:
// docs/rig.md, "The Joint protocol").
//
// The control runs on the host. The firmware's logic is board-independent
// (bridge_core.cpp and joint_protocol.cpp, also built for QEMU's Cortex-M3 in
// firmware/qemu_lm3s6965/); this sketch is the Due's board layer. Together they
//   - reads both HCTL-2021 quadrature decoders over the shared 8-bit bus
//     (thesis section 2.1) every 5 ms (micros() deadlines, no drift),
//   - streams S lines, answers P, obeys E, R, L, U (joint_protocol.cpp),
//   - writes the current setpoint to DAC0 as 1953 + setpoint (12 bit, Appendix A)
//     and, for a tagged U (protocol 2), reports in the S lines when it did (micros()
//     right after the DAC write): the host measures the loop's latency in device time,
//   - drives the servo amplifier's enable pin,
//   - enforces the 50 ms watchdog: enabled and no U for 50 ms -> zero current
//     (checked every sample tick, tripping at the tick that crosses the deadline).
//
// PIN NUMBERS: the thesis's figure 2.3 names the signals (DAC, OE, 8-pin bus,
// SEL, enable, RST) but its text gives no pin numbers. Every number below is
// an ASSUMPTION listed in the wiring table of the README ("Running on the real
// rig"); they MUST be checked against the PCB before the first power-up.
#include "bridge_core.h"

// ---- wiring (ASSUMED; must match the PCB) -----------------------------------------
static const uint8_t PIN_BUS[8] = {33, 34, 35, 36, 37, 38, 39, 40};  // D0..D7 of both HCTL-2021
static const uint8_t PIN_CART_OE = 41;    // output enable, active low
static const uint8_t PIN_CART_SEL = 42;   // high: low byte, low: high byte (thesis 2.1)
static const uint8_t PIN_CART_RST = 43;   // counter reset, active low
static const uint8_t PIN_PEND_OE = 44;
static const uint8_t PIN_PEND_SEL = 45;
static const uint8_t PIN_PEND_RST = 46;
static const uint8_t PIN_AMP_ENABLE = 47; // servo amplifier enable, active high (assumed)
static const uint8_t PIN_LIMIT_LEFT = 48; // limit switches to GND, INPUT_PULLUP (optional)
static const uint8_t PIN_LIMIT_RIGHT = 49;
#define HAVE_LIMIT_SWITCHES 0             // the thesis rig has none: flags bits 2/3 stay 0
// A positive setpoint must push the cart to the right (x grows); check at the
// first power-up (README checklist) and flip this if the motor is wired the other way.
static const bool POSITIVE_SETPOINT_DRIVES_RIGHT = true;

// The native USB port does not reset the board when the host opens it, so the
// counters survive a reconnect. Use Serial (programming port) if that is the
// cable in use: opening it resets the Due (and the sketch zeroes the counters).
#define HOST SerialUSB
static const uint32_t BAUD = 115200;      // ignored by the native port, used by Serial
static const uint32_t SAMPLE_US = JP_SAMPLE_US;   // Ts = 5 ms (thesis section 9.2)

static BridgeCore core;
static JpDevice &dev = core.dev;          // the protocol state (tests read it)

// Read one HCTL-2021: OE low, low byte (SEL high), high byte (SEL low), OE high,
// combine to a signed 16-bit count (thesis section 2.1).
static uint8_t read_bus() {
  uint8_t v = 0;
  for (uint8_t i = 0; i < 8; ++i) v |= (digitalRead(PIN_BUS[i]) ? 1 : 0) << i;
  return v;
}

static int16_t read_decoder(uint8_t pin_oe, uint8_t pin_sel) {
  digitalWrite(pin_oe, LOW);
  digitalWrite(pin_sel, HIGH);
  delayMicroseconds(1);                   // data access time (datasheet: < 100 ns)
  uint8_t lo = read_bus();
  digitalWrite(pin_sel, LOW);
  delayMicroseconds(1);
  uint8_t hi = read_bus();
  digitalWrite(pin_oe, HIGH);
  return bridge_count(hi, lo);
}

// ---- the board hooks of the core (bridge_core.h) -------------------------------------
static uint32_t board_micros(void *) { return micros(); }
static size_t board_tx_room(void *) { return (size_t)HOST.availableForWrite(); }
static void board_tx(void *, const char *buf, size_t n) { HOST.write((const uint8_t *)buf, n); }

static void board_write_output(void *, int dac, bool enable, char) {
  analogWrite(DAC0, dac);
  digitalWrite(PIN_AMP_ENABLE, enable ? HIGH : LOW);
}

static void board_reset_counters(void *) {
  digitalWrite(PIN_CART_RST, LOW);
  digitalWrite(PIN_PEND_RST, LOW);
  delayMicroseconds(2);
  digitalWrite(PIN_CART_RST, HIGH);
  digitalWrite(PIN_PEND_RST, HIGH);
}

static const BridgeBoard board = {0, board_micros, board_tx_room, board_tx,
                                  board_write_output, board_reset_counters};

void setup() {
  for (uint8_t i = 0; i < 8; ++i) pinMode(PIN_BUS[i], INPUT);
  const uint8_t outs[] = {PIN_CART_OE, PIN_CART_SEL, PIN_CART_RST, PIN_PEND_OE,
                          PIN_PEND_SEL, PIN_PEND_RST, PIN_AMP_ENABLE};
  for (uint8_t i = 0; i < sizeof outs; ++i) pinMode(outs[i], OUTPUT);
  digitalWrite(PIN_AMP_ENABLE, LOW);
  digitalWrite(PIN_CART_OE, HIGH);
  digitalWrite(PIN_PEND_OE, HIGH);
  digitalWrite(PIN_CART_RST, HIGH);
  digitalWrite(PIN_PEND_RST, HIGH);
#if HAVE_LIMIT_SWITCHES
  pinMode(PIN_LIMIT_LEFT, INPUT_PULLUP);
  pinMode(PIN_LIMIT_RIGHT, INPUT_PULLUP);
#endif
  analogWriteResolution(12);
  // disabled, DAC at 1953 (zero current); the counters reset (the host homes with R)
  bridge_init(&core, &board, "cartpole_bridge", POSITIVE_SETPOINT_DRIVES_RIGHT);
  HOST.begin(BAUD);
  core.next_sample_us = micros() + SAMPLE_US;
}

void loop() {
  // 1. commands, handled as they arrive (the output written at once)
  while (HOST.available() > 0) bridge_receive(&core, &board, (char)HOST.read());
  // 2. the 5 ms sample, on micros() deadlines
  uint32_t now = micros();
  if (bridge_sample_due(&core, now)) {
    int16_t cart = read_decoder(PIN_CART_OE, PIN_CART_SEL);
    int16_t pend = read_decoder(PIN_PEND_OE, PIN_PEND_SEL);
#if HAVE_LIMIT_SWITCHES
    bool left = digitalRead(PIN_LIMIT_LEFT) == LOW, right = digitalRead(PIN_LIMIT_RIGHT) == LOW;
#else
    bool left = false, right = false;
#endif
    bridge_sample(&core, &board, now, cart, pend, left, right);
  }
  // 3. the DAC and the enable pin follow the state (watchdog, limits) every pass
  bridge_apply_output(&core, &board, 0);
}
