"""Files that hold secrets (passwords, private keys, a rover's config.json): mode 0600 from the first byte.

A file created with the default mode and chmod'ed afterwards is readable by anyone for the moment in between, and a
file rewritten in place is torn if the writer dies halfway. :func:`write_private` does neither: the content goes to
a temporary file in the same directory opened with ``O_CREAT | O_EXCL`` and mode 0600 (the process umask can only
remove bits), is flushed to disk, then renamed over the target, so a reader sees the old file or the new one.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from pathlib import Path

PRIVATE_MODE = 0o600


def write_private(path: Path, content: str | bytes, mode: int = PRIVATE_MODE) -> Path:
    """Atomically replace ``path`` with ``content``; the file never exists with wider permissions than ``mode``."""
    data = content.encode("utf-8") if isinstance(content, str) else content
    temporary = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), mode)
    try:
        with os.fdopen(fd, "wb") as out:
            os.fchmod(out.fileno(), mode)  # a narrower umask would have taken bits the owner needs
            out.write(data)
            out.flush()
            os.fsync(out.fileno())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            temporary.unlink()
        raise
    return path


def private_dir(path: Path) -> Path:
    """Create ``path`` (and parents) if needed; a directory created here is 0700."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    return path
