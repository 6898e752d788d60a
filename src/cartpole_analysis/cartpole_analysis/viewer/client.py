"""A small Foxglove WebSocket client (the ``websockets`` package; no ROS).

What the Foxglove app does when it connects, reduced to what a benchmark
or a test needs: open the connection with the subprotocol of the
foxglove-sdk server, read ``serverInfo`` and the ``advertise`` messages,
``subscribe`` to the wanted channels, and collect the binary message-data
frames (opcode 1: uint32 subscription id, uint64 log time [ns], payload;
little endian) in a background thread. ``cartpole bench loop --view``
uses it to load the viewer as a real client would; the tests use it to
check what the viewer serves. ``python -m cartpole_analysis.viewer.client
ws://HOST:PORT`` runs it as its own process (the benchmark's load, out of
the measuring process) and prints what it received per channel on Ctrl-C.
"""
from __future__ import annotations

import argparse
import json
import signal
import struct
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterable

from .server import SUBPROTOCOL

MESSAGE_DATA = 0x01
"""Opcode of a server's binary message-data frame."""
_HEADER = struct.Struct('<BIQ')
ADVERTISE_QUIET = 0.5
"""[s] Subscribing to every channel: the advertisements are complete when no new channel
came for this long."""


@dataclass(frozen=True)
class Message:
    """One received message: its channel's topic, its log time [ns] and its payload."""

    topic: str
    log_time_ns: int
    payload: bytes


class ViewerClient:
    """Connects, subscribes to ``topics`` (None: every advertised channel) and collects.

    Parameters
    ----------
    url
        ``ws://HOST:PORT``.
    topics
        The channels to subscribe to; the constructor waits until all are
        advertised (ValueError after ``timeout`` otherwise).
    timeout
        Wall seconds for the connection (retried while the server starts)
        and the advertisements.
    keep
        Keep the messages (False: only count them, for a load generator).
    """

    def __init__(self, url: str, topics: Iterable[str] | None = None, timeout: float = 10.0,
                 keep: bool = True) -> None:
        from websockets.sync.client import connect

        deadline = time.monotonic() + timeout
        while True:
            try:
                self._ws = connect(url, subprotocols=[SUBPROTOCOL], open_timeout=timeout,
                                   max_size=None, legacy=True)  # closed by close()
                break
            except OSError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.1)
        self.server_info: dict = {}
        self.channels: dict[str, dict] = {}
        """Topic -> the channel as advertised (id, encoding, schemaName, schema, ...)."""
        wanted = None if topics is None else set(topics)
        last_new = time.monotonic()
        """When the last new channel was advertised: with ``topics`` None, ADVERTISE_QUIET
        after it the advertisements are taken as complete (other frames, such as the
        server's time, may keep coming)."""
        while True:
            now = time.monotonic()
            remaining = deadline - now
            if wanted is not None and wanted <= set(self.channels):
                break
            if wanted is None and self.channels and now - last_new >= ADVERTISE_QUIET:
                break
            try:
                frame = self._ws.recv(timeout=max(remaining, 0.0) if wanted is not None
                                      else min(max(remaining, 0.0), ADVERTISE_QUIET))
            except TimeoutError:
                if wanted is None and self.channels:
                    break
                self._ws.close()
                raise ValueError(f'channels not advertised within {timeout:g} s: '
                                 f'{sorted((wanted or set()) - set(self.channels))}') from None
            if isinstance(frame, str):
                known = len(self.channels)
                self._on_text(json.loads(frame))
                if len(self.channels) > known:
                    last_new = time.monotonic()
        chosen = sorted(self.channels) if wanted is None else sorted(wanted)
        self._topic_of = {i + 1: topic for i, topic in enumerate(chosen)}
        self._ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': sub, 'channelId': self.channels[topic]['id']}
            for sub, topic in self._topic_of.items()]}))
        self.keep = keep
        self.messages: list[Message] = []
        self.counts: dict[str, int] = {topic: 0 for topic in chosen}
        self._condition = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._receive, daemon=True)
        self._thread.start()

    def _on_text(self, message: dict) -> None:
        if message.get('op') == 'serverInfo':
            self.server_info = message
        elif message.get('op') == 'advertise':
            for channel in message.get('channels', []):
                self.channels[channel['topic']] = channel

    def _receive(self) -> None:
        from websockets.exceptions import ConnectionClosed
        try:
            for frame in self._ws:
                if isinstance(frame, str):
                    self._on_text(json.loads(frame))
                    continue
                if len(frame) < _HEADER.size or frame[0] != MESSAGE_DATA:
                    continue
                _, sub, log_time = _HEADER.unpack_from(frame)
                topic = self._topic_of.get(sub)
                if topic is None:
                    continue
                with self._condition:
                    self.counts[topic] += 1
                    if self.keep:
                        self.messages.append(Message(topic, log_time, bytes(frame[_HEADER.size:])))
                    self._condition.notify_all()
        except ConnectionClosed:
            pass
        finally:
            with self._condition:
                self._closed = True
                self._condition.notify_all()

    def wait_for(self, predicate: Callable[['ViewerClient'], bool], timeout: float) -> bool:
        """Wait until ``predicate(self)`` holds (checked on every message); False on timeout."""
        with self._condition:
            return self._condition.wait_for(lambda: predicate(self) or self._closed, timeout) \
                and predicate(self)

    def received(self, topic: str) -> list[Message]:
        """The messages of one channel so far."""
        with self._condition:
            return [m for m in self.messages if m.topic == topic]

    def close(self) -> None:
        self._ws.close()
        self._thread.join(timeout=5.0)

    def __enter__(self) -> 'ViewerClient':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def main(argv: list[str] | None = None) -> int:
    """Subscribe to every channel of a viewer until SIGINT/SIGTERM; print the counts as JSON."""
    parser = argparse.ArgumentParser(prog='python -m cartpole_analysis.viewer.client',
                                     description='a Foxglove WebSocket client of the viewer')
    parser.add_argument('url', help='ws://HOST:PORT')
    parser.add_argument('--timeout', type=float, default=30.0,
                        help='wall seconds to connect and see the channels (default 30)')
    args = parser.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        client = ViewerClient(args.url, timeout=args.timeout, keep=False)
    except (OSError, ValueError) as error:
        print(f'viewer_client: {error}', file=sys.stderr)
        return 2
    print('viewer_client: subscribed to ' + ', '.join(sorted(client.counts)), file=sys.stderr,
          flush=True)
    while not stop.wait(0.5):
        pass
    client.close()
    print(json.dumps(client.counts), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
