"""Host files read from the Cortex-M4F build under QEMU by ARM semihosting (``BKPT 0xAB``;
``run-qemu.py`` starts QEMU with ``-semihosting``): a :class:`HostFile` has the file
methods a :class:`lodestar.firmware.database.Database` source and the F-RAM model
(:mod:`lodestar.regress.fram`) read through, so a star database that does not fit the
build's flash beside the frozen one stays a file of the host.  MicroPython on ARM only (the
call is inline Thumb assembly); the QEMU runner (:mod:`lodestar.regress.qemu`) imports it
there and nowhere else.  Under ``-icount`` a call costs the guest one instruction: the host
does the reading, so it adds nothing to the frame's ticks."""

from array import array

import micropython
import uctypes

SYS_OPEN = 0x01
SYS_CLOSE = 0x02
SYS_READ = 0x06
SYS_SEEK = 0x0A
SYS_FLEN = 0x0C
MODE_RB = 1
"""The semihosting ``SYS_OPEN`` mode of ``"rb"``."""


@micropython.asm_thumb
def _call(r0, r1):
    """Semihosting operation ``r0`` with the parameter block at ``r1``: its result."""
    data(2, 0xBEAB)  # noqa: F821 (the inline assembler's directive)


class HostFile(object):
    """A host file opened read-only (raises ``OSError`` when it cannot be): ``seek(pos,
    whence)``, ``tell()``, ``readinto(buf)`` (bytes read), ``close()``."""

    def __init__(self, path):
        self._name = bytes(path, "utf-8") + b"\0"         # QEMU reads a C string
        self._block = array("I", [uctypes.addressof(self._name), MODE_RB,
                                  len(self._name) - 1])
        self.handle = _call(SYS_OPEN, self._block)
        if self.handle < 0 or self.handle > 0x7FFFFFFF:
            raise OSError("semihosting cannot open " + path)
        self._block[0] = self.handle
        self.size = _call(SYS_FLEN, self._block)
        self.pos = 0

    def seek(self, pos, whence=0):
        self.pos = pos if whence == 0 else (self.pos + pos if whence == 1 else self.size + pos)
        return self.pos

    def tell(self):
        return self.pos

    def readinto(self, buf):
        n = len(buf)
        if self.pos + n > self.size:
            n = self.size - self.pos if self.pos < self.size else 0
        if n == 0:
            return 0
        block = self._block
        block[1] = self.pos
        if _call(SYS_SEEK, block) != 0:
            raise OSError("semihosting seek failed")
        block[1] = uctypes.addressof(buf)
        block[2] = n
        left = _call(SYS_READ, block)
        self.pos += n - left
        return n - left

    def close(self):
        if self.handle >= 0:
            self._block[0] = self.handle
            _call(SYS_CLOSE, self._block)
            self.handle = -1
