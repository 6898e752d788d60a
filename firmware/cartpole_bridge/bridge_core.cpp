// The board-independent loop of the I/O bridge: see bridge_core.h.
#include "bridge_core.h"

static void send(BridgeCore *c, const BridgeBoard *b, const char *buf, size_t n) {
  if (n == 0) return;
  // never block the loop on a host that does not read: drop instead
  if (b->tx_room(b->ctx) >= n) {
    b->tx(b->ctx, buf, n);
  } else {
    ++c->counters.tx_dropped;
  }
}

void bridge_apply_output(BridgeCore *c, const BridgeBoard *b, char cause) {
  b->write_output(b->ctx, jp_dac_value(jp_device_output_setpoint(&c->dev)), c->dev.enabled,
                  cause);
}

void bridge_init(BridgeCore *c, const BridgeBoard *b, const char *name,
                 bool positive_setpoint_drives_right) {
  jp_device_init(&c->dev, name, positive_setpoint_drives_right);
  jp_line_init(&c->rx);
  c->counters = BridgeCounters();
  c->resync_us = 4 * JP_SAMPLE_US;
  bridge_apply_output(c, b, 0);       // disabled, DAC at 1953: zero current
  b->reset_counters(b->ctx);          // power-up reference; the host homes with R
  c->next_sample_us = b->micros(b->ctx) + JP_SAMPLE_US;
}

void bridge_receive(BridgeCore *c, const BridgeBoard *b, char byte) {
  size_t n = 0;
  int r = jp_line_feed(&c->rx, byte, &n);
  if (r == 1) {
    size_t reply_len = 0;
    ++c->counters.lines_in;
    bool reset = jp_device_handle_line(&c->dev, c->rx.buf, n, b->micros(b->ctx), c->out,
                                       sizeof c->out, &reply_len);
    if (reset) b->reset_counters(b->ctx);
    bool refused = reply_len > 0 && c->out[0] == '!';
    if (refused) ++c->counters.refused;
    bridge_apply_output(c, b, refused ? '!' : c->rx.buf[0]);
    jp_device_output_written(&c->dev, b->micros(b->ctx));   // a tagged U took effect now
    send(c, b, c->out, reply_len);
  } else if (r == -1) {
    ++c->counters.oversized;
    send(c, b, c->out, jp_format_error(c->out, sizeof c->out, JP_OVERSIZED, "oversized"));
  }
}

bool bridge_sample_due(BridgeCore *c, uint32_t now) {
  if ((int32_t)(now - c->next_sample_us) < 0) return false;
  c->next_sample_us += JP_SAMPLE_US;
  if ((int32_t)(now - c->next_sample_us) > (int32_t)c->resync_us) {
    c->next_sample_us = now + JP_SAMPLE_US;
    ++c->counters.overruns;
  }
  return true;
}

void bridge_tick(BridgeCore *c, const BridgeBoard *b, uint32_t now, bool left, bool right,
                 JpDevice *at) {
  ++c->counters.samples;
  send(c, b, c->out, jp_device_tick(&c->dev, now, left, right, c->out, sizeof c->out));
  *at = c->dev;
  ++c->dev.seq;   // seq counts every period, sent or not (jp_device_sample on *at)
}

void bridge_send_sample(BridgeCore *c, const BridgeBoard *b, JpDevice *at, uint32_t now,
                        int16_t cart, int16_t pend) {
  send(c, b, c->out, jp_device_sample(at, now, cart, pend, c->out, sizeof c->out));
}

void bridge_sample(BridgeCore *c, const BridgeBoard *b, uint32_t now, int16_t cart,
                   int16_t pend, bool left, bool right) {
  JpDevice at;
  bridge_tick(c, b, now, left, right, &at);
  bridge_send_sample(c, b, &at, now, cart, pend);
}

int16_t bridge_count(uint8_t high, uint8_t low) {
  return (int16_t)((uint16_t)high << 8 | low);
}
