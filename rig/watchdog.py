"""The simulated rig's DAQ output and its external watchdog, in shared memory.

An analog output card holds the last value written to it when the program that writes it
dies; on a real rig a watchdog relay in the amplifier's enable (or in the analog line) opens
when the heartbeat the loop toggles stops for longer than its timeout (see ``docs/rig.md``).
The simulated backend models both: :class:`SharedDAQ` is a small file mapping (the DAQ's held
output, the heartbeat counter, the relay) that the loop writes every cycle, and the watchdog
is a separate process (``python watchdog.py PATH TIMEOUT_S``, started by the backend in its
own session, so it outlives the supervising process) that opens the relay, and so brings the
stacks' voltage to 0 V, once the heartbeat has not changed for ``TIMEOUT_S``.

This file imports the standard library only: the watchdog runs it by path, without the
package, so that it starts in tens of milliseconds.
"""

from __future__ import annotations

import mmap
import os
import struct
import sys
import time

__all__ = ["SharedDAQ", "SIZE", "Watch", "main"]

#: field: (offset, struct format)
FIELDS = {
    "heartbeat": (0, "Q"), "output_V": (8, "d"), "armed": (16, "i"), "relay_open": (20, "i"),
    "cut_at": (24, "d"), "last_beat_at": (32, "d"), "watchdog_pid": (40, "i"), "ready": (44, "i"),
    "quit": (48, "i"), "timeout_s": (56, "d"),
}
SIZE = 64


class SharedDAQ:
    """The mapping at ``path`` (created zeroed when ``create``): the DAQ's output, heartbeat and relay."""

    def __init__(self, path: str, create: bool = False) -> None:
        self.path = path
        flags = os.O_RDWR | (os.O_CREAT | os.O_TRUNC if create else 0)
        fd = os.open(path, flags, 0o600)
        try:
            if create:
                os.ftruncate(fd, SIZE)
            self.mm = mmap.mmap(fd, SIZE)
        finally:
            os.close(fd)

    def get(self, name: str) -> float:
        offset, fmt = FIELDS[name]
        return struct.unpack_from(fmt, self.mm, offset)[0]

    def set(self, name: str, value: float) -> None:
        offset, fmt = FIELDS[name]
        struct.pack_into(fmt, self.mm, offset, int(value) if fmt in "Qi" else float(value))

    @property
    def stack_V(self) -> float:
        """What reaches the stacks: the held output, or 0 V once the relay is open."""
        return 0.0 if self.get("relay_open") else self.get("output_V")

    def close(self) -> None:
        self.mm.close()


class Watch:
    """The watchdog's decision on the times it is given: the relay opens once the heartbeat has not changed for
    longer than ``timeout_s`` while armed (:meth:`poll` says when)."""

    def __init__(self, timeout_s: float, beat: float, now: float) -> None:
        self.timeout_s = float(timeout_s)
        self.last, self.last_t = beat, now

    def poll(self, beat: float, armed: bool, now: float) -> bool:
        """One look at the heartbeat at ``now``: True when the relay must open."""
        if beat != self.last or not armed:
            self.last, self.last_t = beat, now
            return False
        return now - self.last_t > self.timeout_s


def main(argv: list[str]) -> int:
    """``watchdog.py PATH TIMEOUT_S``: watch the heartbeat in PATH; open the relay when it stops."""
    path, timeout_s = argv[0], float(argv[1])
    poll_s = timeout_s / 10.0
    parent = os.getppid()
    daq = SharedDAQ(path)
    daq.set("watchdog_pid", os.getpid())
    daq.set("timeout_s", timeout_s)
    watch = Watch(timeout_s, daq.get("heartbeat"), time.monotonic())
    daq.set("ready", 1)
    while not daq.get("quit"):
        time.sleep(poll_s)
        beat, now = daq.get("heartbeat"), time.monotonic()
        cut = watch.poll(beat, bool(daq.get("armed")), now)
        if watch.last_t == now:
            daq.set("last_beat_at", now)
        elif cut and not daq.get("relay_open"):
            daq.set("relay_open", 1)  # the relay opens: the stacks see 0 V whatever the DAQ holds
            daq.set("cut_at", now)
        if os.getppid() != parent and (daq.get("relay_open") or not daq.get("armed")):
            break  # the supervisor is gone and the output is safe: nothing left to watch
    daq.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
