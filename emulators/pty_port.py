"""A pseudo-terminal an emulator writes into, with an optional stable link name and unplug/replug.

The emulator holds the master side; a reader opens the slave path (``/dev/pts/N``) exactly like a USB
serial adapter. Nothing else holds the slave open, so the emulator can tell whether a reader is there
(:meth:`PtyPort.reader_present`), as a USB CDC device sees the host open its port.

A pty's number changes each time one is made, so :class:`PtyPort` can keep a symlink (``link``)
pointing at the current one, as udev does for ``/dev/serial/by-id``: unplug and plug again and a reader
reopening the link finds the new pty.

Example
-------
>>> import os, serial
>>> port = PtyPort()
>>> port.reader_present()
False
>>> reader = serial.Serial(port.name, timeout=1)
>>> port.reader_present()
True
>>> port.write_all(b"hello\\r\\n")
True
>>> reader.read(7)
b'hello\\r\\n'
>>> reader.close(); port.close()
"""

from __future__ import annotations

import os
import select
import threading
import tty

__all__ = ["PtyPort"]


class PtyPort:
    """Master side of a raw pty (no echo, no CR/LF translation), optionally linked at ``link``."""

    def __init__(self, link: str | None = None) -> None:
        self.link = link
        self.master = -1
        self.path = ""
        self._lock = threading.Lock()
        self.plug()

    @property
    def name(self) -> str:
        """What a reader should open: the link when there is one, else the pty path."""
        return self.link or self.path

    @property
    def plugged(self) -> bool:
        return self.master >= 0

    def plug(self) -> None:
        """Create a fresh pty (and point the link at it)."""
        with self._lock:
            if self.master >= 0:
                return
            m, s = os.openpty()
            tty.setraw(s)  # the settings stay with the pty after this end closes
            os.set_blocking(m, False)
            self.master, self.path = m, os.ttyname(s)
            os.close(s)  # held by nobody until a reader opens it: see reader_present()
            if self.link:
                tmp = f"{self.link}.{os.getpid()}.tmp"
                os.symlink(self.path, tmp)
                os.replace(tmp, self.link)

    def unplug(self) -> None:
        """Close the pty: a reader gets an I/O error, and the path disappears, the link with it (as udev
        removes a ``/dev/serial/by-id`` link). A link left behind would name a freed pty number, which the
        next pty made anywhere on the machine takes: a reader reopening it would find a stranger's port."""
        with self._lock:
            if self.master >= 0:
                os.close(self.master)
            self.master = -1
            if self.link and os.path.islink(self.link):
                os.unlink(self.link)

    def close(self) -> None:
        self.unplug()

    def reader_present(self) -> bool:
        """Whether some process has the slave side open (the master reports a hang-up while none has)."""
        if self.master < 0:
            return False
        p = select.poll()
        p.register(self.master, select.POLLOUT)
        return not any(ev & select.POLLHUP for _, ev in p.poll(0))

    def fileno(self) -> int:
        return self.master

    def read_available(self) -> bytes:
        """Whatever the reader has written (commands), without blocking."""
        if self.master < 0:
            return b""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:  # EIO: nobody has the slave open right now
            return b""

    def write_some(self, data: bytes | memoryview) -> int:
        """Write what fits now; 0 when the reader's buffer is full (or the pty is unplugged)."""
        if self.master < 0:
            return 0
        try:
            return os.write(self.master, data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:
            return 0

    def write_all(self, data: bytes, timeout: float = 5.0) -> bool:
        """Write everything, waiting for room up to ``timeout`` s in total; False when it did not fit."""
        view = memoryview(data)
        while view:
            if self.master < 0:
                return False
            n = self.write_some(view)
            view = view[n:]
            if view and not select.select([], [self.master], [], timeout)[1]:
                return False
        return True
