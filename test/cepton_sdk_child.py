"""Run one of Cepton's decoders (PyPI ``cepton-sdk2`` / ``cepton-sdk3``, proprietary,
installed by the user: never shipped here) in a child process and save every point it
returns, frame by frame, to an .npz file.

    python cepton_sdk_child.py sdk2|sdk3 pcap FILE OUT.npz [FRAME_MS]
    python cepton_sdk_child.py sdk2|sdk3 udp PORT OUT.npz SECONDS [FRAME_MS]

The parent (test/test_cepton_sdk.py) runs this with a timeout, in a private working and
cache directory: a malformed packet once made SDK3 hang and try to allocate ~1 TB.
Only the SDKs' public Python API is used. Known behaviours handled by the parent, not here:
SDK3 starts a frame at each parity toggle and holds the last frame until the next one;
the 3.0.17 Python frame FIFO swaps ``channel_ids`` and ``flags`` (``SWAPPED`` below).
"""
from __future__ import annotations

import sys
import time

import numpy as np

FIELDS = ('timestamps', 'x_raw', 'y_raw', 'z_raw', 'reflectivities_raw', 'channel_ids', 'flags')


def _collect(get_frame, done) -> dict:
    frames = []
    while True:
        f = get_frame()
        if f is not None:
            frames.append({k: np.array(getattr(f, k)) for k in FIELDS})
        elif done():
            break
    out = {k: np.concatenate([f[k] for f in frames]) if frames else np.zeros(0)
           for k in FIELDS}
    out['frame'] = (np.concatenate([np.full(len(f['timestamps']), i) for i, f in enumerate(frames)])
                    if frames else np.zeros(0, int))
    return out


def run_sdk2(source: str, arg: str, seconds: float, frame_ms: int) -> dict:
    import cepton_sdk2 as sdk
    sdk.Initialize()
    sdk.EnableFrameFifo(frameMode=frame_ms, nFrames=400)
    if source == 'pcap':
        sdk.LoadPcap(arg, speed=0, pause_on_load=True)
        sdk.ReplayPcap()

        def get():
            f = sdk.FrameFifoGetFrame(timeout=500)
            if f is not None:
                sdk.FrameFifoRelease()
            return f
        out = _collect(get, lambda: sdk.ReplayIsFinished() and sdk.FrameFifoEmpty())
    else:
        from cepton_sdk2 import c
        c.StartNetworkingOnPort(int(arg))
        print('READY', flush=True)
        end = time.monotonic() + seconds

        def get():
            f = sdk.FrameFifoGetFrame(timeout=200)
            if f is not None:
                sdk.FrameFifoRelease()
            return f
        out = _collect(get, lambda: time.monotonic() > end)
    out['version'] = np.array(sdk.GetVersion())
    return out


def run_sdk3(source: str, arg: str, seconds: float, frame_ms: int) -> dict:
    import cepton_sdk3 as sdk
    from cepton_sdk3 import c
    sdk.initialize()
    sdk.enable_frame_fifo(frame_mode=frame_ms, num_frames=400)
    if source == 'pcap':
        sdk.load_pcap(arg, speed=100, pause_on_load=True)
        sdk.replay_play()
        out = _collect(lambda: sdk.frame_fifo_get_frame(timeout=500),
                       lambda: bool(sdk.replay_is_finished()))
    else:
        c.StartNetworkingOnPort(int(arg))
        print('READY', flush=True)
        end = time.monotonic() + seconds
        out = _collect(lambda: sdk.frame_fifo_get_frame(timeout=200),
                       lambda: time.monotonic() > end)
    out['version'] = np.array(sdk.get_version())
    out['sensors'] = np.array(c.GetSensorCount())
    return out


def main(argv: list[str]) -> int:
    which, source, arg, out_path = argv[:4]
    seconds = float(argv[4]) if source == 'udp' else 0.0
    rest = argv[5:] if source == 'udp' else argv[4:]
    frame_ms = int(rest[0]) if rest else 0
    run = run_sdk2 if which == 'sdk2' else run_sdk3
    np.savez(out_path, **run(source, arg, seconds, frame_ms))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
