// Joint serial protocol (docs/rig.md, "The Joint protocol") for the Arduino Due I/O bridge.
//
// Plain C++ (no Arduino headers): the checksum, the line parser, the line
// formatters and the device's command state machine with its watchdog as a
// pure function of time. The board layers (the sketch cartpole_bridge.ino and
// firmware/qemu_lm3s6965/board.cpp) only move bytes and pins, through the loop in
// bridge_core.cpp; firmware/test/test_joint_protocol.cpp tests this file on the
// host with g++ against the shared vectors (firmware/test_vectors/protocol_vectors.txt),
// which the Python codec (src/cartpole_hw/cartpole_hw/protocol.py) also passes.
//
// Lines: ASCII, '\n' terminated ('\r' before it tolerated), at most
// JP_MAX_LINE bytes without the terminator, ending in "*HH", the XOR of every
// byte before '*' in two hex digits (emitted upper case, either case accepted).
#ifndef CARTPOLE_JOINT_PROTOCOL_H
#define CARTPOLE_JOINT_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#define JP_PROTOCOL_VERSION 2   // 2: tagged U and the latency report in S
#define JP_MAX_LINE 96
#define JP_WATCHDOG_US 50000UL   // no U for 50 ms while enabled -> zero current
#define JP_SAMPLE_US 5000UL      // the sample period Ts; the watchdog runs once a period

#define JP_FLAG_ENABLED     0x01
#define JP_FLAG_WATCHDOG    0x02
#define JP_FLAG_LIMIT_LEFT  0x04
#define JP_FLAG_LIMIT_RIGHT 0x08

// Decode results; the values 1..8 are also the device's "!" codes.
enum JpStatus {
  JP_OK = 0,
  JP_BAD_CHECKSUM = 1,
  JP_MISSING_CHECKSUM = 2,
  JP_OVERSIZED = 3,
  JP_UNKNOWN_TYPE = 4,
  JP_BAD_FIELD_COUNT = 5,
  JP_BAD_NUMBER = 6,
  JP_OUT_OF_RANGE = 7,
  JP_NON_ASCII = 8,
};
// Further "!" codes; >= JP_FAULT_CODE_MIN are faults (the host disarms).
#define JP_ERR_REFUSED 9
#define JP_FAULT_CODE_MIN 16
#define JP_ERR_WATCHDOG 16
#define JP_ERR_LIMIT 17
#define JP_ERR_RX_OVERFLOW 18

const char *jp_status_name(int status);  // "bad_checksum", ... ("ok" for JP_OK)

// A decoded line. type is one of P E R L U V S !; the numeric fields in
// order in num[] (E/L: 0|1, U: setpoint [tag], V: version, S: seq t_us cart
// pend flags [back age_us], !: code); V's name / !'s text in text[].
//
// Protocol version 2: "U,<setpoint>,<tag>" tags a setpoint with the seq of the
// sample it was computed from ("U,<setpoint>" stays valid). Every S line after a
// tagged setpoint took effect carries ",<back>,<age_us>": the command in force
// answers sample seq - back and took effect (written to the DAC) age_us before
// this sample (both mod 2^32). Absent (5 fields) until then and again after an
// untagged U, any E, a watchdog trip or a tagged U while disabled.
struct JpMessage {
  char type;
  int nnum;
  int64_t num[7];
  char text[JP_MAX_LINE + 1];
};

uint8_t jp_checksum(const char *body, size_t n);

// Decode one line (terminator optional). Never reads past len.
JpStatus jp_decode(const char *line, size_t len, JpMessage *out);

// Canonical body of a decoded message ("S,1,5000,-3,12,1"); returns its length.
size_t jp_canonical(const JpMessage *m, char *buf, size_t cap);

// Append "*HH\n" to the body in buf (body length n, capacity cap); returns the
// line length including '\n', or 0 if it does not fit.
size_t jp_finish(char *buf, size_t n, size_t cap);

// report: append ",<back>,<age_us>" (the latency report of version 2).
size_t jp_format_sample(char *buf, size_t cap, uint32_t seq, uint32_t t_us,
                        int16_t cart, int16_t pend, uint8_t flags,
                        bool report = false, uint32_t back = 0, uint32_t age_us = 0);
size_t jp_format_version(char *buf, size_t cap, const char *name);
size_t jp_format_error(char *buf, size_t cap, int code, const char *text);

// Line assembly from single received bytes, bounded: a run longer than
// JP_MAX_LINE + 1 bytes is dropped up to the next '\n' and reported once.
struct JpLineBuffer {
  char buf[JP_MAX_LINE + 2];
  size_t len;
  bool discarding;
};
void jp_line_init(JpLineBuffer *b);
// Returns 1 when a line is complete (in b->buf, length *n, without '\r\n'),
// -1 once per oversized run, 0 otherwise.
int jp_line_feed(JpLineBuffer *b, char c, size_t *n);

// DAC value for a setpoint: dac_zero + setpoint clamped to 0..4095 (Appendix A).
#define JP_DAC_ZERO 1953
#define JP_DAC_MAX 4095
int jp_dac_value(int32_t setpoint);
int32_t jp_clamp_setpoint(int64_t setpoint);   // to [-1953, 2142]
// setpoint = 56.744 x F (A.3), rounded half up, clamped; non-finite -> 0.
int32_t jp_force_to_setpoint(double force);

// ---- the device state machine --------------------------------------------------
struct JpDevice {
  bool enabled;
  bool streaming;
  bool watchdog_tripped;
  bool limit_left;
  bool limit_right;
  bool positive_setpoint_drives_right;   // wiring: check at first power-up
  int32_t setpoint;                      // clamped to the DAC range
  uint32_t last_u_us;
  uint32_t seq;
  const char *name;
  // the latency report (version 2)
  bool pending;           // a tagged U was handled, its output not yet written
  uint32_t pending_tag;
  bool applied;           // a tagged command is in force: S lines carry the report
  uint32_t applied_tag;   // the seq of the sample it answers
  uint32_t applied_us;    // micros() when it was written to the DAC
};
void jp_device_init(JpDevice *d, const char *name, bool positive_setpoint_drives_right);

// Handle one received line at time now_us (micros(), wrapping). A reply line
// (V or !) is written to reply (length *reply_len, 0 if none). Returns true
// when the encoder counters must be reset (R).
bool jp_device_handle_line(JpDevice *d, const char *line, size_t len, uint32_t now_us,
                           char *reply, size_t reply_cap, size_t *reply_len);
// The sketch wrote the output (DAC) at now_us: a pending tagged command took
// effect then (its report starts with the next S line).
void jp_device_output_written(JpDevice *d, uint32_t now_us);
// Once a sample period: watchdog and limit switches. Up to 3 notice lines
// (! watchdog, ! limit) are concatenated into out; returns their total length.
// The watchdog trips at the tick that crosses its deadline: when the next tick
// (JP_SAMPLE_US later) would come more than JP_WATCHDOG_US after the last U, so
// the current is zero within 50 ms of the last U (docs/rig.md), never later.
size_t jp_device_tick(JpDevice *d, uint32_t now_us, bool limit_left, bool limit_right,
                      char *out, size_t cap);
// The setpoint the DAC outputs now: 0 unless enabled, watchdog quiet and not
// pushing towards a closed limit switch (directional inhibit).
int32_t jp_device_output_setpoint(const JpDevice *d);
uint8_t jp_device_flags(const JpDevice *d);
// The S line of this period if streaming (seq counts every period), with the
// latency report while a tagged command is in force; returns its length, 0
// when not streaming.
size_t jp_device_sample(JpDevice *d, uint32_t now_us, int16_t cart, int16_t pend,
                        char *buf, size_t cap);

#endif  // CARTPOLE_JOINT_PROTOCOL_H
