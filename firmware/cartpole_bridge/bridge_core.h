// The I/O bridge's board-independent loop: everything the firmware decides,
// with no Arduino or board header, so the same code runs in the Arduino Due
// sketch (cartpole_bridge.ino) and on QEMU's Cortex-M3 (firmware/qemu_lm3s6965/).
//
//   - host bytes -> lines -> the Joint protocol's device state machine
//     (joint_protocol.cpp), replies and refusals sent back;
//   - the sample clock: 5 ms deadlines on the board's micros() (no drift; a
//     loop more than resync_us late, four periods unless the board says
//     otherwise, resynchronises and counts an overrun; a later one catches up);
//   - per sample: watchdog and limit switches, the S line;
//   - the output: the DAC value (setpoint conversion, Appendix A) and the
//     amplifier's enable, handed to the board on every pass;
//   - the encoder counters as the HCTL-2021 bus delivers them (two bytes,
//     assembled to the signed 16-bit count the S line carries; the host
//     unwraps them across the 16-bit wrap);
//   - counters of what happened (lines, refusals, dropped output, overruns).
//
// The board supplies the clock and the pins through BridgeBoard.
#ifndef CARTPOLE_BRIDGE_CORE_H
#define CARTPOLE_BRIDGE_CORE_H

#include <stddef.h>
#include <stdint.h>

#include "joint_protocol.h"

// What the board does for the core. ctx is passed back to every hook.
// Times follow the loop's order: the now_us of a sample (bridge_sample, bridge_tick) is never
// earlier than micros() was for a line handled before it. The watchdog and the latency report
// take now_us minus that stamp on the wrapping clock, so a stamp newer than the sample reads
// as 2^32 us old: the watchdog trips. The Due reads micros() for each; a board that samples at
// its deadline's time (QEMU's) stamps what it does meanwhile accordingly.
struct BridgeBoard {
  void *ctx;
  uint32_t (*micros)(void *ctx);                 // device time [us], wrapping uint32
  size_t (*tx_room)(void *ctx);                  // bytes the host link takes now
  void (*tx)(void *ctx, const char *buf, size_t n);
  // Write the DAC value (0..4095) and the amplifier enable. cause: the type of
  // the host line just handled ('U', 'E', ...; '!' for a refused line) or 0 for
  // the refresh of every pass (which follows the watchdog and the limits).
  void (*write_output)(void *ctx, int dac, bool enable, char cause);
  void (*reset_counters)(void *ctx);             // pulse the decoders' RST
};

struct BridgeCounters {
  uint32_t lines_in;      // complete host lines handled
  uint32_t refused;       // host lines answered with a "!" code 1..9
  uint32_t oversized;     // overlong runs dropped by the line buffer
  uint32_t tx_dropped;    // lines not sent: the host link had no room
  uint32_t samples;       // sample periods run
  uint32_t overruns;      // resynchronisations of a loop more than 4 periods late
};

struct BridgeCore {
  JpDevice dev;
  JpLineBuffer rx;
  uint32_t next_sample_us;
  uint32_t resync_us;     // a loop later than this resynchronises (4 periods; a board may raise it)
  BridgeCounters counters;
  char out[3 * (JP_MAX_LINE + 2)];
};

void bridge_init(BridgeCore *c, const BridgeBoard *b, const char *name,
                 bool positive_setpoint_drives_right);
// One byte from the host: a completed line is handled at micros(), the output
// written and the tagged command's effect stamped (micros() after the write).
void bridge_receive(BridgeCore *c, const BridgeBoard *b, char byte);
// Is the sample of time now_us due? Advances the deadline (Ts = 5 ms) if so.
bool bridge_sample_due(BridgeCore *c, uint32_t now_us);
// The sample at now_us: watchdog and limits (their "!" notices), then the S line.
void bridge_sample(BridgeCore *c, const BridgeBoard *b, uint32_t now_us, int16_t cart,
                   int16_t pend, bool limit_left, bool limit_right);
// The same in two halves, for a board whose encoders answer later than the
// deadline (QEMU's plant channel): bridge_tick at the deadline (watchdog,
// limits; the device's state then, with its sequence number, kept in *at),
// bridge_send_sample with the counts once they are in (the S line of *at).
void bridge_tick(BridgeCore *c, const BridgeBoard *b, uint32_t now_us, bool limit_left,
                 bool limit_right, JpDevice *at);
void bridge_send_sample(BridgeCore *c, const BridgeBoard *b, JpDevice *at, uint32_t now_us,
                        int16_t cart, int16_t pend);
// The output follows the state (watchdog, limits): call on every pass.
void bridge_apply_output(BridgeCore *c, const BridgeBoard *b, char cause);

// An HCTL-2021 count from its two bus bytes (high byte with SEL low, low with SEL high).
int16_t bridge_count(uint8_t high, uint8_t low);

#endif  // CARTPOLE_BRIDGE_CORE_H
