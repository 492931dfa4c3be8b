"""What the C decoders (libjpeg, libpng, LibRaw, OpenEXR) print, caught instead of printed.

The decoders write their warnings straight to file descriptor 2, past Python, ``-q`` and the
progress bar. :func:`captured` points fd 2 at a temporary file for the length of one decode and
hands back what was written there, so that the caller can judge it (libjpeg's "Corrupt JPEG data"
stops the file: :func:`corruption`) and report it in its own words. While fd 2 is pointed away,
Python's own writes to ``sys.stderr`` wait (:func:`guard_python_stderr` wraps it in a stream that
takes the same lock), so that no line of ours is caught by mistake.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import threading

_LOCK = threading.RLock()

#: Decoder messages that mean the pixels are not all from the file (libjpeg fills what is missing
#: with grey and warns; LibRaw says so when data runs out; libpng when a stream ends early).
CORRUPTION = re.compile(
    r"Corrupt JPEG data|Premature end of JPEG file|Invalid SOS parameters|Inconsistent progression sequence|"
    r"Huffman table 0x[0-9a-f]+ was not defined|Bogus (marker length|Huffman table definition|DQT index)|"
    r"data corrupted|Unexpected end of file|Not enough image data|Read Error|extra compressed data|"
    r"too much image data|IDAT: (CRC|incorrect)|decompression error", re.IGNORECASE)


class _LockedStream:
    """A text stream whose writes wait while a decode has fd 2 (everything else passes through)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text):
        with _LOCK:
            return self._stream.write(text)

    def writelines(self, lines):
        with _LOCK:
            return self._stream.writelines(lines)

    def flush(self):
        with _LOCK:
            return self._stream.flush()

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextlib.contextmanager
def guard_python_stderr():
    """``sys.stderr`` wrapped in a :class:`_LockedStream` for the length of the block (a CLI run)."""
    previous = sys.stderr
    if previous is None or isinstance(previous, _LockedStream):
        yield
        return
    sys.stderr = _LockedStream(previous)
    try:
        yield
    finally:
        if isinstance(sys.stderr, _LockedStream) and sys.stderr._stream is previous:
            sys.stderr = previous


@contextlib.contextmanager
def captured():
    """Point fd 2 at a temporary file for the block; yields a list that receives, after the block, the
    text written there (one string, decoded leniently). One decode at a time holds fd 2."""
    out = []
    with _LOCK:
        with contextlib.suppress(Exception):
            sys.stderr.flush()
        try:
            saved = os.dup(2)
        except OSError:  # no fd 2 at all: nothing to catch
            yield out
            return
        sink = tempfile.TemporaryFile()
        try:
            os.dup2(sink.fileno(), 2)
            try:
                yield out
            finally:
                os.dup2(saved, 2)
        finally:
            os.close(saved)
            sink.seek(0)
            out.append(sink.read(1 << 16).decode("utf-8", "replace"))
            sink.close()


def lines(text):
    """The distinct non-empty lines of a capture, in order."""
    seen = []
    for line in text.splitlines():
        line = line.strip()
        if line and line not in seen:
            seen.append(line)
    return seen


def corruption(text):
    """The first line of ``text`` that says the decoder made up pixels, or None."""
    return next((line for line in lines(text) if CORRUPTION.search(line)), None)
