"""Files written whole or not at all: the one atomic write the sweep store and the rollout checkpoints share."""

from __future__ import annotations

import contextlib
import errno
import itertools
import os
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from spikejax.errors import UserError

__all__ = ["atomic_file"]

_NO_SPACE = (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC))
_temporary_names = itertools.count()


@contextlib.contextmanager
def atomic_file(path: Path, *, when_full: str | None = None) -> Iterator[BinaryIO]:
    """Write ``path`` whole or not at all: temporary file, fsync, rename, fsync of the directory.

    Args:
        path: the file to write.
        when_full: what to tell the user when the disk is full (after "no space
            left on the disk of DIR (writing NAME): "); without it a full disk is
            reported as any other failed write.

    Raises:
        UserError: one line naming ``path`` when the write fails; the old file, if
            any, is left as it was and no temporary file remains.
    """
    path = Path(path)
    temporary = path.parent / f".{path.name}.{os.getpid()}.{next(_temporary_names)}.tmp"
    try:
        with open(temporary, "xb") as file:
            yield file
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        if when_full is not None and isinstance(err, OSError) and err.errno in _NO_SPACE:
            raise UserError(f"no space left on the disk of {path.parent} (writing {path.name}): {when_full}") from None
        if isinstance(err, OSError) and not isinstance(err, UserError):
            raise UserError(f"cannot write {path}: {err.strerror or err}") from None
        raise
    # The rename is durable only once the directory entry is; not every OS can open one.
    with contextlib.suppress(OSError, AttributeError):
        fd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
