"""UDP datagrams into a classic pcap file (libpcap format, Ethernet link type), as a
capture of a sensor's traffic would hold them.

Layouts: the libpcap file format (a 24-byte global header, magic 0xa1b2c3d4,
microsecond timestamps, link type 1 = Ethernet; a 16-byte record header per packet),
Ethernet II (RFC 894), IPv4 (RFC 791, header checksum filled) and UDP (RFC 768, checksum 0
= none, allowed on IPv4). The capture time of a packet is the time given for it.
"""
from __future__ import annotations

import struct
from pathlib import Path
from typing import BinaryIO

PCAP_MAGIC = 0xA1B2C3D4
LINKTYPE_ETHERNET = 1
SNAPLEN = 65535
ETHERTYPE_IPV4 = 0x0800
IPPROTO_UDP = 17
MAX_UDP_PAYLOAD = 65507
SENSOR_MAC = bytes.fromhex('020000000001')     # locally administered, unicast
BROADCAST_MAC = b'\xff' * 6


def _ipv4(address: str) -> bytes:
    parts = address.split('.')
    if len(parts) != 4 or not all(p.isdigit() and int(p) < 256 for p in parts):
        raise ValueError(f'not an IPv4 address: {address!r}')
    return bytes(int(p) for p in parts)


def ipv4_checksum(header: bytes) -> int:
    """RFC 791 header checksum: ones' complement of the ones' complement sum of 16-bit words."""
    s = sum(struct.unpack(f'!{len(header) // 2}H', header))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return ~s & 0xFFFF


def udp_frame(payload: bytes, src_ip: str, dst_ip: str, src_port: int, dst_port: int,
              ident: int = 0) -> bytes:
    """Ethernet II + IPv4 + UDP around ``payload`` (destination MAC: broadcast)."""
    if len(payload) > MAX_UDP_PAYLOAD:
        raise ValueError(f'UDP payload of {len(payload)} bytes exceeds {MAX_UDP_PAYLOAD}')
    udp = struct.pack('!HHHH', src_port, dst_port, 8 + len(payload), 0) + payload
    ip = struct.pack('!BBHHHBBH4s4s', 0x45, 0, 20 + len(udp), ident & 0xFFFF, 0x4000, 64,
                     IPPROTO_UDP, 0, _ipv4(src_ip), _ipv4(dst_ip))
    ip = ip[:10] + struct.pack('!H', ipv4_checksum(ip)) + ip[12:]
    return BROADCAST_MAC + SENSOR_MAC + struct.pack('!H', ETHERTYPE_IPV4) + ip + udp


class PcapWriter:
    """Writes UDP datagrams to a pcap file one at a time (memory flat in the run length).

    ``with PcapWriter(path, src_ip, dst_ip, port) as w: w.write(t_us, payload)``;
    t_us: capture time, microseconds since the Unix epoch.
    """

    def __init__(self, path: str | Path, src_ip: str = '192.168.1.201',
                 dst_ip: str = '255.255.255.255', dst_port: int = 8808,
                 src_port: int | None = None):
        self.path = Path(path)
        self.src_ip, self.dst_ip = src_ip, dst_ip
        _ipv4(src_ip), _ipv4(dst_ip)
        self.dst_port = dst_port
        self.src_port = dst_port if src_port is None else src_port
        self.count = 0
        self._f: BinaryIO | None = None

    def __enter__(self) -> 'PcapWriter':
        self._f = open(self.path, 'xb')
        self._f.write(struct.pack('<IHHiIII', PCAP_MAGIC, 2, 4, 0, 0, SNAPLEN, LINKTYPE_ETHERNET))
        return self

    def write(self, t_us: int, payload: bytes) -> None:
        if t_us < 0 or t_us >= 2**32 * 1_000_000:
            raise ValueError(f'capture time {t_us} us does not fit a pcap record (0 .. 2^32 s)')
        frame = udp_frame(payload, self.src_ip, self.dst_ip, self.src_port, self.dst_port,
                          self.count)
        sec, usec = divmod(int(t_us), 1_000_000)
        self._f.write(struct.pack('<IIII', sec, usec, len(frame), len(frame)) + frame)
        self.count += 1

    def __exit__(self, *exc) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None
