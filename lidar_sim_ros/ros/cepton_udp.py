"""The node as a Cepton sensor on the wire: each simulated frame's STDV packets
(``io/cepton_wire.py``) sent over UDP, paced at the shots' own times.

A sender thread owns the socket and the stream state; the frame timer only hands it the
frame (``submit``, never blocking: a bounded queue, a frame dropped and counted when it
is full). The thread encodes the frame, then sends each packet at its own time (its last
point's, on the node clock) plus a constant lag: spread over the frame period as a
sensor sends them, in wall time or under ``use_sim_time`` (the node clock is then
``/clock``: the packets follow simulated time at the clock's resolution). The lag is the
smallest seen so far from a frame's first packet time to its encoding, set again when a
frame comes more than ``RESYNC_NS`` later than that (a stall, a clock jump): one slow
frame then delays the rest by its lateness once instead of piling up. Packet times are
the points' own (the node clock: system time, or simulated time), in microseconds.

Parameters (read-only, ``PARAMETERS``): ``cepton_udp`` (off by default),
``cepton_udp_address`` (an IPv4 literal, no name lookup; a broadcast address such as
255.255.255.255 works: the socket may broadcast), ``cepton_udp_port`` (8808),
``cepton_udp_queue_frames``.
"""
from __future__ import annotations

import ipaddress
import queue
import socket
import threading
import time
from typing import Callable

from rcl_interfaces.msg import ParameterDescriptor, ParameterType

from lidar_sim_ros.io.cepton_wire import PORT, WireStream

_RO = dict(read_only=True)
PARAMETERS = {
    'cepton_udp': (False, ParameterDescriptor(
        type=ParameterType.PARAMETER_BOOL, **_RO,
        description="also send each frame as a Cepton sensor does: STDV packets over UDP "
                    "(docs/real-data.md)")),
    'cepton_udp_address': ('127.0.0.1', ParameterDescriptor(
        type=ParameterType.PARAMETER_STRING, **_RO,
        description='destination IPv4 address of the packets (unicast or broadcast, e.g. '
                    '255.255.255.255; Cepton\'s driver listens on 0.0.0.0:8808)')),
    'cepton_udp_port': (PORT, ParameterDescriptor(
        type=ParameterType.PARAMETER_INTEGER, **_RO, description='destination UDP port')),
    'cepton_udp_queue_frames': (4, ParameterDescriptor(
        type=ParameterType.PARAMETER_INTEGER, **_RO,
        description='frames waiting to be sent at most; a frame beyond is dropped (counted)')),
}
NS_PER_US = 1000
SIM_CLOCK_POLL_S = 0.001
RESYNC_NS = 200_000_000


class UdpConfigError(ValueError):
    """A cepton_udp_* parameter that cannot be used: names it and its value."""


def check_parameters(address: str, port: int, queue_frames: int) -> None:
    """Raise UdpConfigError naming the parameter and value that cannot be used."""
    try:
        ip = ipaddress.IPv4Address(address)
    except (ipaddress.AddressValueError, ValueError):
        raise UdpConfigError(f'parameter cepton_udp_address: {address!r} is not an IPv4 '
                             'address (a literal such as 127.0.0.1; no name is looked up)') from None
    if ip.is_unspecified:
        raise UdpConfigError(f'parameter cepton_udp_address: {address!r} is where a driver '
                             'listens, not a destination (127.0.0.1: this machine; '
                             '255.255.255.255: broadcast; or the receiver\'s address)')
    if not 1 <= int(port) <= 65535:
        raise UdpConfigError(f'parameter cepton_udp_port: {port} is not a UDP port (1-65535)')
    if not 1 <= int(queue_frames) <= 100:
        raise UdpConfigError(f'parameter cepton_udp_queue_frames: {queue_frames} is not in 1-100')


class CeptonUdpSender:
    """Sends frames' STDV packets from a thread of its own (see the module docstring).

    ``encode(frame, start_ns, state) -> list[Packet]`` turns a frame into packets (the
    node passes ``core.driver_layout.wire_packets`` bound to its simulator); ``now_ns`` is
    the node clock; ``sim_time`` says whether it is ``/clock`` (polled) or system time.
    """

    def __init__(self, address: str, port: int, encode: Callable, now_ns: Callable[[], int],
                 sim_time: bool = False, queue_frames: int = 4):
        check_parameters(address, port, queue_frames)
        self.target = (address, int(port))
        self._encode, self._now_ns, self._sim_time = encode, now_ns, sim_time
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        self._queue: queue.Queue = queue.Queue(maxsize=int(queue_frames))
        self._state = WireStream()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._stats = {'frames': 0, 'packets': 0, 'dropped_frames': 0, 'errors': 0,
                       'last_error': '', 'restarts': 0}
        self._lag_ns: int | None = None       # node clock minus packet time when sent
        self._thread = threading.Thread(target=self._run, name='cepton_udp', daemon=True)
        self._thread.start()

    def submit(self, frame, start_ns: int) -> bool:
        """Hand a frame over without blocking; False (and counted) if the queue is full."""
        try:
            self._queue.put_nowait((frame, int(start_ns)))
            return True
        except queue.Full:
            with self._lock:
                self._stats['dropped_frames'] += 1
            return False

    def take_stats(self) -> dict:
        """Frames and packets sent, frames dropped, send errors since the last call."""
        with self._lock:
            out = dict(self._stats)
            self._stats.update(frames=0, packets=0, dropped_frames=0, errors=0, last_error='',
                               restarts=0)
        return out

    def close(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        self._thread.join(timeout_s)
        self._sock.close()

    # ---------------------------------------------------------------- thread
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame, start_ns = self._queue.get(timeout=0.1)
            except queue.Empty:
                continue
            restarts = self._state.restarts
            try:
                packets = self._encode(frame, start_ns, self._state)
            except Exception as exc:  # noqa: BLE001 - a bad frame must not end the sender
                self._count_error(exc)
                continue
            if self._state.restarts != restarts:   # the clock jumped (io/cepton_wire.py)
                with self._lock:
                    self._stats['restarts'] += self._state.restarts - restarts
            if packets:
                self._send_frame(packets)
            with self._lock:
                self._stats['frames'] += 1

    def _send_frame(self, packets: list) -> None:
        lag = self._now_ns() - packets[0].t_us * NS_PER_US
        if self._lag_ns is None or lag < self._lag_ns or lag > self._lag_ns + RESYNC_NS:
            self._lag_ns = lag
        for pkt in packets:
            due = pkt.t_us * NS_PER_US + self._lag_ns
            if not self._wait_until(due):
                return
            try:
                self._sock.sendto(pkt.payload, self.target)
                with self._lock:
                    self._stats['packets'] += 1
            except OSError as exc:
                self._count_error(exc)

    def _wait_until(self, due_ns: int) -> bool:
        """Sleep until the node clock reaches ``due_ns``; False if stopping."""
        while not self._stop.is_set():
            left_s = (due_ns - self._now_ns()) / 1e9
            if left_s <= 0:
                return True
            time.sleep(min(left_s, SIM_CLOCK_POLL_S) if self._sim_time else min(left_s, 0.05))
        return False

    def _count_error(self, exc: Exception) -> None:
        with self._lock:
            self._stats['errors'] += 1
            self._stats['last_error'] = f'{type(exc).__name__}: {exc}'


def sender_from_node(node) -> CeptonUdpSender | None:
    """The node's sender from its declared ``cepton_udp*`` parameters (None when off)."""
    if not node.get_parameter('cepton_udp').value:
        return None
    from functools import partial

    from lidar_sim_ros.core.driver_layout import wire_packets

    def encode(frame, start_ns, state):
        return wire_packets(frame, node.sim, start_ns, state)
    sim_time = bool(node.get_parameter('use_sim_time').value)
    return CeptonUdpSender(node.get_parameter('cepton_udp_address').value,
                           node.get_parameter('cepton_udp_port').value, encode,
                           partial(lambda clock: clock.now().nanoseconds, node.get_clock()),
                           sim_time, node.get_parameter('cepton_udp_queue_frames').value)


def stats_text(stats: dict) -> str:
    """The sender's share of the node's periodic log line."""
    text = (f'; UDP {stats["frames"]} frames, {stats["packets"]} packets, '
            f'{stats["dropped_frames"]} frames dropped (queue full)')
    if stats.get('restarts'):
        text += f', stream begun afresh {stats["restarts"]} times (clock jumps over 1 s)'
    if stats['errors']:
        text += f', {stats["errors"]} send errors ({stats["last_error"]})'
    return text
