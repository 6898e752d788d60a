// Joint serial protocol: see joint_protocol.h. Mirrors
// src/cartpole_hw/cartpole_hw/protocol.py and device.py rule for rule.
#include "joint_protocol.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static const char *const kNames[] = {"ok", "bad_checksum", "missing_checksum", "oversized",
                                     "unknown_type", "bad_field_count", "bad_number",
                                     "out_of_range", "non_ascii"};

const char *jp_status_name(int status) {
  return (status >= 0 && status <= 8) ? kNames[status] : "unknown";
}

uint8_t jp_checksum(const char *body, size_t n) {
  uint8_t x = 0;
  for (size_t i = 0; i < n; ++i) x ^= (uint8_t)body[i];
  return x;
}

static int hex_value(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

// -?[0-9]{1,10} in [lo, hi]
static JpStatus parse_number(const char *s, size_t n, int64_t lo, int64_t hi, int64_t *out) {
  size_t i = 0;
  bool neg = false;
  if (n > 0 && s[0] == '-') { neg = true; i = 1; }
  size_t digits = n - i;
  if (digits < 1 || digits > 10) return JP_BAD_NUMBER;
  int64_t v = 0;
  for (; i < n; ++i) {
    if (s[i] < '0' || s[i] > '9') return JP_BAD_NUMBER;
    v = v * 10 + (s[i] - '0');
  }
  if (neg) v = -v;
  if (v < lo || v > hi) return JP_OUT_OF_RANGE;
  *out = v;
  return JP_OK;
}

struct ArgSpec {
  char type;
  int nargs;
  int nargs_long;  // the longer form of version 2 (U with its tag, S with the report); 0: none
  int64_t lo[7];
  int64_t hi[7];
  int text_index;  // index of the text field (-1: none)
};

static const int64_t U32MAX = 4294967295LL;
static const ArgSpec kSpecs[] = {
    {'P', 0, 0, {0}, {0}, -1},
    {'R', 0, 0, {0}, {0}, -1},
    {'E', 1, 0, {0}, {1}, -1},
    {'L', 1, 0, {0}, {1}, -1},
    {'U', 1, 2, {-32768, 0}, {32767, U32MAX}, -1},
    {'V', 2, 0, {0, 0}, {65535, 0}, 1},
    {'S', 5, 7, {0, 0, -32768, -32768, 0, 0, 0},
     {U32MAX, U32MAX, 32767, 32767, 15, U32MAX, U32MAX}, -1},
    {'!', 2, 0, {0, 0}, {255, 0}, 1},
};

JpStatus jp_decode(const char *line, size_t len, JpMessage *out) {
  memset(out, 0, sizeof(*out));
  if (len > 0 && line[len - 1] == '\n') --len;
  if (len > 0 && line[len - 1] == '\r') --len;
  if (len > JP_MAX_LINE) return JP_OVERSIZED;
  for (size_t i = 0; i < len; ++i) {
    unsigned char c = (unsigned char)line[i];
    if (c < 0x20 || c > 0x7E) return JP_NON_ASCII;
  }
  size_t star = len;
  for (size_t i = len; i > 0; --i) {
    if (line[i - 1] == '*') { star = i - 1; break; }
  }
  if (star == len) return JP_MISSING_CHECKSUM;
  if (len - star - 1 != 2) return JP_BAD_CHECKSUM;
  int h = hex_value(line[star + 1]), l = hex_value(line[star + 2]);
  if (h < 0 || l < 0) return JP_BAD_CHECKSUM;
  if ((uint8_t)(h * 16 + l) != jp_checksum(line, star)) return JP_BAD_CHECKSUM;
  const size_t n = star;  // body length
  if (n == 0 || (n > 1 && line[1] != ',')) return JP_UNKNOWN_TYPE;
  const ArgSpec *spec = 0;
  for (size_t k = 0; k < sizeof(kSpecs) / sizeof(kSpecs[0]); ++k)
    if (kSpecs[k].type == line[0]) spec = &kSpecs[k];
  if (!spec) return JP_UNKNOWN_TYPE;
  // split the fields after the type; for '!' the text is the rest (commas allowed)
  size_t start[8], stop[8];
  int nfields = 0;
  size_t pos = 1;
  while (pos < n && nfields < 8) {  // line[pos] == ','
    size_t s = pos + 1, e = s;
    bool rest = (line[0] == '!' && nfields == 1);
    while (e < n && (rest || line[e] != ',')) ++e;
    start[nfields] = s;
    stop[nfields] = e;
    ++nfields;
    pos = e;
  }
  if (pos < n) return JP_BAD_FIELD_COUNT;  // more than 8 fields
  if (nfields != spec->nargs && (spec->nargs_long == 0 || nfields != spec->nargs_long))
    return JP_BAD_FIELD_COUNT;
  out->type = spec->type;
  for (int f = 0; f < nfields; ++f) {
    const char *s = line + start[f];
    size_t fl = stop[f] - start[f];
    if (f == spec->text_index) {
      if (spec->type == 'V' && fl == 0) return JP_BAD_FIELD_COUNT;
      memcpy(out->text, s, fl);
      out->text[fl] = 0;
      continue;
    }
    JpStatus st = parse_number(s, fl, spec->lo[f], spec->hi[f], &out->num[out->nnum]);
    if (st != JP_OK) return st;
    ++out->nnum;
  }
  return JP_OK;
}

size_t jp_canonical(const JpMessage *m, char *buf, size_t cap) {
  int w = 0;
  switch (m->type) {
    case 'P': case 'R': w = snprintf(buf, cap, "%c", m->type); break;
    case 'E': case 'L':
      w = snprintf(buf, cap, "%c,%lld", m->type, (long long)m->num[0]); break;
    case 'U':
      if (m->nnum == 2)
        w = snprintf(buf, cap, "U,%lld,%lld", (long long)m->num[0], (long long)m->num[1]);
      else
        w = snprintf(buf, cap, "U,%lld", (long long)m->num[0]);
      break;
    case 'V': w = snprintf(buf, cap, "V,%lld,%s", (long long)m->num[0], m->text); break;
    case '!': w = snprintf(buf, cap, "!,%lld,%s", (long long)m->num[0], m->text); break;
    case 'S':
      w = snprintf(buf, cap, "S,%lld,%lld,%lld,%lld,%lld", (long long)m->num[0],
                   (long long)m->num[1], (long long)m->num[2], (long long)m->num[3],
                   (long long)m->num[4]);
      if (m->nnum == 7 && w >= 0 && (size_t)w < cap) {
        int w2 = snprintf(buf + w, cap - w, ",%lld,%lld", (long long)m->num[5],
                          (long long)m->num[6]);
        w = w2 < 0 ? w2 : w + w2;
      }
      break;
    default: w = snprintf(buf, cap, "?");
  }
  return (w < 0 || (size_t)w >= cap) ? 0 : (size_t)w;
}

size_t jp_finish(char *buf, size_t n, size_t cap) {
  static const char hex[] = "0123456789ABCDEF";
  if (n + 4 > cap || n + 3 > JP_MAX_LINE) return 0;
  uint8_t x = jp_checksum(buf, n);
  buf[n] = '*';
  buf[n + 1] = hex[x >> 4];
  buf[n + 2] = hex[x & 15];
  buf[n + 3] = '\n';
  if (n + 4 < cap) buf[n + 4] = 0;
  return n + 4;
}

size_t jp_format_sample(char *buf, size_t cap, uint32_t seq, uint32_t t_us, int16_t cart,
                        int16_t pend, uint8_t flags, bool report, uint32_t back,
                        uint32_t age_us) {
  int w = report
      ? snprintf(buf, cap, "S,%lu,%lu,%d,%d,%u,%lu,%lu", (unsigned long)seq,
                 (unsigned long)t_us, (int)cart, (int)pend, (unsigned)(flags & 15),
                 (unsigned long)back, (unsigned long)age_us)
      : snprintf(buf, cap, "S,%lu,%lu,%d,%d,%u", (unsigned long)seq, (unsigned long)t_us,
                 (int)cart, (int)pend, (unsigned)(flags & 15));
  if (w < 0 || (size_t)w >= cap) return 0;
  return jp_finish(buf, (size_t)w, cap);
}

size_t jp_format_version(char *buf, size_t cap, const char *name) {
  int w = snprintf(buf, cap, "V,%d,%s", JP_PROTOCOL_VERSION, name);
  if (w < 0 || (size_t)w >= cap) return 0;
  return jp_finish(buf, (size_t)w, cap);
}

size_t jp_format_error(char *buf, size_t cap, int code, const char *text) {
  int w = snprintf(buf, cap, "!,%d,%s", code, text);
  if (w < 0 || (size_t)w >= cap) return 0;
  return jp_finish(buf, (size_t)w, cap);
}

void jp_line_init(JpLineBuffer *b) {
  b->len = 0;
  b->discarding = false;
}

int jp_line_feed(JpLineBuffer *b, char c, size_t *n) {
  if (c == '\n') {
    bool dropped = b->discarding;
    size_t len = b->len;
    b->len = 0;
    b->discarding = false;
    if (dropped) return 0;
    if (len > 0 && b->buf[len - 1] == '\r') --len;
    if (len == 0) return 0;
    if (len > JP_MAX_LINE) return -1;
    b->buf[len] = 0;
    *n = len;
    return 1;
  }
  if (b->discarding) return 0;
  if (b->len >= JP_MAX_LINE + 1) {  // +1: room for a trailing '\r'
    b->discarding = true;
    b->len = 0;
    return -1;
  }
  b->buf[b->len++] = c;
  return 0;
}

int32_t jp_clamp_setpoint(int64_t s) {
  if (s < -JP_DAC_ZERO) return -JP_DAC_ZERO;
  if (s > JP_DAC_MAX - JP_DAC_ZERO) return JP_DAC_MAX - JP_DAC_ZERO;
  return (int32_t)s;
}

int jp_dac_value(int32_t setpoint) {
  int32_t v = JP_DAC_ZERO + setpoint;
  if (v < 0) return 0;
  if (v > JP_DAC_MAX) return JP_DAC_MAX;
  return (int)v;
}

int32_t jp_force_to_setpoint(double force) {
  if (!isfinite(force)) return 0;
  double s = floor(force * 56.744 + 0.5);
  if (s < -1e9) s = -1e9;
  if (s > 1e9) s = 1e9;
  return jp_clamp_setpoint((int64_t)s);
}

// ---- device ----------------------------------------------------------------------
void jp_device_init(JpDevice *d, const char *name, bool positive_setpoint_drives_right) {
  memset(d, 0, sizeof(*d));
  d->name = name;
  d->positive_setpoint_drives_right = positive_setpoint_drives_right;
}

// No tagged command is in force any more: S lines without the report.
static void end_report(JpDevice *d) {
  d->pending = false;
  d->applied = false;
}

void jp_device_output_written(JpDevice *d, uint32_t now_us) {
  if (!d->pending) return;
  d->pending = false;
  d->applied = true;
  d->applied_tag = d->pending_tag;
  d->applied_us = now_us;
}

bool jp_device_handle_line(JpDevice *d, const char *line, size_t len, uint32_t now_us,
                           char *reply, size_t cap, size_t *reply_len) {
  *reply_len = 0;
  JpMessage m;
  JpStatus st = jp_decode(line, len, &m);
  if (st == JP_OK && (m.type == 'V' || m.type == 'S' || m.type == '!')) st = JP_UNKNOWN_TYPE;
  if (st != JP_OK) {
    *reply_len = jp_format_error(reply, cap, st, jp_status_name(st));
    return false;
  }
  switch (m.type) {
    case 'P':
      *reply_len = jp_format_version(reply, cap, d->name);
      return false;
    case 'E':
      d->enabled = m.num[0] != 0;
      d->setpoint = 0;
      d->watchdog_tripped = false;
      d->last_u_us = now_us;
      end_report(d);
      return false;
    case 'L':
      d->streaming = m.num[0] != 0;
      return false;
    case 'R':
      if (d->enabled) {
        *reply_len = jp_format_error(reply, cap, JP_ERR_REFUSED, "reset refused while enabled");
        return false;
      }
      return true;
    case 'U':
      d->setpoint = jp_clamp_setpoint(m.num[0]);
      d->last_u_us = now_us;
      d->watchdog_tripped = false;
      if (m.nnum == 2 && d->enabled) {
        d->pending = true;
        d->pending_tag = (uint32_t)m.num[1];
      } else {
        end_report(d);
      }
      return false;
  }
  return false;
}

size_t jp_device_tick(JpDevice *d, uint32_t now_us, bool limit_left, bool limit_right,
                      char *out, size_t cap) {
  size_t n = 0;
  // unsigned subtraction: correct across the micros() wrap; trip at the tick that
  // would otherwise be the last one before the deadline (elapsed + Ts > 50 ms)
  if (d->enabled && !d->watchdog_tripped &&
      (uint32_t)(now_us - d->last_u_us) > JP_WATCHDOG_US - JP_SAMPLE_US) {
    d->watchdog_tripped = true;
    end_report(d);
    n += jp_format_error(out + n, cap - n, JP_ERR_WATCHDOG, "watchdog");
  }
  if (d->enabled && limit_left && !d->limit_left)
    n += jp_format_error(out + n, cap - n, JP_ERR_LIMIT, "limit left");
  if (d->enabled && limit_right && !d->limit_right)
    n += jp_format_error(out + n, cap - n, JP_ERR_LIMIT, "limit right");
  d->limit_left = limit_left;
  d->limit_right = limit_right;
  return n;
}

int32_t jp_device_output_setpoint(const JpDevice *d) {
  if (!d->enabled || d->watchdog_tripped) return 0;
  int32_t s = d->setpoint;
  bool rightwards = d->positive_setpoint_drives_right ? s > 0 : s < 0;
  bool leftwards = d->positive_setpoint_drives_right ? s < 0 : s > 0;
  if ((rightwards && d->limit_right) || (leftwards && d->limit_left)) return 0;
  return s;
}

uint8_t jp_device_flags(const JpDevice *d) {
  return (d->enabled ? JP_FLAG_ENABLED : 0) | (d->watchdog_tripped ? JP_FLAG_WATCHDOG : 0) |
         (d->limit_left ? JP_FLAG_LIMIT_LEFT : 0) | (d->limit_right ? JP_FLAG_LIMIT_RIGHT : 0);
}

size_t jp_device_sample(JpDevice *d, uint32_t now_us, int16_t cart, int16_t pend, char *buf,
                        size_t cap) {
  uint32_t seq = d->seq++;
  if (!d->streaming) return 0;
  // unsigned subtraction: correct across the seq and micros() wraps
  return jp_format_sample(buf, cap, seq, now_us, cart, pend, jp_device_flags(d), d->applied,
                          seq - d->applied_tag, now_us - d->applied_us);
}
