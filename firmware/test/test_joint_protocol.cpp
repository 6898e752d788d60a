// Host test of the firmware's protocol code (joint_protocol.cpp), built with g++:
//   make -C firmware test     (or: g++ -std=c++11 -Wall -Wextra -I../cartpole_bridge
//   test_joint_protocol.cpp ../cartpole_bridge/joint_protocol.cpp -o test_joint_protocol)
//   ./test_joint_protocol ../test_vectors/protocol_vectors.txt
// Runs the shared vectors (the Python codec passes the same file) and the
// device state machine's cases (watchdog, enable, reset, limits). Prints one
// line per failure and a summary; exit status 0 only if everything passed.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <fstream>
#include <string>
#include <vector>

#include "joint_protocol.h"

static int g_checks = 0, g_failures = 0;

#define CHECK(cond, ...)                                     \
  do {                                                       \
    ++g_checks;                                              \
    if (!(cond)) {                                           \
      ++g_failures;                                          \
      printf("FAIL %s:%d: %s: ", __FILE__, __LINE__, #cond); \
      printf(__VA_ARGS__);                                   \
      printf("\n");                                          \
    }                                                        \
  } while (0)

static std::string unescape(const std::string &s) {
  std::string out;
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '\\' && i + 1 < s.size()) {
      char n = s[i + 1];
      if (n == 'x' && i + 3 < s.size()) {
        out += (char)strtol(s.substr(i + 2, 2).c_str(), 0, 16);
        i += 3;
      } else {
        out += n == 'r' ? '\r' : n == 'n' ? '\n' : n;
        i += 1;
      }
    } else {
      out += s[i];
    }
  }
  return out;
}

static std::string decode_canonical(const std::string &line) {
  JpMessage m;
  JpStatus st = jp_decode(line.data(), line.size(), &m);
  if (st != JP_OK) return std::string("err:") + jp_status_name(st);
  char buf[256];
  jp_canonical(&m, buf, sizeof buf);
  return buf;
}

// A "report" vector: events "<what>@<us>" separated by spaces on a fresh device
// (a host line body, W = the output written, S = tick + sample); the S bodies sent,
// joined by ';'.
static std::string run_report(const std::string &events) {
  JpDevice d;
  jp_device_init(&d, "report", true);
  std::string got;
  size_t pos = 0;
  while (pos < events.size()) {
    size_t end = events.find(' ', pos);
    if (end == std::string::npos) end = events.size();
    std::string token = events.substr(pos, end - pos);
    pos = end + 1;
    size_t at = token.find('@');
    if (at == std::string::npos) return "bad event " + token;
    std::string what = token.substr(0, at);
    uint32_t now = (uint32_t)strtoul(token.c_str() + at + 1, 0, 10);
    char buf[256];
    if (what == "W") {
      jp_device_output_written(&d, now);
    } else if (what == "S") {
      jp_device_tick(&d, now, false, false, buf, sizeof buf);
      size_t n = jp_device_sample(&d, now, 0, 0, buf, sizeof buf);
      if (n < 4) return "no S line";
      if (!got.empty()) got += ";";
      got += std::string(buf, n - 4);  // without "*HH\n"
    } else {
      char line[128], reply[128];
      snprintf(line, sizeof line, "%s", what.c_str());
      size_t ln = jp_finish(line, what.size(), sizeof line), rn = 0;
      jp_device_handle_line(&d, line, ln, now, reply, sizeof reply, &rn);
      if (rn) return "answered " + std::string(reply, rn);
    }
  }
  return got;
}

static void run_vectors(const char *path) {
  std::ifstream in(path);
  CHECK(in.good(), "cannot open %s", path);
  std::string raw;
  int counts[7] = {0, 0, 0, 0, 0, 0, 0};
  while (std::getline(in, raw)) {
    if (raw.empty() || raw[0] == '#') continue;
    size_t a = raw.find('|'), b = raw.find('|', a + 1);
    CHECK(a != std::string::npos && b != std::string::npos, "bad vector line %s", raw.c_str());
    if (a == std::string::npos || b == std::string::npos) continue;
    std::string kind = raw.substr(0, a), x = raw.substr(a + 1, b - a - 1), want = raw.substr(b + 1);
    if (kind == "decode") {
      std::string line = unescape(x);
      std::string got = decode_canonical(line);
      CHECK(got == want, "decode %s: got %s want %s", x.c_str(), got.c_str(), want.c_str());
      std::string got_lf = decode_canonical(line + "\n");
      CHECK(got_lf == want, "decode %s\\n: got %s", x.c_str(), got_lf.c_str());
      // the firmware's line assembler yields the same line
      JpLineBuffer lb;
      jp_line_init(&lb);
      std::string fed = line + "\n";
      size_t n = 0;
      int r = 0, last = 0;
      for (char c : fed) {
        r = jp_line_feed(&lb, c, &n);
        if (r) last = r;
      }
      if (want == "err:oversized") {
        CHECK(last == -1, "line buffer did not flag oversized %s", x.c_str());
      } else if (!line.empty() && line != "\r") {
        CHECK(last == 1, "line buffer lost %s", x.c_str());
      }
      ++counts[0];
    } else if (kind == "encode") {
      char buf[128];
      snprintf(buf, sizeof buf, "%s", x.c_str());
      size_t n = jp_finish(buf, x.size(), sizeof buf);
      std::string got(buf, n);
      CHECK(got == want + "\n", "encode %s: got %s want %s", x.c_str(), got.c_str(), want.c_str());
      ++counts[1];
    } else if (kind == "setpoint") {
      int32_t got = jp_force_to_setpoint(atof(x.c_str()));
      CHECK(got == atoi(want.c_str()), "setpoint(%s) = %d, want %s", x.c_str(), got, want.c_str());
      ++counts[2];
    } else if (kind == "dac") {
      int got = jp_dac_value(jp_clamp_setpoint(atoll(x.c_str())));
      CHECK(got == atoi(want.c_str()), "dac(%s) = %d, want %s", x.c_str(), got, want.c_str());
      ++counts[3];
    } else if (kind == "checksum") {
      char hh[3];
      snprintf(hh, sizeof hh, "%02X", jp_checksum(x.data(), x.size()));
      CHECK(want == hh, "checksum(%s) = %s, want %s", x.c_str(), hh, want.c_str());
      ++counts[4];
    } else if (kind == "watchdog") {
      // enabled, U at T, one tick at T + elapsed; T near the micros() wrap as well
      const uint32_t starts[2] = {1000u, 0xFFFFFF00u};
      for (uint32_t t0 : starts) {
        JpDevice d;
        jp_device_init(&d, "wd", true);
        char line[32], reply[64], out[128];
        size_t rn = 0;
        snprintf(line, sizeof line, "E,1");
        size_t ln = jp_finish(line, 3, sizeof line);
        jp_device_handle_line(&d, line, ln, t0, reply, sizeof reply, &rn);
        snprintf(line, sizeof line, "U,100");
        ln = jp_finish(line, 5, sizeof line);
        jp_device_handle_line(&d, line, ln, t0, reply, sizeof reply, &rn);
        uint32_t at = t0 + (uint32_t)strtoul(x.c_str(), 0, 10);
        jp_device_tick(&d, at, false, false, out, sizeof out);
        bool zero = jp_device_output_setpoint(&d) == 0;
        CHECK(d.watchdog_tripped == (want == "1") && zero == (want == "1"),
              "watchdog %s us after U (from %lu): tripped %d, want %s", x.c_str(),
              (unsigned long)t0, (int)d.watchdog_tripped, want.c_str());
      }
      ++counts[5];
    } else if (kind == "report") {
      std::string got = run_report(x);
      CHECK(got == want, "report %s: got %s want %s", x.c_str(), got.c_str(), want.c_str());
      ++counts[6];
    } else {
      CHECK(false, "unknown vector kind %s", kind.c_str());
    }
  }
  CHECK(counts[0] > 50 && counts[1] > 5 && counts[2] > 5 && counts[3] > 3 && counts[4] > 0 &&
        counts[5] > 5 && counts[6] > 5, "too few vectors read: %d %d %d %d %d %d %d",
        counts[0], counts[1], counts[2], counts[3], counts[4], counts[5], counts[6]);
  printf("vectors: %d decode, %d encode, %d setpoint, %d dac, %d checksum, %d watchdog, "
         "%d report\n", counts[0], counts[1], counts[2], counts[3], counts[4], counts[5],
         counts[6]);
}

static std::string line_of(const char *body) {
  char buf[128];
  snprintf(buf, sizeof buf, "%s", body);
  size_t n = jp_finish(buf, strlen(body), sizeof buf);
  return std::string(buf, n);
}

static std::string handle(JpDevice *d, const char *body, uint32_t now, bool *reset = 0) {
  std::string line = line_of(body);
  char reply[128];
  size_t n = 0;
  bool r = jp_device_handle_line(d, line.data(), line.size(), now, reply, sizeof reply, &n);
  if (reset) *reset = r;
  return std::string(reply, n);
}

static void test_device() {
  JpDevice d;
  jp_device_init(&d, "cartpole_bridge", true);
  char out[256];
  // ping
  CHECK(handle(&d, "P", 0) == line_of("V,2,cartpole_bridge"), "ping answer");
  // disabled: zero output whatever the setpoint
  handle(&d, "U,500", 0);
  CHECK(jp_device_output_setpoint(&d) == 0, "disabled must output 0");
  CHECK(jp_dac_value(jp_device_output_setpoint(&d)) == 1953, "DAC at zero current");
  // enable: zero setpoint until the next U
  handle(&d, "E,1", 1000);
  CHECK(d.enabled && jp_device_output_setpoint(&d) == 0, "E,1 starts from zero");
  handle(&d, "U,500", 2000);
  CHECK(jp_device_output_setpoint(&d) == 500, "U passes while enabled");
  handle(&d, "U,9999", 3000);
  CHECK(d.setpoint == 2142, "U clamped to the DAC range, got %d", d.setpoint);
  // watchdog, once a 5 ms tick: quiet at 45 ms (the next tick is inside the deadline),
  // trips at the tick after, which is at most 50 ms after the U (docs/rig.md)
  CHECK(jp_device_tick(&d, 3000 + 45000, false, false, out, sizeof out) == 0, "no trip at 45 ms");
  size_t n = jp_device_tick(&d, 3000 + 50000, false, false, out, sizeof out);
  CHECK(std::string(out, n) == line_of("!,16,watchdog"), "trip at 50 ms: %.*s", (int)n, out);
  CHECK(d.watchdog_tripped && jp_device_output_setpoint(&d) == 0, "trip zeroes the current");
  CHECK(jp_device_flags(&d) == (JP_FLAG_ENABLED | JP_FLAG_WATCHDOG), "flags bit0|bit1");
  CHECK(jp_device_tick(&d, 3000 + 90000, false, false, out, sizeof out) == 0, "one notice a trip");
  handle(&d, "U,-200", 100000);
  CHECK(!d.watchdog_tripped && jp_device_output_setpoint(&d) == -200, "next U clears the trip");
  // watchdog across the micros() wrap
  handle(&d, "U,10", 0xFFFFFF00u);
  CHECK(jp_device_tick(&d, 0xFFFFFF00u + 40000u, false, false, out, sizeof out) == 0,
        "no trip 40 ms after, across the wrap");
  CHECK(jp_device_tick(&d, 0xFFFFFF00u + 46000u, false, false, out, sizeof out) > 0,
        "trip 46 ms after (the next tick would be late), across the wrap");
  // R refused while enabled
  bool reset = true;
  std::string r = handle(&d, "R", 0, &reset);
  CHECK(!reset && r == line_of("!,9,reset refused while enabled"), "R refused: %s", r.c_str());
  // limit switches: directional inhibit, one notice on closing
  handle(&d, "U,-300", 200000);
  n = jp_device_tick(&d, 200000, true, false, out, sizeof out);
  CHECK(std::string(out, n) == line_of("!,17,limit left"), "limit notice");
  CHECK(jp_device_output_setpoint(&d) == 0, "no force into the left stop");
  handle(&d, "U,300", 201000);
  CHECK(jp_device_output_setpoint(&d) == 300, "force away from the left stop passes");
  CHECK(jp_device_flags(&d) == (JP_FLAG_ENABLED | JP_FLAG_LIMIT_LEFT), "flags bit0|bit2");
  // disable forces zero; R allowed then
  handle(&d, "E,0", 202000);
  CHECK(jp_device_output_setpoint(&d) == 0 && !d.enabled, "E,0 zeroes");
  r = handle(&d, "R", 203000, &reset);
  CHECK(reset && r.empty(), "R while disabled resets the counters");
  // malformed commands answered with their code
  std::string bad = "U,5*00";
  char reply[128];
  size_t rn = 0;
  jp_device_handle_line(&d, bad.data(), bad.size(), 0, reply, sizeof reply, &rn);
  CHECK(std::string(reply, rn) == line_of("!,1,bad_checksum"), "bad checksum answered");
  CHECK(handle(&d, "S,1,2,3,4,5", 0) == line_of("!,4,unknown_type"), "device types refused");
  CHECK(handle(&d, "U,1.5", 0) == line_of("!,6,bad_number"), "bad number answered");
  // streaming: seq counts every period, S only while streaming
  d.seq = 0;
  CHECK(jp_device_sample(&d, 0, 1, 2, out, sizeof out) == 0, "no S while not streaming");
  handle(&d, "L,1", 0);
  n = jp_device_sample(&d, 5000, -3, 12, out, sizeof out);
  CHECK(std::string(out, n) == line_of("S,1,5000,-3,12,4"), "S line: %.*s", (int)n, out);
}

int main(int argc, char **argv) {
  const char *path = argc > 1 ? argv[1] : "../test_vectors/protocol_vectors.txt";
  run_vectors(path);
  test_device();
  printf("%d checks, %d failures\n", g_checks, g_failures);
  return g_failures ? 1 : 0;
}
